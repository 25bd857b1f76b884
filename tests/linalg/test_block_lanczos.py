"""The block shift-invert Lanczos (stepnf/linalg/block_lanczos.py) against closed forms, dense solves and ARPACK.

Models (tests/helpers/pencils.py): the clamped membrane (closed-form spectrum, exact twin pairs) and the
braced lattice (six rigid modes projected out, square symmetry: exact pairs), on MUMPS factorisations.

Tolerances. The iteration stops when each Ritz pair's residual is below 1e-12 of its Ritz value theta =
1 / (lam - sigma) (ARPACK's own criterion); for a symmetric operator the eigenvalue error is at most that
residual and, once converged, the residual squared over the gap: lam within ~1e-12 relative of the
exact one, plus the factorisation's round-off u * cond(K) ~ 1e-16 * 1e3 on these models. Checked at
1e-10 (ARPACK's runs are held to the same, tests/linalg/test_eigen_extension.py). Eigenvectors move by
residual / gap (Davis-Kahan): relative gaps >= 2e-3 in lam on the modes compared, so ~5e-10; checked at
1e-8, twins as eigenspaces. Measured: eigenvalues within 4e-15 of the closed form, subspaces 3e-13.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from helpers.pencils import eigenspaces, lattice, membrane, outside
from stepnf.linalg import block_lanczos, eigen_extension
from stepnf.linalg.block_lanczos import BlockBreakdown, block_shift_invert_modes
from stepnf.linalg.eigen_extension import ARPACK_TOL, START_SEED, shift_invert_modes
from stepnf.linalg.factorization import factorize
from stepnf.linalg.modal_analysis import modal_analysis

LAM_RTOL = 1e-10  # module docstring
SHAPE_TOL = 1e-8  # module docstring
TWIN = 1e-8  # eigenvalues closer than this (relative) form one eigenspace


def assert_modes(lam, vec, lam_ref, vec_ref, M) -> None:
    """(lam, vec) are the reference's first modes: eigenvalues, M-orthonormality, eigenspaces."""
    k = len(lam)
    np.testing.assert_allclose(lam, lam_ref[:k], rtol=LAM_RTOL)
    np.testing.assert_allclose(vec.T @ (M @ vec), np.eye(k), atol=1e-10)
    gaps = np.diff(lam_ref[:k + 1]) / lam_ref[1:k + 1]
    assert gaps[gaps > TWIN].min() > 2e-3  # the premise of SHAPE_TOL
    for g in eigenspaces(lam_ref[:k + 1], TWIN):
        mine = [s for s in g if s < k]  # a twin pair cut by k: the one found lies in the pair's span
        if mine:
            assert outside(vec[:, mine], vec_ref[:, g], M) <= SHAPE_TOL


def sigma_fac(K, M):
    sigma = -1e-3
    return sigma, factorize((K - sigma * M).tocsr(), backend="mumps")


@pytest.mark.parametrize("block", [1, 4, 8])
def test_clamped_membrane_against_its_closed_form(block):
    K, M, omega = membrane(30, free=False)
    sigma, fac = sigma_fac(K, M)
    calls = [0]
    lam, vec = block_shift_invert_modes(M, sigma, fac.solve, 20, None, calls, tol=ARPACK_TOL, seed=START_SEED,
                                        block=block)
    lam_ref, vec_ref = sla.eigh(K.toarray(), M.toarray())
    np.testing.assert_allclose(lam_ref, omega**2, rtol=1e-12)  # the dense reference is the closed form
    assert_modes(lam, vec, lam_ref, vec_ref, M)
    assert calls[0] % block == 0 and calls[0] > 20


def test_lattice_with_its_rigid_modes_projected_out():
    K, M, _, _ = lattice()
    lam_all, vec_all = sla.eigh(K.toarray(), M.toarray())
    Q = vec_all[:, :6]  # the six rigid modes (M-orthonormal)
    assert np.max(np.abs(lam_all[:6])) < 1e-12 * lam_all[-1] and lam_all[6] > 1e-3
    sigma, fac = sigma_fac(K, M)
    lam, vec = block_shift_invert_modes(M, sigma, fac.solve, 16, Q, [0], tol=ARPACK_TOL, seed=START_SEED)
    assert np.max(np.abs(Q.T @ (M @ vec))) < 1e-10  # M-orthogonal to the projected modes
    assert_modes(lam, vec, lam_all[6:], vec_all[:, 6:], M)


def test_shift_invert_modes_takes_the_block_path_and_agrees_with_arpack(monkeypatch):
    K, M, _ = membrane(30, free=False)
    sigma, fac = sigma_fac(K, M)
    lam_a, _ = shift_invert_modes(K, M, sigma, fac, 12, None, [0])
    monkeypatch.setattr(eigen_extension, "BLOCK_MIN_DOFS", 0)
    seen = []
    real = block_lanczos.block_shift_invert_modes
    monkeypatch.setattr(eigen_extension, "block_shift_invert_modes", lambda *a, **kw: seen.append(1) or real(*a, **kw))
    calls = [0]
    lam, vec = shift_invert_modes(K, M, sigma, fac, 12, None, calls)
    assert seen and calls[0] % block_lanczos.BLOCK == 0
    np.testing.assert_allclose(lam, lam_a, rtol=LAM_RTOL)
    lam_ref, vec_ref = sla.eigh(K.toarray(), M.toarray())  # the 12th mode is one of a pair: the dense pair
    assert_modes(lam, vec, lam_ref, vec_ref, M)


def test_modal_analysis_with_extensions_on_the_block_path(monkeypatch):
    """The whole sparse eigen-solve (first batch with the rigid mode, extensions with the found modes
    projected out) on the block path equals the closed form of the free membrane."""
    K, M, omega = membrane(36, free=True)
    monkeypatch.setattr(eigen_extension, "BLOCK_MIN_DOFS", 0)
    b = modal_analysis(K, M, 4, dense_limit=0, backend="mumps", min_omega=float(omega[40]))
    assert b.rigid.shape[1] == 1 and b.n_elastic > 40
    np.testing.assert_allclose(b.omega, omega[1:1 + b.n_elastic], rtol=LAM_RTOL)


def test_no_room_for_the_block_falls_back_to_arpack(monkeypatch):
    """A model too small for k modes in blocks of BLOCK: BlockBreakdown, and shift_invert_modes runs ARPACK."""
    K, M, omega = membrane(5, free=False)  # 25 dofs, 20 modes asked: 20 + 8 > 25
    sigma, fac = sigma_fac(K, M)
    with pytest.raises(BlockBreakdown, match="no room"):
        block_shift_invert_modes(M, sigma, fac.solve, 20, None, [0], tol=ARPACK_TOL, seed=START_SEED)
    monkeypatch.setattr(eigen_extension, "BLOCK_MIN_DOFS", 0)
    lam, _ = shift_invert_modes(K, M, sigma, fac, 20, None, [0])
    np.testing.assert_allclose(lam, omega[:20] ** 2, rtol=LAM_RTOL)


def test_no_convergence_within_the_basis_is_a_breakdown():
    K, M, _ = membrane(30, free=False)
    sigma, fac = sigma_fac(K, M)
    with pytest.raises(BlockBreakdown, match="no convergence within 32 vectors and 0 restarts"):
        block_shift_invert_modes(M, sigma, fac.solve, 20, None, [0], tol=ARPACK_TOL, seed=START_SEED, block=4,
                                 max_dim=32, max_restarts=0)
