"""The full model's frequency-response curve by pseudo-arclength continuation of its forced steady states.

Independent of the ROM: it starts from the linear response at the lower end of the frequency range
and follows the branch of periodic steady states of ``M x'' + C x' + f(x) = F cos(Omega t)``
(:class:`stepnf.verify.forced_orbits.ForcedShooting`) in ``Omega`` up to the upper end, through the
folds. Unknowns ``u = (x0, v0, Omega)`` scaled to ``z = (x0 / a, v0 / (w a), Omega / (w b))`` (``a`` the
linear response's size at ``w``, ``b = 0.05``: a change of ``Omega`` by 5% of ``w`` weighs as much as
one of the response by its resonant size). Each step: the tangent ``t`` (null vector of the scaled
Jacobian ``[S_y - I, S_Omega]``, oriented as the previous one), the predictor ``z + ds t``, Newton's
corrector on the hyperplane ``t . (z - z_pred) = 0``; a step is halved when the corrector fails (still
not contracting by 2 after :data:`MAX_CORRECTOR` iterations) or the tangent turns by more than
:data:`MAX_TURN` (so a pair of folds is not stepped over); the next step aims at a first correction of
:data:`PREDICTOR_ERROR` times the step (the predictor's error grows as its square: ``ds`` times
``sqrt(0.1 ds / |d1|)``, within a factor 2). The corrector keeps the last point's Jacobian (a chord
with Broyden's rank-one updates), renewed where it contracts by less than 4 an iteration.

**Peak and folds.** The peak (largest amplitude ``A``) and the folds (``dOmega/ds = 0``, where a
Floquet multiplier crosses +1) are refined between the continuation's points: on the hyperplanes
``t_i . (z - z_i) = sigma`` through the point ``i`` nearest to them, Brent's method finds the ``sigma``
that maximises ``A`` (peak) or extremises ``Omega`` (fold), each value a corrected point on the curve.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar

from stepnf.errors import NumericalError
from stepnf.verify.forced_orbits import Force, ForcedOrbit, ForcedShooting

#: Corrector iterations after which one that does not contract by 2 fails (the step is halved).
MAX_CORRECTOR = 6
#: Largest turn of the tangent between two accepted points (radians).
MAX_TURN = 0.3
#: The predictor's distance to the curve (the corrector's first increment) the step aims at, relative to the step.
PREDICTOR_ERROR = 0.1
#: Weight of Omega in the arclength (module docstring).
OMEGA_WEIGHT = 0.05


@dataclass
class FullFRC:
    """The full model's FRC: ``orbits`` along the curve (ordered), ``Omega``, ``amplitude``, ``stable``
    arrays of them; ``peak`` and ``folds`` refined (dicts ``{"Omega", "amplitude", "stable"}``);
    ``force_evaluations`` of the whole continuation."""

    orbits: list[ForcedOrbit]
    peak: dict
    folds: list[dict] = field(default_factory=list)
    force_evaluations: int = 0

    @property
    def Omega(self) -> np.ndarray:
        return np.array([o.Omega for o in self.orbits])

    @property
    def amplitude(self) -> np.ndarray:
        return np.array([o.amplitude for o in self.orbits])

    @property
    def stable(self) -> np.ndarray:
        return np.array([o.stable for o in self.orbits])


class Continuation:
    """Pseudo-arclength continuation in ``Omega`` of the steady states of ``sh`` (module docstring);
    ``omega`` the master's linear frequency (rad per model time), ``K`` the stiffness at rest; ``tol`` the
    corrector's tolerance on the scaled unknowns at the refined peak and folds, ``loose`` along the curve."""

    def __init__(self, sh: ForcedShooting, omega: float, K: np.ndarray | None = None, *, tol: float = 1e-10,
                 loose: float = 1e-8):
        self.sh, self.omega, self.tol, self.loose = sh, float(omega), tol, loose
        self.K = sh.stiffness(np.zeros(sh.n)) if K is None else np.asarray(K, dtype=float)
        y = sh.linear_response(self.omega, self.K)
        n = sh.n
        a = max(float(np.abs(y[:n]).max()), float(np.abs(y[n:]).max()) / self.omega, 1e-300)
        self.D = np.concatenate([np.full(n, a), np.full(n, a * self.omega), [self.omega * OMEGA_WEIGHT]])

    # ------------------------------------------------------------ pieces
    def _residual(self, z: np.ndarray) -> np.ndarray:
        """``y(2 pi) - y0`` (2n,) at the scaled point ``z`` (the accurate run)."""
        u = z * self.D
        return self.sh.run(u[:-1], float(u[-1])).y[:, -1] - u[:-1]

    def _jacobian(self, z: np.ndarray):
        """The scaled Jacobian (2n, 2n + 1) at ``z`` and the monodromy (the variational run)."""
        m = 2 * self.sh.n
        u = z * self.D
        _, S = self.sh.variational(u[:m], float(u[m]))
        J = S - np.hstack([np.eye(m), np.zeros((m, 1))])
        return J * self.D[None, :], S[:, :m]

    @staticmethod
    def _tangent(J: np.ndarray, prev: np.ndarray | None) -> np.ndarray:
        t = np.linalg.svd(J)[2][-1]
        ref = prev if prev is not None else np.eye(len(t))[-1]
        return t if t @ ref >= 0 else -t

    def correct(self, zp: np.ndarray, t: np.ndarray, J: np.ndarray, sigma_plane: float | None = None, *,
                tol: float | None = None):
        """Newton on ``R(z) = 0``, ``t . z = t . zp`` (or ``sigma_plane``) from ``zp``, with the chord ``J``
        (the last point's Jacobian, Broyden-updated; renewed when it does not contract):
        ``(z, J, monodromy, iterations)``
        at the converged point, or None. ``tol`` on the scaled increment (default :attr:`tol`)."""
        tol = self.tol if tol is None else tol
        z = zp.copy()
        target = float(t @ zp) if sigma_plane is None else sigma_plane
        last, self.first = np.inf, np.inf
        r = None
        for it in range(1, 3 * MAX_CORRECTOR + 1):
            try:
                r_new = self._residual(z)
                if r is not None:  # Broyden's update of the chord along the last step
                    J = J + np.outer(r_new - r - J @ d, d) / float(d @ d)
                r = r_new
                d = np.linalg.solve(np.vstack([J, t]), -np.concatenate([r, [t @ z - target]]))
            except (NumericalError, np.linalg.LinAlgError):
                return None
            size = float(np.abs(d).max())
            if not np.isfinite(size) or it > MAX_CORRECTOR and size > 0.5 * last:
                return None
            z = z + d
            self.first = min(self.first, size) if it == 1 else self.first
            if size <= tol * max(float(np.abs(z[:-1]).max()), 1.0):
                try:
                    J, mono = self._jacobian(z)
                except NumericalError:
                    return None
                return z, J, mono, it
            if size > 0.25 * last:  # the chord does not contract well: the Jacobian here
                try:
                    J, r = self._jacobian(z)[0], None
                except NumericalError:
                    return None
            last = size
        return None

    def orbit(self, z: np.ndarray, mono: np.ndarray, it: int) -> ForcedOrbit:
        u = z * self.D
        return self.sh.finish(u[:-1], float(u[-1]), it, mono)

    # ------------------------------------------------------------ the curve
    def run(self, frequency_range: tuple[float, float], *, ds: float = 0.05, ds_max: float = 0.5,
            ds_min: float = 1e-6, max_points: int = 600):
        """Points ``[(z, t, orbit, J)]`` from ``Omega = lo w`` until ``Omega > hi w`` (``frequency_range`` =
        ``(lo, hi)``, ratios to ``w``)."""
        lo, hi = frequency_range
        first = self.sh.orbit(lo * self.omega, K=self.K, tol=self.tol)
        z = np.concatenate([first.y0, [first.Omega]]) / self.D
        J, mono = self._jacobian(z)
        t = self._tangent(J, None)
        pts = [(z, t, first, J)]
        while pts[-1][2].Omega <= hi * self.omega:
            if len(pts) >= max_points:
                raise NumericalError(f"forced continuation: {max_points} points without reaching Omega = "
                                     f"{hi * self.omega:.6g} (last {pts[-1][2].Omega:.6g})")
            z, t, _, J = pts[-1]
            got = self.correct(z + ds * t, t, J, tol=self.loose)

            if got is not None:
                zn, Jn, mono, it = got
                tn = self._tangent(Jn, t)
                if tn @ t >= np.cos(MAX_TURN) or ds <= ds_min:
                    pts.append((zn, tn, self.orbit(zn, mono, it), Jn))
                    # the predictor's distance to the curve ~ ds^2: aim at PREDICTOR_ERROR ds
                    ds = min(ds * float(np.clip(np.sqrt(PREDICTOR_ERROR * ds / max(self.first, 1e-300)), 0.5, 2.0)),
                             ds_max)
                    continue
            ds *= 0.5
            if ds < ds_min:
                raise NumericalError(f"forced continuation: the step fell below {ds_min:g} at Omega = "
                                     f"{pts[-1][2].Omega:.6g} (no corrector convergence)")
        return pts

    def extremum(self, pts, i: int, value: Callable[[ForcedOrbit], float], *, maximise: bool) -> ForcedOrbit:
        """The orbit extremising ``value`` on the curve near point ``i`` (between its neighbours)."""
        zi, ti, oi, Ji = pts[i]
        lo = float(ti @ (pts[max(i - 1, 0)][0] - zi))
        hi = float(ti @ (pts[min(i + 1, len(pts) - 1)][0] - zi))
        cache: dict[float, ForcedOrbit] = {}

        def at(sigma: float) -> float:
            # the guess: the chord between the neighbours on the side of sigma
            j = i + 1 if sigma >= 0 else i - 1
            zj = pts[j][0]
            frac = sigma / float(ti @ (zj - zi)) if float(ti @ (zj - zi)) != 0 else 0.0
            got = self.correct(zi + frac * (zj - zi), ti, Ji, float(ti @ zi) + sigma)
            if got is None:
                return np.inf
            z, _, mono, it = got
            cache[sigma] = self.orbit(z, mono, it)
            v = value(cache[sigma])
            return -v if maximise else v
        span = hi - lo
        r = minimize_scalar(at, bounds=(lo, hi), method="bounded", options={"xatol": 1e-7 * max(abs(span), 1e-300)})
        best = cache.get(r.x)
        if best is None or not np.isfinite(r.fun):
            raise NumericalError(f"forced continuation: the extremum near Omega = {oi.Omega:.6g} was not refined")
        return best


def _point(o: ForcedOrbit) -> dict:
    return {"Omega": o.Omega, "amplitude": o.amplitude, "stable": o.stable}


def full_frc(M, C, forces: Force, F: np.ndarray, phi: np.ndarray, omega: float,
             frequency_range: tuple[float, float] = (0.9, 1.25), *, tangent: Callable | None = None,
             K: np.ndarray | None = None, rtol: float = 1e-11, ds: float = 0.05, ds_max: float = 0.5) -> FullFRC:
    """The full model's FRC of the master ``phi`` (M-normalised, linear frequency ``omega``) under
    ``F cos(Omega t)`` over ``Omega / omega`` in ``frequency_range``, with its refined peak and folds."""
    sh = ForcedShooting(M, C, forces, F, tangent=tangent, phi=phi, rtol=rtol)
    cont = Continuation(sh, omega, K)
    pts = cont.run(frequency_range, ds=ds, ds_max=ds_max)
    orbits = [p[2] for p in pts]
    A = np.array([o.amplitude for o in orbits])
    i = int(np.argmax(A))
    if i in (0, len(A) - 1):
        raise NumericalError(f"forced continuation: the largest amplitude is at the range's end (Omega = "
                             f"{orbits[i].Omega:.6g}): the range does not contain the peak")
    peak = cont.extremum(pts, i, lambda o: o.amplitude, maximise=True)
    folds = []
    tOm = np.array([p[1][-1] for p in pts])
    for k in range(len(pts) - 1):
        if tOm[k] * tOm[k + 1] < 0:  # Omega turns between k and k + 1
            j = k if abs(tOm[k]) < abs(tOm[k + 1]) else k + 1
            j = min(max(j, 1), len(pts) - 2)
            folds.append(_point(cont.extremum(pts, j, lambda o: o.Omega, maximise=tOm[k] > 0)))
    return FullFRC(orbits, _point(peak), folds, sh.force_evaluations)


def full_frc_peak(M, C, forces: Force, F: np.ndarray, phi: np.ndarray, omega: float,
                  frequency_range: tuple[float, float] = (0.9, 1.25), **kw) -> tuple[float, float]:
    """``(A_peak, Omega_peak)`` of the full model's FRC (:func:`full_frc`)."""
    frc = full_frc(M, C, forces, F, phi, omega, frequency_range, **kw)
    return frc.peak["amplitude"], frc.peak["Omega"]
