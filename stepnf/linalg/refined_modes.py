"""Refined low modes: shift-inverted Rayleigh-Ritz steps whose solves see K and M apart.

Both eigen-solves of :func:`stepnf.linalg.modal_analysis.modal_analysis` leave, on a stiff model, an
error in the low frequencies far above the round-off of the model's own matrices:

* the dense one (``scipy.linalg.eigh``: a Cholesky of M, a tridiagonal reduction) is backward stable in
  norm only: relative errors up to ``eps lambda_max / lambda_1``, rounded differently for each BLAS
  thread count. SSMTool's clamped von Karman beam (``bench/polynomial_sparse.py``, 297 dofs): w1 +8.2e-9
  with one OpenBLAS thread, -9.7e-10 with two;
* shift-invert Lanczos factorises ``A = K - sigma M`` formed in floating point, each entry rounded by
  ``eps |A_ij|``. On a regular mesh every element rounds its entries alike: the errors add up over the
  mode instead of averaging out. The same beam's w1: +1.3e-10 at 297 dofs, +2.2e-6 at 2,997, +5.5e-4
  to 7.5e-4 at 9,999, whether the shift is -1e-3 lambda_1 or -1e4 lambda_1 (the rounding of ``A`` is
  the cause, not the shift); a FEniCSx hex20 strip at L/h = 1000 (5,400 dofs): +4.4e-4.

:func:`rayleigh_ritz` removes both. With the found modes ``V`` (n, m) and a factorisation of ``A``:
``W = A^-1 M V``, one step of iterative refinement whose residual ``M V - (K W - sigma M W)`` takes the
products with K and M apart (the exact ``A``, not its rounded entries), then the Rayleigh-Ritz pencil
on span(W): ``W^T A W = W^T M V`` (exact for the exact solve; ``v^T K v`` is never formed) against
``W^T M W``, ``lambda = sigma + theta``. What remains is the random rounding of the products with K,
bounded by ``eps / r``, ``r = |v^T K v| / |v|^T |K| |v|`` (:func:`stepnf.linalg.null_space.energy_ratios`),
in practice far below. Measured against exact (rational) Rayleigh quotients, w1 of the beam: 297 dofs
(r = 1e-7) within 9e-12 with one or two BLAS threads; 9,999 dofs (r = 8e-14) 2.3e-6; the strip
(r = 4e-14) 1.1e-5: the floor of double precision on those models.

Where: the dense path always (the modes the run asks for, :func:`refined_count`, on a sparse
factorisation of ``K - s M``, ``s`` = :func:`refinement_shift`: cheap next to the dense solve); the
sparse path when its first shift lies beyond :data:`FAR_SHIFT` times the lowest elastic eigenvalue
found (:func:`far_shift`), with a second factorisation at ``s``. The FE models of the scale benchmark
keep their path and their numbers (they lie at ``|sigma| / lambda_1`` = 7e-3 and below).
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from stepnf.errors import NumericalError
from stepnf.linalg.factorization import factorize
from stepnf.runtime.counters import Counters

#: The refinement's shift, ``-SHIFT_FRACTION * lambda_1`` (lambda_1 the lowest elastic eigenvalue):
#: ``K - s M`` positive definite with rigid-body modes too; the solve damps mode ``k`` against mode ``j``
#: by ``(lambda_j - s) / (lambda_k - s)``, i.e. lambda_j / lambda_k to 1e-3.
SHIFT_FRACTION = 1e-3
#: The sparse path refines (a second factorisation, at :func:`refinement_shift`) when its first shift
#: ``sigma = -1e-10 lambda_scale`` is beyond this times lambda_1 (:func:`far_shift`): lambda_scale /
#: lambda_1 > 1e10, ten decades between the stiffest dof and the fundamental, where the rounding of
#: ``K - sigma M`` showed (module docstring). Measured ``|sigma| / lambda_1``: 7e-3 on the 38k-dof kappa = 25
#: cap (the scale benchmark's model; about h^-2 with the mesh size, < 0.2 at 1M dofs), 6e-3 on the free
#: plate, 2e-3 on the clamped one (left alone: their numbers unchanged); 1.7 on the shallow kappa = 25
#: shell (refined: frequencies move by 2e-11 at most); SSMTool's beam 8e-3 at 297 dofs, 1.0 at 999, 90 at
#: 2,997 (w1 2e-6 off before), 1e4 at 9,999 (1.3e-4 off before); the L/h = 1000 strip 1.8e3 (4.4e-4).
FAR_SHIFT = 1.0
#: Rayleigh-Ritz steps of the dense path: the dense solve's vectors carry ``eps lambda_max / (lambda_k - lambda_j)``
#: along the modes ``k`` just above the refined ones, which one step damps by ``lambda_j / lambda_k`` only
#: (measured on a chain tied to a block 1e14 stiffer, tests/nf/test_mode_conditioning.py: the third mode 5.8e-13
#: off after one step, 6e-15 after two). Lanczos vectors (the sparse path) are converged: one step.
DENSE_STEPS = 2
#: Above this fill (stored entries of ``K - s M`` over n^2) the dense path's refinement factorises with
#: dense LU rather than SuperLU (a model given as full matrices).
DENSE_FILL = 0.25


def refinement_shift(lam1: float) -> float:
    """The shift of the refinement's factorisation for a lowest elastic eigenvalue ``lam1`` (> 0)."""
    return -SHIFT_FRACTION * float(lam1)


def far_shift(sigma: float, lam1: float) -> bool:
    """Whether the sparse path's shift ``sigma`` lies too far below ``lam1`` (:data:`FAR_SHIFT`)."""
    return lam1 > 0 and abs(sigma) > FAR_SHIFT * lam1


def refined_count(omega: np.ndarray, need: int, min_omega: float | None, groups: list[list[int]]) -> int:
    """Elastic modes to refine out of ``omega`` (increasing): ``need`` (the modes the run asks for,
    with its margin), those up to ``min_omega`` and the first above it, and the rest of a degenerate
    group (``groups``) the last one belongs to (a twin is never left half refined)."""
    m = max(int(need), 1)
    if min_omega is not None:
        m = max(m, int(np.searchsorted(omega, min_omega, side="right")) + 1)
    m = min(m, len(omega))
    for g in groups:
        if m - 1 in g:
            m = max(g) + 1
    return m


def refinement_backend(A: sp.spmatrix | np.ndarray) -> str:
    """The back end of the dense path's refinement factorisation: SuperLU (sparse, the same rounding
    whatever the thread count) unless ``A`` is nearly full (:data:`DENSE_FILL`)."""
    n = A.shape[0]
    nnz = A.nnz if sp.issparse(A) else np.count_nonzero(A)
    return "dense" if nnz > DENSE_FILL * n * n else "superlu"


def rayleigh_ritz(K, M, V: np.ndarray, R: np.ndarray, shift: float,
                  solve: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """One shift-inverted Rayleigh-Ritz step on the modes ``V`` (n, m) (module docstring).

    ``solve`` applies ``(K - shift M)^-1`` to (n, m) columns; ``R`` (n, r) the M-normalised rigid-body
    modes (projected out; r may be 0). Returns ``(lam, X)``: eigenvalues (m,) increasing and
    M-orthonormal vectors (n, m), sign not fixed. Two block solves, three products with M, one with K.
    """
    B0 = np.asarray(M @ V)
    W = solve(B0)
    W = W + solve(B0 - (np.asarray(K @ W) - shift * np.asarray(M @ W)))  # K and M apart: A's exact entries
    if R.shape[1]:
        W = W - R @ (np.asarray(M @ R).T @ W)
    MW = np.asarray(M @ W)
    d = np.sqrt(np.einsum("ij,ij->j", W, MW))  # columns of unit mass: a well-scaled small pencil
    if not (np.all(np.isfinite(W)) and np.all(d > 0) and np.all(np.isfinite(d))):  # K - shift M (nearly) singular
        raise NumericalError(f"the refinement's solves with K - {shift:.3g} M gave non-finite or massless vectors")
    W, MW = W / d, MW / d
    Ar = (W.T @ B0) / d  # W^T A W of the scaled columns: A W = M V D^-1
    Br = W.T @ MW
    try:
        theta, C = sla.eigh((Ar + Ar.T) / 2, (Br + Br.T) / 2)
    except (np.linalg.LinAlgError, ValueError) as exc:  # the solves' columns dependent: W^T M W not definite
        raise NumericalError(f"the refinement's Rayleigh-Ritz pencil at shift {shift:.3g} failed: {exc}") from exc
    return shift + theta, W @ C


#: Columns of the modes above the refined ones made M-orthogonal to them per block: (n, CHUNK) temporaries, never
#: another (n, n) array on the dense path (2000 dofs: 4 MB per block against 32 MB for ``phi``).
CHUNK = 256


def refined_modes(K, M, omega: np.ndarray, phi: np.ndarray, rigid: np.ndarray, m: int, shift: float, fac,
                  counters: Counters | None = None, steps: int = 1,
                  copy: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``(omega, phi)`` with the first ``m`` elastic modes refined (:func:`rayleigh_ritz`) on the factorisation
    ``fac`` of ``K - shift M``, the modes above them made M-orthogonal to them again (they move by their own
    error, no more; per :data:`CHUNK` columns). ``phi`` copied, or with ``copy=False`` overwritten (only once
    every step succeeded: on a :class:`NumericalError` it is untouched). The refined columns M-normalised, their
    signs not fixed. ``counters``: the solves are counted as the eigen-solver's (``eigensolver_solves``)."""
    X = phi[:, :m]
    for _ in range(steps):
        lam, X = rayleigh_ritz(K, M, X, rigid, shift, lambda b: fac.solve(b, count=False))
    if counters is not None:
        counters.eigensolver_solves += 2 * m * steps
    if np.any(lam <= 0) or not np.all(np.isfinite(lam)):
        raise NumericalError(f"refined eigenvalues {lam[:5]} are not all positive: is K positive semi-definite?")
    phi = phi.copy() if copy else phi
    phi[:, :m] = X
    MX = np.asarray(M @ X)
    for c0 in range(m, phi.shape[1], CHUNK):
        blk = phi[:, c0:c0 + CHUNK]  # a view: updated in place
        blk -= X @ (MX.T @ blk)
        blk /= np.sqrt(np.einsum("ij,ij->j", blk, np.asarray(M @ blk)))
    omega = np.array(omega, dtype=float)
    omega[:m] = np.sqrt(lam)
    return omega, phi


def refined_dense_modes(K, M, omega: np.ndarray, phi: np.ndarray, rigid: np.ndarray,
                        m: int) -> tuple[np.ndarray, np.ndarray]:
    """The dense path's :func:`refined_modes`: a factorisation of ``K - s M`` of its own
    (:func:`refinement_shift` of ``omega[0]``, :func:`refinement_backend`), released at once. Not counted:
    the dense solve counts as one factorisation, its refinement with it. ``phi`` is overwritten (no copy of the
    (n, n) basis); where ``K - s M`` is singular or the refinement fails, ``(omega, phi)`` as given."""
    if m < 1:
        return omega, phi
    s = refinement_shift(float(omega[0]) ** 2)
    if sp.issparse(K) and sp.issparse(M):
        A = sp.csc_matrix(K - s * M)
    else:  # a model given as full matrices
        A = np.asarray(K.toarray() if sp.issparse(K) else K) - s * np.asarray(M.toarray() if sp.issparse(M) else M)
    try:
        fac = factorize(A, backend=refinement_backend(A), label="K - s M (refined dense modes)")
    except NumericalError:  # singular in floating point (a shift below K's round-off, rigid modes): as solved
        return omega, phi
    try:  # phi is the caller's own (n, n) array: overwritten, not copied
        return refined_modes(K, M, omega, phi, rigid, m, s, fac, steps=DENSE_STEPS, copy=False)
    except NumericalError:  # K - s M nearly singular (non-finite solves, an indefinite pencil): as solved
        return omega, phi
    finally:
        fac.release()
