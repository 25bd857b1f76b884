"""Refined low modes (issue 35, stepnf.linalg.refined_modes): frequencies of a stiff model at the round-off of its
own matrices, whatever the path and the BLAS thread count.

The model is the linear part of SSMTool's clamped von Karman beam (bench/polynomial_sparse.py: L = 1, b = 1,
E = 70e9, rho = 2700; an axial bar and a Hermite beam per element), assembled here. The reference eigenvalue of a
mode is the Rayleigh quotient of scipy's dense eigenvector in exact rational arithmetic: second order in the
vector's error (that vector is off by ~eps lambda_max / gap ~ 1e-9 at most along the low modes), so it is the
eigenvalue of the stored matrices to ~1e-16, whatever the rounding of ``eigh``'s own eigenvalue.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from fractions import Fraction

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

from stepnf.linalg.modal_analysis import lambda_scale, modal_analysis
from stepnf.linalg.null_space import energy_ratios
from stepnf.linalg.refined_modes import FAR_SHIFT


def clamped_beam(n_el: int, h: float = 1e-3) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """K, M (3 n_el - 3 dofs: u, w, theta per inner node) of the clamped beam of thickness ``h`` (m)."""
    L, b, E, rho = 1.0, 1.0, 70e9, 2700.0
    le, A, I = L / n_el, b * h, b * h**3 / 12
    Ke, Me = np.zeros((6, 6)), np.zeros((6, 6))
    a, w = [0, 3], [1, 2, 4, 5]
    Ke[np.ix_(a, a)] = E * A / le * np.array([[1, -1], [-1, 1]])
    Me[np.ix_(a, a)] = rho * A * le / 6 * np.array([[2, 1], [1, 2]])
    Ke[np.ix_(w, w)] = E * I / le**3 * np.array([[12, 6 * le, -12, 6 * le], [6 * le, 4 * le**2, -6 * le, 2 * le**2],
                                                 [-12, -6 * le, 12, -6 * le], [6 * le, 2 * le**2, -6 * le, 4 * le**2]])
    Me[np.ix_(w, w)] = rho * A * le / 420 * np.array([[156, 22 * le, 54, -13 * le], [22 * le, 4 * le**2, 13 * le, -3 * le**2],
                                                      [54, 13 * le, 156, -22 * le], [-13 * le, -3 * le**2, -22 * le, 4 * le**2]])
    dofs = 3 * np.arange(n_el)[:, None] + np.arange(6)
    rows, cols = np.repeat(dofs, 6, axis=1).ravel(), np.tile(dofs, 6).ravel()
    free = np.arange(3, 3 * n_el)
    K = sp.csr_matrix((np.tile(Ke.ravel(), n_el), (rows, cols)))[free][:, free]
    M = sp.csr_matrix((np.tile(Me.ravel(), n_el), (rows, cols)))[free][:, free]
    return K.tocsr(), M.tocsr()


def exact_rayleigh(K: sp.spmatrix, M: sp.spmatrix, x: np.ndarray) -> float:
    """``x^T K x / x^T M x`` in rational arithmetic (the stored floats are exact rationals), rounded once."""
    xs = [Fraction(float(v)) for v in x]

    def quad(A):
        A = A.tocoo()
        return sum(xs[i] * Fraction(float(a)) * xs[j] for i, j, a in zip(A.row, A.col, A.data))
    return float(quad(K) / quad(M))


def reference_modes(K, M, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The first ``k`` frequencies (exact Rayleigh quotients of scipy's eigenvectors) and those vectors (n, k)."""
    _, V = sla.eigh(K.toarray(), M.toarray(), subset_by_index=[0, k - 1])
    return np.sqrt([exact_rayleigh(K, M, V[:, j]) for j in range(k)]), V


CHILD = """
import json, sys
import numpy as np, scipy.sparse as sp
from stepnf.linalg.modal_analysis import modal_analysis
z = np.load(sys.argv[1])
K, M = (sp.csr_matrix((z[k + "_data"], z[k + "_indices"], z[k + "_indptr"])) for k in "KM")
print(json.dumps(modal_analysis(K, M, 4).omega[:4].tolist()))
"""


def test_dense_path_frequencies_do_not_depend_on_the_thread_count(tmp_path):
    """The 297-dof beam (L/h = 1000): its fundamental's energy ratio |phi^T K phi| / |phi|^T |K| |phi| is 1e-7,
    lambda_max / lambda_1 ~ 1e8. Before: the first four frequencies up to 4.0e-9 off with one OpenBLAS thread, 2.7e-9
    with two (scipy's eigh, backward stable in norm only); now within 2e-11 of the exact reference with either
    (measured at most 5.6e-12; eps over the energy ratio, 2e-9, bounds what the rounding of the products with K may
    leave, the random rounding stays far below it)."""
    K, M = clamped_beam(100)
    ref, V = reference_modes(K, M, 4)
    assert K.shape[0] == 297 and energy_ratios(K, V[:, :1])[0] < 2e-7
    model = tmp_path / "beam.npz"
    np.savez(model, **{f"{k}_{a}": getattr(A, a) for k, A in (("K", K), ("M", M)) for a in ("data", "indices", "indptr")})
    runs = {}
    for threads in ("1", "2"):
        env = {**os.environ, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}
        out = subprocess.run([sys.executable, "-c", CHILD, str(model)], env=env, capture_output=True, text=True,
                             check=True)
        runs[threads] = np.array(json.loads(out.stdout.strip().splitlines()[-1]))
        np.testing.assert_allclose(runs[threads], ref, rtol=2e-11, err_msg=f"{threads} BLAS threads")
    np.testing.assert_allclose(runs["1"], runs["2"], rtol=2e-11)


@pytest.mark.parametrize("backend", ["auto", "superlu"])
def test_sparse_path_on_a_stiff_model_agrees_with_the_dense_one(backend):
    """A thin beam (h = 1e-5, 297 dofs): the sparse path's shift -1e-10 lambda_scale lies 719 lambda_1 away, so the
    modes are refined on K - s M, s = -1e-3 lambda_1. Before: w1 2.4e-10 (dense LU) and 1.9e-10 (SuperLU) above the
    dense refined one (the rounding of K - sigma M's entries, alike in every element, adds up over the mode); now
    within 5e-11 (measured 3.5e-12; the floor eps / r, r = 1e-7 the fundamental's energy ratio, bounds it by 2e-9)."""
    K, M = clamped_beam(100, h=1e-5)
    dense = modal_analysis(K, M, 3)
    assert 1e-10 * lambda_scale(K, M) > 100 * FAR_SHIFT * dense.omega[0] ** 2  # the first shift is far
    sparse = modal_analysis(K, M, 3, dense_limit=0, backend=backend)
    assert sparse.solver.endswith(", refined") and not sparse.complete
    # each frequency is the exact Rayleigh quotient of its own vector (before: 1.9e-10 to 2.4e-10 above it)
    own = np.sqrt([exact_rayleigh(K, M, sparse.phi[:, j]) for j in range(3)])
    np.testing.assert_allclose(sparse.omega[:3], own, rtol=5e-11)
    np.testing.assert_allclose(sparse.omega[:3], dense.omega[:3], rtol=5e-11)
    # the refined modes stay M-orthonormal, and M-orthogonal to those above them
    G = sparse.phi.T @ (M @ sparse.phi)
    assert np.abs(G - np.eye(G.shape[0])).max() < 1e-12
    G = dense.phi.T @ (M @ dense.phi)
    assert np.abs(G - np.eye(G.shape[0])).max() < 1e-12


class _NaNSolves:
    """A factorisation whose solves return NaN (K - s M singular in floating point, factorised anyway)."""

    def solve(self, b, count=True):
        return np.full(np.shape(b), np.nan)

    def release(self):
        pass


def test_a_failed_refinement_leaves_the_dense_solve_as_it_was(monkeypatch):
    """Where the refinement's solves break down (NaN), the dense path returns eigh's modes unchanged (frequencies to
    the bit: the old numbers) rather than a ValueError traceback from scipy's eigh (before: "array must not contain
    infs or NaNs") or NaN frequencies; rayleigh_ritz itself raises a NumericalError (exit 3, one line)."""
    import stepnf.linalg.refined_modes as rm
    from stepnf.errors import NumericalError

    K, M = clamped_beam(20)
    lam = sla.eigh(K.toarray(), M.toarray())[0]  # the dense path's call (eigvals_only rounds differently)
    monkeypatch.setattr(rm, "factorize", lambda *a, **k: _NaNSolves())
    b = modal_analysis(K, M, 3)
    assert np.array_equal(b.omega, np.sqrt(lam))
    G = b.phi.T @ (M @ b.phi)
    assert np.abs(G - np.eye(G.shape[0])).max() < 1e-12
    with pytest.raises(NumericalError, match="non-finite"):
        rm.rayleigh_ritz(K, M, b.phi[:, :2], np.zeros((K.shape[0], 0)), -1.0, _NaNSolves().solve)
