"""Forced, damped periodic steady states of the full model by shooting: the independent reference of the FRC.

Model ``M x'' + C x' + f(x) = F cos(Omega t)`` (``f`` the black box's internal force, ``C`` the
damping matrix, ``F`` the force amplitude vector). A steady state is a periodic orbit of the forcing's
period ``T = 2 pi / Omega``. In the phase ``tau = Omega t`` (period 2 pi whatever ``Omega``) with the
state ``y = (x, v)``::

    dy/dtau = g(tau, y) / Omega,     g = (v, M^-1 (F cos tau - C v - f(x)))

the shooting unknowns are ``y0 = (x0, v0)`` (2n) and the equations ``y(2 pi; y0, Omega) - y0 = 0``,
solved by Newton. The Jacobian ``[S_y - I, S_Omega]`` comes from the variational equations::

    dS/dtau = Dg S / Omega,   S(0) = [I, 0],   Dg = [[0, I], [-M^-1 Kt(x), -M^-1 C]]
    (last column, d/dOmega: an extra source -g / Omega^2)

(``Kt`` the model's ``tangent`` or central differences of ``f``), integrated by DOP853 at the loose
``jac_rtol`` (it only steers Newton); the residual is an accurate DOP853 run at ``rtol`` (default
1e-11), as in :mod:`stepnf.verify.periodic`. The monodromy ``S_y(2 pi)`` of the converged orbit gives
its Floquet multipliers: the steady state is stable when all lie inside the unit circle (a fold is
where one crosses +1).

**Amplitude** as for the backbone: ``A = (max q - min q) / 2`` of ``q = phi^T M x`` over one period,
on a grid of the accurate run's dense output refined by Brent's method. :func:`forced_orbit_at_amplitude`
fixes ``A`` and leaves ``Omega`` unknown (well posed at folds, where ``Omega`` is extremal): its extra
row is ``dA/du = (dq(tau_max)/du - dq(tau_min)/du) / 2`` from the variational run's dense output (the
extrema's phases do not move to first order).

Shooting suits small models (the variational system has ``2n (2n + 2)`` components); an FE model's
steady state is reached by time integration (:mod:`stepnf.verify.forced_steady`).
The continuation of the whole FRC is :mod:`stepnf.verify.forced_continuation`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from scipy.integrate import solve_ivp

from stepnf.errors import NumericalError
from stepnf.verify.periodic import refined_extrema

Force = Callable[[np.ndarray], np.ndarray]
#: Grid of the amplitude's first search over one period (then Brent between the grid's neighbours).
AMPLITUDE_GRID = 512


@dataclass
class ForcedOrbit:
    """A periodic steady state: ``Omega`` (rad per model time), initial state ``x0``, ``v0`` (n,),
    ``amplitude`` A of ``q = phi^T M x`` (``(max - min) / 2``, None without ``phi``), ``period``
    ``2 pi / Omega``, ``residual`` ``|y(T) - y0|_inf / scale``, ``multipliers`` (2n,) Floquet
    multipliers, ``stable`` (all inside the unit circle), ``iterations`` Newton's."""

    Omega: float
    x0: np.ndarray
    v0: np.ndarray
    amplitude: float | None
    period: float
    residual: float
    multipliers: np.ndarray
    stable: bool
    iterations: int

    @property
    def y0(self) -> np.ndarray:
        return np.concatenate([self.x0, self.v0])


def _dense(A) -> np.ndarray:
    return A.toarray() if sp.issparse(A) else np.asarray(A, dtype=float)


class ForcedShooting:
    """Shooting for ``M x'' + C x' + f(x) = F cos(Omega t)`` (module docstring).

    ``M``, ``C`` (n, n) dense or sparse (densified: small models); ``forces(x)`` the internal force
    of one field (n,) (a batch function given one field works too); ``F`` (n,); ``tangent(x)``
    ``Df(x)`` (n, n) or None (central differences); ``phi`` (n,) the master mode (M-normalised) whose
    ``q = phi^T M x`` measures the amplitude. :attr:`force_evaluations` counts the fields sent to ``f``.
    """

    def __init__(self, M, C, forces: Force, F: np.ndarray, *, tangent: Callable | None = None,
                 phi: np.ndarray | None = None, rtol: float = 1e-11, jac_rtol: float = 1e-9):
        self.M, self.C = _dense(M), _dense(C)
        self.n = self.M.shape[0]
        self.F = np.asarray(F, dtype=float).reshape(self.n)
        self._f1, self.tangent = forces, tangent
        self.rtol, self.jac_rtol = float(rtol), float(jac_rtol)
        Minv = sla.cho_solve(sla.cho_factor(self.M), np.eye(self.n))  # explicit: small models, many products
        self.Minv = lambda b: Minv @ b
        self.MinvC = self.Minv(self.C)
        self.MinvF = self.Minv(self.F)
        self.Mphi = None if phi is None else self.M @ np.asarray(phi, dtype=float)
        self.force_evaluations = 0

    # ------------------------------------------------------------ model
    def f(self, x: np.ndarray) -> np.ndarray:
        """The internal force of one field (counted)."""
        self.force_evaluations += 1
        return np.asarray(self._f1(x), dtype=float).reshape(self.n)

    def stiffness(self, x: np.ndarray) -> np.ndarray:
        """``Df(x)`` (n, n): the model's tangent, else central differences (2n evaluations)."""
        if self.tangent is not None:
            return _dense(self.tangent(x))
        h = 1e-6 * max(float(np.abs(x).max()), 1e-6)
        cols = [(self.f(x + h * e) - self.f(x - h * e)) / (2 * h) for e in np.eye(self.n)]
        return np.column_stack(cols)

    def linear_response(self, Omega: float, K: np.ndarray | None = None) -> np.ndarray:
        """The linear steady state's ``y0 = (Re X, -Omega Im X)``, ``(K - Omega^2 M + i Omega C) X = F``
        (``K`` the stiffness at rest when not given)."""
        K = self.stiffness(np.zeros(self.n)) if K is None else _dense(K)
        X = np.linalg.solve(K - Omega ** 2 * self.M + 1j * Omega * self.C, self.F)
        return np.concatenate([X.real, -Omega * X.imag])

    def _g(self, tau: float, y: np.ndarray) -> np.ndarray:
        n = self.n
        x, v = y[:n], y[n:2 * n]
        return np.concatenate([v, self.MinvF * np.cos(tau) - self.MinvC @ v - self.Minv(self.f(x))])

    def _scale(self, y0: np.ndarray, Omega: float) -> float:
        n = self.n
        return max(float(np.abs(y0[:n]).max()), float(np.abs(y0[n:]).max()) / Omega, 1e-300)

    def run(self, y0: np.ndarray, Omega: float, *, dense: bool = False):
        """The accurate run over one forcing period from ``y0`` (``solve_ivp`` DOP853 at ``rtol``) in ``tau``."""
        n, s = self.n, self._scale(y0, Omega)
        atol = np.concatenate([np.full(n, 1e-14 * s), np.full(n, 1e-14 * s * Omega)])
        sol = solve_ivp(lambda t, y: self._g(t, y) / Omega, (0.0, 2 * np.pi), y0, method="DOP853",
                        rtol=self.rtol, atol=atol, dense_output=dense)
        if not sol.success:
            raise NumericalError(f"forced shooting at Omega = {Omega:.6g}: the time integration failed ({sol.message})")
        return sol

    def variational(self, y0: np.ndarray, Omega: float, *, dense: bool = False):
        """The run at ``jac_rtol`` with the sensitivities: returns ``(sol, S)``, ``S`` (2n, 2n + 1) the
        derivatives of ``y(2 pi)`` with respect to ``y0`` and ``Omega``."""
        n, m = self.n, 2 * self.n

        def rhs(tau, z):
            y = z[:m]
            S = z[m:].reshape(m, m + 1)
            g = self._g(tau, y)
            Kt = self.Minv(self.stiffness(y[:n]))
            dS = np.vstack([S[n:], -Kt @ S[:n] - self.MinvC @ S[n:]]) / Omega
            dS[:, m] -= g / Omega ** 2
            return np.concatenate([g / Omega, dS.ravel()])
        s = self._scale(y0, Omega)
        z0 = np.concatenate([y0, np.hstack([np.eye(m), np.zeros((m, 1))]).ravel()])
        sol = solve_ivp(rhs, (0.0, 2 * np.pi), z0, method="DOP853", rtol=self.jac_rtol,
                        atol=1e-12 * max(s, 1.0), dense_output=dense)
        if not sol.success:
            raise NumericalError(f"forced shooting at Omega = {Omega:.6g}: the variational integration failed "
                                 f"({sol.message})")
        return sol, sol.y[m:, -1].reshape(m, m + 1)

    # ----------------------------------------------------------- amplitude
    def amplitude(self, sol) -> tuple[float, float, float]:
        """``(A, tau_max, tau_min)`` of ``q = phi^T M x`` on a dense run over one period."""
        if self.Mphi is None:
            raise ValueError("the amplitude needs the master mode phi")
        n = self.n
        tau = np.linspace(0.0, 2 * np.pi, AMPLITUDE_GRID + 1)
        q = self.Mphi @ sol.sol(tau)[:n]
        (qmax, tmax), (qmin, tmin) = refined_extrema(tau, q, lambda t: float(self.Mphi @ sol.sol(t % (2 * np.pi))[:n]),
                                                     1e-13, periodic=True)
        return 0.5 * (qmax - qmin), tmax % (2 * np.pi), tmin % (2 * np.pi)

    def amplitude_gradient(self, vsol, tmax: float, tmin: float) -> np.ndarray:
        """``dA/d(y0, Omega)`` (2n + 1,) from the variational run's dense output at the extrema's phases."""
        n, m = self.n, 2 * self.n

        def dq(t):
            S = vsol.sol(t)[m:].reshape(m, m + 1)
            return self.Mphi @ S[:n]
        return 0.5 * (dq(tmax) - dq(tmin))

    # -------------------------------------------------------------- orbits
    def orbit(self, Omega: float, y0: np.ndarray | None = None, *, tol: float = 1e-10, maxiter: int = 30,
              K: np.ndarray | None = None) -> ForcedOrbit:
        """The steady state at ``Omega`` by Newton on ``y0`` (from the linear response without a guess)."""
        m = 2 * self.n
        y = self.linear_response(Omega, K) if y0 is None else np.asarray(y0, dtype=float).copy()
        for it in range(1, maxiter + 1):
            _, S = self.variational(y, Omega)
            r = self.run(y, Omega).y[:, -1] - y
            dy = np.linalg.solve(S[:, :m] - np.eye(m), -r)
            y = y + dy
            if np.abs(dy).max() <= tol * self._scale(y, Omega):
                return self.finish(y, Omega, it, S[:, :m])
        raise NumericalError(f"forced shooting: Newton did not converge in {maxiter} iterations at Omega = {Omega:.6g}")

    def finish(self, y: np.ndarray, Omega: float, iterations: int, monodromy: np.ndarray) -> ForcedOrbit:
        """The :class:`ForcedOrbit` of a converged ``y`` (one accurate run for the residual and amplitude)."""
        n = self.n
        sol = self.run(y, Omega, dense=self.Mphi is not None)
        res = float(np.abs(sol.y[:, -1] - y).max()) / self._scale(y, Omega)
        A = self.amplitude(sol)[0] if self.Mphi is not None else None
        mu = np.linalg.eigvals(monodromy)
        return ForcedOrbit(float(Omega), y[:n].copy(), y[n:].copy(), A, 2 * np.pi / Omega, res, mu,
                           bool(np.abs(mu).max() < 1.0), iterations)

    def orbit_at_amplitude(self, A: float, Omega0: float, y0: np.ndarray, *, tol: float = 1e-10,
                           maxiter: int = 30) -> ForcedOrbit:
        """The steady state whose amplitude is ``A``, ``Omega`` unknown, by Newton on ``(y0, Omega)`` from
        ``(y0, Omega0)``: the branch is the one the guess is on."""
        m = 2 * self.n
        y, Om = np.asarray(y0, dtype=float).copy(), float(Omega0)
        for it in range(1, maxiter + 1):
            vsol, S = self.variational(y, Om, dense=True)
            sol = self.run(y, Om, dense=True)
            Acur, tmax, tmin = self.amplitude(sol)
            r = np.concatenate([sol.y[:, -1] - y, [Acur - A]])
            J = np.vstack([S - np.hstack([np.eye(m), np.zeros((m, 1))]), self.amplitude_gradient(vsol, tmax, tmin)])
            d = np.linalg.solve(J, -r)
            d *= min(1.0, 0.05 * Om / max(abs(d[m]), 1e-300))  # at most 5% of Omega a step: stay on the branch
            y, Om = y + d[:m], Om + d[m]
            if np.abs(d[:m]).max() <= tol * self._scale(y, Om) and abs(d[m]) <= tol * Om:
                return self.finish(y, Om, it, S[:, :m])
        raise NumericalError(f"forced shooting: Newton at amplitude {A:.6g} did not converge in {maxiter} iterations")


def forced_orbit(M, C, forces: Force, F: np.ndarray, Omega: float, *, x0: np.ndarray | None = None,
                 v0: np.ndarray | None = None, tangent: Callable | None = None, phi: np.ndarray | None = None,
                 K: np.ndarray | None = None, rtol: float = 1e-11) -> ForcedOrbit:
    """The periodic steady state of ``M x'' + C x' + f(x) = F cos(Omega t)`` at ``Omega`` by shooting on
    ``(x0, v0)`` (both or neither: without them, from the linear response with ``K`` or ``Df(0)``).
    ``phi`` (the master mode) to measure its amplitude."""
    sh = ForcedShooting(M, C, forces, F, tangent=tangent, phi=phi, rtol=rtol)
    y0 = None if x0 is None else np.concatenate([np.asarray(x0, float), np.asarray(v0, float)])
    return sh.orbit(Omega, y0, K=K)


def forced_orbit_at_amplitude(M, C, forces: Force, F: np.ndarray, A: float, phi: np.ndarray, *, Omega0: float,
                              x0: np.ndarray, v0: np.ndarray, tangent: Callable | None = None,
                              rtol: float = 1e-11) -> ForcedOrbit:
    """The steady state whose amplitude of ``q = phi^T M x`` is ``A``, ``Omega`` unknown, from the guess
    ``(Omega0, x0, v0)`` (which picks the branch: below or above a fold)."""
    sh = ForcedShooting(M, C, forces, F, tangent=tangent, phi=phi, rtol=rtol)
    return sh.orbit_at_amplitude(A, Omega0, np.concatenate([np.asarray(x0, float), np.asarray(v0, float)]))
