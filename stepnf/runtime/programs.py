"""Programs a scene names: run only when the user allows it, outside the scene.

Some ``[model]`` keys make stepnf start a program the scene file names: the
``calculix`` adapter's ``executable``, the ``code_aster`` adapter's
``command`` and ``templates`` (code_aster command files are Python, run by
code_aster). A scene or sweep file received from someone else must not run
anything on the reader's machine by being read, so these keys are honoured
only when the user allows it, by a decision that is not in the scene:

* on the command line: ``stepnf run|modes|check|verify|sweep --allow-programs``;
* for a user's own machine: the environment variable :data:`ENV`
  (``STEPNF_ALLOW_PROGRAMS=1``; ``0`` or unset: refused);
* in Python: ``load_scene(path, allow_programs=True)`` (also
  :func:`stepnf.sweep.dask_sweep.load_sweep`, :func:`stepnf.cli.check.check_scene`), or the
  context manager :func:`allow_programs` around the calls that build models.

An explicit decision (the flag, the keyword, the context manager) wins over the
environment. Without permission such a key is a
:class:`~stepnf.errors.SceneError` (exit code 2) naming the file, the key and
these three ways; with it, the full command is printed on stderr before it
first runs (:func:`announce`). The adapter's own default program (``ccx`` or
``run_aster`` on PATH, the shipped templates) needs no permission, also when the
scene writes out the documented default; a bare program name is looked up in
the absolute folders of PATH only (:func:`which`). A Dask sweep
passes the decision made where the sweep starts to every case it runs
(:func:`stepnf.sweep.dask_sweep.run_case`); workers never decide it again.
"""
from __future__ import annotations

import argparse
import contextlib
import contextvars
import os
import sys
from pathlib import Path
from typing import Iterator, Sequence

from stepnf.errors import SceneError

#: The environment variable that allows programs named by scenes (``1``, ``true``, ``yes``).
ENV = "STEPNF_ALLOW_PROGRAMS"
_YES = ("1", "true", "yes", "on")
_NO = ("", "0", "false", "no", "off")
#: How to allow a program, quoted in every refusal.
HOW = (f"stepnf runs programs named in a scene only when you allow it: rerun with --allow-programs, or set "
       f"{ENV}=1 (Python: allow_programs=True)")

_decision: contextvars.ContextVar[bool | None] = contextvars.ContextVar("stepnf_allow_programs", default=None)


def programs_allowed() -> bool:
    """The permission in force: the explicit decision (:func:`allow_programs`), else :data:`ENV`.

    An :data:`ENV` value that is neither yes nor no is a :class:`SceneError` naming the variable."""
    explicit = _decision.get()
    if explicit is not None:
        return explicit
    value = os.environ.get(ENV, "").strip().lower()
    if value in _YES:
        return True
    if value in _NO:
        return False
    raise SceneError(f"environment variable {ENV}", None, f"{os.environ.get(ENV)!r}: expected 1 (allow the "
                     "programs a scene names) or 0 (refuse them)")


@contextlib.contextmanager
def allow_programs(decision: bool | None = True) -> Iterator[None]:
    """Within the block, the programs a scene names are allowed (``True``) or refused (``False``),
    whatever :data:`ENV` says; ``None`` leaves the permission in force as it is."""
    if decision is None:
        yield
        return
    token = _decision.set(bool(decision))
    try:
        yield
    finally:
        _decision.reset(token)


def check_allowed(scene_file: str | Path | None, key: str, what: str) -> None:
    """Nothing if programs are allowed; else a SceneError on ``key`` saying ``what`` would run and how to allow it."""
    if not programs_allowed():
        raise SceneError(scene_file, key, f"{what}; {HOW}")


def resolve_program(program: str, base_dir: str | Path) -> str:
    """A program as a scene names it: a bare name (no ``/``) is looked up on PATH when it runs (its
    absolute folders only, :func:`which`); a
    relative path is relative to the scene's folder ``base_dir`` (not the current folder)."""
    if "/" not in program:
        return program
    path = Path(program).expanduser()
    return str(path if path.is_absolute() else (Path(base_dir) / path).resolve())


def which(name: str) -> str | None:
    """The program a bare ``name`` (no ``/``) runs: the first executable ``name`` in an ABSOLUTE folder
    of ``PATH``, else ``None``. Empty, ``.`` and other relative entries are skipped: they mean the
    current folder, which may hold files a received scene shipped (a ``ccx`` beside it)."""
    import shutil

    folders = os.environ.get("PATH", os.defpath).split(os.pathsep)
    absolute = os.pathsep.join(f for f in folders if f and os.path.isabs(f))
    return shutil.which(name, path=absolute) if absolute else None


def announce(argv: Sequence[str], why: str) -> None:
    """Print on stderr the full command about to run (``why``: the scene keys that named it; a bare
    program name is shown as the PATH entry it runs, :func:`which`)."""
    import shlex

    from stepnf.runtime.printable import printable

    args = [str(a) for a in argv]
    if args and "/" not in args[0]:
        args[0] = which(args[0]) or args[0]
    line = printable(f"running a program {why}: {shlex.join(args)}").replace("\n", "\\n")  # one line, inert
    print(f"stepnf: {line}", file=sys.stderr, flush=True)


def program_flag() -> argparse.ArgumentParser:
    """The parent parser of the commands that build models: ``--allow-programs``."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--allow-programs", action="store_true",
                        help="run the programs the scene names ([model] executable, command, templates); the command "
                             f"is printed before it runs (default: refused, exit 2, unless {ENV}=1)")
    return parser
