"""Radial functions of the unit disk: free-plate modes and clamped-plate (Airy) functions.

Both are Bessel combinations ``R(r) = J_k(lam r) + c I_k(lam r) / I_k(lam)``
(``I_k`` scaled by its value at the edge, so nothing overflows for large
``lam``). With the angular factor ``cos k theta`` or ``sin k theta`` they solve
``Delta Delta u = lam^4 u`` on the unit disk:

* free edge (transverse modes of the plate, ``omega = lam^2``): bending moment
  ``R'' + nu (R' - k^2 R) = 0`` and Kirchhoff shear
  ``(Delta R)' - (1 - nu) k^2 (R' - R) = 0`` at ``r = 1``;
* clamped edge (Airy stress functions of a free in-plane edge, ``F = F_r = 0``,
  i.e. ``N_rr = N_rtheta = 0``): ``R(1) = R'(1) = 0``, eigenvalue ``xi^4``.

Normalisation: the integral of ``u^2`` over the unit disk is 1, that is
``pi_k int_0^1 R^2 r dr = 1`` with ``pi_k = 2 pi`` (k = 0) or ``pi`` (k >= 1).
All derivatives are with respect to ``r``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq
from scipy.special import ive, jv


def angular_weight(k: int) -> float:
    """Integral of ``cos^2 k theta`` over ``[0, 2 pi]``: ``2 pi`` for k = 0, else ``pi``."""
    return 2.0 * np.pi if k == 0 else np.pi


def _bessel_at(k: int, z: np.ndarray) -> tuple[np.ndarray, ...]:
    """``J_k, J_k', J_k''`` and ``e^-z I_k, e^-z I_k', e^-z I_k''`` (derivatives in the argument, z > 0).

    Two Bessel evaluations per kind; the derivatives follow from the recurrences
    ``J_k' = k J_k / z - J_{k+1}``, ``I_k' = k I_k / z + I_{k+1}`` and Bessel's equations
    ``J'' = -J'/z - (1 - k^2/z^2) J``, ``I'' = -I'/z + (1 + k^2/z^2) I``.
    At ``z = 0`` (the centre) the limits are approached from ``z = 1e-8``.
    """
    z = np.maximum(z, 1e-8)
    Jk, Jn = jv(k, z), jv(k + 1, z)
    Ik, In = ive(k, z), ive(k + 1, z)
    J1 = k * Jk / z - Jn
    I1 = k * Ik / z + In
    J2 = -J1 / z - (1.0 - k * k / z**2) * Jk
    I2 = -I1 / z + (1.0 + k * k / z**2) * Ik
    return Jk, J1, J2, Ik, I1, I2


def _free_edge(k: int, lam, nu: float):
    """Moment and shear at r = 1 of ``J_k(lam r)`` and of ``I_k(lam r)/I_k(lam)`` (vectorised in lam)."""
    lam = np.asarray(lam, dtype=float)
    J0, J1, J2, I0, I1, I2 = _bessel_at(k, lam)
    i1, i2 = I1 / I0, I2 / I0
    mJ = lam**2 * J2 + nu * (lam * J1 - k * k * J0)
    mI = lam**2 * i2 + nu * (lam * i1 - k * k)
    vJ = -lam**3 * J1 - (1 - nu) * k * k * (lam * J1 - J0)
    vI = lam**3 * i1 - (1 - nu) * k * k * (lam * i1 - 1.0)
    return mJ, mI, vJ, vI


def _free_det(lam, k: int, nu: float):
    mJ, mI, vJ, vI = _free_edge(k, lam, nu)
    return mJ * vI - mI * vJ


def _clamped_det(xi, k: int):
    J0, J1, _, I0, I1, _ = _bessel_at(k, np.asarray(xi, dtype=float))
    return J1 - J0 * I1 / I0


def _roots(f, n: int, start: float, step: float = 0.01) -> np.ndarray:
    """First ``n`` sign changes of ``f`` (vectorised) above ``start``, refined by Brent's method.

    The roots of both frequency equations are about pi apart, so a scan step of
    0.01 cannot step over a pair of them.
    """
    out: list[float] = []
    a = start
    scalar = lambda x: float(f(x))  # noqa: E731
    while len(out) < n:
        x = a + step * np.arange(int(np.ceil((n - len(out) + 2) * 4.0 / step)) + 1)
        y = f(x)
        for i in np.nonzero(y[:-1] * y[1:] <= 0)[0]:
            if len(out) == n:
                break
            if y[i] == 0.0:
                out.append(float(x[i]))
            elif y[i + 1] != 0.0:
                out.append(brentq(scalar, x[i], x[i + 1], xtol=1e-14, rtol=4 * np.finfo(float).eps, maxiter=200))
        a = float(x[-1])
    return np.asarray(out)


@dataclass(frozen=True)
class RadialFamily:
    """``n`` radial functions of one nodal-diameter number ``k``.

    ``lam`` (n,): Bessel parameters (``omega = lam^2`` for plate modes, ``xi``
    for Airy functions); ``c`` (n,): coefficients of the scaled ``I_k``;
    ``norm`` (n,): factors making the disk integral of ``u^2`` equal to 1.
    """

    k: int
    lam: np.ndarray
    c: np.ndarray
    norm: np.ndarray

    def evaluate(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``R, R', R''`` at radii ``r`` (m,), each of shape (n, m), normalised."""
        lam = self.lam[:, None]
        z = lam * np.asarray(r, dtype=float)[None, :]
        J0, J1, J2, I0, I1, I2 = _bessel_at(self.k, z)
        s = np.exp(z - lam) / ive(self.k, self.lam)[:, None]  # e^z / (e^lam e^-lam I_k(lam)) scaling
        c = self.c[:, None]
        R = J0 + c * I0 * s
        dR = lam * (J1 + c * I1 * s)
        d2R = lam**2 * (J2 + c * I2 * s)
        n = self.norm[:, None]
        return n * R, n * dR, n * d2R


def _normalise(k: int, lam: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Factors making ``pi_k int_0^1 R^2 r dr = 1``, from the closed forms (Lommel integrals)

    ``int J_k(lr)^2 r dr = [J_k'(l)^2 + (1 - k^2/l^2) J_k(l)^2] / 2``,
    ``int I_k(lr)^2 r dr = [(1 + k^2/l^2) I_k(l)^2 - I_k'(l)^2] / 2``,
    ``int J_k(lr) I_k(lr) r dr = [J_k(l) I_k'(l) - J_k'(l) I_k(l)] / (2 l)``.
    """
    J0, J1, _, I0, I1, _ = _bessel_at(k, lam)
    i1 = I1 / I0  # I scaled by its edge value
    jj = 0.5 * (J1**2 + (1.0 - k * k / lam**2) * J0**2)
    ii = 0.5 * ((1.0 + k * k / lam**2) - i1**2)
    ji = (J0 * i1 - J1) / (2.0 * lam)
    return 1.0 / np.sqrt(angular_weight(k) * (jj + 2.0 * c * ji + c * c * ii))


def free_plate_family(k: int, n: int, nu: float, start: float = 1.0) -> RadialFamily:
    """The first ``n`` elastic free-edge plate modes with ``k`` nodal diameters (rigid modes excluded),
    ``lam`` above ``start`` (1 is below every root for nu <= 0.95, so for every plate; the lowest root
    of k >= 2 falls like (1 - nu)^(1/4) as nu -> 1, which the clamped edge's Airy functions reach)."""
    lam = _roots(lambda x: _free_det(x, k, nu), n, start=start)
    mJ, mI, vJ, vI = _free_edge(k, lam, nu)
    # the row with the larger coefficient of I_k is the better conditioned one
    c = np.where(np.abs(mI) >= np.abs(vI), -mJ / mI, -vJ / vI)
    return RadialFamily(k, lam, c, _normalise(k, lam, c))


def clamped_plate_family(k: int, n: int) -> RadialFamily:
    """The first ``n`` clamped-edge plate functions (Airy functions) with ``k`` nodal diameters."""
    xi = _roots(lambda x: _clamped_det(x, k), n, start=1.0)
    J0 = jv(k, xi)
    c = -J0  # R = J_k(xi r) - J_k(xi) I_k(xi r)/I_k(xi): R(1) = 0
    return RadialFamily(k, xi, c, _normalise(k, xi, c))
