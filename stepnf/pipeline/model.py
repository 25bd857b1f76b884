"""Stage ``model``: the scene's model of the right kind, its matrices and what it offers, checked before any solve."""
from __future__ import annotations

from typing import Any

from stepnf.errors import SceneError
from stepnf.linalg.factorization import choose_backend
from stepnf.linalg.modal_analysis import rigid_body_fields
from stepnf.nf.diagnostics import check_conditioning, smooth_field
from stepnf.nf.roundoff import eigenvalue_roundoff
from stepnf.pipeline.outputs import RunContext, RunModel
from stepnf.pipeline.plan import check_rigid_count
from stepnf.pipeline.step import step_policy
from stepnf.plugin.adapter import checked_matrices
from stepnf.plugin.modal_model import ModalModel
from stepnf.plugin.registry import build_model, get_solver
from stepnf.runtime.progress import Progress
from stepnf.scene.parse import Scene
from stepnf.step.procedure import ForceEvaluator


def is_modal_model(scene: Scene) -> bool:
    """Whether the scene's solver gives a model in modal coordinates
    (:class:`~stepnf.plugin.modal_model.ModalModel`) rather than a solver adapter (mesh, K, M, forces).
    Raises :class:`~stepnf.errors.UnknownSolverError` for a solver that is not installed."""
    return issubclass(get_solver(scene.solver), ModalModel)


def open_model(scene: Scene, progress: Progress | None = None) -> Any:
    """The scene's model, of the kind its solver gives: a :class:`~stepnf.plugin.modal_model.ModalModel`
    or a :class:`~stepnf.plugin.adapter.SolverAdapter` (the caller closes it), built in the progress
    stage ``model``. The one place where the kind of model is decided; callers branch on the instance."""
    progress = progress or Progress(enabled=False)
    what = "building" if is_modal_model(scene) else "setting up"
    with progress.stage("model", f"{what} the {scene.solver} model"):
        model = build_model(scene)
    line = model.summary() if callable(getattr(model, "summary", None)) else ""  # mesh, element order, dofs
    if line:
        progress.message(line)
    return model


def model_stage(ctx: RunContext, adapter: Any, *, survey: bool = False) -> RunModel:
    """Read the adapter's K and M and refuse what cannot run.

    Returns a :class:`RunModel`: ``K``, ``M`` (real, (n, n), finite, symmetric: else an
    :class:`~stepnf.errors.AdapterError`, exit 3), the backend, the STEP policy and length, the dof
    geometry, the rigid-body fields (when the geometry is known), the smoothest field's eigenvalue and the
    run's force evaluator. Raises :class:`~stepnf.errors.SceneError` (exit 2) on matrices of the wrong
    size, a STEP method the solver does not offer, a rigid-mode count that does not fit, and a numerical
    error (exit 3) on a model too ill-conditioned to solve. ``survey`` (``stepnf modes``): no STEP, so no
    policy, length or force evaluator (and no refusal of the STEP method).
    """
    scene = ctx.scene
    with ctx.progress.stage("matrices", "mass and stiffness matrices"):
        K, M = checked_matrices(adapter)
    n = K.shape[0]
    if K.shape != (n, n) or M.shape != (n, n) or n != adapter.n_dofs:
        raise SceneError(scene.file, "model", f"the adapter returned K {K.shape} and M {M.shape} for "
                         f"{adapter.n_dofs} dofs")
    backend = choose_backend(n, scene.linear_solver)
    policy = None if survey else step_policy(scene, adapter)
    X, dirs = adapter.dof_coordinates(), adapter.dof_directions()
    candidates = rigid_body_fields(X, dirs) if X is not None and dirs is not None else None
    check_rigid_count(scene, n)
    sm = smooth_field(K, M, X, dirs)  # refuse a model whose smoothest field is beyond reach before solving
    smooth = None if sm is None else sm[0]
    if sm is not None:
        check_conditioning(float(eigenvalue_roundoff(K, sm[1][:, None], [sm[0]])[0]),
                           what="model stage, before the eigen-solve: the smoothest field's eigenvalue (its Ritz "
                                "value bounds the fundamental from above)")
    length = forces = None
    if not survey:
        length = scene.thickness if scene.thickness is not None else adapter.characteristic_length()
        forces = ForceEvaluator.for_adapter(adapter, n, ctx.counters, checkpoint=ctx.checkpoint)
    return RunModel(adapter, K, M, backend, policy, length, X, dirs, candidates, smooth, forces)
