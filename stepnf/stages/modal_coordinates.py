"""The run of a model given in modal coordinates (:class:`ModalModel`): modes, evaluators, results.

Such a model has no mesh, no STEP and no linear algebra: its modal coefficients are exact, and
"full order" means every mode of the model.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..backbone import MethodResult
from ..counters import Counters
from ..diagnostics import slow_fast_ratio
from ..evaluators import retained_set
from ..modal_model import ModalModel
from ..plan import resolve_masters, resolve_methods
from ..progress import Progress
from ..results import ModeResult, RunResult
from ..scene import Scene
from .methods import modal_method
from .results import scene_summary
from .state import FULL_METHODS

#: The modal evaluator a full-order method becomes on a modal model.
AS_MODAL = {"dnf": "nf", "md_full": "md_modal", "smd_full": "smd_modal"}


def run_modal_model(scene: Scene, model: ModalModel, progress: Progress) -> RunResult:
    """Stages ``modes`` (frequencies, labels, masters), ``evaluators`` and ``results`` of a modal model."""
    omega = np.asarray(model.omegas(), dtype=float)
    labels = list(model.labels())
    masters = resolve_masters(scene, labels, len(omega), complete=True)
    assert masters is not None
    methods = resolve_methods(scene.methods, scene.qm_order or "modal")
    scales = model.shell_scales()
    maxima = model.mode_maxima()
    with progress.stage("evaluators", "normal form and modal derivatives"):
        modes = [modal_mode(scene, model, p, omega, labels, methods, scales, maxima) for p in masters]
    return RunResult(scene=scene_summary(scene, methods), modes=modes, counts=Counters().to_dict(),
                     timings={}, spectrum={"omega": omega.tolist(), "labels": labels, "n_rigid": 0,
                                           "degenerate_groups": []},
                     model=model.describe(), kappa=scales.kappa if scales else None)


def modal_mode(scene: Scene, model: ModalModel, p: int, omega: np.ndarray, labels: list, methods: dict[str, str],
               scales: Any, maxima: np.ndarray | None) -> ModeResult:
    """Master ``p``'s record: rho over the model's modes (twins excluded) and every method, with Gamma.

    ``scales``: the model's shell scales (omega_bar, Gamma) or None; ``maxima``: max |phi_w| per mode.
    """
    m, tol = len(omega), scene.tolerances
    g = np.asarray(model.quadratic_coefficients(p), dtype=float)
    h = float(model.cubic_coefficient(p))
    groups = [s for s in range(m) if s != p and abs(omega[s] - omega[p]) <= scene.degeneracy_tolerance * omega[p]]
    rho, rho_mode = slow_fast_ratio(p, omega, g, tol, groups)
    rec = ModeResult(index=p, label=labels[p], omega=float(omega[p]), rho=rho, rho_mode=rho_mode,
                     omega_bar=scales.omega_bar(omega[p]) if scales else None,
                     w_max=float(maxima[p]) if maxima is not None else None)
    for name, ev in methods.items():
        r = modal_model_method(scene, p, omega, g, h, labels, ev)
        r.method = name
        if scales is not None:
            r.gamma = scales.gamma(r.T, rec.w_max)
        rec.methods[name] = r
    return rec


def modal_model_method(scene: Scene, p: int, omega: np.ndarray, g: np.ndarray, h: float, labels: list,
                       ev: str) -> MethodResult:
    """Evaluator ``ev`` of master ``p``: a full-order one over every mode (order "all modes")."""
    m = len(omega)
    if ev in FULL_METHODS or ev.endswith("_full"):
        r = modal_method(AS_MODAL[ev], p, omega, g, h, np.arange(m), scene.tolerances, labels)
        r.order = "all modes"
        return r
    return modal_method(ev, p, omega, g, h, retained_set(p, scene.retained_modes, m), scene.tolerances, labels)
