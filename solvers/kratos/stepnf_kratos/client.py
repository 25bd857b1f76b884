"""The parent's side of the Kratos worker process (:mod:`stepnf_kratos.worker`).

Kratos runs in a process of its own, started once per model and kept for its life: an abort, a
segmentation fault or a time-out there becomes a :class:`~stepnf.errors.SolverRunError` (one message with
the end of the worker's log, exit 3), never a crash of stepnf. The worker is started in a session of its
own (so a Ctrl-C at the terminal does not reach it) and registered with :mod:`stepnf.runtime.signals`
(a signal to stepnf kills it), like every external solver (:func:`stepnf.external.process.run_command`).
Threads: ``OMP_NUM_THREADS`` is 1 unless the caller or the environment sets it.
"""
from __future__ import annotations

import contextlib
import os
import pickle
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import weakref
from pathlib import Path
from typing import Any

from stepnf.errors import SolverRunError
from stepnf.external.process import log_tail
from stepnf.runtime.signals import deferred, track


class KratosWorker:
    """A running :mod:`stepnf_kratos.worker`; :meth:`call` sends one request and waits for its reply.

    ``threads``: ``OMP_NUM_THREADS`` of the worker (default: the environment's, else 1); ``timeout``:
    seconds one request may take before the worker is killed.
    """

    def __init__(self, *, threads: int | None = None, timeout: float | None = 3600.0):
        self.folder = Path(tempfile.mkdtemp(prefix="stepnf-kratos-"))
        self.log = self.folder / "kratos.log"
        self.timeout = timeout
        env = dict(os.environ)
        if threads is not None:
            env["OMP_NUM_THREADS"] = str(int(threads))
        else:
            env.setdefault("OMP_NUM_THREADS", "1")
        self._stack = contextlib.ExitStack()
        with open(self.log, "wb") as log, deferred():
            self.proc = subprocess.Popen([sys.executable, "-m", "stepnf_kratos.worker"], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=log, cwd=self.folder, env=env,
                                         start_new_session=True)
            self._stack.enter_context(track(self.proc))
        self._lock = threading.Lock()
        self._timed_out = False  # set by the time-out's kill (not by a kill from elsewhere)
        self._keep = {"folder": False}  # a failure keeps the folder its message names (the log)
        self._finalizer = weakref.finalize(self, _shutdown, self.proc, self._stack, self.folder, self._keep)

    def call(self, command: str, payload: Any = None) -> Any:
        """The worker's result for ``command``; a :class:`SolverRunError` if it failed, died or timed out."""
        with self._lock:
            if self.proc.poll() is not None:
                raise self._died(command)
            timer = None
            if self.timeout is not None:
                timer = threading.Timer(self.timeout, self._kill)
                timer.start()
            try:
                pickle.dump((command, payload), self.proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
                self.proc.stdin.flush()
                status, result = pickle.load(self.proc.stdout)
            except (EOFError, BrokenPipeError, pickle.UnpicklingError, OSError):
                self._keep["folder"] = True
                raise self._died(command) from None
            finally:
                if timer is not None:
                    timer.cancel()
        if status != "ok":
            self._keep["folder"] = True
            raise SolverRunError(f"Kratos failed ({command}): {result}", workdir=self.folder,
                                 log_tail=log_tail(self.log, 8))
        return result

    def _kill(self) -> None:
        self._timed_out = True
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)

    def _died(self, command: str) -> SolverRunError:
        rc = self.proc.wait()
        how = f"killed by {signal.Signals(-rc).name}" if rc < 0 and -rc in signal.valid_signals() else f"exit code {rc}"
        if self._timed_out:
            how += f" (the time-out of {self.timeout:g} s per request)"
        return SolverRunError(f"the Kratos worker process died during '{command}' ({how})", workdir=self.folder,
                              log_tail=log_tail(self.log, 8))

    def close(self) -> None:
        """Stop the worker and remove its folder (kept after a failure: the message names it). Idempotent (also
        run when the object is collected, or at exit)."""
        self._finalizer()

    def __enter__(self) -> "KratosWorker":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _shutdown(proc: subprocess.Popen, stack: contextlib.ExitStack, folder: Path, keep: dict) -> None:
    """Ask the worker to quit (killed after 10 s), close its pipes, unregister it, remove its folder unless
    ``keep["folder"]`` (a failed request: its message names the folder and its log)."""
    if proc.poll() is None:
        with contextlib.suppress(OSError, ValueError):
            pickle.dump(("quit", None), proc.stdin)
            proc.stdin.close()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    for stream in (proc.stdin, proc.stdout):
        with contextlib.suppress(OSError, ValueError):
            stream.close()
    stack.close()
    if not keep["folder"]:
        shutil.rmtree(folder, ignore_errors=True)
