"""Gauss-Legendre collocation for ``M x'' + f(x) = 0``: an implicit integrator for stiff models, with the
exact sensitivities of its own discrete map (for shooting, :mod:`stepnf.verify.periodic`).

**Scheme.** The s-stage Gauss-Legendre Runge-Kutta method (order 2s, A-stable, symplectic and symmetric:
a linear oscillator's amplitude is kept exactly at any ``w dt``, none is damped or amplified) on
``y = (x, v)``. Eliminating the stage velocities leaves the stage displacements ``X_i`` (s, n) as the
unknowns::

    R_i = M Z_i + h^2 sum_j Abar_ij f(X_j) = 0,     Z_i = X_i - x0 - h c_i v0,     Abar = A^2

and the step's end from the converged stages without another force evaluation::

    x1 = x0 + h v0 + sum_j (b^T A Abar^-1)_j Z_j,     v1 = v0 + sum_j (b^T Abar^-1)_j Z_j / h

(``A``, ``b``, ``c`` the Butcher tableau). **Newton** on the s n stage unknowns with one batched force
call of the s stage fields per iteration: the matrix ``I (x) M + h^2 Abar (x) K`` with the linear
stiffness, factorised once per step size (the fast modes of a stiff model are linear to a high
degree, so it contracts by about ``h^2 |Kt - K| / |M|`` on the slow ones); where that does not
contract, the tangent at the current stages (the model's ``tangent``, else central differences of
the forces). **Sensitivities**: differentiating ``R = 0`` at the converged stages gives the step's
derivatives with respect to ``(x0, v0, h)`` through the tangents ``Kt(X_j)``; chained over the steps
they are the derivatives of the discrete end state, consistent with the integration to round-off.

Why not an explicit method on a stiff model: DOP853's step is bounded by ``~3.3 / w_max`` whatever the
accuracy asked, so a model whose highest frequency is 1000 times its master's costs thousands of
steps per period; this scheme's step is set by the master's period alone (``steps`` per run).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from stepnf.errors import NumericalError

ForceBatch = Callable[[np.ndarray], np.ndarray]


def gauss_tableau(s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Butcher tableau ``(A, b, c)`` of the s-stage Gauss-Legendre method (order 2s) on [0, 1]."""
    c, w = np.polynomial.legendre.leggauss(s)
    c, b = 0.5 * (c + 1.0), 0.5 * w
    # A_ij = int_0^{c_i} l_j(t) dt, l_j the Lagrange polynomial of the nodes c
    A = np.zeros((s, s))
    for j in range(s):
        coef = np.polynomial.polynomial.polyfromroots(np.delete(c, j))
        coef /= np.polynomial.polynomial.polyval(c[j], coef)
        integ = np.polynomial.polynomial.polyint(coef)
        A[:, j] = np.polynomial.polynomial.polyval(c, integ)
    return A, b, c


@dataclass
class Work:
    """Work counters of a :class:`GaussLegendre` (all runs): steps, Newton iterations, force fields sent,
    batched force calls, tangent evaluations, factorisations."""

    steps: int = 0
    iterations: int = 0
    force_evaluations: int = 0
    force_calls: int = 0
    tangents: int = 0
    factorizations: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class GaussLegendre:
    """Gauss-Legendre collocation for ``M x'' + f(x) = 0`` (module docstring).

    ``M``, ``K`` (n, n) dense or sparse; ``forces(U)`` the internal forces (m, n) of the fields ``U``
    (m, n); ``tangent(x)`` the tangent stiffness (n, n) dense or sparse, or None (central
    differences); ``stages`` s (order 2s); ``tol`` Newton's stopping increment relative to ``scale``.
    """

    def __init__(self, M, K, forces: ForceBatch, *, tangent: Callable | None = None, stages: int = 6,
                 tol: float = 1e-15, maxiter: int = 30):
        self.M = M.toarray() if sp.issparse(M) else np.asarray(M, dtype=float)
        self.K = K.toarray() if sp.issparse(K) else np.asarray(K, dtype=float)
        self.n = self.M.shape[0]
        self.forces, self.tangent = forces, tangent
        self.s, self.tol, self.maxiter = int(stages), float(tol), int(maxiter)
        self.A, self.b, self.c = gauss_tableau(self.s)
        self.Abar = self.A @ self.A
        Ainv = np.linalg.inv(self.Abar)
        self.dx = self.b @ self.A @ Ainv  # x1 = x0 + h v0 + dx . Z
        self.dv = self.b @ Ainv           # v1 = v0 + dv . Z / h
        self.work = Work()
        self._lu: tuple[float, object] | None = None

    # ------------------------------------------------------------ pieces
    def _f(self, X: np.ndarray) -> np.ndarray:
        self.work.force_evaluations += len(X)
        self.work.force_calls += 1
        return np.asarray(self.forces(X), dtype=float)

    def _tangents(self, X: np.ndarray) -> list[np.ndarray]:
        """``Kt(X_j)`` (n, n) at each stage: the model's tangent, else central differences (one batch)."""
        self.work.tangents += len(X)
        if self.tangent is not None:
            out = []
            for x in X:
                T = self.tangent(x)
                out.append(T.toarray() if sp.issparse(T) else np.asarray(T, dtype=float))
            return out
        n = self.n
        out = []
        for x in X:
            d = 1e-6 * max(float(np.abs(x).max()), 1e-8)
            F = self._f(np.concatenate([x + d * np.eye(n), x - d * np.eye(n)]))
            out.append(((F[:n] - F[n:]) / (2 * d)).T)
        return out

    def _matrix(self, h: float, Ks: list[np.ndarray]) -> np.ndarray:
        """``I (x) M + h^2 (Abar (x) I) diag(Ks)`` (s n, s n)."""
        s, n = self.s, self.n
        J = np.kron(np.eye(s), self.M)
        for i in range(s):
            for j in range(s):
                J[i * n:(i + 1) * n, j * n:(j + 1) * n] += h * h * self.Abar[i, j] * Ks[j]
        return J

    def _factor(self, J: np.ndarray):
        self.work.factorizations += 1
        return sla.lu_factor(J, check_finite=False)

    def _modified(self, h: float):
        if self._lu is None or self._lu[0] != h:
            self._lu = (h, self._factor(self._matrix(h, [self.K] * self.s)))
        return self._lu[1]

    def _residual(self, X, x0, v0, h):
        Z = X - x0 - h * np.outer(self.c, v0)
        F = self._f(X)
        return (Z @ self.M.T + h * h * (self.Abar @ F)).ravel()

    # ----------------------------------------------------------- one step
    def _stages(self, x0, v0, h, guess, scale, what) -> np.ndarray:
        s, n = self.s, self.n
        X = guess.copy()
        lu, sizes = self._modified(h), []
        for it in range(1, self.maxiter + 1):
            self.work.iterations += 1
            dX = -sla.lu_solve(lu, self._residual(X, x0, v0, h), check_finite=False).reshape(s, n)
            size = float(np.abs(dX).max())
            if not np.isfinite(size):
                break
            X = X + dX
            if size <= self.tol * scale or (size <= 1e-12 * scale and len(sizes) and size >= 0.5 * sizes[-1]):
                return X  # converged, or at the round-off floor
            sizes.append(size)
            if len(sizes) >= 3 and sizes[-1] > 0.5 * sizes[-3]:  # not contracting: the tangent at the stages
                lu = self._factor(self._matrix(h, self._tangents(X)))
        raise NumericalError(f"{what}: the implicit stage equations did not converge (step {h:.6g}, "
                             f"last increment {sizes[-1] if sizes else float('nan'):.3g} of the state {scale:.3g})")

    def run(self, x0: np.ndarray, v0: np.ndarray, t_end: float, steps: int, *, sensitivity: bool = False,
            keep: bool = False, what: str = "implicit integration") -> "Run":
        """``steps`` equal steps from ``(x0, v0)`` to ``t_end``.

        ``sensitivity``: also the derivatives of the end state ``(x, v)`` (2n,) with respect to ``x0``
        (n columns) and ``t_end`` (1 column), of the discrete map; ``keep``: the state at every node.
        """
        n = self.n
        x = np.asarray(x0, dtype=float).copy()
        v = np.asarray(v0, dtype=float).copy()
        h = float(t_end) / int(steps)
        scale = max(float(np.abs(x).max()), float(np.abs(v).max()) * h, 1e-300)
        S = np.vstack([np.hstack([np.eye(n), np.zeros((n, 1))]), np.zeros((n, n + 1))]) if sensitivity else None
        dh = np.zeros(n + 1)
        dh[n] = 1.0 / int(steps)
        nodes = [np.concatenate([x, v])] if keep else None
        prev = None
        for k in range(int(steps)):
            self.work.steps += 1
            if prev is None:
                a0 = -np.linalg.solve(self.M, self._f(x[None])[0])
                guess = x + h * np.outer(self.c, v) + 0.5 * h * h * np.outer(self.c ** 2, a0)
            else:  # the last step's collocation polynomial through (0, c, 1), continued
                guess = _extrapolate(self.c, prev, 1.0 + self.c)
            X = self._stages(x, v, h, guess, scale, what)
            Z = X - x - h * np.outer(self.c, v)
            x1 = x + h * v + self.dx @ Z
            v1 = v + (self.dv @ Z) / h
            if S is not None:
                S = self._sensitivity(X, Z, x, v, h, S, dh)
            prev = (x, X, x1)
            x, v = x1, v1
            if not (np.all(np.isfinite(x)) and float(np.abs(x).max()) <= 1e3 * scale):
                raise NumericalError(f"{what}: the integration diverged at t = {(k + 1) * h:.6g}")
            if keep:
                nodes.append(np.concatenate([x, v]))
        return Run(x, v, h, S, None if nodes is None else np.array(nodes))

    def _sensitivity(self, X, Z, x0, v0, h, S, dh) -> np.ndarray:
        """Chain one step: ``S`` (2n, p) the derivatives of ``(x0, v0)``, ``dh`` (p,) those of ``h``."""
        s, n = self.s, self.n
        Ks = self._tangents(X)
        lu = self._factor(self._matrix(h, Ks))
        dx0, dv0 = S[:n], S[n:]
        AF = -(Z @ self.M.T) / (h * h)  # Abar F (s, n) from R = 0: no force evaluation
        # J dX = (I (x) M)(1 dx0 + h c dv0 + c v0 dh) - 2 h dh (Abar (x) I) F
        rhs = np.concatenate([self.M @ (dx0 + h * ci * dv0 + ci * np.outer(v0, dh)) - 2 * h * np.outer(AF[i], dh)
                              for i, ci in enumerate(self.c)])
        dX = sla.lu_solve(lu, rhs, check_finite=False).reshape(s, n, -1)
        dZ = dX - dx0[None] - h * self.c[:, None, None] * dv0[None] - self.c[:, None, None] * np.outer(v0, dh)[None]
        zx = np.einsum("i,inp->np", self.dx, dZ)
        zv = np.einsum("i,inp->np", self.dv, dZ)
        Zv = self.dv @ Z
        dx1 = dx0 + h * dv0 + np.outer(v0, dh) + zx
        dv1 = dv0 + zv / h - np.outer(Zv, dh) / (h * h)
        return np.vstack([dx1, dv1])

    def state_at(self, node: np.ndarray, tau: float) -> np.ndarray:
        """The state ``(x, v)`` (2n,) one step of length ``tau`` after the node state ``(x, v)`` (2n,)."""
        n = self.n
        x, v = node[:n], node[n:]
        if tau == 0.0:
            return node.copy()
        r = self.run(x, v, tau, 1)
        return np.concatenate([r.x, r.v])


@dataclass
class Run:
    """End state ``x``, ``v`` (n,), step ``h``, sensitivities ``S`` (2n, n + 1) or None, ``nodes``
    (steps + 1, 2n) or None."""

    x: np.ndarray
    v: np.ndarray
    h: float
    S: np.ndarray | None
    nodes: np.ndarray | None


def _extrapolate(c: np.ndarray, prev: tuple, at: np.ndarray) -> np.ndarray:
    """Values at ``at`` of the polynomial through ``(0, x0)``, ``(c_i, X_i)``, ``(1, x1)``."""
    x0, X, x1 = prev
    nodes = np.concatenate([[0.0], c, [1.0]])
    vals = np.vstack([x0[None], X, x1[None]])
    out = np.zeros((len(at), vals.shape[1]))
    for j, tj in enumerate(nodes):
        others = np.delete(nodes, j)
        w = np.prod((at[:, None] - others[None]) / (tj - others[None]), axis=1)
        out += np.outer(w, vals[j])
    return out
