"""Run a scene: model -> modal analysis -> STEP -> evaluators -> backbone -> forced responses -> results.

Only what the scene asks for is computed: NF/DNF/MD/SMD of one master mode
need the targeted STEP (two force evaluations, four with the amplitude check),
whatever the model size; the full STEP over the retained modes runs only when
``analysis.tensors = "full"``; the DPIM backbone only with ``[analysis.backbone]``.

The run of a solver adapter is :func:`run_adapter`: each stage a function of the
earlier stages' frozen outputs (:mod:`stepnf.pipeline.outputs`) and of the run's
:class:`~stepnf.pipeline.outputs.RunContext`; :func:`~stepnf.pipeline.results.results_stage`
builds and writes the result. A model given in modal coordinates runs
:func:`~stepnf.pipeline.modal_coordinates.modal_model_outputs`, whose outputs go to the same results.
"""
from __future__ import annotations

import contextlib
import time

from stepnf.errors import SceneError
from stepnf.io.results import RunResult
from stepnf.methods import MODAL
from stepnf.pipeline.backbone import backbone_check_stage, backbone_stage
from stepnf.pipeline.evaluate import evaluators_stage
from stepnf.pipeline.forced import damping_check_stage, forced_stage, forcing_check_stage
from stepnf.pipeline.modal_coordinates import modal_model_outputs, modal_results
from stepnf.pipeline.model import model_stage, open_model
from stepnf.pipeline.modes import modes_stage
from stepnf.pipeline.output_mesh import output_mesh_stage
from stepnf.pipeline.outputs import AdapterFacts, Backbones, Evaluations, RunContext, RunModel, RunModes, StepTerms
from stepnf.pipeline.results import results_stage
from stepnf.pipeline.step import step_stage
from stepnf.plugin.adapter import SolverAdapter
from stepnf.plugin.modal_model import ModalModel
from stepnf.runtime.progress import Progress
from stepnf.scene.parse import Scene
from stepnf.step.checkpoint import Checkpoint

__all__ = ["run_adapter", "run_on_adapter", "run_scene"]


def run_scene(scene: Scene, *, progress: Progress | None = None, write: bool = True) -> RunResult:
    """Compute what ``scene`` asks for and return (and, with ``write``, store) the results.

    With ``write``, the output folder is checked first (before any solver work): a folder that
    is a file, read-only or cannot be created is a :class:`SceneError` on ``output.dir``. A
    results file that cannot be written at the end (full disk) raises
    :class:`stepnf.errors.OutputError` whose ``result`` holds what was computed; the checkpoint
    folder is removed in both cases, and a previous results file is left untouched.
    """
    from stepnf.io.atomic import check_folder, linked, path_exists

    progress = progress or Progress(enabled=False)
    writing = write and scene.write_hdf5
    created = writing and not path_exists(scene.output_dir)
    if writing:
        why = check_folder(scene.output_dir)
        if why is not None:
            raise SceneError(scene.file, "output.dir", f"the output folder {scene.output_dir} is not "
                             f"usable: {why}")
        link = linked(scene.output_dir, output_names(scene.output_name))
        if link is not None:  # stepnf never writes through a link (stepnf.io.atomic): say so before computing
            raise SceneError(scene.file, "output.dir", f"{link} is a symbolic link; stepnf never writes through "
                             "a link: remove it or choose another output folder")
    t_start = time.perf_counter()
    try:
        return _compute(scene, progress, writing, t_start)
    except BaseException as exc:
        # a folder this run made and left empty (a checkpoint to resume from is kept); not when the
        # results were computed and only their file could not be written (OutputError.result): the
        # folder then stays, as the user named it
        if created and getattr(exc, "result", None) is None:
            with contextlib.suppress(OSError):
                scene.output_dir.rmdir()
        raise


def output_names(name: str) -> list[str]:
    """The names a run of output name ``name`` writes in its output folder (results, checkpoint folder,
    field files, figures)."""
    from stepnf.io.fields import FIELD_SUFFIXES

    return [f"{name}.h5", f".{name}.partial", *(f"{name}_fields{s}" for s in FIELD_SUFFIXES),
            f"{name}_modes.png", f"{name}_backbone.png", f"{name}_branches.png", f"{name}_frc.png"]


def _compute(scene: Scene, progress: Progress, writing: bool, started: float) -> RunResult:
    """Open the model, run its stages, close it, then the results stage (which writes when ``writing``)."""
    model = open_model(scene, progress)
    modal = isinstance(model, ModalModel)
    try:  # the model is closed whatever happens, before the results stage
        if modal:
            ctx = RunContext.start(scene, progress, writing=writing, started=started, order=MODAL)
            outputs = modal_model_outputs(ctx, model)
        else:
            ctx = RunContext.start(scene, progress, run_checkpoint(scene, model, writing),
                                   fields=writing and scene.fields, writing=writing, started=started)
            outputs = run_adapter(ctx, model)
    finally:
        model.close()
    return modal_results(ctx, *outputs) if modal else results_stage(ctx, *outputs)


def run_checkpoint(scene: Scene, adapter: SolverAdapter, writing: bool) -> Checkpoint | None:
    """The force checkpoint of a run that writes, keyed by the model (:mod:`stepnf.scene.model_key`: chunks of
    another model are dropped, and the run says so). None for an adapter whose calls are collective over
    MPI ranks: a rank that reused stored forces would skip calls the other ranks make (rank 0 alone writes)."""
    if not writing or adapter.collective:
        return None
    from stepnf.scene.model_key import describe_change, model_key

    return Checkpoint(scene.output_dir / f".{scene.output_name}.partial", key=model_key(scene),
                      describe=describe_change)


def run_adapter(ctx: RunContext, adapter: SolverAdapter) -> tuple[RunModel, RunModes, StepTerms, Evaluations,
                                                                   Backbones, AdapterFacts]:
    """The stages of a solver adapter's run, in order, each returning its frozen output; the ``results``
    stage (:func:`~stepnf.pipeline.results.results_stage`) takes them all, once the adapter is closed."""
    model = model_stage(ctx, adapter)
    backbone_check_stage(ctx, model)
    loaded = forcing_check_stage(ctx, model)
    modes = modes_stage(ctx, model)
    damping_check_stage(ctx, modes)
    terms = step_stage(ctx, model, modes)
    evals = evaluators_stage(ctx, model, modes, terms)
    backbones = forced_stage(ctx, model, modes, evals, backbone_stage(ctx, model, modes, terms, evals), loaded)
    facts = output_mesh_stage(ctx, model)
    return model, modes, terms, evals, backbones, facts


def run_on_adapter(scene: Scene, adapter: SolverAdapter,
                   progress: Progress | None = None) -> tuple[RunResult, RunModel]:
    """The run of ``scene`` on an adapter the caller opened (:func:`~stepnf.pipeline.model.open_model`) and
    closes, nothing written: its result and its ``model`` stage's output (K, M, forces), for a command that
    goes on with the same model (``stepnf verify``) instead of building it again."""
    ctx = RunContext.start(scene, progress or Progress(enabled=False))
    outputs = run_adapter(ctx, adapter)
    return results_stage(ctx, *outputs), outputs[0]
