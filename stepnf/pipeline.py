"""Run a scene: adapter -> modal analysis -> evaluation plan -> STEP -> evaluators -> results.

Only what the scene asks for is computed: NF/DNF/MD/SMD of one master mode
need the targeted STEP (two force evaluations, four with the amplitude check),
whatever the model size; the full STEP over the retained modes runs only when
``analysis.tensors = "full"``; the DPIM backbone only with ``[analysis.backbone]``.

The run of a solver adapter is the sequence :data:`ADAPTER_STAGES` (modules of
:mod:`stepnf.stages`), each stage reading and writing fields of one
:class:`~stepnf.stages.state.RunState`; :func:`~stepnf.stages.results.results_stage`
gathers the result. A model given in modal coordinates runs
:func:`~stepnf.stages.modal_coordinates.run_modal_model`.
"""
from __future__ import annotations

import contextlib
import time
from typing import Callable

from .adapter import SolverAdapter
from .checkpoint import Checkpoint
from .errors import SceneError
from .modal_model import ModalModel
from .progress import Progress, memory_now
from .registry import build_model, get_solver
from .results import RunResult, write_hdf5
from .scene import Scene
from .stages.backbone import backbone_check_stage, backbone_stage
from .stages.evaluate import evaluators_stage
from .stages.modal_coordinates import run_modal_model
from .stages.model import model_stage
from .stages.modes import modes_stage
from .stages.output_mesh import output_mesh_stage
from .stages.results import results_stage
from .stages.state import FULL_METHODS, MODAL_METHODS, RunState
from .stages.step import step_stage

__all__ = ["ADAPTER_STAGES", "FULL_METHODS", "MODAL_METHODS", "run_scene"]

#: The stages of a solver adapter's run, in order (name, function of the run's state); the
#: ``results`` stage then gathers the result. A new stage is one more entry here.
ADAPTER_STAGES: tuple[tuple[str, Callable[[RunState], None]], ...] = (
    ("model", model_stage),
    ("backbone_check", backbone_check_stage),
    ("modes", modes_stage),
    ("step", step_stage),
    ("evaluators", evaluators_stage),
    ("backbone", backbone_stage),
    ("output_mesh", output_mesh_stage),
)


def run_scene(scene: Scene, *, progress: Progress | None = None, write: bool = True) -> RunResult:
    """Compute what ``scene`` asks for and return (and, with ``write``, store) the results.

    With ``write``, the output folder is checked first (before any solver work): a folder that
    is a file, read-only or cannot be created is a :class:`SceneError` on ``output.dir``. A
    results file that cannot be written at the end (full disk) raises
    :class:`stepnf.errors.OutputError` whose ``result`` holds what was computed; the checkpoint
    folder is removed in both cases, and a previous results file is left untouched.
    """
    from .atomic import check_folder, linked, path_exists
    from .errors import OutputError

    progress = progress or Progress(enabled=False)
    writing = write and scene.write_hdf5
    created = writing and not path_exists(scene.output_dir)
    if writing:
        why = check_folder(scene.output_dir)
        if why is not None:
            raise SceneError(scene.file, "output.dir", f"the output folder {scene.output_dir} is not "
                             f"usable: {why}")
        link = linked(scene.output_dir, output_names(scene.output_name))
        if link is not None:  # stepnf never writes through a link (stepnf.atomic): say so before computing
            raise SceneError(scene.file, "output.dir", f"{link} is a symbolic link; stepnf never writes through "
                             "a link: remove it or choose another output folder")
    t_start = time.perf_counter()
    try:
        result, checkpoint = _compute(scene, progress, writing)
    except BaseException:
        if created:  # a folder this run made and left empty (a checkpoint to resume from is kept)
            with contextlib.suppress(OSError):
                scene.output_dir.rmdir()
        raise
    result.timings.update(progress.timings)
    result.timings["total"] = time.perf_counter() - t_start
    result.memory.update(progress.memory)
    result.memory["total"] = memory_now()
    if writing:
        path = scene.output_dir / f"{scene.output_name}.h5"
        try:
            write_hdf5(result, path, scene.text)
        except OutputError as exc:
            exc.result = result  # computed, not stored: the caller can still show it
            raise
        finally:
            if checkpoint is not None:  # the results are computed: the chunks are of no more use
                checkpoint.discard()
        result.hdf5_path = str(path)
        _write_fields(scene, result)
    return result


def output_names(name: str) -> list[str]:
    """The names a run of output name ``name`` writes in its output folder (results, checkpoint folder,
    field files, figures)."""
    from .fields import FIELD_SUFFIXES

    return [f"{name}.h5", f".{name}.partial", *(f"{name}_fields{s}" for s in FIELD_SUFFIXES),
            f"{name}_modes.png", f"{name}_backbone.png"]


def _write_fields(scene: Scene, result: RunResult) -> None:
    """The field files beside the results file (:mod:`stepnf.fields`), once that file is safe.

    A failure is an :class:`OutputError` carrying the result (exit 3; the HDF5 file stays). The
    displacement vectors are dropped afterwards: the files hold them, the result need not.
    """
    from .errors import OutputError
    from .fields import write_mode_fields

    mesh, result.output_mesh = result.output_mesh, None
    if mesh is None:
        return
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
    result.extra_files += [str(p) for p in files]


def _compute(scene: Scene, progress: Progress, writing: bool) -> tuple[RunResult, Checkpoint | None]:
    """Build the model and run the pipeline; the force checkpoint (when writing) goes with the result."""
    cls = get_solver(scene.solver)
    checkpoint = None
    if issubclass(cls, ModalModel):
        with progress.stage("model", f"building the {scene.solver} model"):
            model = build_model(scene)
        try:
            return run_modal_model(scene, model, progress), None
        finally:
            model.close()
    with progress.stage("model", f"setting up the {scene.solver} model"):
        adapter = build_model(scene)
    # no checkpoint for an adapter whose calls are collective over MPI ranks: a rank that
    # reused stored forces would skip calls the other ranks make (rank 0 alone writes)
    # keyed by the model (stepnf.model_key): chunks of another model are dropped, and the run says so
    if writing and not adapter.collective:
        from .model_key import describe_change, model_key

        checkpoint = Checkpoint(scene.output_dir / f".{scene.output_name}.partial", key=model_key(scene),
                                describe=describe_change)
    try:
        result = _run_adapter(scene, adapter, progress, checkpoint, fields=writing and scene.fields)
    finally:
        adapter.close()
    if checkpoint is not None and checkpoint.reused:
        result.counters_note = f"{checkpoint.reused} force evaluations reused from an interrupted run"
        progress.message(result.counters_note)
    return result, checkpoint


def _run_adapter(scene: Scene, adapter: SolverAdapter, progress: Progress,
                 checkpoint: Checkpoint | None = None, *, fields: bool = False) -> RunResult:
    """Run :data:`ADAPTER_STAGES` on ``adapter`` (the scene's methods resolved first), then ``results``;
    ``fields``: the run writes field files (the result then carries the adapter's output mesh)."""
    state = RunState.start(scene, adapter, progress, checkpoint, fields=fields)
    for _name, stage in ADAPTER_STAGES:
        stage(state)
    return results_stage(state)
