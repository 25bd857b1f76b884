"""The progress line of ``stepnf verify`` (:class:`OrbitClock`): which orbit, k of n, the time elapsed and left."""
from __future__ import annotations

import time
from typing import Callable


class OrbitClock:
    """The progress line of ``verify``: before each orbit, which one (mode, amplitude), ``k of n``, the
    time elapsed since the clock started and an estimate of the time left (the mean time of the orbits
    done times the orbits left; none before the first has finished); at the end, the total.
    ``say(text)``: where the lines go (stepnf.cli.main: stderr)."""

    def __init__(self, total: int, say: Callable[[str], None]):
        self.total, self.say = int(total), say
        self.done, self.spent = 0, 0.0
        self.t0 = time.perf_counter()
        self._t = None

    def start(self, what: str) -> None:
        self._t = time.perf_counter()
        elapsed = self._t - self.t0
        left = (f"about {_seconds(self.spent / self.done * (self.total - self.done))} left" if self.done
                else "estimate after the first orbit")
        self.say(f"verify: {what}: orbit {self.done + 1} of {self.total} (elapsed {_seconds(elapsed)}, {left})")

    def stop(self) -> None:
        self.spent += time.perf_counter() - self._t
        self.done += 1

    def finish(self) -> None:
        self.say(f"verify: {self.done} orbit{'s' if self.done != 1 else ''} in {_seconds(self.spent)} "
                 f"(elapsed {_seconds(time.perf_counter() - self.t0)})")


def _seconds(t: float) -> str:
    return f"{t:.1f} s" if t < 120 else f"{int(t // 60)} min {int(t % 60):02d} s"
