"""Solver processes: executables, work folders, runs with a time-out and a log, expected output files."""
from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

from stepnf.errors import SolverRunError, allowed
from stepnf.runtime.programs import which
from stepnf.runtime.signals import Interrupted, deferred, received, track

#: Work-folder keeping policies.
KEEP_POLICIES = ("never", "on_error", "always")


def find_executable(program: str | Path, *, what: str = "solver") -> str:
    """Absolute path of ``program`` (a name on ``PATH`` or a path), or :class:`SolverRunError`. A name is
    looked up in the absolute folders of ``PATH`` only (:func:`stepnf.runtime.programs.which`: an empty, ``.``
    or relative entry would run a file of the current folder)."""
    prog = str(program)
    if os.sep in prog or (os.altsep and os.altsep in prog):
        p = Path(prog).expanduser()
        if p.is_file() and os.access(p, os.X_OK):
            return str(p.resolve())
        raise SolverRunError(f"{what} executable {prog!r} does not exist or is not executable")
    found = which(prog)
    if found is None:
        raise SolverRunError(
            f"{what} executable {prog!r} not found on PATH (its absolute folders); install it or give its full path"
        )
    return found


def log_tail(path: str | Path, n_lines: int = 25, max_chars: int = 4000) -> str:
    """Last ``n_lines`` lines of a text file ('' when it does not exist)."""
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            size = fh.tell()
            fh.seek(max(0, size - 64 * 1024))
            data = fh.read().decode("utf-8", errors="replace")
    except OSError:
        return ""
    text = "\n".join(data.splitlines()[-n_lines:])
    return text[-max_chars:]


# -------------------------------------------------------------- work folders
class WorkFolder:
    """A fresh folder for one solver run, removed or kept on exit.

    Parameters
    ----------
    parent : folder in which to create it (created if needed); ``None``: the system temp folder
    prefix : name prefix of the folder
    keep : ``"never"`` (always remove), ``"on_error"`` (keep when the block raised an error; an
        interruption, Ctrl-C or a signal (:mod:`stepnf.runtime.signals`), is none: the folder is removed), ``"always"``
    """

    def __init__(self, parent: str | Path | None = None, *, prefix: str = "stepnf-", keep: str = "on_error"):
        if keep not in KEEP_POLICIES:
            raise ValueError(f"unknown keep policy {keep!r}. Pick one of {allowed(KEEP_POLICIES)}")
        self.parent = None if parent is None else Path(parent)
        self.prefix = prefix
        self.keep = keep
        self.path: Path | None = None

    def __enter__(self) -> Path:
        if self.parent is not None:
            self.parent.mkdir(parents=True, exist_ok=True)
        self.path = Path(tempfile.mkdtemp(prefix=self.prefix, dir=self.parent))
        return self.path

    def __exit__(self, exc_type, exc, tb) -> None:
        # an interruption (Ctrl-C, a signal: stepnf.runtime.signals) is no error, nor the solver's death it caused
        failed = exc_type is not None and not issubclass(exc_type, KeyboardInterrupt) and received() is None
        if self.path is None:
            return
        if self.keep == "always" or (self.keep == "on_error" and failed):
            return
        shutil.rmtree(self.path, ignore_errors=True)


# ----------------------------------------------------------------- commands
@dataclass(frozen=True)
class RunRecord:
    """One finished solver run: command, folder, log file, wall time (s)."""

    argv: tuple[str, ...]
    workdir: Path
    log: Path
    seconds: float


def run_command(
    argv: Sequence[str | Path],
    *,
    cwd: str | Path,
    timeout: float | None = None,
    log_name: str = "solver.log",
    env: Mapping[str, str] | None = None,
    what: str = "solver",
) -> RunRecord:
    """Run ``argv`` in ``cwd``; stdout and stderr go to ``cwd/log_name``.

    ``argv[0]`` is resolved with :func:`find_executable`. ``env`` entries are
    added to the current environment. On time-out the whole process group is
    killed. Raises :class:`SolverRunError` (with the work folder and the tail
    of the log) on a missing executable, a non-zero exit or a time-out. While
    it runs the process group is registered with :mod:`stepnf.runtime.signals`: a
    SIGINT, SIGTERM or SIGHUP to stepnf kills it (the main thread then
    unwinds with :class:`~stepnf.runtime.signals.Interrupted`; a call in another
    thread raises its :class:`SolverRunError`, and :class:`WorkFolder`
    removes the folder all the same). A signal while the solver starts waits
    until its group is registered (:func:`~stepnf.runtime.signals.deferred`), so no
    solver is left running unregistered.
    """
    cwd = Path(cwd)
    log = cwd / log_name
    try:
        exe = find_executable(argv[0], what=what)
    except SolverRunError as exc:
        raise SolverRunError(str(exc).split("\n")[0], workdir=cwd) from None
    args = [exe] + [str(a) for a in argv[1:]]
    full_env = dict(os.environ)
    full_env.update(env or {})
    t0 = time.perf_counter()
    with open(log, "wb") as out, contextlib.ExitStack() as tracked:
        with deferred():  # a signal until the child is tracked must not lose it (stepnf.runtime.signals.deferred)
            try:
                proc = subprocess.Popen(args, cwd=cwd, stdout=out, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL, env=full_env, start_new_session=True)
            except OSError as exc:
                raise SolverRunError(f"{what} could not start: {' '.join(args)}: {exc}", workdir=cwd) from exc
            tracked.enter_context(track(proc))
        try:
            signum = received()
            if signum is not None:  # the signal came while it started: stop it now that it is tracked
                if threading.current_thread() is threading.main_thread():
                    raise Interrupted(signum)
                raise SolverRunError(f"{what} stopped: stepnf was interrupted", workdir=cwd)
            rc = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            raise SolverRunError(
                f"{what} timed out after {timeout:g} s: {' '.join(args)}", workdir=cwd, log_tail=log_tail(log)
            ) from None
        except BaseException:
            _kill_group(proc)
            raise
    seconds = time.perf_counter() - t0
    if rc != 0:
        raise SolverRunError(
            f"{what} exited with code {rc}: {' '.join(args)}", workdir=cwd, log_tail=log_tail(log)
        )
    return RunRecord(tuple(args), cwd, log, seconds)


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        proc.kill()
    proc.wait()


def require_files(workdir: str | Path, names: Sequence[str], *, log: str | Path | None = None,
                  what: str = "solver") -> list[Path]:
    """Paths of the expected output files; :class:`SolverRunError` naming the missing ones."""
    workdir = Path(workdir)
    paths = [workdir / n for n in names]
    missing = [p.name for p in paths if not p.is_file()]
    if missing:
        raise SolverRunError(
            f"{what} finished but did not write {missing}", workdir=workdir,
            log_tail=log_tail(log) if log is not None else "",
        )
    return paths


def missing_output(workdir: str | Path, message: str, *, log_name: str = "solver.log") -> SolverRunError:
    """A :class:`SolverRunError` for a missing field in an output, with the log tail."""
    workdir = Path(workdir)
    return SolverRunError(message, workdir=workdir, log_tail=log_tail(workdir / log_name))
