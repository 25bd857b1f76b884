"""``stepnf.run(scene)``: the run of ``stepnf run SCENE`` from Python, returning a :class:`~stepnf.api.view.RunView`.

The scene is a TOML file or a dict of the same content (what ``tomllib.load`` returns). It is checked
by the same key checks (:func:`stepnf.scene.parse.load_scene` / :func:`~stepnf.scene.parse.parse_scene`)
and computed by the same run (:func:`stepnf.pipeline.run.run_scene`), so the numbers are those of
``stepnf run --json``, bit for bit. What the command line reports as a message is raised, with that
message as ``str(exc)`` (without the ``stepnf: error:`` prefix the command adds):
:class:`~stepnf.errors.SceneError` for bad input (exit 2 on the command line),
:class:`~stepnf.errors.NumericalError` and :class:`~stepnf.errors.SolverRunError` for a numerical or
solver failure, :class:`~stepnf.errors.OutputError` for a file that cannot be written (exit 3; its
``result`` holds what was computed).

Files: by default (``output=None``) nothing is written, neither the results file nor the field files,
the figures or the checkpoint of an interrupted run: a loop over designs leaves no trace.
``output=True`` writes what ``stepnf run SCENE`` writes, where the scene's ``[output]`` says;
``output="folder"`` writes it in that folder, as ``stepnf run SCENE --output folder``.
"""
from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any, Mapping

from stepnf.api.view import RunView
from stepnf.errors import OutputWarning, SceneError
from stepnf.io.results import RunResult
from stepnf.pipeline.run import run_scene
from stepnf.runtime.progress import Progress
from stepnf.scene.parse import Scene, load_scene, parse_scene
from stepnf.runtime.programs import allow_programs as permission


def run(scene: str | os.PathLike[str] | Mapping[str, Any], *, output: bool | str | os.PathLike[str] | None = None,
        allow_programs: bool | None = None, progress: bool = False,
        base_dir: str | os.PathLike[str] | None = None) -> RunView:
    """Run ``scene`` (a TOML file, or a dict of the same tables) and return its results.

    ``output``: None or False, nothing written; True, the files ``stepnf run`` writes (results file,
    field files, the figures of ``[output] plot``) where the scene's ``[output]`` says; a folder, there
    (as ``--output``). ``allow_programs``: True allows the programs the scene names (as
    ``--allow-programs``), False refuses them, None (default) leaves the decision to
    ``STEPNF_ALLOW_PROGRAMS`` as the command line without the flag does (:mod:`stepnf.runtime.programs`).
    ``progress``: print the stage lines on stderr, as the command line does without ``--quiet``.
    ``base_dir``: for a dict, the folder its relative paths (``[model] file``, ``[output] dir``) start
    from (default: the current folder); a file's are relative to the file's folder.
    """
    with permission(allow_programs):
        sc = _scene(scene, base_dir)
        if output is not None and output is not False and output is not True:
            if not str(output).strip():
                raise SceneError(sc.file, None, f"output must name a folder, got {str(output)!r}")
            sc.output_dir = Path(output)
        writing = output is not None and output is not False
        result = run_scene(sc, progress=Progress(enabled=bool(progress)), write=writing)
        if writing and sc.plot:
            _figures(sc, result)
    return RunView(result.to_dict(), result)


def _scene(scene: Any, base_dir: Any) -> Scene:
    """The checked scene of a path or a mapping (a TypeError for anything else)."""
    if isinstance(scene, (str, os.PathLike)):
        return load_scene(scene)
    if isinstance(scene, Mapping):
        base = Path(base_dir).resolve() if base_dir is not None else Path.cwd()
        return parse_scene(scene, base_dir=base)
    raise TypeError(f"stepnf.run takes a scene file (str or Path) or a dict of its tables, got "
                    f"{type(scene).__name__}")


def _figures(scene: Scene, result: RunResult) -> None:
    """``NAME_modes.png`` and ``NAME_backbone.png`` as ``stepnf run`` draws them
    (:mod:`stepnf.report.run_figures`); a figure that cannot be drawn or written is an
    :class:`~stepnf.errors.OutputWarning` with the command line's words (the results file is written)."""
    from stepnf.report.run_figures import draw_run_figures

    for line in draw_run_figures(scene, result):
        warnings.warn(line.removeprefix("stepnf: "), OutputWarning, stacklevel=3)
