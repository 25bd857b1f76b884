"""The output mesh of the FEniCSx solid adapters (for :mod:`stepnf.io.fields`): the input volume mesh itself.

The adapters keep the mesh they were built from (:class:`stepnf.geometry.VolumeMesh`:
points and one block of cells in meshio/VTK node order), so no DOLFINx call is
needed: with the default degree 2 on a quadratic mesh (``hexahedron27``,
``tetra10``) every dof node is a mesh point; on a linear mesh the mid-edge
dof nodes are not, and the fields are written at the vertices only (see
:mod:`stepnf.io.fields`). Under MPI every rank holds the whole input mesh and
the gathered dof coordinates, so the same mesh serves the distributed adapter.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from stepnf.plugin import OutputMesh


def volume_output_mesh(mesh: Any) -> OutputMesh:
    """``mesh`` (``points`` (N, 3), ``cells`` (E, k) 0-based in VTK order, meshio ``cell_type``) as an
    :class:`~stepnf.io.fields.OutputMesh`."""
    return OutputMesh(np.asarray(mesh.points, dtype=float), [(str(mesh.cell_type), np.asarray(mesh.cells, np.int64))])
