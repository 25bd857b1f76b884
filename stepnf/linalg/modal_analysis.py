"""Modal analysis: ``K phi = w^2 M phi``, M-normalised, rigid-body modes set aside.

Dense LAPACK for small models, sparse shift-invert Lanczos (ARPACK through
``scipy.sparse.linalg.eigsh``, with a stepnf factorisation as the inverse) for
large ones, or the adapter's own eigen-solver when it declares
``provides_eigenmodes``. When the sparse path finds rigid-body modes, the
elastic ones are computed again with the rigid ones projected out (same
factorisation): a cluster of rigid modes at ``1/|sigma|`` otherwise costs
the elastic frequencies up to ~1e-4 of their accuracy. When the run needs more
modes than the first batch holds, the next ones are computed with every mode
found so far projected out, on the same factorisation, and merged
(:mod:`stepnf.linalg.eigen_extension`); the adapter's eigen-solver starts over instead.

Rigid-body modes (``rigid_modes`` None, the scene's "auto") are decided from the model
(:mod:`stepnf.linalg.null_space`): an eigenvalue with ``|w^2| <= rigid_tolerance * lambda_scale``
(``lambda_scale = max(diag K / diag M)`` bounds the largest eigenvalue in order of magnitude) is
only a candidate, rigid when K has a null vector there: the rigid-body fields of the dof
coordinates that K does not resist, and any other eigenvector whose residual ``K x`` is at the
round-off of K (a mechanism). A structure its conditions hold has none, however low its
fundamental (a slender cantilever's lies near 1e-11 lambda_scale); a polynomial model with no
zero eigenvalue has none. A scene may also state the count (``analysis.rigid_modes``).

A semi-definite M (reduced integration, massless dofs) has infinite eigenvalues: the dense path
then solves the pencil ``(M, K - sigma M)`` and drops them, saying how many (``massless``,
``solver``); shift-invert Lanczos never reaches them.

The low modes are refined (:mod:`stepnf.linalg.refined_modes`: a shift-inverted Rayleigh-Ritz step whose solve
sees K and M apart) on the dense path, and on the sparse path when its shift lies beyond lambda_1 (a stiff model):
their frequencies then carry the round-off of the model's matrices, not that of ``eigh`` (which depends on the
BLAS thread count) or of the entries of ``K - sigma M``.

Degenerate groups (e.g. the sine and cosine companions of a (k, n) shell mode)
are runs of elastic modes whose frequencies agree to ``degeneracy_tolerance``
(relative).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from stepnf.runtime.counters import Counters
from stepnf.linalg.eigen_extension import extension_size, merged_modes, shift_invert_modes
from stepnf.errors import NumericalError
from stepnf.linalg.factorization import DENSE_LIMIT, matrix_diagonal
from stepnf.linalg.null_space import (dense_modes, rigid_body_fields, rigid_field_count, rigid_indices,
                                      rigid_modes_from, rigid_span)
from stepnf.linalg.refined_modes import far_shift, refined_count, refined_dense_modes, refined_modes, refinement_shift
from stepnf.linalg.shifted import ShiftedFactorizer


#: Room for rigid-body modes in a first eigen-solve that has to find them (a free 3D body has six).
_RIGID_ROOM = 6
#: Re-exported: callers import the rigid-body fields from here.
__all__ = ["ModalBasis", "lambda_scale", "degenerate_groups", "modal_analysis", "extend_basis", "rigid_body_fields",
           "rigid_modes_from", "modes_near", "probe_vector", "orient_degenerate"]


@dataclass
class ModalBasis:
    """Eigenmodes of a model, elastic and rigid apart.

    ``omega`` (m,) elastic angular frequencies, increasing; ``phi`` (n, m)
    M-normalised elastic modes (column ``s`` is elastic mode ``s``); ``rigid``
    (n, r) M-normalised rigid-body modes; ``degenerate_groups``: lists of
    elastic-mode indices sharing a frequency; ``complete``: every mode of the
    model was computed (dense solve).
    """

    omega: np.ndarray
    phi: np.ndarray
    rigid: np.ndarray
    rigid_eigenvalues: np.ndarray
    degenerate_groups: list[list[int]] = field(default_factory=list)
    complete: bool = False
    solver: str = ""
    #: the eigen-solver's factorisation of ``K - shift M`` (sparse path), reusable by later solves
    factorization: Any = None
    shift: float = 0.0
    #: directions without mass (infinite eigenvalues of a semi-definite M) left out of a dense solve
    massless: int = 0

    @property
    def n_elastic(self) -> int:
        return len(self.omega)

    def twins(self, p: int) -> list[int]:
        """Other members of the degenerate group of mode ``p``."""
        for g in self.degenerate_groups:
            if p in g:
                return [s for s in g if s != p]
        return []


def _normalise(phi: np.ndarray, M: sp.spmatrix) -> np.ndarray:
    norms = np.sqrt(np.einsum("ij,ij->j", phi, M @ phi))
    if np.any(norms <= 0) or not np.all(np.isfinite(norms)):
        raise NumericalError("a computed mode has zero or non-finite mass: is M positive definite?")
    phi = phi / norms
    # sign convention: the largest entry of each mode is positive (reproducible output)
    idx = np.argmax(np.abs(phi), axis=0)
    signs = np.sign(phi[idx, np.arange(phi.shape[1])])
    signs[signs == 0] = 1.0
    return phi * signs


def lambda_scale(K: sp.spmatrix, M: sp.spmatrix) -> float:
    """``max(diag K / diag M)``: the order of magnitude of the largest eigenvalue."""
    dk, dm = matrix_diagonal(K), matrix_diagonal(M)
    ok = dm > 0
    if not ok.any():
        raise NumericalError("the mass matrix has no positive diagonal entry")
    return float(np.max(np.abs(dk[ok]) / dm[ok]))


def degenerate_groups(omega: np.ndarray, tol: float) -> list[list[int]]:
    """Runs of consecutive frequencies equal to relative tolerance ``tol``."""
    groups: list[list[int]] = []
    cur = [0] if len(omega) else []
    for s in range(1, len(omega)):
        if abs(omega[s] - omega[s - 1]) <= tol * max(abs(omega[s]), 1e-300):
            cur.append(s)
        else:
            if len(cur) > 1:
                groups.append(cur)
            cur = [s]
    if len(cur) > 1:
        groups.append(cur)
    return groups


def _split(lam: np.ndarray, vec: np.ndarray, K, M, scale: float, rigid_tol: float,
           rigid_modes: int | None, degeneracy_tol: float, complete: bool, solver: str,
           n_rigid_fields: int | None = None) -> ModalBasis:
    order = np.argsort(lam)
    lam, vec = lam[order], vec[:, order]
    if rigid_modes is None:
        rig = rigid_indices(lam, vec, K, scale, rigid_tol, n_rigid_fields)
    else:
        rig = np.arange(int(rigid_modes))
    ela = np.setdiff1d(np.arange(len(lam)), rig)
    if np.any(lam[ela] <= 0):
        bad = lam[ela][lam[ela] <= 0]
        raise NumericalError(
            f"eigenvalues {bad[:5]} are zero or negative but K has no null vector there (rigid-body tolerance "
            f"{rigid_tol:g} x {scale:.3e}): K is not positive semi-definite, or set analysis.rigid_modes"
        )
    phi = _normalise(vec, M)
    omega = np.sqrt(lam[ela])
    return ModalBasis(omega=omega, phi=phi[:, ela], rigid=phi[:, rig], rigid_eigenvalues=lam[rig],
                      degenerate_groups=degenerate_groups(omega, degeneracy_tol),
                      complete=complete, solver=solver)


def modal_analysis(
    K: sp.spmatrix,
    M: sp.spmatrix,
    n_modes: int | None = None,
    *,
    counters: Counters | None = None,
    rigid_tolerance: float = 1e-11,
    rigid_modes: int | None = None,
    degeneracy_tolerance: float = 1e-4,
    min_omega: float | None = None,
    enough: Callable[[ModalBasis], bool] | None = None,
    max_modes: int = 400,
    dense_limit: int = DENSE_LIMIT,
    backend: str = "auto",
    eigensolver: Callable[[int, float], tuple[np.ndarray, np.ndarray]] | None = None,
    rigid_candidates: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None,
    first_batch: int | None = None,
) -> ModalBasis:
    """Lowest elastic modes of ``(K, M)``.

    Computes at least ``n_modes`` elastic modes (all of them when the model is
    small enough for a dense solve) and, when ``min_omega`` is given, keeps
    going until the highest computed frequency exceeds it (up to
    ``max_modes``); ``enough(basis)`` may ask for more modes still (e.g.
    until a labelled master mode is found). The sparse path extends its basis
    batch by batch (:func:`stepnf.linalg.eigen_extension.extension_size` modes more
    each time) on one factorisation. ``eigensolver(k, shift=...)`` is the
    adapter's own solver. ``rigid_candidates`` (n, 6), e.g. from
    :func:`rigid_body_fields`, lets the sparse path find the rigid-body modes
    without Lanczos and project them out from the start. ``first_batch``: the
    sparse path's first Lanczos run computes that many modes (default
    ``n_modes`` + 4 for twins, + room for the rigid-body modes when they are
    not known beforehand), e.g. a guess from the number of labelled masters.
    """
    n = K.shape[0]
    if K.shape != (n, n) or M.shape != (n, n):
        raise ValueError(f"K {K.shape} and M {M.shape} must be square and of the same size")
    scale = lambda_scale(K, M)
    n_rb = None  # rigid motions K does not resist, when the dof geometry gives them
    if rigid_candidates is not None and rigid_modes is None:
        n_rb = rigid_field_count(K, rigid_span(rigid_candidates))
    need = max(int(n_modes or 1), 1)
    if n <= dense_limit and eigensolver is None:
        lam, vec, massless = dense_modes(K, M, scale, rigid_tolerance)
        if counters is not None:
            counters.factorizations += 1
        solver = "dense" if not massless else f"dense, (M, K - sigma M): {massless} massless directions dropped"
        if massless and progress:
            progress(f"eigen-solve: M is singular: {massless} directions without mass (infinite eigenvalues) dropped")
        basis = _split(lam, vec, K, M, scale, rigid_tolerance, rigid_modes, degeneracy_tolerance, True, solver, n_rb)
        basis.massless = massless
        # the modes the run uses, as many as the sparse path's first batch (and those below min_omega)
        m = refined_count(basis.omega, _first_size(need, first_batch, 0, max_modes), min_omega,
                          basis.degenerate_groups)
        omega, phi = refined_dense_modes(K, M, basis.omega, basis.phi, basis.rigid, m)
        return _refined(basis, omega, phi, m, M, degeneracy_tolerance)

    if eigensolver is not None:
        return _adapter_modes(eigensolver, K, M, n_rb, need, _first_size(need, first_batch, rigid_modes, max_modes),
                              scale, rigid_tolerance, rigid_modes, degeneracy_tolerance, min_omega, enough, max_modes,
                              progress)
    # a small negative shift: K - sigma M is regular even with rigid-body modes
    sigma = -1e-10 * scale if scale > 0 else -1.0
    R = None  # rigid modes, when the dof geometry gives them: every Lanczos run then projects them out
    if rigid_candidates is not None and rigid_modes is None:
        R = rigid_modes_from(K, M, rigid_candidates, scale, rigid_tolerance, n_rb)
    # on the union pattern of K and M, shared with them: no copy of the indices, no sparse sum kept
    shifter = ShiftedFactorizer(K, M, counters=counters, backend=backend)
    fac = shifter.factorizer(sigma, "K - sigma M (eigen-solve)")
    k = _first_size(need, first_batch, rigid_modes if R is None else 0, max_modes)  # R known: no room for it
    k = min(k, n - 2 - (R.shape[1] if R is not None else 0))
    if progress:
        progress(f"eigen-solve: {k} modes of a {n}-dof model")
    calls = [0]
    basis = _first_batch(K, M, sigma, fac, k, R, calls, scale, rigid_tolerance, rigid_modes, degeneracy_tolerance,
                         f"shift-invert Lanczos ({fac.backend})")
    if counters is not None:
        counters.eigensolver_solves += calls[0]
    basis.factorization, basis.shift = fac, sigma
    refine = basis.n_elastic > 0 and far_shift(sigma, float(basis.omega[0]) ** 2)
    if refine:  # a stiff model: the later batches and the refinement on K - s M, s near lambda_1
        s_ref = refinement_shift(float(basis.omega[0]) ** 2)
        try:
            basis.factorization = shifter.factorizer(s_ref, "K - s M (refined eigen-solve)")
        except NumericalError:  # K - s M singular in floating point (s below K's round-off): not refined
            refine = False
    if refine:
        basis.shift = s_ref
        fac.release()
        if progress:
            progress(f"eigen-solve: shift {sigma:.3g} beyond lambda_1 = {basis.omega[0] ** 2:.3g}: modes refined "
                     f"at {basis.shift:.3g}")
    while True:
        room = min(max_modes - basis.n_elastic, n - 2 - basis.n_elastic - basis.rigid.shape[1])
        if room <= 0 or _satisfied(basis, need, min_omega, enough):
            if not refine:
                return basis
            try:
                omega, phi = refined_modes(K, M, basis.omega, basis.phi, basis.rigid, basis.n_elastic, basis.shift,
                                           basis.factorization, counters)
            except NumericalError as exc:  # K - s M nearly singular: the Lanczos modes, said so
                if progress:
                    progress(f"eigen-solve: modes not refined ({exc})")
                return replace(basis, solver=f"{basis.solver}, not refined")
            return _refined(basis, omega, phi, basis.n_elastic, M, degeneracy_tolerance, f"{basis.solver}, refined")
        more = min(extension_size(basis.n_elastic, need), room)
        if progress:
            progress(f"eigen-solve: {more} more modes of a {n}-dof model ({basis.n_elastic} found)")
        basis = extend_basis(K, M, basis, more, counters=counters, degeneracy_tolerance=degeneracy_tolerance)


def _refined(basis: ModalBasis, omega: np.ndarray, phi: np.ndarray, m: int, M, degeneracy_tolerance: float,
             solver: str | None = None) -> ModalBasis:
    """``basis`` with the modes of :mod:`stepnf.linalg.refined_modes` (the first ``m`` refined, signs fixed)."""
    phi[:, :m] = _normalise(phi[:, :m], M)
    return replace(basis, omega=omega, phi=phi, degenerate_groups=degenerate_groups(omega, degeneracy_tolerance),
                   solver=basis.solver if solver is None else solver)


def extend_basis(K: sp.spmatrix, M: sp.spmatrix, basis: ModalBasis, more: int, *, counters: Counters | None = None,
                 degeneracy_tolerance: float = 1e-4) -> ModalBasis:
    """``basis`` and its next ``more`` elastic modes, on the basis' own factorisation.

    The new modes are computed with every mode of ``basis`` (rigid and elastic) projected out
    M-orthogonally (:mod:`stepnf.linalg.eigen_extension`), then merged by frequency: a mode an earlier
    batch missed comes back in its place. Degenerate groups are those of the merged frequencies
    (relative ``degeneracy_tolerance``). ``basis`` must come from the sparse path (it carries
    ``factorization`` and ``shift``); ``counters.eigensolver_solves`` counts the shifted solves.
    """
    if basis.factorization is None:
        raise ValueError("extend_basis needs a basis from the sparse path (with its factorisation)")
    calls = [0]
    Q = np.column_stack([basis.rigid, basis.phi])
    more = min(int(more), K.shape[0] - Q.shape[1] - 2)  # ARPACK: k + q < n, plus one vector to spare
    if more < 1:
        raise ValueError(f"no mode left to add: {Q.shape[1]} of {K.shape[0]} found")
    lam, vec = shift_invert_modes(K, M, basis.shift, basis.factorization, more, Q, calls)
    if counters is not None:
        counters.eigensolver_solves += calls[0]
    new = _deflated_basis(lam, vec, M, basis.rigid, basis.rigid_eigenvalues, degeneracy_tolerance, basis.solver)
    omega, phi = merged_modes(basis.omega, basis.phi, new.omega, new.phi)
    return ModalBasis(omega=omega, phi=phi, rigid=basis.rigid, rigid_eigenvalues=basis.rigid_eigenvalues,
                      degenerate_groups=degenerate_groups(omega, degeneracy_tolerance), complete=False,
                      solver=basis.solver, factorization=basis.factorization, shift=basis.shift)


def _satisfied(basis: ModalBasis, need: int, min_omega: float | None,
               enough: Callable[[ModalBasis], bool] | None) -> bool:
    """Whether ``basis`` holds ``need`` elastic modes, reaches ``min_omega`` and passes ``enough``."""
    done = basis.n_elastic >= need and (min_omega is None or basis.omega[-1] > min_omega)
    return done and (enough is None or enough(basis))


def _first_size(need: int, first_batch: int | None, rigid_modes: int | None, max_modes: int) -> int:
    """Modes of the first eigen-solve: the elastic ones (``first_batch``, or ``need`` + 4 for a twin
    and the modes just above; at most ``max_modes``, unless ``need`` is more) and room for the rigid
    ones it has to find (``rigid_modes``, the scene's count; six when None; 0 when they are projected
    out from the start)."""
    elastic = need + 4 if first_batch is None else max(int(first_batch), 1)
    elastic = min(elastic, max(int(max_modes), need))
    return elastic + (_RIGID_ROOM if rigid_modes is None else int(rigid_modes))


def _adapter_modes(eigensolver, K, M, n_rb: int | None, need: int, k: int, scale: float, rigid_tolerance: float,
                   rigid_modes: int | None, degeneracy_tolerance: float, min_omega: float | None, enough,
                   max_modes: int, progress) -> ModalBasis:
    """The adapter's own eigen-solver, ``k`` modes first: it cannot project found modes out, so a
    run that needs more modes starts over with about twice as many."""
    n = M.shape[0]
    while True:
        k = min(k, n - 2)
        if progress:
            progress(f"eigen-solve: {k} modes of a {n}-dof model")
        lam, vec = eigensolver(k, shift=0.0)
        basis = _split(np.asarray(lam, dtype=float), vec, K, M, scale, rigid_tolerance, rigid_modes,
                       degeneracy_tolerance, False, "adapter", n_rb)
        if _satisfied(basis, need, min_omega, enough) or k >= min(max_modes, n - 2):
            return basis
        k = min(max(2 * k, k + 8), max_modes, n - 2)


def _first_batch(K, M, sigma: float, fac, k: int, R: np.ndarray | None, calls: list[int], scale: float,
                 rigid_tolerance: float, rigid_modes: int | None, degeneracy_tolerance: float,
                 solver: str) -> ModalBasis:
    """The lowest ``k`` modes by shift-invert Lanczos (elastic ones only when ``R`` is known)."""
    n = K.shape[0]
    if R is not None:
        lam, vec = shift_invert_modes(K, M, sigma, fac, k, R, calls)
        mech = rigid_indices(lam, vec, K, scale, rigid_tolerance) if rigid_modes is None else np.zeros(0, int)
        if len(mech):  # mechanisms that are no rigid motion of the whole (a loose part, a hinge)
            ela = np.setdiff1d(np.arange(len(lam)), mech)
            R = np.column_stack([R, _normalise(vec[:, mech], M)])
            found = np.concatenate([np.zeros(R.shape[1] - len(mech)), lam[mech]])
            return _deflated_basis(lam[ela], vec[:, ela], M, R, found, degeneracy_tolerance, solver)
        return _deflated_basis(lam, vec, M, R, np.zeros(R.shape[1]), degeneracy_tolerance, solver)
    lam, vec = shift_invert_modes(K, M, sigma, fac, k, None, calls)
    basis = _split(lam, vec, K, M, scale, rigid_tolerance, rigid_modes, degeneracy_tolerance, False, solver)
    if basis.rigid.shape[1] and basis.n_elastic:
        # The rigid modes sit at 1/|sigma| in the shift-inverted spectrum and swamp the elastic ones
        # (errors ~1e-4 on small models): redo the elastic modes with the rigid ones projected out,
        # same factorisation.
        R = basis.rigid
        lam, vec = shift_invert_modes(K, M, sigma, fac, min(basis.n_elastic, n - R.shape[1] - 1), R, calls)
        basis = _deflated_basis(lam, vec, M, R, basis.rigid_eigenvalues, degeneracy_tolerance, solver)
    return basis


def _deflated_basis(lam, vec, M, R, rigid_eigenvalues, degeneracy_tolerance, solver) -> ModalBasis:
    if np.any(lam <= 0):
        raise NumericalError(f"eigenvalues {lam[lam <= 0][:5]} are zero or negative once the rigid-body modes "
                             "are set aside: K is not positive semi-definite, or set analysis.rigid_modes")
    omega = np.sqrt(lam)
    return ModalBasis(omega=omega, phi=_normalise(vec, M), rigid=R, rigid_eigenvalues=rigid_eigenvalues,
                      degenerate_groups=degenerate_groups(omega, degeneracy_tolerance), complete=False,
                      solver=solver)


def modes_near(K: sp.spmatrix, M: sp.spmatrix, sigma: float, solve: Callable[[np.ndarray], np.ndarray],
               k: int = 4, *, v0: np.ndarray | None = None, counters: Counters | None = None,
               tol: float = 1e-8) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` eigenpairs nearest ``sigma`` (an angular frequency squared), M-normalised.

    ``solve`` applies ``(K - sigma M)^-1`` with a factorisation that already
    exists (the DNF's ``K - 4 w^2 M``), so the check for 1:2 internal
    resonances costs a few solves and no new factorisation. Returns
    ``(omega, phi)`` sorted by frequency (negative eigenvalues, i.e. rigid
    modes, come back as omega = 0).
    """
    n = K.shape[0]
    k = min(k, n - 2)
    calls = [0]

    def op(b: np.ndarray) -> np.ndarray:
        calls[0] += 1
        return solve(b)

    Op = spla.LinearOperator((n, n), matvec=op, dtype=float)
    lam, vec = spla.eigsh(sp.csr_matrix(K), k=k, M=sp.csr_matrix(M), sigma=sigma, which="LM", OPinv=Op,
                          v0=v0, tol=tol)
    if counters is not None:
        counters.eigensolver_solves += calls[0]
    order = np.argsort(lam)
    lam, vec = lam[order], vec[:, order]
    return np.sqrt(np.maximum(lam, 0.0)), _normalise(vec, M)


def probe_vector(X: np.ndarray | None, D: np.ndarray | None, n: int) -> np.ndarray:
    """A fixed pseudo-random field, a function of each dof's position and direction only.

    It does not depend on the dof ordering, so two solvers (or a serial and an
    MPI run, whose orderings differ) that compute the same degenerate
    eigenspace orient it the same way (:func:`orient_degenerate`).
    """
    if X is None or D is None:
        return np.random.default_rng(20201).standard_normal(n)
    X = np.asarray(X, dtype=float)
    scale = max(float(np.ptp(X)), 1e-300)
    t = X / scale @ np.array([12.9898, 78.233, 37.719]) + 4.1 * np.asarray(D, dtype=float)
    return np.sin(t) * 43758.5453 % 1.0 - 0.5


def orient_degenerate(basis: ModalBasis, M: sp.spmatrix, probe: np.ndarray, exact: float = 1e-8) -> ModalBasis:
    """Fix the basis of every degenerate group (in place): any rotation within a group is an
    eigenbasis, and the solver's pick is arbitrary; T of a mode of the group depends on it when the
    model is not exactly axisymmetric. The first mode of the group becomes the M-projection of
    ``probe`` on the group, the others the rest in an order and orientation fixed the same way.
    Only groups equal to ``exact`` (relative) are turned: a pair split by the mesh (a few 1e-4)
    has eigenvectors of its own, which a rotation would spoil.
    """
    for group in basis.degenerate_groups:
        w = basis.omega[group]
        if w.max() - w.min() > exact * w.max():
            continue
        V = basis.phi[:, group]
        c = V.T @ (M @ probe)  # coordinates of the probe in the group
        if not np.linalg.norm(c) > 0:
            continue
        # an orthonormal basis of R^d whose first vector is c/|c| (Householder), orientation fixed
        d = len(group)
        e1 = np.zeros(d)
        e1[0] = 1.0
        u = c / np.linalg.norm(c)
        w = u - e1
        Q = np.eye(d) if np.linalg.norm(w) < 1e-14 else np.eye(d) - 2.0 * np.outer(w, w) / (w @ w)
        W = V @ Q  # first column along the probe, the others orthogonal to it
        for j in range(1, d):  # orient the others by the probe's second-order content
            if float(W[:, j] @ (M @ (probe * probe))) < 0:
                W[:, j] = -W[:, j]
        basis.phi[:, group] = W
    return basis
