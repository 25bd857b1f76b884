"""Termination signals and the solver process groups they must end.

An external solver runs in a process group of its own (:func:`stepnf.external.process.run_command`
starts it with ``start_new_session``), so a signal sent to stepnf alone, or a Ctrl-C at the
terminal, does not reach it. Every such group is registered here while it runs (:func:`track`).

:func:`handled` (the command line runs every command in it) makes SIGINT, SIGTERM and SIGHUP alike:
the handler kills every registered group (SIGKILL to the whole group: the solver and what it started), then
raises :class:`Interrupted` (a ``KeyboardInterrupt``) in the main thread. The run unwinds as after
a Ctrl-C: work folders are removed per their keep policy (an interruption is not a solver error,
so ``keep = "on_error"`` removes them), a sweep's local Dask cluster is closed (its workers' solver
groups killed first, :func:`stop_children`), the checkpoints already written
stay (a rerun resumes from them), and the command exits with 128 + the signal's number (130
SIGINT, 143 SIGTERM, 129 SIGHUP). A second signal while that clean-up runs ends the process at
once (after killing the groups again) with the same code. A signal ignored when stepnf started
(``nohup``: SIGHUP) stays ignored.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from contextlib import contextmanager
from typing import Iterator

#: The signals handled like Ctrl-C.
HANDLED = ("SIGINT", "SIGTERM", "SIGHUP")

_lock = threading.RLock()  # re-entrant: the handler runs in the main thread, maybe inside track()
_groups: dict[int, subprocess.Popen] = {}  # process-group id -> its leader
_received: int | None = None  # the first signal received (its number), None before
_deferring = 0  # > 0 while the main thread starts a solver (deferred())


class Interrupted(KeyboardInterrupt):
    """The run was stopped by the signal ``signum`` (a ``KeyboardInterrupt``, so it unwinds like Ctrl-C)."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(signal_name(signum))

    @property
    def exit_code(self) -> int:
        """128 + the signal's number, the shell's convention (130 SIGINT, 143 SIGTERM, 129 SIGHUP)."""
        return 128 + self.signum


def signal_name(signum: int) -> str:
    """``"SIGTERM"`` for 15, ``"signal 42"`` for a number without a name."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def interruption(exc: KeyboardInterrupt) -> int:
    """Say on stderr that the run was interrupted (by which signal) and return the exit code: 128 + the signal
    (130 for a plain ``KeyboardInterrupt``, a Ctrl-C outside :func:`handled`)."""
    by = f" by {exc}" if isinstance(exc, Interrupted) else ""
    print(f"stepnf: interrupted{by}; results already written are intact (a rerun resumes from the checkpoints)",
          file=sys.stderr)
    return exc.exit_code if isinstance(exc, Interrupted) else 128 + signal.SIGINT


def received() -> int | None:
    """The number of the first handled signal received so far (None: none)."""
    return _received


@contextmanager
def track(proc: subprocess.Popen) -> Iterator[None]:
    """Register ``proc`` (the leader of a new process group) while the block runs."""
    with _lock:
        _groups[proc.pid] = proc
    try:
        yield
    finally:
        with _lock:
            _groups.pop(proc.pid, None)


@contextmanager
def deferred() -> Iterator[None]:
    """Hold back the :class:`Interrupted` of a handled signal while the main thread runs the block: a solver
    starting (:func:`stepnf.external.process.run_command`: from ``Popen`` to :func:`track`; raised in
    between, it would leave the child running unregistered in its own session). The handler still records
    the signal (:func:`received`) and kills the groups registered so far; the caller checks
    :func:`received` once the child is tracked and stops (a block that raises instead, the solver not
    starting, raises the :class:`Interrupted`). Not ``signal.pthread_sigmask``: the child would inherit the
    blocked mask and start deaf to SIGINT, SIGTERM and SIGHUP. In another thread the handler never runs:
    the block runs as it is."""
    global _deferring
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = _received
    _deferring += 1
    try:
        yield
    except BaseException as exc:
        if before is None and _received is not None and not isinstance(exc, KeyboardInterrupt):
            raise Interrupted(_received) from exc
        raise
    finally:
        _deferring -= 1


def kill_groups() -> int:
    """SIGKILL every registered process group (the solver and its own children); the number signalled."""
    with _lock:
        procs = list(_groups.values())
    for proc in procs:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            try:
                proc.kill()
            except OSError:
                pass
    return len(procs)


def stop_children(signum: int) -> int:
    """Act as if ``signum`` had been received, without raising: kill every registered group (the
    :class:`~stepnf.external.process.WorkFolder` of each then goes, as on an interruption). For a process that
    got no signal itself: a sweep's Dask workers, whose client was interrupted (:func:`stepnf.sweep.dask_sweep.run_sweep`);
    they are closed right after. Returns the number of groups signalled."""
    global _received
    if _received is None:
        _received = signum
    return kill_groups()


def _handler(signum: int, frame: object) -> None:
    global _received
    kill_groups()
    if _received is not None and not _deferring:  # a second signal during the clean-up: stop now
        os._exit(128 + _received)
    if _received is None:
        _received = signum
    if _deferring:  # a solver is starting: run_command stops once it is tracked (deferred())
        return
    raise Interrupted(signum)


@contextmanager
def handled() -> Iterator[None]:
    """Handle :data:`HANDLED` as the module docstring says while the block runs (the previous handlers
    are put back after it). Only the main thread can set handlers: elsewhere the block runs as it is."""
    global _received
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _received = None
    previous = {}
    for name in HANDLED:
        sig = getattr(signal, name, None)
        if sig is None or signal.getsignal(sig) == signal.SIG_IGN:
            continue
        previous[sig] = signal.signal(sig, _handler)
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, signal.SIG_DFL if old is None else old)  # None: a handler set outside Python
        _received = None
