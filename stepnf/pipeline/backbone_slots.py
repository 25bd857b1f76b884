"""Where the backbone's shifted factorisations live on a large model: one slot per parity of the harmonic.

The DPIM of a master solves ``K - (m w)^2 M`` for the harmonics ``m = p, p - 2, ...`` of each order
``p``: harmonic ``m`` at orders ``m, m + 2, ..., N``, and consecutive orders have opposite parities.
With one live factorisation (one slot), every use of a shift above the computed spectrum
factorises again (the order in between took the slot). With two slots, one for the even harmonics
and one for the odd, and the shift a slot holds solved first in its order
(:meth:`stepnf.dpim.solves.ShiftedSolves.solve_many`), order ``p + 2`` starts with the shift order
``p`` ended with: for a master whose harmonics 2..7 all lie above the spectrum, order 7 costs 8
factorisations instead of 12 (the fewest two slots allow), for one live factorisation more.

Slot 0 is the run's own (``FullOrderContext.slot``, shared with DNF); slot 1 is a
:class:`~stepnf.linalg.shifted.Slot` of the backbone stage: a second :class:`~stepnf.linalg.shifted.ShiftedFactorizer`
instance (its ``refactor``: MUMPS's analysis kept across shifts), or the adapter's factorisations, one
at a time.
"""
from __future__ import annotations

import numpy as np


class ParitySlots:
    """A ``factory(sigma, label)`` for :class:`~stepnf.dpim.solves.ShiftedSolves` of the master at ``omega``
    (rad/s): harmonic ``m = sqrt(sigma) / omega`` goes to ``slots[m % 2]`` (module docstring), each a
    :class:`~stepnf.linalg.shifted.Slot`."""

    def __init__(self, omega: float, slots: tuple):
        self.omega, self.slots = float(omega), slots

    def slot(self, sigma: float):
        return self.slots[int(round(np.sqrt(sigma) / self.omega)) % 2]

    def __call__(self, sigma: float, label: str) -> "SlotSolve":
        return SlotSolve(self.slot(sigma), sigma, label)

    def holds(self, sigma: float) -> bool:
        """Whether ``sigma``'s slot holds its factorisation now (solving it costs no factorisation)."""
        return self.slot(sigma).holds(sigma)


class SlotSolve:
    """The solve of one shift through a slot (the factorisation made again when the slot moved on)."""

    def __init__(self, slot, sigma: float, label: str):
        self.slot, self.sigma, self.label = slot, sigma, label

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self.slot.factorization(self.sigma, self.label).solve(b)

    def release(self) -> None:
        self.slot.release()
