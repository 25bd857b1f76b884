"""First-order changes of a quadratic manifold's T (full-order SMD and MD), without a linear solve.

STEP gives ``Gv = G(phi_p, phi_p)`` and ``h`` at two amplitudes; each method's ``T_error`` is the
relative change of T between them. DNF gets it from its own solutions (:func:`stepnf.nf.evaluators.dnf`);
the quadratic manifolds of :func:`stepnf.nf.evaluators.smd_full` and :func:`stepnf.nf.evaluators.md_full`
get it here, from theta, the computed modes and the gradient of the paper's Eq. (7), where a second
solve at the check amplitude used to cost as much as the method itself (issue 14).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from stepnf.nf.coefficient import MethodResult
from stepnf.errors import NumericalError


@dataclass(frozen=True)
class Spectrum:
    """Computed modes for the linearised ``T_error`` of :func:`stepnf.nf.evaluators.smd_full`, :func:`stepnf.nf.evaluators.md_full` (no solve).

    ``modes`` (n, k): M-orthonormal mode shapes, rigid and the lowest elastic
    ones, in any order; ``eigenvalues`` (k,) their ``w^2`` (rad/s)^2 (rigid:
    0); ``mass_modes`` = ``M @ modes`` (e.g. ``DeflatedSolver.MPsi``).
    """

    modes: np.ndarray
    eigenvalues: np.ndarray
    mass_modes: np.ndarray


def qm_T_error(res: MethodResult, forms: tuple[float, float, float], phi: np.ndarray, omega_p: float,
                theta: np.ndarray, sigma: float, D: np.ndarray, dGv: np.ndarray, dh: float,
                spectrum: Spectrum | None) -> float:
    """``|dT| / |T|``, dT the first-order change of a quadratic manifold's T for ``(dGv, dh)``, without a solve.

    ``theta = -2 Z Gv`` with ``Z = (K - sigma M)^-1`` on the M-orthogonal
    complement of ``D`` (SMD: sigma = 0, D = the rigid modes; MD: sigma =
    w_p^2, D = p and its twins), symmetric, ``(K - sigma M) Z = I - M D D^T``.
    So ``d theta = -2 Z dGv`` and, as ``Z^T = Z`` (theta is its own adjoint)::

        dg_p = phi . dGv     dt = 2 theta . dGv     dmu1 = -2 (Z M phi) . dGv
        dmu2 = -4 (Z M theta) . dGv     dk2 = -4 theta . dGv + sigma dmu2

    into dC (:func:`~stepnf.nf.coefficient.qm_coefficients`) and the gradient of
    Eq. (7). ``Z M phi = phi / (w_p^2 - sigma)`` (an eigenvector; 0 for MD,
    phi in D), ``Z M theta`` from :func:`resolvent_mass`. T is quadratic in
    (Gv, h): T(Gv - dGv) - T + dT is exactly the second-order term.
    """
    w2 = omega_p ** 2
    dmu1 = 0.0 if sigma == w2 else -2.0 * float(phi @ dGv) / (w2 - sigma)
    dmu2 = -4.0 * float(resolvent_mass(theta, forms[0], forms[1], sigma, D, spectrum) @ dGv)
    td = float(theta @ dGv)
    dC = (1.5 * w2 * dmu1 + float(phi @ dGv), w2 * dmu1, 2 * w2 * dmu1,
          2.0 * td + 0.5 * sigma * dmu2 + dh, w2 * dmu2, w2 * dmu2)
    dT, T = backbone_dT(res.C, dC, omega_p), res.T
    return abs(dT) / abs(T) if T != 0 else (0.0 if dT == 0 else float(np.inf))


def backbone_dT(C: Sequence[float], dC: Sequence[float], omega: float) -> float:
    """First-order change of :func:`~stepnf.nf.coefficient.backbone_T` (Eq. 7) for a change dC of C1..C6."""
    C1, C2, C3 = (float(c) for c in C[:3])
    d1, d2, d3, d4, d5, d6 = (float(c) for c in dC)
    w2 = omega * omega
    dquad = (20 * C1 + 10 * C2 - 11 * C3) * d1 + (10 * C1 + 8 * C2 - 7 * C3) * d2 + (2 * C3 - 7 * C2 - 11 * C1) * d3
    return -dquad / (24.0 * w2 * w2) + (3 * d4 + d5 - 3 * d6) / (8.0 * w2)


def resolvent_mass(theta: np.ndarray, mu2: float, k2: float, sigma: float, D: np.ndarray,
                    spectrum: Spectrum | None) -> np.ndarray:
    """``Z M theta`` (``Z``: :func:`qm_T_error`) from the computed modes, without a solve or a sparse product.

    Exact on the computed modes (``c_s / (lam_s - sigma)``, ``c = modes^T M
    theta``; modes in span D left out). The rest ``r`` (M-orthogonal to every
    computed mode, hence on modes above them and above sigma: ``spectrum``
    must hold the lowest modes, up to sigma at least) is divided by its
    Rayleigh quotient ``lam_r - sigma``, ``r^T M r = mu2 - |c|^2``, ``r^T K r =
    k2 - sum lam c^2``: exact when the change of the force is parallel to Gv
    there (the weights 1/(lam_s - sigma) average to it), and small beside the
    computed part otherwise (the mu2 term weighs a mode ``(w_p^2 / lam_s)^2``
    less than the t term). Below 1e-10 of mu2 (cancellation) r is left out.
    """
    if sigma > 0 and (spectrum is None or not np.any(np.asarray(spectrum.eigenvalues) >= sigma)):
        raise NumericalError(f"linearised T_error: `spectrum` must hold every mode up to sigma = {sigma:.6g}")
    out, r, rMr, rKr = np.zeros_like(theta), theta, mu2, k2
    if spectrum is not None and spectrum.modes.shape[1]:
        Psi, lam = spectrum.modes, np.asarray(spectrum.eigenvalues, dtype=float)
        c = spectrum.mass_modes.T @ theta
        inD = np.sum((spectrum.mass_modes.T @ D) ** 2, axis=1) > 0.5 if D.shape[1] else np.zeros(len(c), bool)
        out = Psi @ np.where(inD, 0.0, c / np.where(inD, 1.0, lam - sigma))
        r, rMr, rKr = theta - Psi @ c, mu2 - float(c @ c), k2 - float(lam @ c**2)
    if rMr <= 1e-10 * mu2:
        return out
    lam_r = rKr / rMr
    if lam_r <= sigma:
        raise NumericalError(f"linearised T_error: the modes below sigma = {sigma:.6g} must be in `spectrum` "
                         f"(the rest of theta has Rayleigh quotient {lam_r:.6g})")
    return out + r / (lam_r - sigma)
