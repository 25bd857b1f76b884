"""The sparse eigen-solve extends its basis (found modes projected out, same factorisation) instead of
starting over: the extended basis equals a single run of the final size.

Models: square membranes (5-point Laplacian, uniform mass rho; clamped, or free with the constant as
rigid mode), whose spectrum is known in closed form (``(mu_i + mu_j) / rho``, exact twin pairs
``i != j``), and a braced spring lattice on an 8 x 8 x 3 grid (six rigid modes, square symmetry:
exact pairs). Every model is solved on the sparse path (``dense_limit=0``).

Tolerances. ARPACK (tol 1e-12) stops when each Ritz pair's residual is below 1e-12 of its Ritz
value mu = 1/(lam - sigma) of the shift-inverted operator; for a symmetric operator the eigenvalue
error is at most that residual, so each run's lam is within ~1e-12 relative of the exact one (the
factorisation both runs share adds u * cond(K) ~ 1e-16 * 1e4 on these models, the same in both):
two runs agree to ~2e-12 relative, checked at 1e-10 (50x for round-off of other BLAS thread counts).
Eigenvectors move by residual / gap (Davis-Kahan): the lowest modes compared here have relative gaps
>= 2.9e-3 in omega (6e-3 in lam), asserted on each model, except exact twins (compared as
subspaces), so sin(angle) <= 1e-12 / 6e-3 ~ 2e-10 per run; checked at 1e-8. Subspace distances are
measured as the M-norm of the part of one basis outside the other's span (accurate to round-off,
unlike 1 - cos). Measured: frequencies <= 1.5e-15 apart, subspaces <= 5e-12, closed form <= 5e-15.
"""
from __future__ import annotations


import numpy as np
import pytest

from stepnf.runtime.counters import Counters
from helpers.pencils import RHO, eigenspaces, lattice, membrane, outside
from stepnf.linalg.eigen_extension import shift_invert_modes
from stepnf.linalg.shifted import ShiftedFactorizer
from stepnf.linalg.modal_analysis import ModalBasis, extend_basis, lambda_scale, modal_analysis, rigid_body_fields

OMEGA_RTOL = 1e-10  # module docstring: two ARPACK runs agree to ~2e-12
SHAPE_TOL = 1e-8  # module docstring: residual / gap ~ 2e-10
TWIN = 1e-8  # frequencies closer than this (relative) are one eigenspace: exact twins agree to ~1e-14


def assert_same_modes(ext: ModalBasis, ref: ModalBasis, M) -> None:
    """ext's modes are ref's first ones: frequencies, and each eigenspace of ext inside ref's."""
    m = ext.n_elastic
    assert ref.n_elastic > m
    np.testing.assert_allclose(ext.omega, ref.omega[:m], rtol=OMEGA_RTOL)
    gaps = np.diff(ref.omega[: m + 1]) / ref.omega[1: m + 1]
    assert gaps[gaps > TWIN].min() > 2.5e-3  # the premise of SHAPE_TOL
    for group in eigenspaces(ref.omega, TWIN):
        if group[0] >= m:
            break
        mine = [s for s in group if s < m]  # ext may end inside a pair: its twin must lie in ref's pair
        assert outside(ext.phi[:, mine], ref.phi[:, group], M) <= SHAPE_TOL
    Phi = np.column_stack([ext.rigid, ext.phi])
    np.testing.assert_allclose(Phi.T @ (M @ Phi), np.eye(Phi.shape[1]), atol=1e-10)  # M-orthonormal
    assert ext.degenerate_groups == [g for g in ref.degenerate_groups if max(g) < m]


def extended(K, M, target: int, **kw):
    """modal_analysis asked for 2 modes and then, through ``enough``, for ``target``: the sizes of
    the bases it went through, the basis and its counters."""
    sizes: list[int] = []
    c = Counters()

    def enough(b: ModalBasis) -> bool:
        sizes.append(b.n_elastic)
        return b.n_elastic >= target

    b = modal_analysis(K, M, 2, dense_limit=0, backend="superlu", enough=enough, counters=c, **kw)
    return b, sizes, c


def single(K, M, n_modes: int, **kw) -> ModalBasis:
    return modal_analysis(K, M, n_modes, dense_limit=0, backend="superlu", **kw)


@pytest.mark.parametrize("case", ["clamped", "free_lanczos_rigid", "free_candidates"])
def test_extended_membrane_equals_single_run(case):
    free = case != "clamped"
    K, M, exact = membrane(36 if free else 48, free)
    kw = {}
    if case == "free_candidates":  # the constant is rigid, the x coordinate is not
        x = np.repeat(np.arange(36.0), 36)
        kw["rigid_candidates"] = np.column_stack([np.ones(36 * 36), x])
    b, sizes, c = extended(K, M, 24, **kw)
    assert len(sizes) >= 2 and sizes[-1] == b.n_elastic >= 24  # extended at least once
    assert b.rigid.shape[1] == int(free) and c.factorizations == 1
    ref = single(K, M, b.n_elastic + 4, **kw)
    assert_same_modes(b, ref, M)
    # and the closed form: the factorisation's round-off, u cond(K) ~ 1e-16 * 1e4, is the bound here
    np.testing.assert_allclose(b.omega, exact[int(free): int(free) + b.n_elastic], rtol=1e-10)


def test_extended_lattice_with_six_rigid_modes_equals_single_run():
    K, M, X, D = lattice()
    kw = {"rigid_candidates": rigid_body_fields(X, D)}
    b, sizes, _ = extended(K, M, 24, **kw)
    assert len(sizes) >= 2 and b.rigid.shape[1] == 6
    assert_same_modes(b, single(K, M, b.n_elastic + 4, **kw), M)


def test_degenerate_pair_split_between_batches():
    """The first batch ends on one twin of an exact pair; the extension finds the other one."""
    K, M, exact = membrane(48, free=False)
    first = 12  # clamped, no candidates: the first batch is need + 4 twins + 6 rigid room = 12 modes
    split = [first - 1, first]
    assert split in eigenspaces(exact[:40], TWIN)  # exact modes 11 and 12 are a pair
    b, sizes, _ = extended(K, M, 24)
    assert sizes[0] == first  # the first batch held one twin of the pair
    np.testing.assert_allclose(b.omega[split], exact[split], rtol=1e-10)
    assert split in b.degenerate_groups
    # the pair's two modes span the exact eigenspace: sin(i p pi/49) sin(j q pi/49) and its transpose
    m = 48
    grid = np.arange(1, m + 1) * np.pi / (m + 1)
    mu = 2 - 2 * np.cos(grid)
    lam = exact[split[0]] ** 2 * RHO
    i, j = next((i, j) for i in range(m) for j in range(i + 1, m) if abs(mu[i] + mu[j] - lam) < 1e-12)
    E = np.column_stack([np.kron(np.sin((i + 1) * grid), np.sin((j + 1) * grid)),
                         np.kron(np.sin((j + 1) * grid), np.sin((i + 1) * grid))])
    E /= np.sqrt(np.einsum("ij,ij->j", E, M @ E))  # M-orthonormal (orthogonal since i != j)
    assert outside(b.phi[:, split], E, M) <= SHAPE_TOL


def test_a_mode_missed_by_a_batch_comes_back_in_its_place():
    """A basis with holes (mode 3 and one twin of the pair 11/12 left out, as ARPACK could miss them):
    the extension finds them first, below the highest mode found, and the merge sorts them in."""
    K, M, _ = membrane(48, free=False)
    ref = single(K, M, 26)
    assert [11, 12] in ref.degenerate_groups
    assert not any(3 in g for g in ref.degenerate_groups)
    keep = [s for s in range(20) if s not in (3, 12)]
    holed = ModalBasis(omega=ref.omega[keep], phi=ref.phi[:, keep], rigid=ref.rigid,
                       rigid_eigenvalues=ref.rigid_eigenvalues, factorization=ref.factorization, shift=ref.shift)
    b = extend_basis(K, M, holed, 6)
    assert b.n_elastic == 24
    assert_same_modes(b, ref, M)


def restart_solves(K, M, first: int, target: int) -> int:
    """Shifted solves of the former scheme: runs of first, max(2k, k + 8), ... modes from scratch until
    one holds ``target`` (no rigid modes), on one factorisation."""
    sigma = -1e-10 * lambda_scale(K, M)
    fac = ShiftedFactorizer(K, M, backend="superlu").factorizer(sigma)
    calls, k = [0], first
    while True:
        shift_invert_modes(K, M, sigma, fac, k, None, calls)
        if k >= target:
            return calls[0]
        k = max(2 * k, k + 8)


def test_extension_costs_fewer_solves_than_starting_over():
    """The main job's pattern: a first batch of 6 (n_modes 2 + 4 twins, rigid modes known or none),
    15 needed. Former scheme: 6, 14, 28 modes from scratch; now 6, then 9 more."""
    K, M, _ = membrane(48, free=False)
    b, sizes, c = extended(K, M, 15, rigid_modes=0)
    assert sizes == [6, 15]
    old = restart_solves(K, M, 6, 15)
    # measured: 129-130 against 221-236 (ARPACK's random start moves both by a few solves)
    assert c.eigensolver_solves < 0.75 * old


def test_adapter_eigensolver_still_starts_over():
    """An adapter's solver cannot project found modes out: modal_analysis asks it for 12, then 24."""
    K, M, exact = membrane(20, free=False)
    asked: list[int] = []
    lam = exact**2

    def eigensolver(k: int, shift: float = 0.0):
        asked.append(k)
        vec = np.eye(K.shape[0])[:, :k] / np.sqrt(RHO)  # shapes are not checked here, only the sizes asked
        return lam[:k], vec

    b = modal_analysis(K, M, 2, eigensolver=eigensolver, enough=lambda b: b.n_elastic >= 20)
    assert asked == [12, 24] and b.solver == "adapter" and b.n_elastic == 24


def test_first_batch_sets_the_first_run():
    """A caller's guess (e.g. from the number of labelled masters) replaces n_modes + 4 (+ rigid room)."""
    K, M, _ = membrane(48, free=False)
    b, sizes, _ = extended(K, M, 15, rigid_modes=0, first_batch=16)
    assert sizes == [16] and b.n_elastic == 16


def test_first_batch_respects_max_modes():
    """max_modes caps the first run as it caps the extensions: 2 needed (+ 4 for twins) with max_modes = 4
    computes 4 elastic modes, not 6; a need above max_modes is still met."""
    K, M, _ = membrane(48, free=False)
    assert single(K, M, 2, rigid_modes=0, max_modes=4).n_elastic == 4
    assert single(K, M, 2, rigid_modes=0).n_elastic == 6
    assert single(K, M, 5, rigid_modes=0, max_modes=4).n_elastic == 5
