"""Work counters reported in every result (``counts`` in the JSON)."""
from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass
class Counters:
    """What a run asked of the solver and of the linear algebra.

    ``force_evaluations``: prescribed displacement fields sent to the solver.
    ``linear_solves``: right-hand sides solved with a factorisation, outside
    the eigen-solver. ``factorizations``: sparse (or dense) factorisations,
    the eigen-solver's included. ``eigensolver_solves``: solves made inside
    the eigen-solver's iterations.
    """

    force_evaluations: int = 0
    linear_solves: int = 0
    factorizations: int = 0
    eigensolver_solves: int = 0
    solver_runs: int = 0
    #: tangent stiffness matrices asked of the solver (STEP with method = "tangent")
    tangent_evaluations: int = 0
    #: wall-clock seconds spent factorising (all factorisations above)
    factorization_seconds: float = 0.0

    def to_dict(self) -> dict[str, int | float]:
        d = asdict(self)
        d["factorization_seconds"] = round(self.factorization_seconds, 4)
        return d
