"""Modal analysis: dense and sparse shift-invert paths agree; rigid modes and degenerate pairs are found.

Tolerances: the dense LAPACK solve and shift-invert Lanczos (ARPACK tol
1e-12) both resolve these well-conditioned 30-dof systems to round-off:
measured frequency differences <= 2.1e-15 relative and mode-shape
differences <= 2.5e-13 (all three back ends, with 0, 1 and 6 rigid modes).
1e-10 on frequencies and 1e-8 on mode shapes (eigenvector errors scale like
the eigenvalue error over the spectral gap) leave wide margins. Before the
deflation of the rigid modes in ``stepnf.linalg.modal_analysis`` the sparse path was off by
8e-5 on the 6-rigid-mode system: this test caught it.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.runtime.counters import Counters
from stepnf.linalg.modal_analysis import modal_analysis
from helpers.systems import solver_backends, modal_to_physical, random_system


_backends = solver_backends


@pytest.fixture(scope="module")
def rigid6():
    M, K, _, _ = random_system(30, 3, rigid=6)
    return sp.csr_matrix(M), sp.csr_matrix(K)


def test_dense_path_mass_normalised_and_rigid_detected(rigid6):
    M, K = rigid6
    basis = modal_analysis(K, M)
    assert basis.solver == "dense" and basis.complete
    assert basis.rigid.shape == (30, 6) and basis.n_elastic == 24
    Phi = np.column_stack([basis.rigid, basis.phi])
    np.testing.assert_allclose(Phi.T @ (M @ Phi), np.eye(30), atol=1e-12)
    np.testing.assert_allclose(basis.phi.T @ (K @ basis.phi), np.diag(basis.omega**2), atol=1e-11)
    # rigid modes: K R = 0 to round-off relative to ||K||
    assert np.abs(K @ basis.rigid).max() < 1e-12 * abs(K).max()
    assert np.all(np.diff(basis.omega) > 0)


@pytest.mark.parametrize("backend", _backends())
def test_sparse_shift_invert_equals_dense(rigid6, backend):
    M, K = rigid6
    dense = modal_analysis(K, M)
    counters = Counters()
    sparse = modal_analysis(K, M, 10, dense_limit=0, backend=backend, counters=counters)
    assert sparse.solver.startswith("shift-invert") and not sparse.complete
    assert sparse.rigid.shape[1] == 6
    assert sparse.n_elastic >= 10
    m = sparse.n_elastic
    # measured: <= 2.1e-15 relative
    np.testing.assert_allclose(sparse.omega, dense.omega[:m], rtol=1e-10)
    # same sign convention (largest entry positive) -> same vectors
    np.testing.assert_allclose(sparse.phi, dense.phi[:, :m], atol=1e-8)
    # rigid subspaces coincide: the M-projection of one on the other is orthogonal
    C = dense.rigid.T @ (M @ sparse.rigid)
    np.testing.assert_allclose(np.linalg.svd(C, compute_uv=False), np.ones(6), atol=1e-10)
    assert counters.factorizations == 1 and counters.eigensolver_solves > 0


@pytest.mark.parametrize("dense_limit", [2000, 0], ids=["dense", "sparse"])
def test_degenerate_pairs_reported(dense_limit):
    # elastic spectrum with two exact pairs and one near pair (1e-3 apart, not degenerate at 1e-4)
    omega = np.sqrt([1.0, 2.0, 2.0, 3.5, 5.0, 5.0, 7.0, 7.007, 9.0, 11.0, 12.0, 13.0, 14.0, 15.0])
    m = len(omega)
    M, K, _, _ = modal_to_physical(omega, np.zeros((m,) * 3), np.zeros((m,) * 4), seed=8, rigid=3)
    basis = modal_analysis(sp.csr_matrix(K), sp.csr_matrix(M), 8, dense_limit=dense_limit)
    assert basis.rigid.shape[1] == 3
    np.testing.assert_allclose(basis.omega[:8], omega[:8], rtol=1e-10)
    assert basis.degenerate_groups[:2] == [[1, 2], [4, 5]]
    assert [6, 7] not in basis.degenerate_groups
    assert basis.twins(1) == [2] and basis.twins(5) == [4] and basis.twins(0) == []
    # a degenerate pair is still M-orthonormal
    P = basis.phi[:, [1, 2, 4, 5]]
    np.testing.assert_allclose(P.T @ (M @ P), np.eye(4), atol=1e-10)


def test_rigid_modes_count_override():
    """A scene may state the number of rigid modes instead of relying on the tolerance."""
    M, K, _, _ = random_system(12, 4, rigid=2)
    for kwargs in ({}, {"rigid_modes": 2}, {"rigid_modes": 2, "dense_limit": 0}):
        basis = modal_analysis(sp.csr_matrix(K), sp.csr_matrix(M), 4, **kwargs)
        assert basis.rigid.shape[1] == 2 and basis.n_elastic >= 4
    # a tolerance too tight to see the rigid modes: the count given by the scene still sets them apart
    basis = modal_analysis(sp.csr_matrix(K), sp.csr_matrix(M), rigid_tolerance=0.0, rigid_modes=2)
    assert basis.rigid.shape[1] == 2 and basis.omega[0] > 0.5


def test_degenerate_pairs_get_a_solver_independent_orientation():
    """Two different bases of the same degenerate eigenspace come out identical once oriented."""
    from stepnf.linalg.modal_analysis import ModalBasis, orient_degenerate, probe_vector

    rng = np.random.default_rng(5)
    n = 12
    M = sp.diags(rng.uniform(1, 2, n)).tocsr()
    L = np.sqrt(M.diagonal())
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V = Q / L[:, None]  # M-orthonormal
    omega = np.array([1.0, 2.0, 2.0, 3.0])
    X = rng.uniform(size=(n, 3))
    D = np.tile([0, 1, 2], n // 3)
    probe = probe_vector(X, D, n)
    c, s = np.cos(0.7), np.sin(0.7)
    bases = []
    for R2 in (np.eye(2), np.array([[c, -s], [s, c]]), np.array([[0.0, 1.0], [1.0, 0.0]])):
        phi = V[:, :4].copy()
        phi[:, 1:3] = phi[:, 1:3] @ R2
        b = ModalBasis(omega=omega.copy(), phi=phi, rigid=np.zeros((n, 0)), rigid_eigenvalues=np.zeros(0),
                       degenerate_groups=[[1, 2]])
        bases.append(orient_degenerate(b, M, probe).phi)
    for other in bases[1:]:
        assert np.allclose(other, bases[0], atol=1e-13)
    # the probe depends on positions, not on the dof order
    perm = rng.permutation(n)
    assert np.allclose(probe_vector(X[perm], D[perm], n), probe[perm])


def test_matrix_diagonal_is_read_once_per_matrix():
    """stepnf.linalg.factorization.matrix_diagonal: the diagonal, kept for the same object (read-only), read again for a
    new one, dropped when the matrix is collected."""
    import gc

    import scipy.sparse as sp

    from stepnf.linalg import factorization as linalg
    A = sp.random(50, 50, density=0.2, random_state=1, format="csr") + sp.eye(50, format="csr")
    d = linalg.matrix_diagonal(A)
    assert np.array_equal(d, A.diagonal()) and not d.flags.writeable
    assert linalg.matrix_diagonal(A) is d
    B = A.copy()
    assert linalg.matrix_diagonal(B) is not d and np.array_equal(linalg.matrix_diagonal(B), d)
    key = id(B)
    del B
    gc.collect()
    assert key not in linalg._DIAGONALS
    assert np.array_equal(linalg.matrix_diagonal(np.diag([1.0, 2.0])), [1.0, 2.0])  # a dense matrix too
