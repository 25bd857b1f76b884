"""Modal analysis: ``K phi = w^2 M phi``, M-normalised, rigid-body modes set aside.

Dense LAPACK for small models, sparse shift-invert Lanczos (ARPACK through
``scipy.sparse.linalg.eigsh``, with a stepnf factorisation as the inverse) for
large ones, or the adapter's own eigen-solver when it declares
``provides_eigenmodes``.

Rigid-body modes are the eigenvalues with ``|w^2| <= rigid_tolerance * lambda_scale``
where ``lambda_scale = max(diag K / diag M)`` bounds the largest eigenvalue
in order of magnitude; computed rigid eigenvalues sit at round-off
(~1e-16 lambda_scale), the lowest elastic ones of thin 3D shells near
1e-8 lambda_scale, so the default 1e-11 leaves three decades either side. A
scene may also state the count (``analysis.rigid_modes``).

Degenerate groups (e.g. the sine and cosine companions of a (k, n) shell mode)
are runs of elastic modes whose frequencies agree to ``degeneracy_tolerance``
(relative).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .counters import Counters
from .errors import NumericalError
from .linalg import DENSE_LIMIT, shifted_factorization


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
    dk = np.asarray(K.diagonal()).ravel() if sp.issparse(K) else np.diag(K)
    dm = np.asarray(M.diagonal()).ravel() if sp.issparse(M) else np.diag(M)
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


def _split(lam: np.ndarray, vec: np.ndarray, M, scale: float, rigid_tol: float,
           rigid_modes: int | None, degeneracy_tol: float, complete: bool, solver: str) -> ModalBasis:
    order = np.argsort(lam)
    lam, vec = lam[order], vec[:, order]
    if rigid_modes is None:
        r = int(np.sum(np.abs(lam) <= rigid_tol * scale))
    else:
        r = int(rigid_modes)
    if np.any(lam[r:] <= 0):
        bad = lam[r:][lam[r:] <= 0]
        raise NumericalError(
            f"eigenvalues {bad[:5]} are zero or negative but above the rigid-body tolerance "
            f"({rigid_tol:g} x {scale:.3e}): K is not positive semi-definite, or set analysis.rigid_modes"
        )
    phi = _normalise(vec, M)
    omega = np.sqrt(lam[r:])
    return ModalBasis(omega=omega, phi=phi[:, r:], rigid=phi[:, :r], rigid_eigenvalues=lam[:r],
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
    progress: Callable[[str], None] | None = None,
) -> ModalBasis:
    """Lowest elastic modes of ``(K, M)``.

    Computes at least ``n_modes`` elastic modes (all of them when the model is
    small enough for a dense solve) and, when ``min_omega`` is given, keeps
    going until the highest computed frequency exceeds it (up to
    ``max_modes``); ``enough(basis)`` may ask for more modes still (e.g.
    until a labelled master mode is found). ``eigensolver(k, shift)`` is the
    adapter's own solver.
    """
    n = K.shape[0]
    if K.shape != (n, n) or M.shape != (n, n):
        raise ValueError(f"K {K.shape} and M {M.shape} must be square and of the same size")
    scale = lambda_scale(K, M)
    if n <= dense_limit and eigensolver is None:
        Kd = K.toarray() if sp.issparse(K) else np.asarray(K)
        Md = M.toarray() if sp.issparse(M) else np.asarray(M)
        try:
            lam, vec = sla.eigh(Kd, Md)
        except np.linalg.LinAlgError as exc:
            raise NumericalError(f"dense eigen-solve failed: {exc} (is M positive definite?)") from exc
        if counters is not None:
            counters.factorizations += 1
        return _split(lam, vec, M, scale, rigid_tolerance, rigid_modes, degeneracy_tolerance, True, "dense")

    need = max(int(n_modes or 1), 1)
    extra = 6 if rigid_modes is None else int(rigid_modes)
    k = min(need + extra + 4, n - 2)  # +4: the twin of the top mode
    # a small negative shift: K - sigma M is regular even with rigid-body modes
    sigma = -1e-10 * scale if scale > 0 else -1.0
    fac = None
    while True:
        if progress:
            progress(f"eigen-solve: {k} modes of a {n}-dof model")
        if eigensolver is not None:
            lam, vec = eigensolver(k, 0.0)
            lam = np.asarray(lam, dtype=float)
            solver = "adapter"
        else:
            if fac is None:
                fac = shifted_factorization(K, M, sigma, counters=counters, backend=backend,
                                            label="K - sigma M (eigen-solve)")
            calls = [0]

            def opinv(b: np.ndarray) -> np.ndarray:
                calls[0] += 1
                return fac.solve(b, count=False)

            Op = spla.LinearOperator((n, n), matvec=opinv, dtype=float)
            lam, vec = spla.eigsh(sp.csr_matrix(K), k=k, M=sp.csr_matrix(M), sigma=sigma,
                                  which="LM", OPinv=Op, tol=1e-12)
            if counters is not None:
                counters.eigensolver_solves += calls[0]
            solver = f"shift-invert Lanczos ({fac.backend})"
        basis = _split(lam, vec, M, scale, rigid_tolerance, rigid_modes, degeneracy_tolerance, False, solver)
        done = basis.n_elastic >= need and (min_omega is None or basis.omega[-1] > min_omega)
        if done and (enough is None or enough(basis)):
            return basis
        if k >= min(max_modes, n - 2):
            return basis
        k = min(max(2 * k, k + 8), max_modes, n - 2)

