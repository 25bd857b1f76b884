"""Progress reports on stderr: stage lines with timings, and a counter for long loops."""
from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from typing import Iterator, TextIO


class Progress:
    """Prints ``[stepnf] stage ... (1.23 s)`` lines; silent when ``enabled`` is False."""

    def __init__(self, enabled: bool = True, stream: TextIO | None = None):
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.timings: dict[str, float] = {}
        self._last_bar = 0.0

    def message(self, text: str) -> None:
        if self.enabled:
            print(f"[stepnf] {text}", file=self.stream, flush=True)

    @contextmanager
    def stage(self, key: str, text: str) -> Iterator[None]:
        t0 = time.perf_counter()
        self.message(f"{text} ...")
        finished = False
        try:
            yield
            finished = True
        finally:
            dt = time.perf_counter() - t0
            self.timings[key] = self.timings.get(key, 0.0) + dt
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
        print(f"[stepnf] {text} [{'#' * fill}{'.' * (width - fill)}] {done}/{total}", end=end,
              file=self.stream, flush=True)
