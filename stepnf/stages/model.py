"""Stage ``model``: the matrices and what the model offers, checked before any solve."""
from __future__ import annotations

from ..adapter import checked_matrices
from ..diagnostics import check_conditioning, conditioning_ratio, smooth_eigenvalue
from ..errors import SceneError
from ..linalg import choose_backend
from ..modal import rigid_body_fields
from ..plan import check_rigid_count
from .state import RunState
from .step import step_policy


def model_stage(state: RunState) -> None:
    """Read the adapter's K and M and refuse what cannot run.

    Reads ``scene``, ``adapter``, ``progress``. Writes ``K``, ``M`` (real, (n, n), finite,
    symmetric: else an :class:`~stepnf.errors.AdapterError`, exit 3), ``backend``, ``policy``, ``X``,
    ``dirs``, ``candidates`` (rigid-body fields, when the dof geometry is known) and ``smooth``.
    Raises :class:`~stepnf.errors.SceneError` (exit 2) on matrices of the wrong size, a STEP method
    the solver does not offer, a rigid-mode count that does not fit, and a numerical error (exit 3)
    on a model too ill-conditioned to solve.
    """
    scene, adapter = state.scene, state.adapter
    with state.progress.stage("matrices", "mass and stiffness matrices"):
        state.K, state.M = checked_matrices(adapter)
    K, M, n = state.K, state.M, state.n
    if K.shape != (n, n) or M.shape != (n, n) or n != adapter.n_dofs:
        raise SceneError(scene.file, "model", f"the adapter returned K {K.shape} and M {M.shape} for "
                         f"{adapter.n_dofs} dofs")
    state.backend = choose_backend(n, scene.linear_solver)
    state.policy = step_policy(scene, adapter)
    state.X, state.dirs = adapter.dof_coordinates(), adapter.dof_directions()
    X, dirs = state.X, state.dirs
    state.candidates = rigid_body_fields(X, dirs) if X is not None and dirs is not None else None
    check_rigid_count(scene, n)
    state.smooth = smooth_eigenvalue(K, M, X, dirs)  # refuse a hopelessly ill-conditioned model before solving
    if state.smooth is not None:
        check_conditioning(conditioning_ratio(state.smooth, K, M))
