"""Progress reports on stderr: stage lines with timings, and a counter for long loops.

Each stage also records the process's memory at its end (:func:`memory_now`): the
peak resident set size reached so far and the current one, in MB (MiB, 2**20
bytes). Under MPI every rank measures its own process.
"""
from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager
from typing import Iterator, TextIO

from stepnf.runtime.printable import printable


def peak_rss_mb() -> float | None:
    """Peak resident memory of this process so far, in MiB (``getrusage``); None where unavailable."""
    try:
        import resource
    except ImportError:  # not on Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    per_mib = 2**20 if sys.platform == "darwin" else 1024  # bytes on macOS, KiB on Linux and the BSDs
    return peak / per_mib


def current_rss_mb() -> float | None:
    """Current resident memory of this process, in MiB (``/proc/self/statm``); None where unavailable."""
    try:
        with open("/proc/self/statm") as f:
            resident_pages = int(f.read().split()[1])
        return resident_pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def memory_now() -> dict[str, float | None]:
    """``{"peak_rss_mb": ..., "rss_mb": ...}`` of this process now, in MiB, rounded to 0.1 (None: unknown).

    The peak is never below the current value (the kernel updates its high-water mark lazily).
    """
    peak, rss = peak_rss_mb(), current_rss_mb()
    if peak is not None and rss is not None:
        peak = max(peak, rss)
    return {"peak_rss_mb": None if peak is None else round(peak, 1),
            "rss_mb": None if rss is None else round(rss, 1)}


def thousands(n: int) -> str:
    """``73 000``: an integer with its thousands separated by spaces (for counts in progress lines)."""
    return f"{int(n):,}".replace(",", " ")


class Progress:
    """Prints ``[stepnf] stage ... (1.23 s)`` lines; silent when ``enabled`` is False.

    ``timings``: stage key -> wall-clock seconds (summed over the stage's entries), in the order
    the stages were first entered. ``memory``: stage key -> :func:`memory_now` at the stage's
    last end, in the order of those ends (so the peaks never decrease along the dict).
    """

    def __init__(self, enabled: bool = True, stream: TextIO | None = None):
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.timings: dict[str, float] = {}
        self.memory: dict[str, dict[str, float | None]] = {}
        self._last_bar = 0.0

    def message(self, text: str) -> None:
        if self.enabled:
            print(f"[stepnf] {printable(text)}", file=self.stream, flush=True)

    @contextmanager
    def stage(self, key: str, text: str) -> Iterator[None]:
        t0 = time.perf_counter()
        self.message(f"{text} ...")
        finished = False
        try:
            yield
            finished = True
        except MemoryError as exc:  # the command line's message names the innermost stage
            try:
                if getattr(exc, "stepnf_stage", None) is None:
                    exc.stepnf_stage = text
            except MemoryError:  # no room even for the note: the error goes on without it
                pass
            raise
        finally:
            dt = time.perf_counter() - t0
            self.timings[key] = self.timings.get(key, 0.0) + dt
            self.memory.pop(key, None)  # re-inserted: the dict follows the order of the stages' ends
            self.memory[key] = memory_now()
            # a stage that raised is not "done": the error message follows
            self.message(f"{text}: {'done' if finished else 'stopped'} in {dt:.2f} s")

    def bar(self, done: int, total: int, text: str = "") -> None:
        """A one-line progress bar, redrawn at most every 0.5 s."""
        if not self.enabled:
            return
        now = time.perf_counter()
        if done < total and now - self._last_bar < 0.5:
            return
        self._last_bar = now
        width = 30
        fill = int(width * done / max(total, 1))
        end = "\n" if done >= total else "\r"
        print(f"[stepnf] {printable(text)} [{'#' * fill}{'.' * (width - fill)}] {done}/{total}", end=end,
              file=self.stream, flush=True)
