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
    dT  = (3 (dh + dA) + w^2 dB) / (8 w^2) + dT_lambda
    dT_lambda = c eps_lam |lambda dT/dlambda|                    (the master's own eigenvalue error,
                                                                  eps_lam = eps |phi|^T |K| |phi| / lambda or
                                                                  the pair's own inconsistency if larger:
                                                                  :func:`eigenvalue_roundoff`,
                                                                  through T's slope: :func:`eigenvalue_part`)

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
cancel the same way; :func:`qm_roundoff` bounds them alike. ``dT_lambda`` does not fall with ``q``: it is
kept apart (``extra["roundoff_dT_lambda"]``) so the raise of the amplitude is decided without it.

Where STEP's own changes grow as the amplitude shrinks and exceed this per-entry model's bound (a third
amplitude shows a negative rate: :func:`stepnf.step.truncation.rounding_excess`), the model is shown short by that
factor (``MasterStep.rounding_excess``: 3e4 on the paper's plate at 1e-6 h, whose solid forces round at eps
of the unit Green-Lagrange strain, not of the strain): the forces' part of the bound is multiplied by it
(:class:`Rounding` ``excess``; ``extra["roundoff_excess"]``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp

from stepnf.linalg.factorization import DENSE_LIMIT
from stepnf.linalg.null_space import abs_energy, abs_product
from stepnf.nf.coefficient import MethodResult, backbone_T, qm_coefficients

EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class Rounding:
    """What the full-order evaluators (:func:`dnf`, :func:`smd_full`, :func:`md_full`) need to bound T's
    rounding (:mod:`stepnf.nf.roundoff`): the STEP amplitude ``q`` (modal), ``H(phi_p, phi_p, phi_p)`` (n,)
    or None, the solver's printed force digits (None: full double precision) and ``excess``, the factor by
    which STEP's own changes showed the per-entry rounding model short (``MasterStep.rounding_excess``, at
    least 1): the forces' part of the bound is multiplied by it."""

    q: float
    Hv: np.ndarray | None = None
    digits: int | None = None
    excess: float = 1.0


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


def step_rounding(kp: np.ndarray, K: sp.spmatrix | None, phi: np.ndarray, q: float, Gv: np.ndarray,
                  Hv: np.ndarray | None, digits: int | None, *, Kphi: np.ndarray | None = None,
                  floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Per-entry bounds of the rounding of ``f(+-q phi)`` (module docstring): the solver's own,
    ``eps q (|K| |phi|)_i`` (``kp = |K| |phi|``, (n,)), and the printed, ``eps_f |f_i|`` with ``f`` the
    force at ``q phi`` rebuilt from K, ``Gv`` and ``Hv`` (None: the cubic force left out). ``Kphi``: ``K phi``
    when the caller has it (then ``K`` is not used: no sparse product per call); ``floor``: the least
    ``eps_f`` (``EPS``: the rounding of the nonlinear force itself even at full precision)."""
    f = q * (K @ phi if Kphi is None else Kphi) + q * q * Gv + (q ** 3 * Hv if Hv is not None else 0.0)
    return EPS * q * kp, max(printed_rounding(digits), floor) * np.abs(f)


def dnf_roundoff(phi: np.ndarray, q: float, omega_p: float, T: float, Gv: np.ndarray, Hv: np.ndarray | None,
                 y: np.ndarray, z: np.ndarray, K: sp.spmatrix, M: sp.spmatrix,
                 digits: int | None, slope: float | None = None, excess: float = 1.0) -> tuple[float, dict]:
    """Relative error of DNF's T that rounding leaves (module docstring), and its parts.

    ``phi`` mass-normalised (n,), ``q`` the STEP amplitude (modal), ``Gv``, ``Hv`` = G(phi, phi),
    H(phi, phi, phi) (n,; ``Hv`` None: the cubic force is left out of ``|f|``), ``y``, ``z`` DNF's two
    solutions, ``digits`` the solver's printed force digits (None: full double precision), ``slope``
    = ``lambda dT/dlambda`` (:func:`dnf_slope`; None: the eigenvalue's part left out), ``excess``
    (:class:`Rounding`) the factor on the forces' part (``dh``, ``dA``, ``dB`` as computed, before it).
    Returns ``(dT / |T|, parts)`` with ``parts`` = ``dh``, ``dA``, ``dB``, ``dT_lambda`` (the master's own
    eigenvalue error through T: :func:`eigenvalue_part`), ``dT`` (absolute, the model's units; ``dT``
    holds ``dT_lambda``), ``eps_lambda``, ``lambda_slope`` and ``excess`` (when not 1); ``inf`` when T is 0
    with a non-zero bound.
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
    eps_lam, dT_lam = eigenvalue_part(K, phi, omega_p, slope) if slope is not None else (0.0, 0.0)
    dT = excess * (3.0 * (dh + dA) + w2 * dB) / (8.0 * w2) + dT_lam
    rel = dT / abs(T) if T != 0 else (0.0 if dT == 0 else np.inf)
    parts = {"dh": dh, "dA": dA, "dB": dB, "dT_lambda": float(dT_lam), "dT": float(dT), "eps_lambda": eps_lam,
             "lambda_slope": float(slope or 0.0)}
    return float(rel), parts | ({"excess": float(excess)} if excess != 1.0 else {})


def qm_roundoff(phi: np.ndarray, q: float, omega_p: float, T: float, Gv: np.ndarray, Hv: np.ndarray | None,
                theta: np.ndarray, K: sp.spmatrix, digits: int | None,
                slope: float | None = None, excess: float = 1.0) -> tuple[float, dict]:
    """Relative error of a quadratic manifold's T (MD, SMD: ``theta`` its modal derivative) that rounding
    leaves through ``C4 = k2/2 + 2 t + h`` (``k2 = theta^T K theta``, ``t = theta^T Gv``): ``dC4 = dh +
    2 |theta|^T dGv + eps |theta|^T |K| |theta|``, ``dT = 3 dC4 / (8 w^2)`` (T's other terms do not cancel),
    plus the master's eigenvalue error through ``slope`` = ``lambda dT/dlambda`` (:func:`qm_slope`; None: left
    out), ``excess`` the factor on ``dC4`` (:class:`Rounding`). Returns ``(dT / |T|, parts)``, ``parts`` as
    :func:`dnf_roundoff`'s: ``dC4`` (before the factor), ``dT_lambda``, ``dT``, ``eps_lambda``,
    ``lambda_slope``, ``excess`` (when not 1)."""
    w2 = omega_p ** 2
    aphi, ath = np.abs(phi), np.abs(theta)
    kp, kt = abs_product(K, np.column_stack([aphi, ath])).T
    own, printed = step_rounding(kp, K, phi, q, Gv, Hv, digits)
    dC4 = (weighted_rounding(aphi, own, printed) / q ** 3 + 2.0 * weighted_rounding(ath, own, printed) / q ** 2
           + EPS * float(ath @ kt))
    eps_lam, dT_lam = eigenvalue_part(K, phi, omega_p, slope) if slope is not None else (0.0, 0.0)
    dT = excess * 3.0 * dC4 / (8.0 * w2) + dT_lam
    rel = float(dT / abs(T)) if T != 0 else (0.0 if dT == 0 else np.inf)
    parts = {"dC4": float(dC4), "dT_lambda": float(dT_lam), "dT": float(dT), "eps_lambda": eps_lam,
             "lambda_slope": float(slope or 0.0)}
    return rel, parts | ({"excess": float(excess)} if excess != 1.0 else {})


def eigenvalue_roundoff(K: sp.spmatrix, phi: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Relative error of each eigenvalue ``lam`` (k,) that rounding K's entries and the products with K by
    ``eps`` leaves, on its own mode ``phi`` (n, k; M-normalised): ``eps |phi|^T |K| |phi| / |lam|``
    (first order: ``d lambda = phi^T dK phi``, ``|dK| <= eps |K|``). For a mode that is locally a rigid
    motion (the bending of a slender solid) the terms of ``phi^T K phi`` cancel and the bound approaches
    ``eps lambda_max / lambda``; for a mode that no such cancellation makes (``K`` diagonal) it is ``eps``.
    ``inf`` where ``lam`` is 0.

    That bound assumes an eigen-solver whose backward error follows K's entries (a sparse factorisation). A
    dense ``eigh`` (Householder reduction) errs by ``~eps ||K||`` whatever the mode: on a graded model (a soft
    chain weakly tied to a stiff block, dofs interleaved) its fundamental is 2.7% off where the bound says 4e-12
    (tests/nf/test_mode_conditioning.py). The pair is then inconsistent: ``lam`` differs from the Rayleigh
    quotient ``phi^T K phi`` of its own vector (second order in the vector's error, accurate to 4e-7 there), so
    the larger of the bound and ``|lam - phi^T K phi| / |lam|`` is returned (``phi^T M phi = 1`` taken; an
    error of the normalisation counts in it)."""
    lam_s = np.asarray(lam, dtype=float)
    lam = np.abs(lam_s)
    X = np.asarray(phi, dtype=float).reshape(K.shape[0], -1)
    scale = np.maximum(EPS * abs_energy(K, X), np.abs(lam_s - np.einsum("ij,ij->j", X, np.asarray(K @ X))))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(lam > 0, scale / np.where(lam > 0, lam, 1.0), np.inf)


#: the eigenvalue's part of T's bound takes this many times :func:`eigenvalue_roundoff` on a model small
#: enough for stepnf's dense eigen-solve (:data:`~stepnf.linalg.factorization.DENSE_LIMIT` dofs or fewer):
#: LAPACK's ``eigh`` reduces the whole matrix, so its backward error is a small multiple of ``eps ||K||``,
#: measured 1.6x to 2.2x the first-order bound on tests/nf/test_eigenvalue_sensitivity.py's three dofs (its T
#: then of the wrong sign). Above that (the sparse shift-invert path, whose factorisation's error follows K's
#: entries) the bound itself: the error measured 13x to 40x below it on the FEniCSx tet10 strip at
#: L/h = 1000 (tests/pipeline/test_slender_tet10.py)
EIGEN_SAFETY = 4.0


def eigenvalue_part(K: sp.spmatrix, phi: np.ndarray, omega_p: float, slope: float) -> tuple[float, float]:
    """What the master's own eigenvalue error costs T: ``(eps_lam, c eps_lam |lambda dT/dlambda|)``.

    ``eps_lam`` is :func:`eigenvalue_roundoff` of ``phi`` (n,; M-normalised) at ``lambda = omega_p^2``
    (``c``: :func:`eigen_safety`, 4 for a dense eigen-solve, else 1);
    ``slope`` = ``lambda dT/dlambda`` (T's units) with the mode shape held (:func:`dnf_slope`,
    :func:`qm_slope`). The computed pair is exact for a K rounded by ``dK``; the eigenvalue then differs from
    K's Rayleigh quotient of the computed vector by ``phi^T dK phi`` (first order). The vector's own error is
    left out: ``c_s = phi_s^T dK phi / (lambda - lambda_s)`` along each other mode, divided by the gap, about
    ``sqrt(eps_p eps_s lambda_p lambda_s) / |lambda_p - lambda_s|`` (7e-4 for the tet10 strip's mode 0 against
    its mode 2, 40 times below its ``eps_lam``), moves T by ``c_s`` times T's derivative along a mixture of
    the two modes; that needs a STEP per neighbour (docs/design.md, "Round-off of T")."""
    eps_lam = float(eigenvalue_roundoff(K, np.asarray(phi, dtype=float)[:, None], [omega_p ** 2])[0])
    return eps_lam, eigen_safety(K) * eps_lam * abs(float(slope))


def eigen_safety(K: sp.spmatrix) -> float:
    """:data:`EIGEN_SAFETY` for a model of at most ``DENSE_LIMIT`` dofs (a dense eigen-solve), else 1."""
    return EIGEN_SAFETY if K.shape[0] <= DENSE_LIMIT else 1.0


def dnf_slope(w2: float, h_s: float, dB_dlam: float) -> float:
    """``lambda dT/dlambda`` of DNF's ``T = 3 h_s / (8 lambda) - B / 4`` (``h_s = A + h + lambda B``, which does
    not depend on lambda for a given phi): ``-3 h_s / (8 lambda) - lambda B' / 4``, ``B' = dB/dlambda``
    (:func:`stepnf.nf.evaluators.dnf`: ``4 (z - y)^T M z / lambda``, no solve)."""
    return -3.0 * h_s / (8.0 * w2) - w2 * dB_dlam / 4.0


def qm_slope(omega_p: float, g_p: float, h: float, forms: tuple[float, float, float, float],
             s: float | None = None) -> float:
    """``lambda dT/dlambda`` of a quadratic manifold's T (:func:`stepnf.nf.coefficient.qm_coefficients`, forms
    ``(mu1, mu2, k2, t)``) with phi held. SMD (``s`` None): theta = -2 K^+ G(phi, phi) does not depend on
    lambda. MD: theta = -2 Z Gv, ``Z = (K - lambda M)^-1`` on the M-complement of phi (and its twins), so
    ``theta' = Z M theta`` and, with ``s = theta^T M Z M theta``: ``mu2' = 2 s``, ``k2' = 2 (lambda s + mu2)``,
    ``t' = -mu2 / 2``, ``mu1' = 0``. Central difference of the closed form (:func:`lambda_slope`)."""
    mu1, mu2, k2, t = (float(v) for v in forms)
    w2 = omega_p ** 2

    def T_at(lam: float) -> float:
        d = lam - w2
        m2, kk, tt = (mu2, k2, t) if s is None else (mu2 + 2 * s * d, k2 + 2 * (w2 * s + mu2) * d, t - mu2 * d / 2)
        return backbone_T(qm_coefficients(float(np.sqrt(lam)), g_p, h, mu1, m2, kk, tt), float(np.sqrt(lam)))

    return lambda_slope(T_at, w2)


def lambda_slope(T_at: Callable[[float], float], w2: float) -> float:
    """``lambda dT/dlambda`` at ``lambda = w2`` ((rad/s)^2) of ``T_at(lambda)`` (T's units): central difference,
    relative step 1e-4 (T is rational in lambda: the difference's error ~1e-8 of the slope away from a
    resonance)."""
    return w2 * (T_at(1.0001 * w2) - T_at(0.9999 * w2)) / (2e-4 * w2)


def with_modal_eigen_part(res: MethodResult, T_of: Callable[[np.ndarray], float], omega: np.ndarray, p: int,
                          K: sp.spmatrix, phi: np.ndarray) -> MethodResult:
    """``res`` (a modal method of master ``p``: NF, modal MD or SMD) with the master's own eigenvalue error
    through T (:func:`eigenvalue_part`) as its rounding bound ``extra["roundoff"]`` and its parts
    (``roundoff_dT_lambda``, ``roundoff_eps_lambda``, ``roundoff_lambda_slope``); ``T_error`` the larger of
    it and the two-amplitude change (kept as ``extra["T_change"]``). ``T_of(omega)``: the method's T with
    the angular frequencies ``omega`` (m,) and every coefficient as in ``res``; the slope ``lambda dT/dlambda``
    is its central difference in ``omega[p]^2`` (:func:`lambda_slope`). Unchanged when T
    or the slope is not finite (a resonance within the step)."""
    w2 = float(omega[p]) ** 2
    if not np.isfinite(res.T) or res.T == 0 or w2 <= 0:
        return res

    def at(lam: float) -> float:
        om = np.array(omega, dtype=float)
        om[p] = np.sqrt(lam)
        return T_of(om)

    slope = lambda_slope(at, w2)
    if not np.isfinite(slope):
        return res
    eps_lam, dT = eigenvalue_part(K, phi, float(omega[p]), slope)
    rel = dT / abs(res.T)
    res.extra.update(T_change=res.T_error, roundoff=rel, roundoff_dT_lambda=dT, roundoff_eps_lambda=eps_lam,
                     roundoff_lambda_slope=float(slope))
    res.T_error = rel if res.T_error is None else max(res.T_error, rel)
    return res


def cancellation(A: float, h: float, w2B: float) -> float:
    """How much T's terms cancel: ``(3 (|A| + |h|) + |w^2 B|) / |3 (A + h) + w^2 B|`` (``inf`` at T = 0)."""
    den = abs(3.0 * (A + h) + w2B)
    num = 3.0 * (abs(A) + abs(h)) + abs(w2B)
    return float(num / den) if den > 0 else np.inf


def roundoff_message(p: int, T: float, extra: dict, tolerance: float) -> str:
    """The one-line message of master ``p``'s ``t_roundoff`` flag: the bound ``extra["roundoff"]`` (relative) split
    into what the forces' rounding and the solves leave (with the cancellation of T's terms when measured,
    ``extra["cancellation"]``; a larger STEP amplitude reduces it) and what the master's own eigenvalue error
    leaves through T's slope (``extra["roundoff_dT_lambda"]``: :func:`eigenvalue_part`; no amplitude does)."""
    total = float(extra["roundoff"])
    eig = float(extra.get("roundoff_dT_lambda", 0.0)) / abs(T) if T != 0 and np.isfinite(T) else 0.0
    amp, parts = max(total - eig, 0.0), []
    if amp > 0 or not eig > 0:
        c = float(extra.get("cancellation", np.nan))
        x = float(extra.get("roundoff_excess", 1.0))
        parts.append(f"{amp:.1e} from the forces' rounding and the solves"
                     + (f" (T's terms cancel {c:.2g}-fold)" if np.isfinite(c) else "")
                     + (f" (x {x:.2g}: STEP's own changes grew as the amplitude shrank, {x:.2g} times their "
                        "rounding bound)" if x > 1.0 else ""))
    if eig > 0:
        sens = abs(float(extra.get("roundoff_lambda_slope", 0.0)) / T)  # eig = (c eps_lambda) sens
        parts.append(f"{eig:.1e} from mode {p}'s own eigenvalue (resolved to about {eig / sens:.0e}, times "
                     f"|lambda dT/dlambda| / |T| = {sens:.3g}; no STEP amplitude reduces it)")
    return f"rounding leaves T an error of up to {total:.2e} (relative; tolerance {tolerance:.1e}): " + "; ".join(parts)


def with_qm_roundoff(res: MethodResult, phi: np.ndarray, omega_p: float, Gv: np.ndarray, theta: np.ndarray | None,
                     K: sp.spmatrix, rounding: Rounding | None, *, forms: tuple | None = None,
                     h: float = 0.0, s: float | None = None) -> MethodResult:
    """``res`` (:func:`stepnf.nf.evaluators.smd_full`, :func:`stepnf.nf.evaluators.md_full`) with
    ``extra["roundoff"]`` (:func:`qm_roundoff`; its parts as ``extra["roundoff_<part>"]``), ``extra["T_change"]``
    (the two-amplitude change) and ``T_error`` the larger of the two; unchanged without ``rounding``.
    ``forms`` = ``(mu2, k2, t)`` (``theta^T M theta``, ``theta^T K theta``, ``theta^T Gv``) and ``h``: the
    master's eigenvalue error through ``lambda dT/dlambda`` (:func:`qm_slope`; ``s = theta^T M Z M theta`` for
    MD, None for SMD) joins the bound as ``extra["roundoff_dT_lambda"]``; without ``forms`` it is left out."""
    if rounding is None or theta is None or not np.isfinite(res.T):
        return res
    slope = None
    if forms is not None:
        w2 = omega_p ** 2
        slope = qm_slope(omega_p, float(phi @ Gv), h, (float(res.C[1]) / w2, *forms), s)
    rel, parts = qm_roundoff(phi, rounding.q, omega_p, res.T, Gv, rounding.Hv, theta, K, rounding.digits,
                             slope=slope, excess=rounding.excess)
    res.extra.update({f"roundoff_{k}": v for k, v in parts.items()})
    res.extra["T_change"], res.extra["roundoff"] = res.T_error, rel
    res.T_error = rel if res.T_error is None else max(res.T_error, rel)
    return res
