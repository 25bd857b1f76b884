"""The output mesh of the CalculiX adapter (for :mod:`stepnf.io.fields`): the nodes and elements ccx runs.

Each ``C3D*`` element block becomes a meshio cell block of the same node order
(:data:`stepnf.geometry.inp.MESHIO_TYPES`: CalculiX's solid elements number their nodes
as VTK does), with node ids turned into 0-based positions in ``points``. The
dofs are the nodes' translations (dof ``3 i + d``), so every dof lies on a
point.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from stepnf.plugin import OutputMesh

from stepnf.geometry.inp import MESHIO_TYPES


def deck_output_mesh(node_ids: np.ndarray, points: np.ndarray,
                     blocks: Sequence[tuple[str, np.ndarray, np.ndarray]]) -> OutputMesh:
    """``points`` (N, 3) of the nodes ``node_ids`` (N,) and the element ``blocks``
    ``[(ccx type, element ids, connectivity in node ids)]`` as an :class:`~stepnf.io.fields.OutputMesh`
    (blocks of the same meshio type joined)."""
    ids = np.asarray(node_ids, dtype=np.int64)
    pos = np.full(int(ids.max()) + 1, -1, dtype=np.int64)
    pos[ids] = np.arange(len(ids))
    cells: dict[str, list[np.ndarray]] = {}
    for ccx_type, _, conn in blocks:
        cells.setdefault(MESHIO_TYPES[ccx_type.upper()], []).append(pos[np.asarray(conn, dtype=np.int64)])
    return OutputMesh(np.asarray(points, dtype=float), [(t, np.concatenate(c)) for t, c in cells.items()])
