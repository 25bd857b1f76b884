"""DNF's T from the condensed cubic term ``h_s`` (STEP along the quadratic manifold), without its cancellation.

``A + h = h_s - w^2 B`` (``h_s = h - 2 y^T G(phi, phi)``, ``B = 4 y^T M z``: :func:`stepnf.nf.evaluators.dnf`),
so ``T = (3 (A + h) + w^2 B) / (8 w^2) = 3 h_s / (8 w^2) - B / 4``: with ``h_s`` measured directly
(:mod:`stepnf.step.manifold_probe`) no term of T cancels another beyond what the structure's physics does
(a cantilever's first mode: the stiffening of its curvature against the inertia of its axial motion).
"""
from __future__ import annotations

import numpy as np

from stepnf.nf.coefficient import MethodResult
from stepnf.nf.roundoff import dnf_slope


def dnf_condensed(omega_p: float, h_s: float, dh_s: float, first: MethodResult, dB: float = 0.0) -> MethodResult:
    """DNF's result from ``h_s`` (model units, mass-normalised phi) and the error estimate ``dh_s`` of it.

    ``first``: DNF of the same master from the STEP at ``+-q phi`` (its ``B``, its fields and flags are
    kept); ``dB``: an error estimate of that ``B`` (absolute; the larger of it and ``first``'s rounding
    bound of ``B`` is used). ``T_error`` and ``extra["roundoff"]``: ``(3 dh_s / (8 w^2) + dB / 4 + dT_lambda)
    / |T|``, ``dT_lambda = c eps_lam |lambda dT/dlambda|`` the master's own eigenvalue error
    (:func:`stepnf.nf.roundoff.eigenvalue_part`; ``c eps_lam`` as ``first``'s part over its slope, and
    ``dB/dlambda`` from ``first``: :func:`stepnf.nf.evaluators.dnf`; :func:`stepnf.nf.roundoff.dnf_slope`),
    also in ``extra["roundoff_dT_lambda"]``; ``extra`` also keeps ``h_s``, ``dh_s`` and the first ``T``.
    """
    w2 = omega_p ** 2
    B = float(first.extra["B"])
    T = 3.0 * h_s / (8.0 * w2) - B / 4.0
    dB = max(float(dB), float(first.extra.get("roundoff_dB", 0.0)))
    eps_lam = float(first.extra.get("roundoff_eps_lambda", 0.0))
    slope = dnf_slope(w2, h_s, float(first.extra.get("dB_dlambda", 0.0)))
    s1 = abs(float(first.extra.get("roundoff_lambda_slope", 0.0)))  # first's part over its slope: c eps_lam
    dT_lam = float(first.extra.get("roundoff_dT_lambda", 0.0)) / s1 * abs(slope) if s1 > 0 else 0.0
    dT = 3.0 * dh_s / (8.0 * w2) + dB / 4.0 + dT_lam
    rel = dT / abs(T) if T != 0 else (0.0 if dT == 0 else np.inf)
    res = MethodResult(first.method, float(T), (0.0, 0.0, 0.0, h_s - w2 * B, w2 * B, 0.0), list(first.flags),
                       order=first.order)
    res.fields = first.fields
    res.extra = {k: v for k, v in first.extra.items() if not k.startswith("roundoff") and k != "T_change"}
    # what still cancels: the two terms of T (a cantilever's first mode: 15-fold), no longer A against h
    res.extra["cancellation"] = (3.0 * abs(h_s) / (8.0 * w2) + abs(B) / 4.0) / abs(T) if T != 0 else np.inf
    res.extra.update(h_s=float(h_s), dh_s=float(dh_s), dB=dB, T_first=float(first.T), roundoff=float(rel),
                     roundoff_dT=float(dT), roundoff_dT_lambda=dT_lam, roundoff_eps_lambda=eps_lam,
                     roundoff_lambda_slope=float(slope),
                     T_change=None)  # no second STEP amplitude: no change measured
    res.T_error = float(rel)
    return res
