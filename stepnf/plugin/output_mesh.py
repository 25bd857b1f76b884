"""The mesh an adapter offers for the field files (``output_mesh()`` of :class:`~stepnf.plugin.adapter.SolverAdapter`).

What stepnf writes on it is :mod:`stepnf.io.fields`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OutputMesh:
    """A mesh to write fields on: ``points`` (P, 3) in model length units and ``cells``, meshio cell
    blocks ``[(meshio type, connectivity (E, k) of 0-based point indices, VTK node order)]``."""

    points: np.ndarray
    cells: list[tuple[str, np.ndarray]]

    @property
    def n_points(self) -> int:
        return int(len(self.points))
