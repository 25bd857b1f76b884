"""The ROM's forced responses side by side with the full model's (issue 34, item 4): one row per peak and fold.

For each forcing level's curve (:class:`stepnf.forced.frc.FRC`, or its JSON dict), the full model's reference:

* **small models** (``method = "continuation"``): the full FRC by shooting and pseudo-arclength continuation
  over the curve's frequency range (:func:`stepnf.verify.forced_continuation.full_frc`), independent of the
  ROM; its refined peak and folds against the ROM's (the folds paired in the order of ``Omega``);
* **FE models** (``method = "integration"``): the steady state by time integration
  (:class:`stepnf.verify.forced_steady.ForcedIntegration`) at the ROM's peak frequency, started from the ROM's
  state there (``theta = -pi/2``: in quadrature with the force); the row's ``full`` ``Omega`` is the ROM's,
  its ``spread`` the relative change of Aitken's last estimates (large: not settled, e.g. near a fold pair,
  where the transient slows down).
  Folds are not checked (the branch between them is unstable: time integration cannot follow it).

A row: ``{"what": "peak" | "fold", "rom": {"Omega", "amplitude"}, "full": {"Omega", "amplitude"} | None,
"dA": A_rom / A_full - 1, "dOmega": Omega_rom / Omega_full - 1, "method"}`` (``full`` None and a ``reason``
when the full model has no such point: a fold the ROM finds and the full model does not, or the reverse).
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from stepnf.verify.forced_continuation import full_frc
from stepnf.verify.forced_steady import ForcedIntegration


def _point(p: dict) -> dict:
    return {"Omega": float(p["Omega"]), "amplitude": float(p["amplitude"])}


def _row(what: str, rom: dict, full: dict | None, method: str, reason: str = "") -> dict:
    out = {"what": what, "rom": _point(rom), "full": None if full is None else _point(full), "method": method}
    if full is None:
        out["reason"] = reason
    else:
        out["dA"] = rom["amplitude"] / full["amplitude"] - 1
        out["dOmega"] = rom["Omega"] / full["Omega"] - 1
    return out


def forced_rows(res: Any, curve: Any, F: np.ndarray, M, C, K, forces: Callable[[np.ndarray], np.ndarray], *,
                method: str, frequency_range: tuple[float, float] | None = None, tangent: Callable | None = None,
                periods: int = 30, steps: int = 128) -> list[dict]:
    """The rows of one level's curve ``curve`` (an FRC or its JSON: ``peak``, ``folds``) of the master of the
    DPIM result ``res``, force amplitude ``F`` (n,); ``M``, ``C``, ``K`` the model's matrices, ``forces(U)`` its
    batched internal forces; ``method`` ``"continuation"`` (``frequency_range``, ratios to ``res.omega``, the
    range the continuation crosses: the curve's) or ``"integration"`` (``periods`` of ``steps`` steps)."""
    doc = curve.to_json() if hasattr(curve, "to_json") else curve
    peak, folds = doc["peak"], sorted(doc.get("folds", []), key=lambda p: p["Omega"])
    Mphi = np.asarray(M @ res.phi).ravel()
    if method == "integration":
        rho = float(peak["rho"])
        x0, v0 = res.displacement(-np.pi / 2, rho), res.velocity(-np.pi / 2, rho)
        run = ForcedIntegration(M, C, K, forces, F).run(x0, v0, float(peak["Omega"]), Mphi, periods=periods,
                                                          steps=steps)
        rows = [_row("peak", peak, {"Omega": peak["Omega"], "amplitude": run.amplitude}, method)]
        rows[0]["spread"] = run.spread / run.amplitude  # how settled: Aitken's last estimates, relative
        return rows + [_row("fold", f, None, method, "not followed by time integration") for f in folds]
    if method != "continuation":
        raise ValueError(f"method must be 'continuation' or 'integration', got {method!r}")
    if frequency_range is None:
        raise ValueError("the continuation needs the frequency range (ratios to omega)")
    f1 = lambda x: np.asarray(forces(np.asarray(x)[None]), dtype=float)[0]  # noqa: E731
    full = full_frc(M, C, f1, F, res.phi, res.omega, frequency_range, tangent=tangent, K=_dense(K))
    rows = [_row("peak", peak, full.peak, method)]
    ref = sorted(full.folds, key=lambda p: p["Omega"])
    for k in range(max(len(folds), len(ref))):
        if k < len(folds) and k < len(ref):
            rows.append(_row("fold", folds[k], ref[k], method))
        elif k < len(folds):
            rows.append(_row("fold", folds[k], None, method, "the full model has no fold here"))
        else:
            rows.append({"what": "fold", "rom": None, "full": _point(ref[k]), "method": method,
                         "reason": "the ROM has no fold here"})
    return rows


def _dense(A) -> np.ndarray:
    return A.toarray() if hasattr(A, "toarray") else np.asarray(A, dtype=float)
