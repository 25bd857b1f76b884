"""Writing CalculiX input blocks: nodes, elements, prescribed displacements.

ccx reads at most 20 characters per number and silently truncates longer
ones, so every real is written with ``%.13e`` (at most 20 characters:
sign, 1 digit, point, 13 digits, ``e``, sign, 3 exponent digits), which keeps
14 significant digits.

Node order: VTK's ``hexahedron20`` (meshio's, :mod:`stepnf.geometry`) and
CalculiX's ``C3D20`` are the same (corners 1-8, then the mid-nodes of the
bottom edges 12 23 34 41, of the top edges 56 67 78 85, of the vertical
edges 15 26 37 48), so :data:`C3D20_FROM_VTK` is the identity; it is kept
explicit so that another element type can add its own permutation.
"""
from __future__ import annotations

from typing import Iterable

import numpy as np

#: Real-number format accepted by ccx without truncation (<= 20 characters).
REAL = "%.13e"

#: Column ``k`` of a C3D20 connectivity is column ``C3D20_FROM_VTK[k]`` of a VTK hexahedron20 one.
C3D20_FROM_VTK = np.arange(20)

#: meshio cell type -> (CalculiX element type, permutation from VTK order).
CCX_ELEMENTS = {"hexahedron20": ("C3D20", C3D20_FROM_VTK)}

#: Largest number of entries on one line of an ``*ELEMENT`` block (ccx continues on the next line).
_PER_LINE = 16


def format_nodes(ids: np.ndarray, points: np.ndarray, nset: str = "NALL") -> str:
    """``*NODE, NSET=nset`` block: one ``id, x, y, z`` line per node."""
    ids = np.asarray(ids, dtype=np.int64)
    points = np.asarray(points, dtype=float)
    rows = np.empty((len(ids), 4), dtype=object)
    rows[:, 0] = ids
    rows[:, 1:] = points
    body = ("%d, " + ", ".join([REAL] * 3) + "\n") * len(ids)
    return f"*NODE, NSET={nset}\n" + body % tuple(rows.ravel())


def format_elements(ccx_type: str, ids: np.ndarray, conn: np.ndarray, elset: str = "EALL") -> str:
    """``*ELEMENT, TYPE=ccx_type, ELSET=elset`` block; ``conn`` holds node ids in ccx order."""
    ids = np.asarray(ids, dtype=np.int64)
    conn = np.asarray(conn, dtype=np.int64)
    full = np.column_stack([ids, conn])
    lines = []
    k = full.shape[1]
    for row in full:
        parts = [", ".join(str(v) for v in row[i:i + _PER_LINE]) for i in range(0, k, _PER_LINE)]
        lines.append(",\n".join(parts))
    return f"*ELEMENT, TYPE={ccx_type}, ELSET={elset}\n" + "\n".join(lines) + "\n"


def format_boundary(ids: np.ndarray, U: np.ndarray) -> str:
    """``*BOUNDARY`` data lines ``node, dof, dof, value`` prescribing every dof of every node.

    ``U`` (n_nodes, d) holds the displacement of each node in directions 1..d.
    """
    ids = np.asarray(ids, dtype=np.int64)
    U = np.asarray(U, dtype=float)
    n, d = U.shape
    rows = np.empty((n * d, 4), dtype=object)
    rows[:, 0] = np.repeat(ids, d)
    rows[:, 1] = np.tile(np.arange(1, d + 1), n)
    rows[:, 2] = rows[:, 1]
    rows[:, 3] = U.ravel()
    return (("%d, %d, %d, " + REAL + "\n") * (n * d) % tuple(rows.ravel())).rstrip("\n")


def mesh_text(ids: np.ndarray, points: np.ndarray, element_blocks: Iterable[tuple[str, np.ndarray, np.ndarray]]) -> str:
    """The whole mesh file: nodes (set NALL) then element blocks (set EALL)."""
    out = [format_nodes(ids, points)]
    out += [format_elements(t, eids, conn) for t, eids, conn in element_blocks]
    return "".join(out)
