"""Rigid-body modes from the model (null vectors of K), not from an eigenvalue ratio, and eigen-solves with a
singular mass matrix (issue 31, items 3 and 4).

Tolerances: these systems are small and well scaled apart from the spread built into them; the dense LAPACK
solve and shift-invert Lanczos (ARPACK tol 1e-12) agree on them to round-off (measured <= 1e-13 relative on
the frequencies), so 1e-10 leaves a wide margin. Reference eigenvalues of a diagonal K are exact.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

from helpers.systems import modal_to_physical, random_system
from stepnf.linalg.modal_analysis import lambda_scale, modal_analysis, rigid_body_fields
from stepnf.linalg.null_space import moving_dofs, residuals, rigid_field_count, rigid_span


def soft_system(rigid: int, soft: float, seed: int = 4):
    """M, K with ``rigid`` zero eigenvalues, then one at ``soft`` x the largest, then 1 .. 100 (dense, random basis)."""
    w2 = np.concatenate([[soft * 100.0], np.linspace(1.0, 100.0, 20)])
    h = np.zeros((21,) * 4)
    M, K, _, _ = modal_to_physical(np.sqrt(w2), np.zeros((21,) * 3), h, seed=seed, rigid=rigid)
    return sp.csr_matrix(M), sp.csr_matrix(K)


@pytest.mark.parametrize("dense_limit", [2000, 0], ids=["dense", "sparse"])
@pytest.mark.parametrize("rigid", [0, 1])
def test_a_soft_fundamental_below_the_tolerance_stays_elastic(dense_limit, rigid):
    """w^2 = 3e-12 lambda_max < rigid_tolerance (1e-11): K has no null vector there, so it is elastic mode 0
    (was: counted rigid, the second mode became "mode 0"); a true zero eigenvalue is still rigid."""
    M, K = soft_system(rigid, 3e-12)
    b = modal_analysis(K, M, 4, dense_limit=dense_limit)
    assert b.rigid.shape[1] == rigid
    # 3e-10 (rad/s)^2 = 3e-12 x 100; resolved to ~eps x 100 / 3e-10 ~ 1e-4 relative (random dense basis)
    assert b.omega[0] ** 2 == pytest.approx(3e-10, rel=1e-3)
    assert b.omega[1] ** 2 == pytest.approx(1.0, rel=1e-10)


@pytest.mark.parametrize("dense_limit", [2000, 0], ids=["dense", "sparse"])
def test_a_polynomial_model_with_no_zero_eigenvalue_has_no_rigid_mode(dense_limit):
    """K = diag(1, 1e14), M = I: the fundamental (1e-14 of the largest) is kept as mode 0 (was: dropped as rigid,
    mode 0 at 1e7 rad/s)."""
    K, M = sp.diags([1.0, 1e14]).tocsr(), sp.identity(2, format="csr")
    if dense_limit == 0:  # ARPACK needs k < n: the same spectrum on 8 dofs
        K, M = sp.diags([1.0, 1e14, 2e14, 3e14, 4e14, 5e14, 6e14, 7e14]).tocsr(), sp.identity(8, format="csr")
    b = modal_analysis(K, M, 1, dense_limit=dense_limit)
    assert b.rigid.shape[1] == 0
    assert b.omega[0] == pytest.approx(1.0, rel=1e-12)  # a diagonal K: exact


def test_free_body_keeps_six_rigid_modes_and_its_bits():
    """A free body: six rigid modes, and the same eigen-solve as before (the count of the old ratio test)."""
    M, K, _, _ = random_system(30, 3, rigid=6)
    M, K = sp.csr_matrix(M), sp.csr_matrix(K)
    b = modal_analysis(K, M)
    lam, vec = sla.eigh(K.toarray(), M.toarray())
    assert b.rigid.shape[1] == 6 and int(np.sum(np.abs(lam) <= 1e-11 * lambda_scale(K, M))) == 6
    # bit for bit above the refined modes (issue 35: the first n_modes + 4 = 5 elastic ones are refined by a
    # shift-invert Rayleigh-Ritz step, stepnf.linalg.refined_modes): the split is the old one
    assert np.array_equal(b.omega[5:], np.sqrt(lam[11:]))
    np.testing.assert_allclose(b.omega[:5], np.sqrt(lam[6:11]), rtol=1e-13)  # a well-conditioned random pencil


def clamped_lattice(loose: bool = False):
    """An SPD "held" K with dof coordinates (40 nodes x 3); with ``loose`` one more node no element touches."""
    rng = np.random.default_rng(5)
    n_nodes = 40 + loose
    X = np.repeat(rng.uniform(-1, 1, (n_nodes, 3)), 3, axis=0)
    D = np.tile([0, 1, 2], n_nodes)
    n = len(D)
    A = rng.standard_normal((120, 120))
    K = np.zeros((n, n))
    K[:120, :120] = A @ A.T / 120 + 0.1 * np.eye(120)
    return sp.csr_matrix(K), sp.diags(rng.uniform(1, 2, n)).tocsr(), X, D


@pytest.mark.parametrize("dense_limit", [2000, 0], ids=["dense", "sparse"])
def test_a_mechanism_that_is_no_rigid_motion_is_found_and_named(dense_limit):
    """A held structure (rigid fields resisted) with a node no element stiffens: three mechanisms, found by the
    null test on the eigenvectors (was, on the sparse path: counted as elastic modes at w = 0)."""
    K, M, X, D = clamped_lattice(loose=True)
    C = rigid_body_fields(X, D)
    assert rigid_field_count(K, rigid_span(C)) == 0
    b = modal_analysis(K, M, 4, dense_limit=dense_limit, rigid_candidates=C)
    assert b.rigid.shape[1] == 3 and b.omega[0] > 0.01
    assert np.abs(b.rigid[:120]).max() < 1e-12  # only the loose node's dofs move
    text = moving_dofs(b.rigid[:, 0], X, D)
    assert text.startswith("1 dofs move") or text.startswith("2 dofs move") or text.startswith("3 dofs move")
    assert f"({X[-1, 0]:.4g}, {X[-1, 1]:.4g}, {X[-1, 2]:.4g})" in text


def test_rigid_field_residuals_separate_free_and_held():
    """The rigid fields are null vectors of a free K to round-off and far from them once held."""
    K, M, X, D = clamped_lattice()
    Q = rigid_span(rigid_body_fields(X, D))
    T = np.eye(120) - Q @ np.linalg.solve(Q.T @ (M @ Q), (M @ Q).T)  # kills the rigid motions
    Kfree = sp.csr_matrix(T.T @ K.toarray() @ T)
    assert rigid_field_count(Kfree, Q) == 6 and rigid_field_count(K, Q) == 0
    assert residuals(Kfree, Q).max() < 1e-14  # measured ~1e-16
    assert residuals(K, Q).min() > 1e-3


def massless_system(rigid: int):
    """A dense SPD K (or with ``rigid`` zero eigenvalues), M lumped with 4 massless dofs, and the reference:
    the eigenvalues of K statically condensed on the dofs with mass."""
    rng = np.random.default_rng(7)
    A = rng.standard_normal((60, 60))
    K = A @ A.T / 60 + np.eye(60)
    if rigid:  # K P with P the orthogonal projector off ``rigid`` random directions: those are its null space
        Z = np.linalg.qr(rng.standard_normal((60, rigid)))[0]
        P = np.eye(60) - Z @ Z.T
        K = P @ K @ P
    m = rng.uniform(1.0, 2.0, 60)
    gone = np.array([3, 11, 17, 25])
    m[gone] = 0.0
    keep = np.setdiff1d(np.arange(60), gone)
    Kc = K[np.ix_(keep, keep)] - K[np.ix_(keep, gone)] @ np.linalg.solve(K[np.ix_(gone, gone)], K[np.ix_(gone, keep)])
    ref = sla.eigh(Kc, np.diag(m[keep]), eigvals_only=True)
    return sp.csr_matrix(K), sp.diags(m).tocsr(), ref[rigid:]


@pytest.mark.parametrize("rigid", [0, 6])
def test_singular_mass_matrix_dense_and_sparse(rigid):
    """Lumped masses with massless dofs: the dense path solves (M, K - sigma M) and drops the 4 infinite
    eigenvalues, saying so (was: "is M positive definite?"); shift-invert agrees. Reference: K condensed on
    the dofs with mass (exact elimination), eigenvalues 1 .. 10 resolved to ~1e-15 by both. (ARPACK needs
    room: its Krylov space lies in the range of M, 56 dimensions here for 16 + 20 vectors.)"""
    K, M, ref = massless_system(rigid)
    dense = modal_analysis(K, M)
    assert dense.massless == 4 and "4 massless" in dense.solver
    assert dense.rigid.shape[1] == rigid and dense.n_elastic == 60 - 4 - rigid
    np.testing.assert_allclose(dense.omega ** 2, ref, rtol=1e-10)
    np.testing.assert_allclose(dense.phi.T @ (M @ dense.phi), np.eye(dense.n_elastic), atol=1e-10)
    sparse = modal_analysis(K, M, 6, dense_limit=0)
    assert sparse.rigid.shape[1] == rigid
    np.testing.assert_allclose(sparse.omega[:6] ** 2, ref[:6], rtol=1e-10)


def test_nearly_massless_lumped_dofs_keep_the_low_frequencies():
    """Lumped masses of 1e-14 beside 1 (a dof that is massless in all but round-off): the dense solve takes
    the pencil (M, K - sigma M) and drops them, the low frequencies equal static condensation to 1e-12
    (measured 1e-15; ``eigh(K, M)`` put them 2-8% off with no error before, review of issue 31)."""
    rng = np.random.default_rng(2)
    n = 10
    A = rng.standard_normal((n, n))
    K = A @ A.T + np.eye(n)
    m = np.ones(n)
    light = np.zeros(n, dtype=bool)
    light[[2, 5, 7]] = True
    m[light] = 1e-14
    r = ~light
    Kc = K[np.ix_(r, r)] - K[np.ix_(r, light)] @ np.linalg.solve(K[np.ix_(light, light)], K[np.ix_(light, r)])
    ref = np.sqrt(sla.eigh(Kc, np.diag(m[r]), eigvals_only=True))
    b = modal_analysis(sp.csr_matrix(K), sp.csr_matrix(np.diag(m)))
    assert b.massless == 3 and b.n_elastic == 7
    assert np.max(np.abs(b.omega / ref - 1)) < 1e-12
