"""Deflated shifted solves (computed modes + CG with the eigen-solver's factors) equal direct solves."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from stepnf.runtime.counters import Counters
from stepnf.linalg.deflation import DeflatedSolver
from stepnf.errors import NumericalError
from stepnf.linalg.modal_analysis import modal_analysis


def laplacian_2d(m: int):
    """Free-free 2D Laplacian (one rigid mode: the constant) and a lumped mass."""
    d = sp.diags([-np.ones(m - 1), np.r_[1, 2 * np.ones(m - 2), 1], -np.ones(m - 1)], [-1, 0, 1])
    I = sp.eye(m)
    K = (sp.kron(d, I) + sp.kron(I, d)).tocsr()
    M = sp.diags(np.random.default_rng(0).uniform(1.0, 2.0, m * m)).tocsr()
    return K, M


@pytest.fixture(scope="module")
def system():
    K, M = laplacian_2d(45)  # 2025 dofs
    c = Counters()
    b = modal_analysis(K, M, 30, dense_limit=0, counters=c, rigid_modes=1, backend="superlu")
    F0 = b.factorization
    ds = DeflatedSolver(K, M, b.phi, b.omega**2, b.rigid, lambda v: F0.solve(v, count=False), c)
    return K, M, b, ds


def test_pseudo_inverse(system):
    K, M, b, ds = system
    rhs = np.random.default_rng(1).standard_normal(K.shape[0])
    rhs -= M @ (b.rigid @ (b.rigid.T @ rhs))  # self-equilibrated
    x = ds.pinv(rhs)
    assert np.linalg.norm(K @ x - rhs) <= 1e-9 * np.linalg.norm(rhs)
    assert abs(float(b.rigid[:, 0] @ (M @ x))) <= 1e-10 * np.linalg.norm(x)  # M-orthogonal to the rigid mode


def test_shift_inside_the_spectrum(system):
    K, M, b, ds = system
    sigma = 0.5 * b.omega[-1] ** 2
    assert ds.admissible(sigma)
    rhs = np.random.default_rng(2).standard_normal(K.shape[0])
    x = ds.solve(rhs, sigma)
    ref = spla.spsolve((K - sigma * M).tocsc(), rhs)
    assert np.linalg.norm(x - ref) <= 1e-8 * np.linalg.norm(ref)
    assert max(ds.iterations) < 60  # the point of it: tens of solves instead of a factorisation


def test_bordered_modal_derivative(system):
    """Excluding mode p equals the bordered system [[K - w^2 M, M phi], [phi^T M, 0]]."""
    K, M, b, ds = system
    p = 3
    w2 = b.omega[p] ** 2
    rhs = np.random.default_rng(3).standard_normal(K.shape[0])
    x = ds.solve(rhs, w2, exclude=[b.rigid.shape[1] + p])
    Mp = M @ b.phi[:, p]
    A = sp.bmat([[K - w2 * M, sp.csr_matrix(Mp[:, None])], [sp.csr_matrix(Mp[None, :]), None]]).tocsc()
    ref = spla.spsolve(A, np.r_[rhs, 0.0])[:-1]
    assert np.linalg.norm(x - ref) <= 1e-7 * np.linalg.norm(ref)


def test_shift_above_the_computed_spectrum_is_refused(system):
    K, M, b, ds = system
    with pytest.raises(NumericalError, match="not below the computed spectrum"):
        ds.solve(np.ones(K.shape[0]), 2 * b.omega[-1] ** 2)


def test_lockstep_solves_equal_one_by_one_solves(system):
    """solve_many (the three kinds of solve together, each with its own shift and exclusions) against
    solve, column by column: same answers, same CG iterations per column, same solve count.

    Both stop at a residual below 1e-12 |b| (rtol); the preconditioned operator's condition number
    on this 2025-dof Laplacian is at most (lam_c - sigma_0) / (lam_c - sigma) ~ 2 for these shifts, so
    each solution is within ~1e-12 of the exact one and the two within 1e-10 (margin 50 for the
    orthogonalisations' round-off)."""
    K, M, b, ds = system
    rng = np.random.default_rng(4)
    nr, p = b.rigid.shape[1], 3
    B = rng.standard_normal((K.shape[0], 4))
    B[:, 0] -= M @ (b.rigid @ (b.rigid.T @ B[:, 0]))
    cases = [(0.0, tuple(range(nr))), (0.5 * b.omega[-1] ** 2, ()), (b.omega[p] ** 2, (nr + p,)), (0.1, ())]
    B[:, 3] = 0.0  # a zero right-hand side: converged before the first iteration
    c = ds.counters
    before = c.linear_solves
    ds.iterations.clear()
    ref = np.column_stack([ds.solve(B[:, j], s, exclude=e) for j, (s, e) in enumerate(cases)])
    one_by_one = (c.linear_solves - before, sorted(ds.iterations))
    ds.iterations.clear()
    before = c.linear_solves
    X = ds.solve_many(B, [s for s, _ in cases], [e for _, e in cases])
    assert (c.linear_solves - before, sorted(ds.iterations)) == one_by_one
    for j in range(3):
        assert np.linalg.norm(X[:, j] - ref[:, j]) <= 1e-10 * np.linalg.norm(ref[:, j]), j
    assert not X[:, 3].any()


def test_lockstep_refuses_what_solve_refuses(system):
    K, M, b, ds = system
    with pytest.raises(NumericalError, match="not below the computed spectrum"):
        ds.solve_many(np.ones((K.shape[0], 2)), [0.1, 2 * b.omega[-1] ** 2], [(), ()])
    with pytest.raises(NumericalError, match="an eigenvalue of a mode not excluded"):
        ds.solve_many(np.ones((K.shape[0], 2)), [0.1, 0.0], [(), ()])  # the rigid mode at sigma = 0
    with pytest.raises(ValueError, match="2 right-hand sides, 1 shifts"):
        ds.solve_many(np.ones((K.shape[0], 2)), [0.0], [(), ()])
