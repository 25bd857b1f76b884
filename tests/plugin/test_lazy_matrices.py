"""LazyMatrices: K and M built once; M keeps K's index arrays when the patterns agree (issue 14's memory)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.adapter import SolverAdapter, checked_matrices
from stepnf.plugin.lazy_matrices import LazyMatrices


def chain(n: int) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """A spring chain's K and consistent-mass M: one tridiagonal pattern, separate index arrays."""
    K = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr")
    M = sp.diags([np.ones(n - 1), 4 * np.ones(n), np.ones(n - 1)], [-1, 0, 1], format="csr") / 6
    return K, M


class Chain(LazyMatrices, SolverAdapter):
    builds = 0

    def __init__(self, n: int, lumped: bool = False):
        self.n, self.lumped, self.timings = n, lumped, {}

    @property
    def n_dofs(self) -> int:
        return self.n

    def _build_stiffness(self):
        type(self).builds += 1
        return chain(self.n)[0]

    def _build_mass(self):
        type(self).builds += 1
        return sp.identity(self.n, format="csr") if self.lumped else chain(self.n)[1]

    def _internal_force(self, u):
        return self.stiffness_matrix() @ u


def test_mass_shares_the_stiffness_index_arrays():
    ad = Chain(50)
    K_ref, M_ref = chain(50)
    assert ad.mass_matrix().indices is not None and "stiffness" not in ad.timings  # M first: nothing to share
    K, M = ad.stiffness_matrix(), ad.mass_matrix()
    assert np.shares_memory(M.indices, K.indices) and np.shares_memory(M.indptr, K.indptr)
    assert (M != M_ref).nnz == 0 and (K != K_ref).nnz == 0
    # the core's checked copies keep sharing (no copy of the indices on the way)
    Kc, Mc = checked_matrices(ad)
    assert np.shares_memory(Mc.indices, Kc.indices)
    np.testing.assert_array_equal((Mc @ np.arange(50.0)), M_ref @ np.arange(50.0))


def test_unsorted_patterns_are_not_shared():
    """Matrices whose column indices are not sorted (a solver's own dof order, e.g. the kratos adapter's
    equation numbering) keep their own index arrays: scipy sorts them in place when an operation needs it
    (``M.max()``), which through shared arrays scrambled K's entries (the harness then found K asymmetric)."""
    K_ref, M_ref = chain(30)

    def unsorted(A):  # the same matrix with each row's entries stored in reverse column order
        order = np.concatenate([np.arange(a, b)[::-1] for a, b in zip(A.indptr[:-1], A.indptr[1:])])
        return sp.csr_matrix((A.data[order], A.indices[order], A.indptr.copy()), shape=A.shape)

    K_un, M_un = unsorted(K_ref), unsorted(M_ref)
    assert not K_un.has_sorted_indices and (K_un != K_ref).nnz == 0

    class Unsorted(Chain):
        def _build_stiffness(self):
            return K_un.copy()

        def _build_mass(self):
            return M_un.copy()

    ad = Unsorted(30)
    M = ad.mass_matrix()
    K = ad.stiffness_matrix()
    assert M.max() == M_ref.max()  # scipy's max() first sorts M's indices in place (sum_duplicates)
    assert (K != K_ref).nnz == 0 and (ad.mass_matrix() != M_ref).nnz == 0


def test_different_patterns_are_left_alone():
    ad = Chain(20, lumped=True)
    K, M = ad.stiffness_matrix(), ad.mass_matrix()
    assert M.nnz == 20 and K.nnz == 58 and not np.shares_memory(M.indices, K.indices)
    assert (M != sp.identity(20)).nnz == 0


def test_built_once():
    Chain.builds = 0
    ad = Chain(10)
    for _ in range(3):
        ad.stiffness_matrix(), ad.mass_matrix()
    assert Chain.builds == 2
