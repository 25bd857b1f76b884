"""Sanity checks of user meshes: coincident nodes and tangled elements, reported before any solve.

A mesh with duplicate nodes (a seam meshed twice, parts not merged) has extra
zero-energy motions that surface much later as "negative eigenvalues" or, worse,
as plausible but wrong modes; a tangled element (its Jacobian changes sign
inside it) is integrated with |det J| by most codes and gives wrong stiffness
without any error. Both are caught here, naming what was found.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .hexahedra import gauss_points, jacobians


def duplicate_nodes(points: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """Pairs (k, 2) of node indices closer than ``rtol`` times the mesh size (bounding-box diagonal)."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2:
        return np.zeros((0, 2), dtype=int)
    diag = float(np.linalg.norm(np.ptp(pts, axis=0)))
    pairs = cKDTree(pts).query_pairs(rtol * max(diag, 1e-300), output_type="ndarray")
    return np.asarray(pairs, dtype=int).reshape(-1, 2)


def tangled_cells(points: np.ndarray, cells: np.ndarray, n_nodes: int) -> np.ndarray:
    """Indices of hexahedra (20 or 27 nodes, VTK order) whose Jacobian determinant changes sign.

    Sampled at the 4 x 4 x 4 Gauss points and the 27 nodes of the reference
    cell. A uniformly negative determinant (mirrored node order) is a valid
    cell and is not reported.
    """
    from .hexahedra import HEX27_NODES

    xi_g, _ = gauss_points(4)
    xi = np.vstack([xi_g, HEX27_NODES])
    det = jacobians(np.asarray(points, dtype=float), np.asarray(cells, dtype=int), xi)  # (E, q)
    scale = np.max(np.abs(det), axis=1, keepdims=True)
    pos = (det > 1e-12 * scale).any(axis=1)
    neg = (det < -1e-12 * scale).any(axis=1)
    return np.nonzero(pos & neg)[0]
