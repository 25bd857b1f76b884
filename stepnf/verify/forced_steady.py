"""Forced, damped steady states of a large (FE) model by time integration: the reference where shooting's
variational equations are out of reach.

Model ``M x'' + C x' + f(x) = F cos(Omega t)``, ``M``, ``C``, ``K`` sparse, ``f`` the black box's batched
forces. **Scheme**: the implicit midpoint rule on ``(x, v)`` with ``x1 - x0 = dt (v0 + v1) / 2``::

    (2 / dt^2) M (x1 - x0 - dt v0) + C (x1 - x0) / dt + f(xm) = F cos(Omega (t + dt / 2)),   xm = (x0 + x1) / 2

(symplectic and symmetric: no numerical damping; for a linear model the trapezoidal rule, whose frequency
error ``(w dt)^2 / 12`` is 2e-4 at 128 steps a period: a detuning of 2e-4 moves a peak's amplitude by
``(2e-4 / xi)^2 / 2``, 2e-4 at ``xi = 0.01``). **Newton**: modified, on ``(2 / dt^2) M + C / dt + K / 2``
factorised once (``K`` the linear stiffness), with Anderson mixing (depth :data:`DEPTH`) for the nonlinear
part; one force evaluation an iteration.

**Steady state**: started near it (the ROM's state at the peak), the transient decays as
``exp(-xi w t)``. The amplitude ``A_k = (max q - min q) / 2`` of ``q = phi^T M x`` over each period ``k``
(extrema refined by the parabola through the three nodes around them) converges geometrically; Aitken's
``A - (dA)^2 / d2A`` on the last three periods extrapolates it (:func:`steady_amplitude`), and the spread of
the last extrapolations says how far it is settled.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from stepnf.errors import NumericalError

#: Anderson mixing's memory in the modified Newton of each step.
DEPTH = 5


@dataclass
class SteadyRun:
    """Per-period amplitudes ``amplitudes`` (periods,), the extrapolated ``amplitude`` and its ``spread``
    (largest change of the Aitken estimate over the last three periods), ``force_evaluations``, ``x``,
    ``v`` (n,) the end state."""

    amplitudes: np.ndarray
    amplitude: float
    spread: float
    force_evaluations: int
    x: np.ndarray
    v: np.ndarray


def steady_amplitude(A: np.ndarray) -> tuple[float, float]:
    """Aitken's extrapolation of a geometrically converging sequence ``A`` (>= 5 values): the estimate from
    its last three, and the largest change of the estimates from the last three triples."""
    est = []
    for k in range(len(A) - 3, len(A)):
        a0, a1, a2 = A[k - 2], A[k - 1], A[k]
        d2 = a2 - 2 * a1 + a0
        est.append(a2 if d2 == 0 else a2 - (a2 - a1) ** 2 / d2)
    return float(est[-1]), float(max(est) - min(est))


class ForcedIntegration:
    """The implicit midpoint rule for ``M x'' + C x' + f(x) = F cos(Omega t)`` (module docstring).

    ``M``, ``C``, ``K`` (n, n) sparse or dense; ``forces(U)`` the internal forces (m, n) of fields (m, n);
    ``F`` (n,); ``tol`` Newton's increment relative to the state's size.
    """

    def __init__(self, M, C, K, forces: Callable[[np.ndarray], np.ndarray], F: np.ndarray, *,
                 tol: float = 1e-10, maxiter: int = 60):
        self.M, self.C, self.K = (sp.csc_matrix(A) for A in (M, C, K))
        self.forces, self.F = forces, np.asarray(F, dtype=float)
        self.tol, self.maxiter = tol, maxiter
        self.force_evaluations = 0
        self._lu: tuple[float, object] | None = None

    def _f(self, x: np.ndarray) -> np.ndarray:
        self.force_evaluations += 1
        return np.asarray(self.forces(x[None]), dtype=float)[0]

    def _solver(self, dt: float):
        if self._lu is None or self._lu[0] != dt:
            J0 = (2 / dt ** 2) * self.M + self.C / dt + 0.5 * self.K
            self._lu = (dt, spla.splu(sp.csc_matrix(J0)))
        return self._lu[1]

    def step(self, x0: np.ndarray, v0: np.ndarray, t: float, dt: float, Omega: float):
        """One step from ``(x0, v0)`` at ``t``: ``(x1, v1)``."""
        lu = self._solver(dt)
        load = self.F * np.cos(Omega * (t + 0.5 * dt)) + (2 / dt) * (self.M @ v0)
        x1 = x0 + dt * v0
        scale = max(float(np.abs(x0).max()), float(np.abs(v0).max()) * dt, 1e-300)
        G, R = [], []  # Anderson: the fixed-point map's iterates and residuals
        for it in range(self.maxiter):
            r = (2 / dt ** 2) * (self.M @ (x1 - x0)) + self.C @ (x1 - x0) / dt + self._f(0.5 * (x0 + x1)) - load
            d = -lu.solve(r)
            G.append(x1 + d)
            R.append(d)
            if len(R) > DEPTH + 1:
                G.pop(0)
                R.pop(0)
            size = float(np.abs(d).max())
            if size <= self.tol * scale:
                x1 = x1 + d
                return x1, 2 * (x1 - x0) / dt - v0
            if len(R) > 1:  # x_new = G_k - sum gamma_j (G_j - G_j-1), gamma from least squares on the residuals
                dR = np.column_stack([R[j + 1] - R[j] for j in range(len(R) - 1)])
                dG = np.column_stack([G[j + 1] - G[j] for j in range(len(G) - 1)])
                gamma = np.linalg.lstsq(dR, R[-1], rcond=None)[0]
                x1 = G[-1] - dG @ gamma
            else:
                x1 = G[-1]
        raise NumericalError(f"forced time integration: Newton did not converge at t = {t:.6g} (step {dt:.3g}; "
                             f"last increment {size:.3g} of the state {scale:.3g})")

    def run(self, x0: np.ndarray, v0: np.ndarray, Omega: float, Mphi: np.ndarray, *, periods: int = 30,
            steps: int = 128) -> SteadyRun:
        """``periods`` forcing periods of ``steps`` steps from ``(x0, v0)`` at ``t = 0``; amplitudes of
        ``q = Mphi . x`` per period and their extrapolation (:func:`steady_amplitude`)."""
        if periods < 5:
            raise ValueError("the extrapolation needs at least 5 periods")
        T = 2 * np.pi / Omega
        dt = T / steps
        x, v = np.asarray(x0, float).copy(), np.asarray(v0, float).copy()
        amps = []
        for k in range(periods):
            q = [float(Mphi @ x)]
            for j in range(steps):
                x, v = self.step(x, v, (k * steps + j) * dt, dt, Omega)
                q.append(float(Mphi @ x))
            amps.append(0.5 * (_extremum(np.array(q), 1.0) - _extremum(np.array(q), -1.0)))
        A, spread = steady_amplitude(np.array(amps))
        return SteadyRun(np.array(amps), A, spread, self.force_evaluations, x, v)


def _extremum(q: np.ndarray, sign: float) -> float:
    """The largest (``sign = 1``) or smallest value of the samples ``q`` over one period (its ends the same
    phase), refined by the parabola through the sample and its two neighbours."""
    qq = q[:-1]
    i = int(np.argmax(sign * qq))
    a, b, c = qq[i - 1], qq[i], qq[(i + 1) % len(qq)]
    den = a - 2 * b + c
    return float(b if den == 0 else b - 0.125 * (c - a) ** 2 / den)
