"""``stepnf check SCENE``: the conformance harness (:mod:`stepnf.testing.harness`) on the model a scene describes.

The scene is read and checked as ``stepnf run`` reads it, its solver's adapter
is built with ``from_config`` from the scene's ``[model]`` table, and every
check of :data:`stepnf.testing.harness.CHECKS` runs on it, ``from_config`` included
with that same table. One line per check says ``passed``, ``skipped`` (and
why the check does not apply) or ``FAILED`` (and what is wrong). The CLI
exits with 0 when no check failed, 3 when one did, 2 for a bad scene or an
unknown solver. The checks use the default :class:`stepnf.testing.harness.Tolerances`
(forces computed in double precision), plus the bound of the rounding of the
digits an adapter declares it prints (``force_digits``, CalculiX: 7) where that
rounding matters; tighter or looser tolerances are for Python
(``run_checks(..., Tolerances(batch=1e-6, ...))``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from stepnf.errors import SceneError
from stepnf.testing.harness import CheckResult


@dataclass(frozen=True)
class SceneCheck:
    """The results of the harness on a scene's model: ``solver`` name, adapter ``cls`` name, one result per check."""

    scene: Path
    solver: str
    cls: str
    results: list[CheckResult]

    @property
    def failed(self) -> list[CheckResult]:
        return [r for r in self.results if r.status == "failed"]


def check_scene(path: str | Path, *, allow_programs: bool | None = None) -> SceneCheck:
    """Build the adapter of the scene at ``path`` and run every conformance check on it.

    Raises :class:`~stepnf.errors.SceneError` (bad scene, or a solver that is a modal model: the
    harness checks FE adapters), :class:`~stepnf.errors.UnknownSolverError`, or
    :class:`~stepnf.errors.AdapterError` when the adapter fails while it builds the model.
    ``allow_programs``: as for :func:`stepnf.scene.parse.load_scene`.
    """
    from stepnf.pipeline.model import is_modal_model, open_model
    from stepnf.plugin.registry import get_solver
    from stepnf.runtime.programs import allow_programs as allowing
    from stepnf.scene.parse import load_scene
    from stepnf.testing.harness import run_checks

    scene = load_scene(path, allow_programs=allow_programs)
    if is_modal_model(scene):
        raise SceneError(scene.file, "model.solver", f"{scene.solver!r} is a modal model "
                         f"({get_solver(scene.solver).__name__}), not an FE solver adapter: the conformance "
                         "harness checks adapters (forces, M and K)")
    model = open_model(scene)
    try:
        with allowing(scene.allow_programs):  # the from_config check builds the model again
            results = run_checks(lambda: model, config=scene.model, base_dir=scene.base_dir)
    finally:
        model.close()
    return SceneCheck(Path(path), scene.solver, type(model).__name__, results)


def format_check(report: SceneCheck) -> str:
    """One line per check, then a summary line."""
    width = max(len(r.name) for r in report.results)
    lines = [f"stepnf check: {report.scene} (solver {report.solver!r}, {report.cls})"]
    for r in report.results:
        status = "FAILED" if r.status == "failed" else r.status
        lines.append((f"  {status:8s} {r.name.ljust(width)}  {r.reason}").rstrip())
    counts = {s: sum(r.status == s for r in report.results) for s in ("passed", "skipped", "failed")}
    lines.append(f"{counts['passed']} passed, {counts['skipped']} skipped, {counts['failed']} failed")
    return "\n".join(lines)
