"""Stage ``step``: the STEP force (or tangent-stiffness) evaluations the scene's evaluators need."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..adapter import SolverAdapter
from ..diagnostics import inverse_mass_norm2
from ..errors import SceneError
from ..evaluators import retained_set
from ..scene import Scene
from ..step import ForceEvaluator, StepPolicy, full_step, step_amplitude, targeted_steps, targeted_steps_tangent
from .state import FULL_METHODS, MODAL_METHODS, RunState


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


def step_stage(state: RunState) -> None:
    """Run STEP for the master modes (targeted) and, with ``tensors = "full"``, over the retained modes.

    Reads ``scene``, ``adapter``, ``K``, ``M``, ``policy``, ``dirs``, ``basis``, ``masters``,
    ``counters``, ``checkpoint`` (forces of an interrupted run are reused from it). Writes ``steps``
    (master -> :class:`~stepnf.step.MasterStep`), ``full`` (:class:`~stepnf.step.FullStep` or None),
    ``arrays`` (``g``, ``h``, ``full_modes``) and ``flags`` (no characteristic length, full STEP).
    Amplitudes are relative to the scene's thickness or the adapter's characteristic length.
    """
    scene, adapter = state.scene, state.adapter
    mask = np.asarray(state.dirs) < 3 if state.dirs is not None else None
    length = scene.thickness if scene.thickness is not None else adapter.characteristic_length()
    if length is None and state.policy.amplitude is None:
        state.flags.append({"kind": "no_length", "message": "the model gives no characteristic length (no dof "
                            "coordinates): STEP amplitudes are relative_amplitude x 1 model length unit; set "
                            "[analysis] thickness or [analysis.step] amplitude"})
    forces = ForceEvaluator(adapter.internal_forces, state.n, state.counters,
                            batch_size=1024 if adapter.prefers_batches else 64, checkpoint=state.checkpoint)
    evaluators = state.evaluators
    if bool(evaluators & FULL_METHODS) or (bool(evaluators & MODAL_METHODS) and scene.tensors != "full"):
        targeted_stage(state, forces, length, mask)
    if scene.tensors == "full":
        full_plan_stage(state, forces, length, mask)


def targeted_stage(state: RunState, forces: ForceEvaluator, length: float | None, mask: np.ndarray | None) -> None:
    """Two force evaluations per master (four with the amplitude check), or tangents; writes ``steps``."""
    policy, masters, Phi = state.policy, state.masters, state.phi
    qs = np.array([step_amplitude(Phi[:, p], policy, length, mask) for p in masters])
    per = 4 if policy.check else 2
    if policy.method == "tangent":
        with state.progress.stage("step", f"STEP (targeted, tangent): {len(masters) * per} tangent stiffnesses"):
            for st in targeted_steps_tangent(state.adapter.tangent_stiffness, state.K, Phi[:, masters], qs, policy,
                                             masters, state.counters):
                state.steps[st.p] = st
    else:
        with state.progress.stage("step", f"STEP (targeted): {len(masters) * per} force evaluations"):
            for st in targeted_steps(forces, state.K, Phi[:, masters], qs, policy, masters):
                state.steps[st.p] = st


def full_plan_stage(state: RunState, forces: ForceEvaluator, length: float | None, mask: np.ndarray | None) -> None:
    """The full STEP over the retained modes up to the highest master; writes ``full``, ``arrays``, ``flags``."""
    Phi, masters, progress = state.phi, state.masters, state.progress
    Sfull = retained_set(max(masters), state.n_ret, state.m)
    qf = np.array([step_amplitude(Phi[:, s], state.policy, length, mask) for s in Sfull])
    with progress.stage("step_full", f"STEP (full plan) over {len(Sfull)} modes"):
        # the M^-1 norm of each master's G(phi_p, phi_p), for the modal-truncation flag
        state.full = full_step(forces, state.K, Phi[:, Sfull], qf, state.policy, modes=Sfull,
                               progress=lambda d, t: progress.bar(d, t, "STEP"),
                               norm2=lambda v: inverse_mass_norm2(state.M, v),
                               norm_columns=[list(Sfull).index(p) for p in masters if p in list(Sfull)])
    state.arrays["g"], state.arrays["h"], state.arrays["full_modes"] = state.full.g, state.full.h, Sfull
    state.flags += state.full.flags
