"""The averaged forced and damped dynamics of one master on its conservative DPIM manifold.

The manifold of :class:`stepnf.dpim.parametrisation.DPIMResult` is
``x(theta, rho) = sum_m X_m(rho) cos(m theta)``, ``X_m(rho) = sum_p rho^p Y[p, m]``, with ``v = Omega_c
dx/dtheta`` and ``theta' = Omega_c(rho) = omega + sum_k c_k rho^(2k)``. On it the conservative motion has
the action ``I = (1/2 pi) oint v^T M dx``. Damping ``-C v`` and forcing ``F cos(Omega t)`` are added at
first order (averaging over the fast angle, ``psi = theta - Omega t`` slow)::

    I'   = -D / Omega_d - (f1 / 2) sin psi
    psi' = Omega_d - Omega - (1/2) (df1/dI) cos psi

    I(rho)  = Omega_d(rho) sum_m m^2/2 X_m^T M X_m          (action)
    D(rho)  = Omega_d(rho)^2 sum_m m^2/2 X_m^T C X_m        (mean power dissipated over the orbit)
    f1(rho) = F^T X_1(rho)                                   (the work of F on the first harmonic)
    Omega_d(rho) = Omega_c(rho) - omega + omega_d,  omega_d = omega sqrt(1 - xi^2)

``I'`` is the power balance (``dH/dt = v^T (F cos Omega t - C v)``, ``dI = dH / Omega``), ``psi'`` the
angle's response to the forcing's Hamiltonian ``-x^T F cos(Omega t)``; the damping's part of ``psi'``
averages to zero (``x`` even, ``v`` odd in theta). The shift to ``omega_d`` makes the linear limit exact:
peak ``rho = kappa / (2 xi omega omega_d)``. Every function is a polynomial in ``rho``
(:class:`numpy.polynomial.Polynomial`), derivatives analytic.

Steady states (``I' = psi' = 0``): ``sin psi = -2 D / (Omega_d f1)`` and
``Omega = Omega_d + (1/2)(df1/dI) c``, ``c = -cos psi = +-sqrt(1 - sin^2 psi)``; they exist while
``2 D <= Omega_d f1``, the first equality being the peak. Stability: the Jacobian of ``(I', psi')`` in
``(I, psi)``; stable iff its trace < 0 and determinant > 0 (the determinant vanishes at the folds).
The measured amplitude of a steady state is the backbone's ``A(rho)`` plus :meth:`Averaged.amplitude_shift`
(the averaging's oscillating part of the action, first order in the forcing).
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
from numpy.polynomial import Polynomial as P

from stepnf.forced.damping import damped_frequency


def manifold_grams(res: Any, C: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Gram matrices ``(Y_i^T M Y_j, Y_i^T C Y_j)`` of the coefficients of ``res`` (a
    :class:`~stepnf.dpim.parametrisation.DPIMResult`, keys sorted) and ``M phi`` (n,): what :class:`Averaged` needs of
    the model's matrices, the same for every forcing level (one product of each matrix with the coefficients per
    master, not per level)."""
    Ys = res.stacked(sorted(res.Y))  # (k, n): the run's stacked coefficients (arrays()), no copy
    MY = np.asarray(res.M @ Ys.T).T
    CY = np.asarray(C(Ys))
    return Ys @ MY.T, Ys @ CY.T, np.asarray(res.M @ res.phi)


class Averaged:
    """The averaged dynamics of the master of ``res`` under damping ``C`` and forcing ``F`` (module docstring).

    ``res``: a :class:`~stepnf.dpim.parametrisation.DPIMResult`; ``C(V)``: the damping product on fields
    (k, n) (:class:`stepnf.forced.damping.Damping`); ``xi``: the master's damping ratio (sets ``omega_d``);
    ``F`` (n,): the force amplitude (model force units); ``grams``: :func:`manifold_grams` of ``res`` and ``C``
    when known (computed otherwise). ``I, D, f1, Od`` polynomials in ``rho``. The ``*_many`` methods take arrays of
    steady states (an FRC's points at once); their one-point forms wrap them.
    """

    def __init__(self, res: Any, C: Callable[[np.ndarray], np.ndarray], xi: float, F: np.ndarray,
                 grams: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None):
        self.omega = float(res.omega)
        self.xi = float(xi)
        self.omega_d = damped_frequency(self.omega, self.xi)
        N = res.order
        keys = sorted(res.Y)
        GM, GC, Mphi = grams if grams is not None else manifold_grams(res, C)  # Y_i^T M Y_j, Y_i^T C Y_j, M phi
        sm, sc = np.zeros(2 * N + 1), np.zeros(2 * N + 1)
        cmnc = np.zeros((N + 1, N + 1, 2 * N + 1))  # [m, n, k]: rho^k coefficient of X_m^T C X_n
        for i, (p, m) in enumerate(keys):
            for j, (q, mm) in enumerate(keys):
                cmnc[m, mm, p + q] += GC[i, j]
                if m == mm and m > 0:
                    sm[p + q] += m * m / 2.0 * GM[i, j]
                    sc[p + q] += m * m / 2.0 * GC[i, j]
        F = np.asarray(F, dtype=float)
        fmc, amc = np.zeros((N + 1, N + 1)), np.zeros((N + 1, N + 1))  # [m, p]: F^T Y[p, m], phi^T M Y[p, m]
        for (p, m), y in res.Y.items():
            fmc[m, p] += float(F @ y)
            amc[m, p] += float(Mphi @ y)
        self._fmc, self._amc = fmc, amc
        self._damc = np.hstack([amc[:, 1:] * np.arange(1, N + 1), np.zeros((N + 1, 1))])  # [m, p-1]: da_m/drho
        ms = np.arange(N + 1)
        self._ms, self._up = ms, 1.0 / (ms + 1.0)
        self._down = np.where(ms == 1, 0.0, 1.0 / np.where(ms == 1, 1.0, ms - 1.0))
        dmn, smn = ms[:, None] - ms[None, :], ms[:, None] + ms[None, :]
        self._mn, self._dmn, self._smn = (ms[:, None] * ms[None, :]).astype(float), dmn, smn
        self._inv_dmn = np.where(dmn == 0, 0.0, 1.0 / np.where(dmn == 0, 1, dmn))
        self._inv_smn = np.where(smn == 0, 0.0, 1.0 / np.where(smn == 0, 1, smn))
        self._grid = np.linspace(0.0, np.pi, 64 * (N + 1) + 1)
        self._cos = np.cos(np.outer(ms, self._grid))
        fc = fmc[1]
        od = np.zeros(2 * len(res.c) + 1)
        od[0] = self.omega_d
        od[2::2] = res.c
        self.Od = P(od)
        self._cmnc = cmnc
        self.I = self.Od * P(sm)
        self.D = self.Od ** 2 * P(sc)
        self.f1 = P(fc)
        self.dI, self.dD, self.df1, self.dOd = self.I.deriv(), self.D.deriv(), self.f1.deriv(), self.Od.deriv()
        self.ddI, self.ddf1 = self.dI.deriv(), self.df1.deriv()
        self.reach = self.Od * self.f1 - 2.0 * self.D  # >= 0 where steady states exist

    # ---------------------------------------------------------------- steady states
    def sin_psi(self, rho: np.ndarray) -> np.ndarray:
        """``sin psi = -2 D / (Omega_d f1)`` on the steady states of amplitude ``rho``."""
        return -2.0 * self.D(rho) / (self.Od(rho) * self.f1(rho))

    def gain(self, rho: np.ndarray) -> np.ndarray:
        """``(1/2) df1/dI`` (rad per time unit)."""
        return 0.5 * self.df1(rho) / self.dI(rho)

    def omega_of(self, rho: np.ndarray, c: np.ndarray) -> np.ndarray:
        """``Omega = Omega_d + (1/2)(df1/dI) c`` with ``c = -cos psi`` given (its sign picks the branch)."""
        return self.Od(rho) + self.gain(rho) * c

    def cos_abs(self, rho: np.ndarray) -> np.ndarray:
        """``|cos psi| = sqrt(1 - sin^2 psi)`` (0 where the level set ends)."""
        return np.sqrt(np.clip(1.0 - self.sin_psi(rho) ** 2, 0.0, None))

    def domega(self, rho: np.ndarray, sign: float) -> np.ndarray:
        """``dOmega/drho`` on the branch ``c = sign |cos psi|`` (analytic; infinite at the peak)."""
        rho = np.asarray(rho, dtype=float)
        s = self.sin_psi(rho)
        a = self.Od(rho) * self.f1(rho)
        da = self.dOd(rho) * self.f1(rho) + self.Od(rho) * self.df1(rho)
        ds = -2.0 * (self.dD(rho) * a - self.D(rho) * da) / (a * a)
        cabs = np.sqrt(np.clip(1.0 - s * s, 1e-300, None))
        dgain = 0.5 * (self.ddf1(rho) * self.dI(rho) - self.df1(rho) * self.ddI(rho)) / self.dI(rho) ** 2
        return self.dOd(rho) + sign * (dgain * cabs - self.gain(rho) * s * ds / cabs)

    def jacobian(self, rho: float | np.ndarray, c: float | np.ndarray) -> np.ndarray:
        """The Jacobian (2, 2) of ``(I', psi')`` in ``(I, psi)`` at the steady state ``(rho, c = -cos psi)``;
        (..., 2, 2) for arrays ``rho``, ``c`` (elementwise: the same numbers as point by point)."""
        rho, c = np.asarray(rho, dtype=float), np.asarray(c, dtype=float)
        s = self.sin_psi(rho)
        cos = -c
        dI = self.dI(rho)
        f1, df1 = self.f1(rho), self.df1(rho)
        Od, dOd = self.Od(rho), self.dOd(rho)
        d_loss = (self.dD(rho) * Od - self.D(rho) * dOd) / (Od * Od)  # d(D/Omega_d)/drho
        g = df1 / dI  # df1/dI
        dg = (self.ddf1(rho) * dI - df1 * self.ddI(rho)) / (dI * dI)  # d(df1/dI)/drho
        J = np.empty(np.broadcast_shapes(rho.shape, c.shape) + (2, 2))
        J[..., 0, 0], J[..., 0, 1] = (-d_loss - 0.5 * df1 * s) / dI, -0.5 * f1 * cos
        J[..., 1, 0], J[..., 1, 1] = (dOd - 0.5 * dg * cos) / dI, 0.5 * g * s
        return J

    def extremes(self, rho: float) -> tuple[float, float]:
        """``(theta_max, theta_min)`` of :meth:`extremes_many` at one ``rho``."""
        tmax, tmin = self.extremes_many(np.array([rho], dtype=float))
        return float(tmax[0]), float(tmin[0])

    def amplitude_shift(self, rho: float, c: float, theta_max: float, theta_min: float) -> float:
        """:meth:`amplitude_shift_many` at one steady state ``(rho, c = -cos psi)``."""
        one = lambda x: np.array([x], dtype=float)  # noqa: E731
        return float(self.amplitude_shift_many(one(rho), one(c), one(theta_max), one(theta_min))[0])

    def extremes_many(self, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The phases ``(theta_max, theta_min)`` (n,) each in [0, pi] of the extremes of ``q(theta) = sum_m a_m(rho)
        cos(m theta)`` at every ``rho`` (n,) (``q`` is even: these are its extremes over the period), on a grid of
        64 (N + 1) points then Newton, each point stopping on its own (a first-order shift of A needs them to
        O(grid spacing) only; refined for good measure)."""
        ms = self._ms
        a = (np.asarray(rho, dtype=float)[:, None] ** ms) @ self._amc.T  # (n, m): a_m per point
        q = a @ self._cos
        out = []
        for i in (np.argmax(q, axis=1), np.argmin(q, axis=1)):
            t = self._grid[i]
            live = np.ones(len(t), dtype=bool)
            for _ in range(8):
                d1 = -np.einsum("nm,nm->n", ms * a, np.sin(np.outer(t, ms)))
                d2 = -np.einsum("nm,nm->n", ms * ms * a, np.cos(np.outer(t, ms)))
                with np.errstate(divide="ignore", invalid="ignore"):
                    step = d1 / d2
                live &= (d2 != 0) & ~(np.abs(step) > self._grid[1])
                if not live.any():
                    break
                t = np.where(live, t - np.where(live, step, 0.0), t)
            out.append(t)
        return out[0], out[1]

    def amplitude_shift_many(self, rho: np.ndarray, c: np.ndarray, theta_max: np.ndarray,
                             theta_min: np.ndarray) -> np.ndarray:
        """First-order change of the measured amplitude ``A`` of ``q = phi^T M x`` on the forced steady states
        ``(rho, c = -cos psi)`` (n,), whose ``q`` is extremal at ``theta_max``, ``theta_min`` (n,) on the manifold.

        Averaging removes the oscillating part of ``I'``; the near-identity change of variables that does it
        gives the action on the orbit ``I = I_bar + u(theta)``, ``u = (1/Omega_d) int (I' - mean) dtheta``:
        ``u = (1/(2 Omega_d)) sum_m m f_m [cos((m+1) theta - psi)/(m+1) + cos((m-1) theta + psi)/(m-1)]``
        (``f_m = F^T X_m``, no ``m = 1`` second term) ``- (1/2) sum_mn m n X_m^T C X_n [sin((m-n) theta)/(m-n)
        - sin((m+n) theta)/(m+n)]`` (the damping's part; 0 at theta = 0, pi). The angle's correction does not
        move an extremum's value (``dq/dtheta = 0`` there), so ``dA = (1/2) [q_I u](theta_max) - (1/2)
        [q_I u](theta_min)``, ``q_I = (dq/drho) / I'``. Linear limit: ``dA = kappa cos psi / (4 w^2)``: the
        exact ellipse ``x = a cos(Omega t - psi)`` seen from the circles of the free oscillator. With it the
        FRC's flanks are second order in the forcing; the peak (``cos psi = 0`` at theta = 0, pi) is unchanged.
        """
        rho, c = np.asarray(rho, dtype=float), np.asarray(c, dtype=float)
        psi = np.arctan2(self.sin_psi(rho), -c)[:, None]
        ms = self._ms
        pw = rho[:, None] ** np.arange(self._cmnc.shape[2])  # (n, k)
        fm = ms * (pw[:, : len(ms)] @ self._fmc.T)  # m f_m (n, m)
        dam = pw[:, : len(ms)] @ self._damc.T  # d a_m / drho (n, m)
        v = self._mn * np.einsum("mjk,nk->nmj", self._cmnc, pw)  # m j X_m^T C X_j (n, m, j)
        Od, dI = self.Od(rho), self.dI(rho)

        def u(theta: np.ndarray) -> np.ndarray:
            th = theta[:, None]
            forced = 0.5 * np.sum(fm * (np.cos((ms + 1) * th - psi) * self._up
                                        + np.cos((ms - 1) * th + psi) * self._down), axis=1)
            th = th[:, :, None]
            damped = -0.5 * np.sum(v * (np.sin(self._dmn * th) * self._inv_dmn
                                        - np.sin(self._smn * th) * self._inv_smn), axis=(1, 2))
            return forced / Od + damped

        def q_I(theta: np.ndarray) -> np.ndarray:
            return np.sum(dam * np.cos(np.outer(theta, ms)), axis=1) / dI

        return 0.5 * (q_I(theta_max) * u(theta_max) - q_I(theta_min) * u(theta_min))

    def stable(self, rho: float | np.ndarray, c: float | np.ndarray) -> bool | np.ndarray:
        """Asymptotically stable: trace < 0 and determinant > 0 (:meth:`jacobian`; a bool array for arrays,
        each determinant by LAPACK as for one point: the same sign at the folds, where it vanishes)."""
        J = self.jacobian(rho, c)
        out = (J[..., 0, 0] + J[..., 1, 1] < 0) & (np.linalg.det(J) > 0)
        return bool(out) if out.ndim == 0 else out
