"""Stage ``results``: the run's typed outputs gathered into one :class:`RunResult`, timed and written.

The only stage that builds the result, and the last: the records of the master modes get their backbone
blocks, the arrays of the results file are gathered from the stages' outputs (:func:`run_arrays`), the
run flags, counts, timings and memory are set, and with ``ctx.writing`` the HDF5 file and the field files
are written (:func:`write_results`). Afterwards only the paths of the figures a caller draws are added
(``extra_files``), and the records' displacement fields are dropped once written (memory).
"""
from __future__ import annotations

import time
from dataclasses import asdict, replace
from typing import Any

import numpy as np

from stepnf.flags import new_flag
from stepnf.nf.gamma import NO_AMPLITUDE, share_flag, transverse_share
from stepnf.io.results import ModeResult, RunResult, write_hdf5
from stepnf.pipeline.forced import with_forced
from stepnf.pipeline.outputs import (AdapterFacts, Backbones, Evaluations, RunContext, RunModel, RunModes,
                                     StepTerms)
from stepnf.runtime.progress import memory_now
from stepnf.scene.parse import Scene


def scene_summary(scene: Scene, methods: dict[str, str]) -> dict[str, Any]:
    """The ``scene`` block of the results: what was asked, and the evaluator each method ran as."""
    return {"file": str(scene.file) if scene.file else None, "solver": scene.solver,
            "master_modes": scene.master_modes, "methods": scene.methods,
            "evaluators": methods, "retained_modes": scene.retained_modes, "tensors": scene.tensors,
            "step": asdict(scene.step)}


def field_arrays(model: RunModel, modes: RunModes, facts: AdapterFacts) -> dict[str, np.ndarray]:
    """The master mode shapes and the dof geometry.

    Fields over the whole mesh are rebuilt as ``full = zeros(n_full_dofs); full[free_dofs] = field``.
    """
    X, dirs = model.X, model.dirs
    arrays = {"phi_masters": modes.phi[:, modes.masters]}
    free = facts.free_dofs
    if free is not None:
        arrays["free_dofs"] = np.asarray(free.free, dtype=np.int64)
        arrays["n_full_dofs"] = np.asarray(free.n_full, dtype=np.int64)
    if X is not None:
        arrays["dof_coordinates"] = np.asarray(X, dtype=float)
    if dirs is not None:
        arrays["dof_directions"] = np.asarray(dirs)
    return arrays


def run_arrays(modes: RunModes, terms: StepTerms, evals: Evaluations, backbones: Backbones) -> dict[str, np.ndarray]:
    """The arrays of the results file from the stages' outputs, in the order the stages made them:
    ``omega``, ``master_modes``; ``g``, ``h``, ``full_modes`` (full STEP); ``Gv_<p>``; ``backbone_<p>_*``;
    ``frc_<p>_<i>_*`` (the forced responses)."""
    arrays = {"omega": modes.basis.omega, "master_modes": np.asarray(modes.masters)}
    if terms.full is not None:
        arrays["g"], arrays["h"], arrays["full_modes"] = terms.full.g, terms.full.h, terms.full_modes
    for p, Gv in evals.Gv.items():
        arrays[f"Gv_{p}"] = Gv
    for bb in backbones.by_master.values():
        arrays.update(bb.arrays)
    for fo in backbones.forced.values():
        arrays.update(fo.arrays)
    return arrays


def with_backbones(records: list[ModeResult], backbones: Backbones) -> list[ModeResult]:
    """The master modes' records completed by the backbone stage's output: each master's ``backbone``
    block, and on every method the flags of a refused parametrisation (once per kind)."""
    for rec in records:
        bb = backbones.by_master.get(rec.index)
        if bb is None:
            continue
        for flag in bb.method_flags:
            for r in rec.methods.values():
                if not any(f.get("kind") == flag.get("kind") for f in r.flags):
                    r.flags.append(dict(flag))
        rec.backbone = bb.block
    return records


def with_transverse_shares(records: list[ModeResult], model: RunModel, modes: RunModes, evals: Evaluations,
                           transverse) -> list[ModeResult]:
    """With ``[analysis] transverse`` and a Gamma: each master's ``transverse_share`` (its kinetic energy in that
    direction, :func:`stepnf.nf.gamma.transverse_share`) and, below :data:`~stepnf.nf.gamma.GAMMA_SHARE_MIN`, a
    ``gamma_not_transverse`` flag on every method that has a Gamma (the table shows it n/a, the number is kept)."""
    if transverse is None or evals.gscale is None or model.dirs is None:
        return records
    for rec in records:
        rec.transverse_share = transverse_share(modes.phi[:, rec.index], model.M, model.X, model.dirs, transverse)
        flag = share_flag(rec.transverse_share)
        for r in rec.methods.values() if flag is not None else ():
            if r.gamma is not None:
                r.flags.append(dict(flag))
    return records


def spectrum_summary(model: RunModel, modes: RunModes, scales: Any) -> dict[str, Any]:
    """The ``spectrum`` block: elastic frequencies (rad/s), labels, rigid modes, solvers used."""
    basis, omega = modes.basis, modes.omega
    spectrum = {"omega": omega.tolist(), "labels": modes.labels, "n_rigid": int(basis.rigid.shape[1]),
                "rigid_eigenvalues": basis.rigid_eigenvalues.tolist(),
                "degenerate_groups": basis.degenerate_groups, "eigensolver": basis.solver,
                "linear_solver": model.backend}
    if scales is not None:
        spectrum["omega_bar"] = [scales.omega_bar(w) for w in omega]
    return spectrum


def gamma_flags(records: list[ModeResult], no_gamma: str | None) -> list[dict]:
    """The ``no_gamma`` run flag when no method of any master has a Gamma."""
    if not any(r.gamma is not None for rec in records for r in rec.methods.values()):
        return [new_flag("no_gamma", message=no_gamma or NO_AMPLITUDE)]
    return []


def reuse_note(ctx: RunContext) -> str | None:
    """What the checkpoint gave (force evaluations of an interrupted run reused), said once; None if nothing."""
    if ctx.checkpoint is None or not ctx.checkpoint.reused:
        return None
    note = f"{ctx.checkpoint.reused} force evaluations reused from an interrupted run"
    ctx.progress.message(note)
    return note


def results_stage(ctx: RunContext, model: RunModel, modes: RunModes, terms: StepTerms, evals: Evaluations,
                  backbones: Backbones, facts: AdapterFacts) -> RunResult:
    """The :class:`RunResult` of a solver adapter's run, from every stage's output (module docstring),
    written when ``ctx.writing`` (:func:`write_results`)."""
    records = with_transverse_shares(with_forced(with_backbones(evals.modes, backbones), backbones), model, modes, evals,
                                     ctx.scene.transverse)
    flags = list(modes.flags) + list(terms.flags) + gamma_flags(records, evals.no_gamma)
    arrays = run_arrays(modes, terms, evals, backbones)
    arrays.update(field_arrays(model, modes, facts))
    counts = ctx.counters.to_dict()
    counts["force_evaluations_reused"] = ctx.checkpoint.reused if ctx.checkpoint is not None else 0
    description = dict(facts.description)
    if evals.gscale is not None:
        description["gamma"] = evals.gscale.source
    scales = evals.scales
    result = RunResult(scene=scene_summary(ctx.scene, ctx.methods), modes=records, counts=counts,
                       timings={}, spectrum=spectrum_summary(model, modes, scales), model=description,
                       kappa=scales.kappa if scales else None, flags=flags, arrays=arrays,
                       output_mesh=facts.output_mesh, backbones=backbones.results,
                       counters_note=reuse_note(ctx))
    return write_results(ctx, result)


def timed(ctx: RunContext, result: RunResult) -> RunResult:
    """``result`` with the stages' timings and memory and the run's total (seconds since ``ctx.started``)."""
    timings = {**result.timings, **ctx.progress.timings, "total": time.perf_counter() - ctx.started}
    memory = {**result.memory, **ctx.progress.memory, "total": memory_now()}
    return replace(result, timings=timings, memory=memory)


def write_results(ctx: RunContext, result: RunResult) -> RunResult:
    """``result`` timed and, with ``ctx.writing``, stored: the HDF5 file, then the field files.

    A results file that cannot be written (full disk) raises :class:`stepnf.errors.OutputError` whose
    ``result`` holds what was computed; the checkpoint folder is removed in both cases. The returned
    result names the files written and holds no output mesh (and no displacement vectors: the field
    files hold them).
    """
    from stepnf.errors import OutputError

    result = timed(ctx, result)
    if not ctx.writing:
        return result
    scene = ctx.scene
    path = scene.output_dir / f"{scene.output_name}.h5"
    try:
        write_hdf5(result, path, scene.text)
    except OutputError as exc:
        exc.result = result  # computed, not stored: the caller can still show it
        raise
    finally:
        if ctx.checkpoint is not None:  # the results are computed: the chunks are of no more use
            ctx.checkpoint.discard()
    written = replace(result, hdf5_path=str(path), output_mesh=None)
    files = field_files(scene, written, result.output_mesh)
    return replace(written, extra_files=written.extra_files + files)


def field_files(scene: Scene, result: RunResult, mesh: Any) -> list[str]:
    """The field files beside the results file (:mod:`stepnf.io.fields`), once that file is safe.

    A failure is an :class:`OutputError` carrying the result (exit 3; the HDF5 file stays). The
    displacement vectors are dropped afterwards: the files hold them, the result need not.
    """
    from stepnf.errors import OutputError
    from stepnf.io.fields import write_mode_fields

    if mesh is None:
        return []
    try:
        files = write_mode_fields(result.hdf5_path, mesh, result.modes, result.arrays["phi_masters"],
                                  result.arrays.get("dof_coordinates"), result.arrays.get("dof_directions"),
                                  who=f"solver adapter {result.model.get('adapter')} ({scene.solver!r})")
    except OutputError as exc:
        exc.result = result
        raise
    finally:
        for rec in result.modes:
            for r in rec.methods.values():
                r.fields = {}
    return [str(p) for p in files]
