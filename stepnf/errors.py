"""Exceptions raised by stepnf.

Every error a user can provoke says *where* (file, key or stage), *what was
given* and *what is allowed*, in the style of meshio's messages.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable


class StepnfError(Exception):
    """Base class of every error stepnf raises on purpose."""


class SceneError(StepnfError, ValueError):
    """A scene file is malformed or contradictory.

    Parameters
    ----------
    file : path of the scene (or ``None`` for an in-memory scene)
    key : dotted key, e.g. ``"analysis.master_modes"``
    message : what is wrong and what is allowed
    """

    def __init__(self, file: str | Path | None, key: str | None, message: str):
        self.file = None if file is None else str(file)
        self.key = key
        self.message = message
        where = self.file or "<scene>"
        if key:
            where += f": [{key}]"
        super().__init__(f"{where}: {message}")


class AdapterError(StepnfError):
    """A solver adapter returned something unusable (wrong shape, NaN, ...)."""


class SolverRunError(StepnfError):
    """An external solver failed: missing executable, exit code, time-out, missing output."""

    def __init__(self, message: str, *, workdir: str | Path | None = None, log_tail: str = ""):
        self.workdir = None if workdir is None else str(workdir)
        self.log_tail = log_tail
        text = message
        if workdir is not None:
            text += f"\n  work folder: {workdir}"
        if log_tail:
            text += "\n  end of the solver log:\n    " + "\n    ".join(log_tail.rstrip().splitlines())
        super().__init__(text)


class UnknownSolverError(StepnfError, ValueError):
    """No adapter is installed under the requested name."""

    def __init__(self, name: str, installed: Iterable[str]):
        self.name = name
        self.installed = sorted(installed)
        super().__init__(
            f"Unknown solver {name!r}. Pick one of {self.installed} "
            "(adapters register under the entry-point group 'stepnf.solvers')."
        )


class StoreError(StepnfError, ValueError):
    """A results file or sweep store is unreadable, corrupt or not stepnf's."""


class InputFileError(SceneError, StoreError):
    """A file named on the command line to be read (``stepnf show RESULT.h5``) is missing, a folder,
    not stepnf's or damaged.

    Bad input (exit code 2), like a scene or a mesh: the user gave the file. Also a
    :class:`StoreError`. A store stepnf finds damaged in its own output folder (a sweep's) stays a
    plain :class:`StoreError` (exit 3: a file it cannot use or update).
    """

    def __init__(self, file: str | Path, message: str):
        super().__init__(file, None, message)

    @classmethod
    def of(cls, file: str | Path, exc: BaseException) -> "InputFileError":
        """The same message as ``exc`` (a :class:`StoreError` of a reader, which names ``file`` first)."""
        text, prefix = str(exc), f"{file}: "
        return cls(file, text[len(prefix):] if text.startswith(prefix) else text)


class OutputError(StepnfError):
    """A result file could not be written (full disk, read-only or vanished folder, ...).

    ``path`` is the file, ``errno`` the operating system's error number (or
    ``None``). ``result`` may hold what was computed and could not be stored,
    so that a caller can still show it.
    """

    def __init__(self, message: str, *, path: str | Path | None = None, errno: int | None = None):
        self.path = None if path is None else str(path)
        self.errno = errno
        self.result: Any = None
        super().__init__(message)


class NumericalError(StepnfError, ArithmeticError):
    """A numerical stage cannot produce a meaningful number (singular matrix, NaN)."""


class NoSingleModeManifold(NumericalError):
    """The DPIM's refusal of one master: its forces drive a degenerate twin (``kind`` "twin_driven"), or a
    harmonic ``m`` of the parametrisation meets a mode exactly (``kind`` "internal_resonance_1_<m>",
    ``K - (m w)^2 M`` singular). The run's backbone stage turns it into a flag of that master
    (:mod:`stepnf.flags`) and goes on. ``mode``: the mode concerned, when known."""

    def __init__(self, message: str, kind: str = "twin_driven", mode: int | None = None, **extra):
        super().__init__(message)
        self.kind, self.mode, self.extra = kind, mode, extra


def allowed(values: Iterable[Any]) -> str:
    """Format a list of allowed values for an error message."""
    return "[" + ", ".join(repr(v) for v in values) + "]"


class MeshError(SceneError):
    """A user's mesh is unusable (empty, NaN coordinates, dangling or degenerate cells, ...).

    A :class:`SceneError` (bad input, exit code 2) whose ``file`` is the mesh
    file; the message names the cell or node at fault (0-based positions in
    the file, or the file's own ids when it numbers its nodes and elements).
    """

    def __init__(self, file: str | Path | None, message: str):
        super().__init__(file, None, message)


class UnitsWarning(UserWarning):
    """The model's numbers look like a mix of unit systems (e.g. a mesh in mm with SI material constants)."""


class ModelWarning(UserWarning):
    """The model computes, but something in it deserves a look (e.g. elastic modes counted as rigid)."""


class OutputWarning(UserWarning):
    """Something optional could not be written (a checkpoint chunk); the run goes on without it."""


class StaleWarning(UserWarning):
    """A stored result (a checkpoint, a sweep case) was made for another model: it is computed again."""
