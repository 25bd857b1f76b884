"""ShiftedFactorizer: K - sigma M for successive shifts on one pattern (stepnf/linalg/shifted.py).

Accuracy references: LDL^T (MUMPS) and LU (SuperLU, LAPACK) are backward stable, so a solve has a
relative residual ||A x - b|| / (||A||_1 ||x||) of a few unit round-offs times a modest growth
factor: 1e-12 leaves a factor ~5000 over u = 1.1e-16 for n = 240. Two such solutions differ by at
most cond(A) times that (A's condition number computed here, densely).
"""
import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

from stepnf.runtime.counters import Counters
from stepnf.errors import NumericalError
from stepnf.nf.evaluators import FullOrderContext
from stepnf.linalg.factorization import factorize
from stepnf.linalg.shifted import ShiftedFactorizer, union_pattern

BACKENDS = ["mumps", "superlu", "dense"]
N = 240
BACKWARD = 1e-12


def backend_or_skip(backend):
    if backend == "mumps":
        pytest.importorskip("petsc4py")
    return backend


def pencil(n=N):
    """K: a fixed-fixed string of unequal springs (tridiagonal); M: consistent-like mass with a coupling
    at distance 2 (pentadiagonal without the first off-diagonal): the patterns differ, the union is
    pentadiagonal. Both symmetric positive definite."""
    k = 1.0 + np.linspace(0.0, 1.0, n + 1) ** 2
    K = sp.diags([-k[1:-1], k[:-1] + k[1:], -k[1:-1]], [-1, 0, 1], shape=(n, n), format="csr")
    m = np.full(n - 2, 0.1)
    M = sp.diags([m, np.full(n, 1.0), m], [-2, 0, 2], shape=(n, n), format="csr")
    return K, M


def eigenvalues(K, M):
    return sla.eigh(K.toarray(), M.toarray(), eigvals_only=True)


def relative_residual(K, M, sigma, x, b):
    A = (K - sigma * M).toarray()
    return np.linalg.norm(A @ x - b) / (np.linalg.norm(A, 1) * np.linalg.norm(x))


def shifts(K, M):
    lam = eigenvalues(K, M)
    # below the spectrum (definite), between eigenvalues 5 and 6 and 40 and 41 (indefinite)
    return [0.5 * lam[0], 0.5 * (lam[4] + lam[5]), 0.5 * (lam[39] + lam[40])]


@pytest.mark.parametrize("backend", BACKENDS)
def test_successive_shifts_match_a_fresh_factorisation(backend):
    backend_or_skip(backend)
    K, M = pencil()
    S = ShiftedFactorizer(K, M, backend=backend)
    b = np.random.default_rng(0).standard_normal((N, 2))
    for sigma in shifts(K, M):
        x = S.refactor(sigma).solve(b)
        A = (K - sigma * M).tocsr()
        x_ref = factorize(A, backend=backend).solve(b)
        for j in range(2):
            assert relative_residual(K, M, sigma, x[:, j], b[:, j]) <= BACKWARD
        # both backward stable: the solutions agree to cond(A) x the backward error (x2, two solves)
        cond = np.linalg.cond(A.toarray())
        assert np.linalg.norm(x - x_ref) <= 2 * cond * BACKWARD * np.linalg.norm(x_ref)


@pytest.mark.parametrize("make", ["refactor", "factorizer"])
def test_block_solve_equals_one_column_at_a_time(make):
    """MUMPS: k columns in one call (MatMatSolve) against k single solves, on an indefinite shift.

    Both backward stable (module docstring): each column within 2 cond(A) x BACKWARD of the other."""
    backend_or_skip("mumps")
    K, M = pencil()
    sigma = shifts(K, M)[2]
    fac = getattr(ShiftedFactorizer(K, M, backend="mumps"), make)(sigma)
    B = np.random.default_rng(5).standard_normal((N, 5))
    X = fac.solve(B)
    cond = np.linalg.cond((K - sigma * M).toarray())
    for j in range(5):
        x = fac.solve(B[:, j])
        assert relative_residual(K, M, sigma, X[:, j], B[:, j]) <= BACKWARD
        assert np.linalg.norm(X[:, j] - x) <= 2 * cond * BACKWARD * np.linalg.norm(x)


def test_union_pattern_values_are_exactly_k_minus_sigma_m():
    pytest.importorskip("petsc4py")
    K, M = pencil()
    indptr, indices, data_K, data_M = union_pattern(K, M)
    assert len(indices) == (K + M).nnz == 5 * N - 6  # pentadiagonal union
    sigma = 3.7
    A = sp.csr_matrix((data_K - sigma * data_M, indices, indptr), shape=K.shape)
    # the same floating-point operations as scipy's K - sigma M on each entry: equal bit for bit
    assert abs(A - (K - sigma * M)).max() == 0.0
    S = ShiftedFactorizer(K, M, backend="mumps")
    assert np.array_equal(S.values(sigma), data_K - sigma * data_M)


def two_shifts(backend: str):
    """``K, M``, two shifts, a factoriser on ``backend`` and a right-hand side of ones."""
    backend_or_skip(backend)
    K, M = pencil()
    s1, s2, _ = shifts(K, M)
    return K, M, s1, s2, ShiftedFactorizer(K, M, backend=backend), np.ones(N)


@pytest.mark.parametrize("backend", BACKENDS)
def test_superseded_factorisation_raises(backend):
    K, M, s1, s2, S, b = two_shifts(backend)
    f1 = S.refactor(s1, "first")
    f1.solve(b)
    f2 = S.refactor(s2, "second")
    with pytest.raises(RuntimeError, match="factorisation of first was superseded by the factorisation of second"):
        f1.solve(b)
    f1.release()  # harmless: the shared factors belong to f2 now
    assert relative_residual(K, M, s2, f2.solve(b), b) <= BACKWARD


@pytest.mark.parametrize("backend", BACKENDS)
def test_independent_factorisations_live_together(backend):
    K, M, s1, s2, S, b = two_shifts(backend)
    f1, f2 = S(s1, "one"), S(s2, "two")
    assert relative_residual(K, M, s1, f1.solve(b), b) <= BACKWARD
    assert relative_residual(K, M, s2, f2.solve(b), b) <= BACKWARD
    f1.release()
    with pytest.raises(RuntimeError, match="factorisation of one was released"):
        f1.solve(b)
    assert relative_residual(K, M, s2, f2.solve(b), b) <= BACKWARD


@pytest.mark.parametrize("backend", BACKENDS)
def test_exactly_singular_shift_is_a_numerical_error_and_the_next_shift_works(backend):
    backend_or_skip(backend)
    K, M = pencil(N - 1)
    c = 2.5  # an uncoupled dof with k = c, m = 1: K - c M has a zero row and column, exactly
    K = sp.block_diag([K, sp.csr_matrix([[c]])], format="csr")
    M = sp.block_diag([M, sp.csr_matrix([[1.0]])], format="csr")
    S = ShiftedFactorizer(K, M, backend=backend)
    with pytest.raises(NumericalError, match="singular"):
        S.refactor(c, "K - c M").solve(np.ones(N))
    sigma = 0.5 * eigenvalues(K, M)[0]
    b = np.ones(N)
    assert relative_residual(K, M, sigma, S.refactor(sigma).solve(b), b) <= BACKWARD


@pytest.mark.parametrize("backend", BACKENDS)
def test_release_then_refactor_and_counters(backend):
    backend_or_skip(backend)
    K, M = pencil()
    s1, s2, s3 = shifts(K, M)
    c = Counters()
    S = ShiftedFactorizer(K, M, counters=c, backend=backend)
    b = np.ones((N, 3))
    S.refactor(s1).solve(b)
    f = S.refactor(s2)
    f.solve(b[:, 0])
    f.release()
    f.release()  # idempotent
    with pytest.raises(RuntimeError, match="was released"):
        f.solve(b[:, 0])
    g = S.refactor(s3)  # a new instance after the release
    assert relative_residual(K, M, s3, g.solve(b[:, 0]), b[:, 0]) <= BACKWARD
    S(s1).solve(b[:, 0])
    assert c.factorizations == 4
    assert c.linear_solves == 3 + 1 + 1 + 1
    assert c.factorization_seconds > 0.0
    S.close()
    with pytest.raises(RuntimeError, match=r"was freed by ShiftedFactorizer.close\(\)"):
        g.solve(b[:, 0])


@pytest.mark.parametrize("backend", BACKENDS)
def test_context_slot_with_the_factorizer(backend):
    """FullOrderContext's one slot (DNF, the backbone's ShiftSolve) on a ShiftedFactorizer: asking again
    for a shift returns the kept factorisation, another shift replaces it, release_shifted frees it."""
    backend_or_skip(backend)
    K, M = pencil()
    s1, s2, _ = shifts(K, M)
    c = Counters()
    ctx = FullOrderContext(K, M, None, c, backend, ShiftedFactorizer(K, M, counters=c, backend=backend))
    b = np.ones(N)
    f1 = ctx.shifted_factorization(s1, "one")
    assert ctx.shifted_factorization(s1, "one") is f1
    x2 = ctx.shifted_factorization(s2, "two").solve(b)
    x1 = ctx.shifted_factorization(s1, "one").solve(b)  # asked again: factorised again
    assert relative_residual(K, M, s2, x2, b) <= BACKWARD
    assert relative_residual(K, M, s1, x1, b) <= BACKWARD
    assert c.factorizations == 3
    last = ctx.shifted_factorization(s1, "one")
    ctx.release_shifted()
    with pytest.raises(RuntimeError, match="released"):
        last.solve(b)


def resident_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20


@pytest.mark.slow
def test_release_returns_the_memory_of_the_factors():
    """A 3D Laplacian (27k dofs, 7-point): MUMPS's factors take tens of MB; release() gives them back
    to the system (resident memory falls by at least half of what the factorisation added)."""
    pytest.importorskip("petsc4py")
    if not __import__("os").path.exists("/proc/self/statm"):
        pytest.skip("needs /proc")
    m = 30
    L = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    Id = sp.identity(m)
    K = (sp.kron(sp.kron(L, Id), Id) + sp.kron(sp.kron(Id, L), Id) + sp.kron(sp.kron(Id, Id), L)).tocsr()
    M = sp.identity(m**3, format="csr")
    S = ShiftedFactorizer(K, M, backend="mumps")
    S.pattern()  # the union pattern (kept until close; here K's own arrays)
    before = resident_mb()
    f = S.refactor(0.01)
    S.refactor(0.02)  # in place: no second set of factors
    f = S.refactor(0.03)
    grown = resident_mb() - before
    f.release()
    freed = before + grown - resident_mb()
    assert grown > 20.0  # the factors are there to be freed (measured ~57 MB)
    assert freed >= 0.5 * grown


@pytest.mark.parametrize("refactor", [True, False])
def test_slot_keeps_one_factorisation(refactor):
    """stepnf.linalg.shifted.Slot: asking again is free, a new shift retires the old factorisation (superseded by a
    refactor, released otherwise: its solves raise, never wrong numbers), a failed one leaves nothing held."""
    from stepnf.linalg.shifted import Slot

    backend_or_skip("mumps")
    K, M = pencil(N - 1)
    K = sp.block_diag([K, sp.csr_matrix([[2.5]])], format="csr")  # an uncoupled dof: K - 2.5 M exactly singular
    M = sp.block_diag([M, sp.csr_matrix([[1.0]])], format="csr")
    c = Counters()
    S = ShiftedFactorizer(K, M, counters=c, backend="mumps")
    slot = Slot(S.refactor if refactor else S.factorizer, S.close, refactor=refactor)
    s1, s2 = shifts(K, M)[:2]
    f1 = slot.factorization(s1, "one")
    assert slot.factorization(s1, "one") is f1 and slot.holds(s1) and c.factorizations == 1
    f2 = slot.factorization(s2, "two")
    assert slot.holds(s2) and not slot.holds(s1) and c.factorizations == 2
    with pytest.raises(RuntimeError, match="superseded" if refactor else "released"):
        f1.solve(np.ones(N))
    b = np.ones(N)
    assert relative_residual(K, M, s2, f2.solve(b), b) <= BACKWARD
    with pytest.raises(NumericalError, match="singular"):
        slot.factorization(2.5, "singular")
    assert not slot.holds(s2) and not slot.holds(2.5)
    slot.close()
