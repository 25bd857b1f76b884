"""Radial parts of the von Karman coupling integrals on the unit disk.

For ``u = U(r) c_u(theta)``, ``v = V(r) c_v(theta)``, ``q = Q(r) c_q(theta)``
(``c`` = cos or sin of ``k theta``) the trilinear integral of
``q L(u, v)``, with the von Karman bracket in polar coordinates

    L(u, v) = u_rr (v_r/r + v_tt/r^2) + v_rr (u_r/r + u_tt/r^2)
              - 2 (u_rt/r - u_t/r^2) (v_rt/r - v_t/r^2),

separates into ``R1 * I1 + R2 * I2`` with the angular factors
``I1 = int c_q c_u c_v``, ``I2 = int c_q c_u' c_v'`` (see
:func:`stepnf.models._quadrature.angular_factors`) and the radial integrals

    R1 = int_0^1 Q [U'' (V'/r - k_v^2 V/r^2) + V'' (U'/r - k_u^2 U/r^2)] r dr
    R2 = -2 int_0^1 Q (U'/r - U/r^2) (V'/r - V/r^2) r dr.
"""
from __future__ import annotations

import numpy as np

Triple = tuple[np.ndarray, np.ndarray, np.ndarray]  # R, R', R'' on the radial nodes, shape (n, m)


def _parts(f: Triple, k: int, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    R, dR, d2R = f
    return d2R, dR / r - k * k * R / r**2, dR / r - R / r**2


def laplacian(f: Triple, k: int, r: np.ndarray) -> np.ndarray:
    """Radial part of the Laplacian of ``R(r) cos k theta``: ``R'' + R'/r - k^2 R/r^2``."""
    R, dR, d2R = f
    return d2R + dR / r - k * k * R / r**2


def trilinear(Q: np.ndarray, u: Triple, ku: int, v: Triple, kv: int, r: np.ndarray, w: np.ndarray,
              angular: tuple[float, float], *, diagonal: bool = False) -> np.ndarray:
    """``int q L(u_i, v_j) dS`` for all (b, i, j): shape (nq, nu, nv), or (nq, n) with ``diagonal``
    (then ``u`` and ``v`` are the same family and only i = j is formed).

    ``Q`` (nq, m) the radial parts of q; ``r``, ``w`` the radial rule (``r dr`` is applied here);
    ``angular = (I1, I2)``. A zero angular factor skips its radial integral.
    """
    I1, I2 = angular
    Qw = Q * (r * w)[None, :]
    u2, ua, ub = _parts(u, ku, r)
    v2, va, vb = _parts(v, kv, r)
    if diagonal:
        out = np.zeros((Q.shape[0], u2.shape[0]))
        if I1:
            out += I1 * (Qw @ (u2 * va + v2 * ua).T)
        if I2:
            out += I2 * (-2.0) * (Qw @ (ub * vb).T)
        return out
    nu_, nv_ = u2.shape[0], v2.shape[0]
    out = np.zeros((Q.shape[0], nu_ * nv_))
    if I1:
        prod = (u2[:, None, :] * va[None, :, :] + ua[:, None, :] * v2[None, :, :]).reshape(nu_ * nv_, -1)
        out += I1 * (Qw @ prod.T)
    if I2:
        prod = (ub[:, None, :] * vb[None, :, :]).reshape(nu_ * nv_, -1)
        out += I2 * (-2.0) * (Qw @ prod.T)
    return out.reshape(Q.shape[0], nu_, nv_)
