"""The run of a model given in modal coordinates (:class:`ModalModel`): modes, evaluators, backbone, results.

Such a model has no mesh, no STEP and no linear algebra: its modal coefficients are exact, and
"full order" means every mode of the model.

``[analysis.backbone]``: the DPIM (:class:`stepnf.dpim.parametrisation.DPIM`) of each master in modal
coordinates, ``M = I``, ``K = diag(omega^2)``, ``f(X) = K X + g(X, X) + h(X, X, X)`` from the model's own modal
forces (:mod:`stepnf.pipeline.modal_forces`: for the von Karman shell, over the modes the master drives
by symmetry), so the backbone is that of the model's own truncation, an independent route to the
full-order one of a solver adapter. Same JSON block (:func:`stepnf.dpim.backbone_report.backbone_report`)
and HDF5 arrays (``backbone_<p>_*``, fields over the modes listed in ``backbone_<p>_modes``) as the
adapter path. ``A`` is the amplitude of the master's modal coordinate ``X_p`` (the model's own
normalisation); ``W_max / h`` from the model's transverse field where it gives one. Masters in
``[analysis.backbone] manifolds`` get the backbone of their manifold of several modes instead
(:mod:`stepnf.pipeline.modal_manifolds`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from stepnf.nf.coefficient import MethodResult
from stepnf.dpim.backbone_report import WMax, backbone_report
from stepnf.dpim.parametrisation import DPIM, DPIMResult, DPIMTolerances, ModeSpectrum
from stepnf.errors import SceneError
from stepnf.flags import new_flag
from stepnf.runtime.counters import Counters
from stepnf.nf.diagnostics import slow_fast_ratio
from stepnf.nf.evaluators import retained_set
from stepnf.plugin.modal_model import ModalModel
from stepnf.pipeline.plan import resolve_masters
from stepnf.runtime.progress import Progress
from stepnf.io.results import ModeResult, RunResult
from stepnf.scene.parse import Scene
from stepnf.pipeline.apply_method import modal_method
from stepnf.pipeline.modal_forces import ModalSystem, modal_system
from stepnf.pipeline.modal_manifolds import Subspaces, modal_manifold_backbone, modal_plans
from stepnf.pipeline.outputs import BackboneOutput, Backbones, Evaluations, RunContext
from stepnf.pipeline.results import scene_summary, with_backbones, write_results
from stepnf.methods import FULL, MODAL, method


@dataclass(frozen=True)
class ModalSpectrum:
    """Stage ``modes`` of a modal model: its angular frequencies (rad/s, its own units), labels, the master
    modes (the scene's order) and its description (asked at the end of its run, while it is open)."""

    omega: np.ndarray
    labels: list
    masters: list[int]
    description: dict


def modal_model_outputs(ctx: RunContext, model: ModalModel) -> tuple[ModalSpectrum, Evaluations, Backbones]:
    """Stages ``modes`` (frequencies, labels, masters), ``evaluators`` and ``backbone`` of a modal model, as
    the same :class:`Evaluations` and :class:`Backbones` as a solver adapter's run."""
    scene, progress, methods = ctx.scene, ctx.progress, ctx.methods
    if scene.forcing is not None:  # (issue 34: forced responses from a solver adapter's M, K and forces)
        raise SceneError(scene.file, "analysis.forcing", f"forced responses are not computed for the {scene.solver!r} "
                         "model (modal coordinates) yet: remove [analysis.forcing] and [analysis.damping], or use a "
                         "solver adapter")
    omega = np.asarray(model.omegas(), dtype=float)
    labels = list(model.labels())
    masters = resolve_masters(scene, labels, len(omega), complete=True)
    assert masters is not None
    subspaces = Subspaces(model)
    plans = modal_plans(scene, model, omega, labels, masters, subspaces)  # manifolds: checked before any solve
    scales = model.shell_scales()
    maxima = model.mode_maxima()
    with progress.stage("evaluators", "normal form and modal derivatives"):
        modes = [modal_mode(scene, model, p, omega, labels, methods, scales, maxima) for p in masters]
    backbones: dict[int, BackboneOutput] = {}
    if scene.backbone is not None:
        member = {q: plan for plan in plans for q in plan.modes}
        made: dict[tuple[int, ...], tuple] = {}
        with progress.stage("backbone", f"DPIM backbone to order {scene.backbone.order} in modal coordinates"):
            for rec in modes:
                if rec.index in member:  # on its manifold of several modes (stepnf.pipeline.modal_manifolds)
                    plan = member[rec.index]
                    backbones[rec.index] = modal_manifold_backbone(scene, model, plan, subspaces.holder(plan.modes),
                                                                   made, rec.index, labels, progress)
                else:
                    backbones[rec.index] = modal_backbone(scene, model, rec, labels)
    return (ModalSpectrum(omega, labels, masters, model.describe()), Evaluations(modes, scales),
            Backbones(backbones))


def modal_result(ctx: RunContext, spectrum: ModalSpectrum, evals: Evaluations, backbones: Backbones) -> RunResult:
    """The :class:`RunResult` of a modal model's outputs (no counts: no force evaluation, no solve)."""
    arrays: dict[str, np.ndarray] = {}
    for bb in backbones.by_master.values():
        arrays.update(bb.arrays)
    scales = evals.scales
    return RunResult(scene=scene_summary(ctx.scene, ctx.methods), modes=with_backbones(evals.modes, backbones),
                     counts=Counters().to_dict(), timings={},
                     spectrum={"omega": spectrum.omega.tolist(), "labels": spectrum.labels, "n_rigid": 0,
                               "degenerate_groups": []},
                     model=spectrum.description, kappa=scales.kappa if scales else None, arrays=arrays,
                     backbones=backbones.results)


def modal_results(ctx: RunContext, spectrum: ModalSpectrum, evals: Evaluations, backbones: Backbones) -> RunResult:
    """Stage ``results`` of a modal model: its result, timed and written as a solver adapter's
    (:func:`stepnf.pipeline.results.write_results`)."""
    return write_results(ctx, modal_result(ctx, spectrum, evals, backbones))


def run_modal_model(scene: Scene, model: ModalModel, progress: Progress) -> RunResult:
    """The result of a modal model's stages (:func:`modal_model_outputs`), neither timed nor written."""
    ctx = RunContext.start(scene, progress, order=MODAL)
    return modal_result(ctx, *modal_model_outputs(ctx, model))


def modal_dpim(system: ModalSystem, order: int, labels: list, *, probe: float = 1.0,
               tolerances: DPIMTolerances = DPIMTolerances()) -> DPIMResult:
    """The DPIM of ``system``'s master to odd ``order`` (M = I, K = diag(omega^2); module docstring).

    ``probe``: polarisation size in modal coordinates (exact for the cubic modal force: only round-off
    depends on it); ``tolerances``: of the resonance and twin checks. Internal-resonance flags name the
    model's modes (global index and label).
    """
    m = len(system.omega)
    K = sp.diags(system.omega ** 2).tocsr()
    phi = np.zeros(m)
    phi[system.local] = 1.0
    model = DPIM(system.forces, K, sp.identity(m, format="csr"), ModeSpectrum(omega=system.omega), tolerances=tolerances)
    res = model.parametrise(phi, float(system.omega[system.local]), order, probe=probe, master=system.local)
    for f in res.flags:
        if f.get("mode") is not None:
            s = int(system.index[int(f["mode"])])
            f["message"] = f["message"].replace(f"mode {f['mode']} ", f"mode {s} {labels[s]} ", 1).replace(
                f"master mode {system.local}", f"master mode {int(system.index[system.local])}")
            f["mode"] = s
    return res


def modal_backbone(scene: Scene, model: ModalModel, rec: ModeResult, labels: list) -> BackboneOutput:
    """Master ``rec.index``'s DPIM, its ``backbone`` block and its HDF5 arrays (``backbone_<p>_*``).

    A model without modal forces (:func:`stepnf.pipeline.modal_forces.modal_system`) is a SceneError on
    ``analysis.backbone`` (exit 2); ``w_over_h`` without its transverse field too.
    """
    spec, p = scene.backbone, rec.index
    system = modal_system(model, p)
    if system is None:
        raise SceneError(scene.file, "analysis.backbone", f"the {scene.solver!r} model gives only g^s_pp and "
                         "h^p_ppp, not its whole modal force: no DPIM backbone")
    wmax = WMax(1.0, linear=system.transverse) if system.transverse is not None else None
    if spec.w_over_h is not None and wmax is None:
        raise SceneError(scene.file, "analysis.backbone.w_over_h", f"the {scene.solver!r} model gives no "
                         "transverse displacement field; give amplitudes instead")
    res = modal_dpim(system, spec.order, labels, tolerances=DPIMTolerances(resonance=scene.tolerances.resonance,
                                                                           twin=scene.degeneracy_tolerance))
    block = backbone_report(res, spec, wmax, probe=1.0, fallback=1.0)
    block["modes"] = [int(s) for s in system.index]
    if int(system.index[system.local]) != p:
        block["flags"].append(new_flag("backbone_twin", mode=int(system.index[system.local]),
                                       message=f"the backbone of master {p} is that of its cos twin "
                                               f"{int(system.index[system.local])} (the same by rotation)"))
    arrays: dict[str, np.ndarray] = {}
    for key, val in res.arrays().items():
        if key in ("index", "Y", "c"):
            arrays[f"backbone_{p}_{key}"] = val
    arrays[f"backbone_{p}_omega_p"] = np.asarray(res.omega)
    arrays[f"backbone_{p}_modes"] = np.asarray(system.index, dtype=int)
    for key in ("amplitude", "omega", "w_max_over_h"):
        if block[key] is not None:
            arrays[f"backbone_{p}_{key}"] = np.asarray([np.nan if v is None else float(v) for v in block[key]])
    return BackboneOutput(res, block, (), arrays)


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
    """Evaluator ``ev`` of master ``p``: a full-order one as its modal variant (:attr:`stepnf.methods.Method.modal`)
    over every mode (order "all modes")."""
    m = len(omega)
    if method(ev).order == FULL:
        r = modal_method(method(ev).modal, p, omega, g, h, np.arange(m), scene.tolerances, labels)
        r.order = "all modes"
        return r
    return modal_method(ev, p, omega, g, h, retained_set(p, scene.retained_modes, m), scene.tolerances, labels)
