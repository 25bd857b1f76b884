"""Stage ``step``: the STEP force (or tangent-stiffness) evaluations the scene's evaluators need."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from stepnf.flags import new_flag
from stepnf.plugin.adapter import SolverAdapter
from stepnf.plugin.dofs import rotation_mask, translation_mask
from stepnf.nf.diagnostics import inverse_mass_norm2
from stepnf.errors import SceneError
from stepnf.nf.evaluators import retained_set
from stepnf.scene.parse import Scene
from stepnf.step.procedure import ForceEvaluator, FullStep, MasterStep, StepPolicy, full_step, step_amplitude, targeted_steps, targeted_steps_tangent
from stepnf.pipeline.outputs import RunContext, RunModel, RunModes, StepTerms
from stepnf.methods import FULL_EVALUATORS, MODAL_EVALUATORS
from stepnf.pipeline.state import StageView


def step_policy(scene: Scene, adapter: SolverAdapter) -> StepPolicy:
    """The scene's ``[analysis.step]`` completed by the adapter's default relative amplitude.

    ``method = "tangent"`` on a solver without tangent stiffness is a :class:`SceneError` (exit 2).
    """
    policy = scene.step
    if policy.relative_amplitude is None and adapter.step_relative_amplitude is not None:
        policy = replace(policy, relative_amplitude=float(adapter.step_relative_amplitude))
    if policy.method == "tangent" and not adapter.provides_tangent_stiffness:
        raise SceneError(scene.file, "analysis.step.method",
                         f"'tangent' needs a solver that provides tangent stiffness; {scene.solver!r} does not. "
                         "Allowed here: ['forces']")
    return policy


def step_stage(ctx: RunContext, model: RunModel, modes: RunModes) -> StepTerms:
    """Run STEP for the master modes (targeted) and, with ``tensors = "full"``, over the retained modes.

    Returns :class:`StepTerms`: master -> :class:`~stepnf.step.procedure.MasterStep`, the
    :class:`~stepnf.step.procedure.FullStep` (or None) and its modes, and the run flags (no characteristic
    length, full STEP). Forces of an interrupted run are reused from the checkpoint (``model.forces``).
    Amplitudes are relative to the scene's thickness or the adapter's characteristic length (``model.length``),
    measured on the translations; the rotations of a shell's fields are bounded on their own
    (:data:`~stepnf.plugin.dofs.MAX_ROTATION`).
    """
    scene, state = ctx.scene, StageView(ctx, model, modes)
    mask = translation_mask(model.dirs)
    flags: list[dict] = []
    if model.length is None and model.policy.amplitude is None:
        flags.append(new_flag("no_length", message="the model gives no characteristic length (no dof "
                              "coordinates): STEP amplitudes are relative_amplitude x 1 model length unit; set "
                              "[analysis] thickness or [analysis.step] amplitude"))
    evaluators = ctx.evaluators
    steps: dict[int, MasterStep] = {}
    full = Sfull = None
    if bool(evaluators & FULL_EVALUATORS) or (bool(evaluators & MODAL_EVALUATORS) and scene.tensors != "full"):
        steps = targeted_stage(state, model.forces, model.length, mask)
    if scene.tensors == "full":
        full, Sfull = full_plan_stage(state, model.forces, model.length, mask)
        flags += full.flags
    return StepTerms(steps, full, Sfull, tuple(flags))


def targeted_stage(state: StageView, forces: ForceEvaluator, length: float | None,
                   mask: np.ndarray | None) -> dict[int, MasterStep]:
    """Two force evaluations per master (four with the amplitude check), or tangents: master -> its STEP."""
    policy, masters, Phi = state.policy, state.masters, state.phi
    rot = rotation_mask(state.dirs)
    qs = np.array([step_amplitude(Phi[:, p], policy, length, mask, rot) for p in masters])
    per = 4 if policy.check else 2
    steps: dict[int, MasterStep] = {}
    if policy.method == "tangent":
        with state.progress.stage("step", f"STEP (targeted, tangent): {len(masters) * per} tangent stiffnesses"):
            for st in targeted_steps_tangent(state.adapter.tangent_stiffness, state.K, Phi[:, masters], qs, policy,
                                             masters, state.counters):
                steps[st.p] = st
    else:
        with state.progress.stage("step", f"STEP (targeted): {len(masters) * per} force evaluations"):
            for st in targeted_steps(forces, state.K, Phi[:, masters], qs, policy, masters,
                                     digits=getattr(state.adapter, "force_digits", None)):
                steps[st.p] = st
    return steps


def full_plan_stage(state: StageView, forces: ForceEvaluator, length: float | None,
                    mask: np.ndarray | None) -> tuple[FullStep, np.ndarray]:
    """The full STEP over the retained modes up to the highest master, and those modes."""
    Phi, masters, progress = state.phi, state.masters, state.progress
    Sfull = retained_set(max(masters), state.n_ret, state.m)
    rot = rotation_mask(state.dirs)
    qf = np.array([step_amplitude(Phi[:, s], state.policy, length, mask, rot) for s in Sfull])
    with progress.stage("step_full", f"STEP (full plan) over {len(Sfull)} modes"):
        # the M^-1 norm of each master's G(phi_p, phi_p), for the modal-truncation flag
        full = full_step(forces, state.K, Phi[:, Sfull], qf, state.policy, modes=Sfull,
                         progress=lambda d, t: progress.bar(d, t, "STEP"),
                         norm2=lambda v: inverse_mass_norm2(state.M, v),
                         norm_columns=[list(Sfull).index(p) for p in masters if p in list(Sfull)])
    return full, Sfull
