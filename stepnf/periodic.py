"""Periodic orbits of the full model by shooting: the independent reference for DPIM backbones.

Model ``M x'' + f(x) = 0`` (conservative, ``f`` a gradient, no velocity
terms), hence reversible (``t -> -t``). A nonlinear-normal-mode orbit is a
*brake orbit*: it starts at rest, ``x(0) = x0, v(0) = 0``, and is at rest
again at half its period, after which it retraces itself. So the shooting
unknowns are ``(x0, T)`` (n + 1) and the equations::

    v(T/2; x0) = 0                       (n)
    phi^T M x0 = q0                      (1, the amplitude condition)

solved by Newton. The Jacobian is ``[[dv/dx0, v'(T/2)/2], [phi^T M, 0]]``
with ``dv/dx0`` from the variational equations
``d/dt [X; V] = [V; -M^-1 Df(x) X]``, ``X(0) = I, V(0) = 0``, ``Df`` from
``tangent(x)`` or central differences of f along the columns of X (the
Jacobian only steers Newton: the converged orbit's accuracy is that of the
residual integration, ``solve_ivp`` DOP853 with ``rtol = 1e-12``).

The amplitude is measured as for the backbone: ``A = (max q - min q) / 2``,
``q = phi^T M x(t)`` over one period (over [0, T/2] by reversibility), on a
dense grid of the integrator's dense output refined by Brent's method. An
outer secant iteration on ``q0`` hits a requested ``A``; a continuation in
``q0`` from small amplitudes (linear guess ``x0 = q0 phi``, ``T = 2 pi / w``)
keeps Newton on the branch of the master mode.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.integrate import solve_ivp
from scipy.optimize import minimize_scalar

from .errors import NumericalError

Force = Callable[[np.ndarray], np.ndarray]


@dataclass
class PeriodicOrbit:
    """A converged brake orbit: ``x0`` (n,), period ``T``, ``omega = 2 pi / T``, amplitude ``A`` of q_p."""

    x0: np.ndarray
    period: float
    omega: float
    amplitude: float
    q0: float
    residual: float
    newton_iterations: int


class Shooting:
    """Shooting for the brake orbits of ``M x'' + f(x) = 0`` near master mode ``phi`` (module docstring).

    ``M``, ``K`` (n, n) dense or sparse; ``f(x)`` the internal force of one
    field (n,); ``tangent(x)`` (optional) ``Df(x)`` (n, n); ``phi``
    M-normalised; ``omega`` its angular frequency.
    """

    def __init__(self, M, K, f: Force, phi: np.ndarray, omega: float, *, tangent: Callable | None = None,
                 rtol: float = 1e-12, jac_rtol: float = 1e-9):
        self.n = len(phi)
        self.M = M
        self.K = K
        self.f = f
        self.tangent = tangent
        self.phi = np.asarray(phi, dtype=float)
        self.Mphi = np.asarray(M @ self.phi).ravel()
        self.omega = float(omega)
        self.rtol, self.jac_rtol = rtol, jac_rtol
        if sp.issparse(M):
            lu = spla.splu(sp.csc_matrix(M))
            self.Minv = lu.solve
        else:
            cho = sla.cho_factor(np.asarray(M, dtype=float))
            self.Minv = lambda b: sla.cho_solve(cho, b)

    # ------------------------------------------------------------ dynamics
    def _rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        n = self.n
        return np.concatenate([y[n:], -self.Minv(self.f(y[:n]))])

    def _df(self, x: np.ndarray, X: np.ndarray) -> np.ndarray:
        if self.tangent is not None:
            return np.asarray(self.tangent(x) @ X)
        h = 1e-4 * max(np.abs(x).max(), 1e-8)
        cols = [(self.f(x + h * X[:, j]) - self.f(x - h * X[:, j])) / (2 * h) for j in range(X.shape[1])]
        return np.column_stack(cols)

    def _rhs_var(self, t: float, y: np.ndarray) -> np.ndarray:
        n = self.n
        x, v = y[:n], y[n:2 * n]
        X = y[2 * n:2 * n + n * n].reshape(n, n)
        V = y[2 * n + n * n:].reshape(n, n)
        dV = -self.Minv(self._df(x, X))
        return np.concatenate([v, -self.Minv(self.f(x)), V.ravel(), dV.ravel()])

    def _scale(self, x0: np.ndarray) -> float:
        return max(np.abs(x0).max(), 1e-300)

    def integrate(self, x0: np.ndarray, t_end: float, *, dense: bool = False):
        """``solve_ivp`` (DOP853, ``rtol``) from rest at ``x0`` to ``t_end``."""
        s = self._scale(x0)
        y0 = np.concatenate([x0, np.zeros(self.n)])
        atol = np.concatenate([np.full(self.n, 1e-14 * s), np.full(self.n, 1e-14 * s * self.omega)])
        sol = solve_ivp(self._rhs, (0.0, t_end), y0, method="DOP853", rtol=self.rtol, atol=atol,
                        dense_output=dense)
        if not sol.success:
            raise NumericalError(f"shooting: the time integration failed ({sol.message})")
        return sol

    # ------------------------------------------------------------- Newton
    def orbit(self, q0: float, x0: np.ndarray, T: float, *, tol: float = 1e-11,
              maxiter: int = 25) -> PeriodicOrbit:
        """Newton on ``(x0, T)`` at ``phi^T M x0 = q0`` from the guess ``(x0, T)``."""
        n = self.n
        x0 = np.asarray(x0, dtype=float).copy()
        x0 += self.phi * (q0 - float(self.Mphi @ x0))
        for it in range(1, maxiter + 1):
            s = self._scale(x0)
            y0 = np.concatenate([x0, np.zeros(n), np.eye(n).ravel(), np.zeros(n * n)])
            sol = solve_ivp(self._rhs_var, (0.0, T / 2), y0, method="DOP853", rtol=self.jac_rtol,
                            atol=1e-12 * max(s, 1.0))
            if not sol.success:
                raise NumericalError(f"shooting: the variational integration failed ({sol.message})")
            yT = sol.y[:, -1]
            V = yT[2 * n + n * n:].reshape(n, n)
            # the residual from the accurate integration
            ye = self.integrate(x0, T / 2).y[:, -1]
            r = np.concatenate([ye[n:], [float(self.Mphi @ x0) - q0]])
            acc = -self.Minv(self.f(ye[:n]))
            J = np.zeros((n + 1, n + 1))
            J[:n, :n] = V
            J[:n, n] = 0.5 * acc
            J[n, :n] = self.Mphi
            try:
                step = np.linalg.solve(J, -r)
            except np.linalg.LinAlgError as exc:
                raise NumericalError(f"shooting: singular Newton matrix at q0 = {q0:.6g} ({exc})") from exc
            if not np.all(np.isfinite(step)):
                raise NumericalError(f"shooting: Newton step not finite at q0 = {q0:.6g}")
            x0 = x0 + step[:n]
            T = T + step[n]
            small = np.abs(step[:n]).max() <= tol * s and abs(step[n]) <= tol * T
            if small:
                ye = self.integrate(x0, T / 2).y[:, -1]
                res = float(np.abs(ye[n:]).max() / (self.omega * s))
                return PeriodicOrbit(x0, T, 2 * np.pi / T, self.amplitude(x0, T), q0, res, it)
        raise NumericalError(f"shooting: Newton did not converge in {maxiter} iterations at q0 = {q0:.6g}")

    def amplitude(self, x0: np.ndarray, T: float) -> float:
        """``(max q - min q) / 2`` over the orbit (reversibility: [0, T/2] suffices)."""
        sol = self.integrate(x0, T / 2, dense=True)
        t = np.linspace(0.0, T / 2, 2001)
        q = self.Mphi @ sol.sol(t)[: self.n]
        qf = lambda s: float(self.Mphi @ sol.sol(min(max(s, 0.0), T / 2))[: self.n])  # noqa: E731
        ext = []
        for i, sgn in ((int(np.argmax(q)), -1.0), (int(np.argmin(q)), 1.0)):
            lo, hi = t[max(i - 1, 0)], t[min(i + 1, len(t) - 1)]
            r = minimize_scalar(lambda s: sgn * qf(s), bounds=(lo, hi), method="bounded", options={"xatol": 1e-14 * T})
            val = sgn * r.fun
            ext.append(max(val, q[i]) if sgn < 0 else min(val, q[i]))
        return 0.5 * (ext[0] - ext[1])

    def at_amplitude(self, A: float, *, steps: int = 6, guess: tuple[np.ndarray, float] | None = None,
                     tol: float = 1e-12, maxiter: int = 30) -> PeriodicOrbit:
        """The orbit whose amplitude of ``q_p`` is ``A``: continuation in ``q0``, then secant on ``q0``.

        Without ``guess``, ``steps`` continuation steps from ``q0 = A / steps``
        (linear guess); with ``guess = (x0, T)`` Newton starts from it.
        """
        if guess is None:
            x0, T = self.phi * (A / steps), 2 * np.pi / self.omega
            orb = self.orbit(A / steps, x0, T)
            for k in range(2, steps + 1):
                q = A * k / steps
                orb = self.orbit(q, orb.x0 * (q / orb.q0), orb.period)
        else:
            x0, T = guess
            orb = self.orbit(float(self.Mphi @ x0), x0, T)
        prev = None
        for _ in range(maxiter):
            if abs(orb.amplitude - A) <= tol * A:
                return orb
            slope = 1.0 if prev is None else (orb.amplitude - prev.amplitude) / (orb.q0 - prev.q0)
            q = orb.q0 + (A - orb.amplitude) / slope
            prev, orb = orb, self.orbit(q, orb.x0 * (q / orb.q0), orb.period)
        raise NumericalError(f"shooting: amplitude {A:.6g} not reached (last {orb.amplitude:.12g})")
