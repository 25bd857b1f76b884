"""Drive an external FE solver through command templates and files (solver-independent).

An *external* solver is one stepnf cannot see inside: it reads input files
written from a template, runs as a separate process in a work folder, and
writes result files that stepnf parses. This package holds the pieces every such
adapter shares, and nothing specific to one FE code (no FE import), in four
modules (:mod:`.templates`, :mod:`.process`, :mod:`.adapter`, :mod:`.keys`):

:class:`CommandTemplate`
    Text with named placeholders ``${name}`` (``$$`` is a literal ``$``). An
    unfilled placeholder is an error naming it and the template file;
    :attr:`CommandTemplate.placeholders` lists them.
:func:`find_executable`
    Resolve a program name or path, or raise :class:`~stepnf.errors.SolverRunError`.
:class:`WorkFolder`
    A fresh folder per solver run (in the system temp folder or under a
    scene-given parent), removed or kept on exit by policy
    (``"never"``, ``"on_error"``, ``"always"``).
:func:`run_command`
    Run a command inside the work folder with a time-out, its output captured
    to a log file; a missing executable, a non-zero exit or a time-out raises
    :class:`~stepnf.errors.SolverRunError` with the work folder and the tail
    of the log.
:func:`require_files`
    Raise the same error when an expected output file is missing.
:class:`ExternalSolverAdapter`
    A :class:`~stepnf.plugin.adapter.SolverAdapter` base whose batch hook sends a
    whole batch of displacement fields to ONE solver run (split into chunks
    of :attr:`ExternalSolverAdapter.max_fields_per_run` when the solver limits
    it). A subclass implements :meth:`~ExternalSolverAdapter.write_force_job`
    and :meth:`~ExternalSolverAdapter.read_forces`. Results of the chunks
    already computed are cached, so a failure in a later chunk loses nothing
    (the error carries them as ``partial``) and a retry does not redo them.
:data:`~stepnf.external.keys.RUN_KEYS`, :func:`~stepnf.external.keys.check_solid_config`, :func:`~stepnf.external.keys.build_solid`
    The ``[model]`` keys of every template-driven adapter (run settings, a
    user's mesh or a generated cap, the material) and the one build of its
    model from them. A key that names a program (:attr:`SolidFromScene.program_keys
    <stepnf.external.keys.SolidFromScene.program_keys>`: calculix ``executable``, code_aster
    ``command`` and ``templates``) is refused unless the user allows it (:mod:`stepnf.runtime.programs`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from stepnf.runtime.lazy import lazy_exports

if TYPE_CHECKING:
    from stepnf.external.adapter import ExternalSolverAdapter
    from stepnf.external.keys import (EXECUTABLE, RUN_KEYS, RUN_RANGES, SolidFromScene, build_solid, check_solid_config,
                                      solid_model_keys)
    from stepnf.external.process import (KEEP_POLICIES, RunRecord, WorkFolder, find_executable, log_tail, missing_output,
                                         require_files, run_command)
    from stepnf.external.templates import CommandTemplate, TemplateError

_NAMES = {"ExternalSolverAdapter": "adapter",
          **{n: "keys" for n in ("EXECUTABLE", "RUN_KEYS", "RUN_RANGES", "SolidFromScene", "build_solid",
                                 "check_solid_config", "solid_model_keys")},
          **{n: "process" for n in ("KEEP_POLICIES", "RunRecord", "WorkFolder", "find_executable", "log_tail",
                                    "missing_output", "require_files", "run_command")},
          "CommandTemplate": "templates", "TemplateError": "templates"}
__getattr__ = lazy_exports(__name__, _NAMES, globals())
__all__ = ["ExternalSolverAdapter", "EXECUTABLE", "RUN_KEYS", "RUN_RANGES", "build_solid", "check_solid_config",
           "solid_model_keys", "SolidFromScene", "KEEP_POLICIES", "RunRecord", "WorkFolder", "find_executable", "log_tail",
           "missing_output", "require_files", "run_command", "CommandTemplate", "TemplateError"]
