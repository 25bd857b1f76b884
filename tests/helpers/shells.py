"""Shell meshes the Kratos tests build (tests/solvers/kratos/)."""
from __future__ import annotations

import numpy as np


def square_plate(n: int, element: str, side: float = 1.0):
    """n x n quadrilaterals (dkq) or 2 n^2 triangles (dkt) of the square [0, side]^2 at z = 0, as a
    :class:`stepnf_kratos.ShellMesh` with the node set "edge" (the four sides)."""
    from stepnf_kratos import ShellMesh

    x = np.linspace(0.0, side, n + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    P = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    i = np.arange(len(P)).reshape(n + 1, n + 1)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    cells = np.column_stack([a, b, c, d]) if element == "dkq" else np.concatenate(
        [np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    edge = np.flatnonzero((X.ravel() == 0) | (X.ravel() == side) | (Y.ravel() == 0) | (Y.ravel() == side))
    return ShellMesh(P, cells, "quad" if element == "dkq" else "triangle", {"edge": edge})
