"""Periodic orbits of the full model that need not start at rest: shooting on ``(x0, v0, T)``.

:class:`stepnf.verify.periodic.Shooting` finds brake orbits (at rest at ``t = 0`` and ``T / 2``), which is what
a branch of a manifold's reduced dynamics gives when a rotation of its point makes every ``zeta_l`` real (then
``V(z) = 0`` there). Some branches have no such point (the elliptic orbits of a 1:1 pair, ``zeta_2 = i zeta_1``:
no time of the orbit where every velocity vanishes). For those the unknowns are the whole initial state and the
period, ``(x0, v0, T)`` (2n + 1), and the equations::

    y(T; x0, v0) - (x0, v0) = 0          (2n, periodicity; the v rows divided by w)
    phi^T M x0 = q0                      (1, the amplitude condition)
    phi^T M v0 = 0                       (1, the phase condition: t = 0 at a turning point of q)

2n + 2 equations of which one is redundant (the energy is conserved, so periodicity holds in one direction
for free): Gauss-Newton (least squares, of full column rank 2n + 1, quadratic convergence onto a zero residual),
``dy(T)/dy0`` from the variational equations (``Df`` from ``tangent`` or central differences of f), the residual
from DOP853 at ``rtol = 1e-12`` as in :class:`~stepnf.verify.periodic.Shooting`. The amplitude
``A = (max q - min q) / 2`` is measured over the whole period (no reversibility assumed), on a dense grid of the
integrator's output refined by Brent's method; a secant iteration on ``q0`` hits a requested ``A``.
Explicit integration only: small, non-stiff models (those ``stepnf verify`` shoots).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.integrate import solve_ivp

from stepnf.errors import NumericalError
from stepnf.verify.periodic import mass_solver, refined_half_range


@dataclass
class FreeOrbit:
    """A converged orbit: initial state ``x0``, ``v0`` (n,), ``period``, ``omega = 2 pi / period``, the amplitude
    of ``q = phi^T M x``, ``q0 = q(0)``, the relative residual and the Newton iterations of its last solve."""

    x0: np.ndarray
    v0: np.ndarray
    period: float
    omega: float
    amplitude: float
    q0: float
    residual: float
    newton_iterations: int


class FreeShooting:
    """Shooting on ``(x0, v0, T)`` for ``M x'' + f(x) = 0`` (module docstring); ``phi`` M-normalised, ``omega``
    a frequency scale (the master's, rad per model time unit), ``f(x)`` one field's internal force,
    ``tangent(x)`` (optional) ``Df(x)`` dense (n, n)."""

    def __init__(self, M, K, f: Callable[[np.ndarray], np.ndarray], phi: np.ndarray, omega: float, *,
                 tangent: Callable | None = None, rtol: float = 1e-12, jac_rtol: float = 1e-9):
        self.n = len(phi)
        self.M, self.K, self._f, self.tangent = M, K, f, tangent
        self.Mphi = np.asarray(M @ np.asarray(phi, dtype=float)).ravel()
        self.omega, self.rtol, self.jac_rtol = float(omega), rtol, jac_rtol
        self.force_evaluations = 0
        self.Minv = mass_solver(M)

    @property
    def work(self) -> dict:
        """``method`` ("explicit", shooting on the whole state) and ``force_evaluations``."""
        return {"method": "explicit", "unknowns": "x0, v0, T", "force_evaluations": int(self.force_evaluations)}

    def f(self, x: np.ndarray) -> np.ndarray:
        self.force_evaluations += 1
        return np.asarray(self._f(x), dtype=float)

    def _rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        return np.concatenate([y[self.n:], -self.Minv(self.f(y[:self.n]))])

    def _rhs_var(self, t: float, y: np.ndarray) -> np.ndarray:
        n = self.n
        x, v = y[:n], y[n:2 * n]
        X = y[2 * n:2 * n + 2 * n * n].reshape(n, 2 * n)
        V = y[2 * n + 2 * n * n:].reshape(n, 2 * n)
        if self.tangent is not None:
            DfX = np.asarray(self.tangent(x) @ X)
        else:
            h = 1e-4 * max(float(np.abs(x).max()), 1e-8)
            DfX = np.column_stack([(self.f(x + h * X[:, j]) - self.f(x - h * X[:, j])) / (2 * h)
                                   for j in range(2 * n)])
        return np.concatenate([v, -self.Minv(self.f(x)), V.ravel(), -self.Minv(DfX).ravel()])

    def integrate(self, y0: np.ndarray, t_end: float, *, dense: bool = False):
        """DOP853 at ``rtol`` from the state ``y0 = (x0, v0)`` (2n,) to ``t_end``."""
        s = max(float(np.abs(y0[:self.n]).max()), float(np.abs(y0[self.n:]).max()) / self.omega, 1e-300)
        atol = np.concatenate([np.full(self.n, 1e-14 * s), np.full(self.n, 1e-14 * s * self.omega)])
        sol = solve_ivp(self._rhs, (0.0, t_end), y0, method="DOP853", rtol=self.rtol, atol=atol, dense_output=dense)
        if not sol.success:
            raise NumericalError(f"shooting: the time integration failed ({sol.message})")
        return sol

    def orbit(self, q0: float, x0: np.ndarray, v0: np.ndarray, T: float, *, tol: float = 1e-11,
              maxiter: int = 25) -> FreeOrbit:
        """Gauss-Newton on ``(x0, v0, T)`` at ``phi^T M x0 = q0``, ``phi^T M v0 = 0`` from the guess."""
        n, w = self.n, self.omega
        y = np.concatenate([x0, v0]).astype(float)
        y[:n] += self.Mphi * (q0 - float(self.Mphi @ y[:n])) / float(self.Mphi @ self.Mphi)
        y[n:] -= self.Mphi * float(self.Mphi @ y[n:]) / float(self.Mphi @ self.Mphi)
        D = np.concatenate([np.ones(n), np.full(n, 1.0 / w)])  # the v rows divided by w
        for it in range(1, maxiter + 1):
            s = max(float(np.abs(y[:n]).max()), 1e-300)
            Y0 = np.concatenate([y, np.hstack([np.eye(n), np.zeros((n, n))]).ravel(),
                                 np.hstack([np.zeros((n, n)), np.eye(n)]).ravel()])
            var = solve_ivp(self._rhs_var, (0.0, T), Y0, method="DOP853", rtol=self.jac_rtol,
                            atol=1e-12 * max(s, 1.0))
            if not var.success:
                raise NumericalError(f"shooting: the variational integration failed ({var.message})")
            S = np.vstack([var.y[2 * n:2 * n + 2 * n * n, -1].reshape(n, 2 * n),
                           var.y[2 * n + 2 * n * n:, -1].reshape(n, 2 * n)])
            yT = self.integrate(y, T).y[:, -1]  # the residual from the accurate integration
            r = np.concatenate([D * (yT - y), [float(self.Mphi @ y[:n]) - q0, float(self.Mphi @ y[n:]) / w]])
            J = np.zeros((2 * n + 2, 2 * n + 1))
            J[:2 * n, :2 * n] = D[:, None] * (S - np.eye(2 * n))
            J[:2 * n, 2 * n] = D * self._rhs(T, yT)
            J[2 * n, :n] = self.Mphi
            J[2 * n + 1, n:2 * n] = self.Mphi / w
            step = np.linalg.lstsq(J, -r, rcond=None)[0]
            if not np.all(np.isfinite(step)):
                raise NumericalError(f"shooting: Newton step not finite at q0 = {q0:.6g}")
            y, T = y + step[:2 * n], T + step[2 * n]
            if np.abs(D * step[:2 * n]).max() <= tol * s and abs(step[2 * n]) <= tol * T:
                yT = self.integrate(y, T).y[:, -1]
                res = float(np.abs(D * (yT - y)).max() / s)
                return FreeOrbit(y[:n], y[n:], T, 2 * np.pi / T, self.amplitude(y, T), q0, res, it)
        raise NumericalError(f"shooting on (x0, v0, T): Newton did not converge in {maxiter} iterations at "
                             f"q0 = {q0:.6g}")

    def amplitude(self, y0: np.ndarray, T: float) -> float:
        """``(max q - min q) / 2`` over one whole period from the state ``y0``."""
        sol = self.integrate(y0, T, dense=True)
        t = np.linspace(0.0, T, 4001)
        q = self.Mphi @ sol.sol(t)[:self.n]
        return refined_half_range(t, q, lambda s: float(self.Mphi @ sol.sol(min(max(s, 0.0), T))[:self.n]),
                                  1e-14 * T)

    def at_amplitude(self, A: float, guess: tuple[np.ndarray, np.ndarray, float], *, tol: float = 1e-12,
                     maxiter: int = 30) -> FreeOrbit:
        """The orbit whose amplitude of ``q`` is ``A``, from ``guess = (x0, v0, T)`` (``q'(0)`` near 0): secant
        on ``q0``."""
        x0, v0, T = guess
        orb = self.orbit(float(self.Mphi @ x0), x0, v0, T)
        prev = None
        for _ in range(maxiter):
            if abs(orb.amplitude - A) <= tol * A:
                return orb
            slope = 1.0 if prev is None else (orb.amplitude - prev.amplitude) / (orb.q0 - prev.q0)
            q = orb.q0 + (A - orb.amplitude) / slope
            prev, orb = orb, self.orbit(q, orb.x0 * (q / orb.q0), orb.v0 * (q / orb.q0), orb.period)
        raise NumericalError(f"shooting: amplitude {A:.6g} not reached (last {orb.amplitude:.12g})")

    def samples(self, orb: FreeOrbit, count: int) -> np.ndarray:
        """States ``(x, v)`` (count + 1, 2n) at evenly spaced times over one period of ``orb``."""
        sol = self.integrate(np.concatenate([orb.x0, orb.v0]), orb.period, dense=True)
        return sol.sol(np.linspace(0.0, orb.period, count + 1)).T
