"""What rounding leaves of T's digits: the forces' round-off and the solves, through T's cancellation.

On a slender structure T is a small difference of large terms: DNF's ``A`` and ``h`` of a cantilever
of L/h = 300 are ``-/+ 1.4e6`` and sum to ``1.8`` (docs/design.md section 1, "Round-off of T").
The two-amplitude STEP check cannot see an error that does not change with the amplitude, and a
force evaluated by a black box carries, per entry, an absolute rounding of about::

    noise_i = eps (|K| |u|)_i + eps_f |f_i(u)|          u = +-q phi

``eps (|K| |u|)_i``: the solver's own floating-point rounding, which scales with the element forces
(the bending stresses of a slender mode are huge against the nodal resultants ``K u = w^2 M u``);
``eps_f |f_i|``: the digits a solver prints (``force_digits``; CalculiX: 7, ``eps_f = 5e-7``).
Propagated to first order (``y = K^+ Gv``, ``z = (K - 4 w^2 M)^-1 Gv``)::

    dh  = |phi|^T noise / q^3                                    (h from f(+q phi) - f(-q phi))
    dGv = noise / q^2                                            (Gv from f(+q phi) + f(-q phi))
    dA  = 2 |y + z|^T dGv + eps (|y|^T |K| |y| + |z|^T |K| |z|) (A = -(y + z)^T Gv is quadratic in Gv;
                                                                  the solves' backward error)
    dB  = 8 |y|^T |M| |z| (|dGv| / |Gv|)                        (B = 4 y^T M z, quadratic in Gv)
    dT  = (3 (dh + dA) + w^2 dB) / (8 w^2)

where a sum ``|w|^T noise`` takes the solver's own rounding in magnitude (it may be systematic: a
solver's linear force and its assembled matrix differ coherently) and the printing in root-sum-square,
:data:`PRINTED_SIGMAS` standard deviations of independent roundings (:func:`weighted_rounding`).
``dT / |T|`` (relative to the computed T: at 1 or more not even T's sign is established) exceeded the
true error in every case measured, by 1.5x to 1000x (FEniCSx cantilever strips, bench/cantilever.py; the
paper's plate at tiny amplitudes, tests/nf/test_stability.py); it is first order, so where the noise is
as large as G itself (amplitudes of 1e-6 h) the two-amplitude change is what shows it. It falls as
``1 / q^2``, so a larger STEP amplitude restores the digits of a model
whose force is an exact cubic, and STEP along the quadratic manifold removes the cancellation
(:mod:`stepnf.pipeline.slender_dnf`, :mod:`stepnf.step.manifold_probe`).

The quadratic manifolds (MD, SMD: ``C4 = k2/2 + 2 t + h``, :func:`stepnf.nf.coefficient.qm_coefficients`)
cancel the same way; :func:`qm_roundoff` bounds them alike.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stepnf.linalg.null_space import abs_product

EPS = float(np.finfo(float).eps)


def printed_rounding(digits: int | None) -> float:
    """Relative rounding of a force entry printed with ``digits`` significant digits (0 when None)."""
    return 0.0 if not digits else 0.5 * 10.0 ** (1 - int(digits))


#: a printed force's rounding is bounded by this many standard deviations of the sum of the entries'
#: independent roundings (uniform in +-eps_f |f_i|: variance (eps_f |f_i|)^2 / 3); the sum of many independent
#: bounded terms is near Gaussian, which exceeds 5 sigma with a probability of 6e-7
PRINTED_SIGMAS = 5.0


def weighted_rounding(weights: np.ndarray, solver: np.ndarray, printed: np.ndarray) -> float:
    """Bound of ``sum_i weights_i e_i`` for per-entry roundings ``e_i`` made of the solver's own (bounded by
    ``solver_i``, summed in magnitude: they may be systematic) and the printing of the numbers (bounded by
    ``printed_i``, independent from entry to entry: :data:`PRINTED_SIGMAS` standard deviations)."""
    w = np.abs(weights)
    return float(w @ solver) + PRINTED_SIGMAS * float(np.sqrt(np.sum((w * printed) ** 2) / 3.0))


def step_rounding(kp: np.ndarray, K: sp.spmatrix, phi: np.ndarray, q: float, Gv: np.ndarray,
                  Hv: np.ndarray | None, digits: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Per-entry bounds of the rounding of ``f(+-q phi)`` (module docstring): the solver's own,
    ``eps q (|K| |phi|)_i`` (``kp = |K| |phi|``, (n,)), and the printed, ``eps_f |f_i|`` with ``f`` the
    force at ``q phi`` rebuilt from K, ``Gv`` and ``Hv`` (None: the cubic force left out)."""
    f = q * (K @ phi) + q * q * Gv + (q ** 3 * Hv if Hv is not None else 0.0)
    return EPS * q * kp, printed_rounding(digits) * np.abs(f)


def dnf_roundoff(phi: np.ndarray, q: float, omega_p: float, T: float, Gv: np.ndarray, Hv: np.ndarray | None,
                 y: np.ndarray, z: np.ndarray, K: sp.spmatrix, M: sp.spmatrix,
                 digits: int | None) -> tuple[float, dict]:
    """Relative error of DNF's T that rounding leaves (module docstring), and its parts.

    ``phi`` mass-normalised (n,), ``q`` the STEP amplitude (modal), ``Gv``, ``Hv`` = G(phi, phi),
    H(phi, phi, phi) (n,; ``Hv`` None: the cubic force is left out of ``|f|``), ``y``, ``z`` DNF's two
    solutions, ``digits`` the solver's printed force digits (None: full double precision).
    Returns ``(dT / |T|, parts)`` with ``parts`` = ``dh``, ``dA``, ``dB``, ``dT`` (absolute, the
    model's units); ``inf`` when T is 0 with a non-zero bound.
    """
    w2 = omega_p ** 2
    aphi, ay, az = np.abs(phi), np.abs(y), np.abs(z)
    kp, ky, kz = abs_product(K, np.column_stack([aphi, ay, az])).T
    own, printed = step_rounding(kp, K, phi, q, Gv, Hv, digits)
    dh = weighted_rounding(aphi, own, printed) / q ** 3
    dA = 2.0 * weighted_rounding(y + z, own, printed) / q ** 2 + EPS * (float(ay @ ky) + float(az @ kz))
    gn = float(np.linalg.norm(Gv))
    dG = np.linalg.norm(own + printed) / q ** 2
    dB = 8.0 * float(ay @ abs_product(M, az)[:, 0]) * (float(dG) / gn if gn > 0 else 0.0)
    dT = (3.0 * (dh + dA) + w2 * dB) / (8.0 * w2)
    rel = dT / abs(T) if T != 0 else (0.0 if dT == 0 else np.inf)
    return float(rel), {"dh": dh, "dA": dA, "dB": dB, "dT": float(dT)}


def qm_roundoff(phi: np.ndarray, q: float, omega_p: float, T: float, Gv: np.ndarray, Hv: np.ndarray | None,
                theta: np.ndarray, K: sp.spmatrix, digits: int | None) -> float:
    """Relative error of a quadratic manifold's T (MD, SMD: ``theta`` its modal derivative) that rounding
    leaves through ``C4 = k2/2 + 2 t + h`` (``k2 = theta^T K theta``, ``t = theta^T Gv``): ``dC4 = dh +
    2 |theta|^T dGv + eps |theta|^T |K| |theta|``, ``dT = 3 dC4 / (8 w^2)`` (T's other terms do not cancel)."""
    w2 = omega_p ** 2
    aphi, ath = np.abs(phi), np.abs(theta)
    kp, kt = abs_product(K, np.column_stack([aphi, ath])).T
    own, printed = step_rounding(kp, K, phi, q, Gv, Hv, digits)
    dC4 = (weighted_rounding(aphi, own, printed) / q ** 3 + 2.0 * weighted_rounding(ath, own, printed) / q ** 2
           + EPS * float(ath @ kt))
    dT = 3.0 * dC4 / (8.0 * w2)
    return float(dT / abs(T)) if T != 0 else (0.0 if dT == 0 else np.inf)


def cancellation(A: float, h: float, w2B: float) -> float:
    """How much T's terms cancel: ``(3 (|A| + |h|) + |w^2 B|) / |3 (A + h) + w^2 B|`` (``inf`` at T = 0)."""
    den = abs(3.0 * (A + h) + w2B)
    num = 3.0 * (abs(A) + abs(h)) + abs(w2B)
    return float(num / den) if den > 0 else np.inf
