"""Stage ``results``: the run's spectrum, counts, arrays and flags gathered into a :class:`RunResult`."""
from __future__ import annotations

from dataclasses import asdict
from typing import Any

import numpy as np

from ..gamma import NO_AMPLITUDE
from ..results import RunResult
from ..scene import Scene
from .state import RunState


def scene_summary(scene: Scene, methods: dict[str, str]) -> dict[str, Any]:
    """The ``scene`` block of the results: what was asked, and the evaluator each method ran as."""
    return {"file": str(scene.file) if scene.file else None, "solver": scene.solver,
            "master_modes": scene.master_modes, "methods": scene.methods,
            "evaluators": methods, "retained_modes": scene.retained_modes, "tensors": scene.tensors,
            "step": asdict(scene.step)}


def field_arrays(state: RunState) -> None:
    """Add the master mode shapes and the dof geometry to ``arrays``.

    Fields over the whole mesh are rebuilt as ``full = zeros(n_full_dofs); full[free_dofs] = field``.
    """
    arrays, X, dirs = state.arrays, state.X, state.dirs
    arrays["phi_masters"] = state.phi[:, state.masters]
    free = state.adapter.free_dof_map()
    if free is not None:
        arrays["free_dofs"] = np.asarray(free.free, dtype=np.int64)
        arrays["n_full_dofs"] = np.asarray(free.n_full, dtype=np.int64)
    if X is not None:
        arrays["dof_coordinates"] = np.asarray(X, dtype=float)
    if dirs is not None:
        arrays["dof_directions"] = np.asarray(dirs)


def spectrum_summary(state: RunState) -> dict[str, Any]:
    """The ``spectrum`` block: elastic frequencies (rad/s), labels, rigid modes, solvers used."""
    basis, omega = state.basis, state.omega
    spectrum = {"omega": omega.tolist(), "labels": state.labels, "n_rigid": int(basis.rigid.shape[1]),
                "rigid_eigenvalues": basis.rigid_eigenvalues.tolist(),
                "degenerate_groups": basis.degenerate_groups, "eigensolver": basis.solver,
                "linear_solver": state.backend}
    if state.scales is not None:
        spectrum["omega_bar"] = [state.scales.omega_bar(w) for w in omega]
    return spectrum


def results_stage(state: RunState) -> RunResult:
    """The :class:`RunResult` of the run (timings are added by :func:`stepnf.pipeline.run_scene`).

    Reads every field the other stages wrote; adds the ``no_gamma`` run flag when no method has a
    Gamma, and the checkpoint's reused force evaluations to the counts.
    """
    if not any(r.gamma is not None for rec in state.modes for r in rec.methods.values()):
        state.flags.append({"kind": "no_gamma", "message": state.no_gamma or NO_AMPLITUDE})
    field_arrays(state)
    spectrum = spectrum_summary(state)
    counts = state.counters.to_dict()
    counts["force_evaluations_reused"] = state.checkpoint.reused if state.checkpoint is not None else 0
    model = state.adapter.describe()
    if state.gscale is not None:
        model["gamma"] = state.gscale.source
    scales = state.scales
    return RunResult(scene=scene_summary(state.scene, state.methods), modes=state.modes, counts=counts,
                     timings={}, spectrum=spectrum, model=model,
                     kappa=scales.kappa if scales else None, flags=state.flags, arrays=state.arrays,
                     output_mesh=state.output_mesh, backbones=state.backbones)
