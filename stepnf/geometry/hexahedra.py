"""Quadratic hexahedra in VTK node order: reference nodes and shape functions (pure numpy).

Reference cube ``[0, 1]^3``. Node order (VTK / meshio ``hexahedron27``):

* 0-7: corners ``(0,0,0) (1,0,0) (1,1,0) (0,1,0) (0,0,1) (1,0,1) (1,1,1) (0,1,1)``;
* 8-19: edge mid-nodes: bottom ``01 12 23 30``, top ``45 56 67 74``, vertical ``04 15 26 37``;
* 20-25: face centres ``-x +x -y +y -z +z``; 26: body centre.

``hexahedron20`` is the first 20 nodes (serendipity element).
"""
from __future__ import annotations

import numpy as np

#: Reference coordinates of the 27 nodes, VTK order.
HEX27_NODES = np.array([
    [0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1],
    [.5, 0, 0], [1, .5, 0], [.5, 1, 0], [0, .5, 0],
    [.5, 0, 1], [1, .5, 1], [.5, 1, 1], [0, .5, 1],
    [0, 0, .5], [1, 0, .5], [1, 1, .5], [0, 1, .5],
    [0, .5, .5], [1, .5, .5], [.5, 0, .5], [.5, 1, .5], [.5, .5, 0], [.5, .5, 1],
    [.5, .5, .5],
], dtype=float)


def _lagrange_1d(t: np.ndarray, node: float) -> tuple[np.ndarray, np.ndarray]:
    """Quadratic Lagrange polynomial on nodes {0, 1/2, 1} equal to 1 at ``node``, and its derivative."""
    if node == 0.0:
        return 2 * (t - .5) * (t - 1), 4 * t - 3
    if node == 1.0:
        return 2 * t * (t - .5), 4 * t - 1
    return 4 * t * (1 - t), 4 - 8 * t


def shape_functions(xi: np.ndarray, n_nodes: int = 27) -> tuple[np.ndarray, np.ndarray]:
    """Shape functions ``N (q, n)`` and reference gradients ``dN (q, n, 3)`` at points ``xi (q, 3)``."""
    xi = np.atleast_2d(np.asarray(xi, dtype=float))
    q = len(xi)
    if n_nodes == 27:
        N = np.ones((q, 27))
        dN = np.ones((q, 27, 3))
        for a, node in enumerate(HEX27_NODES):
            vals = [_lagrange_1d(xi[:, d], node[d]) for d in range(3)]
            N[:, a] = vals[0][0] * vals[1][0] * vals[2][0]
            for d in range(3):
                dN[:, a, d] = np.prod([vals[e][1] if e == d else vals[e][0] for e in range(3)], axis=0)
        return N, dN
    if n_nodes == 20:
        return _serendipity20(xi)
    if n_nodes == 8:
        return _trilinear8(xi)
    raise ValueError(f"Unknown hexahedron with {n_nodes} nodes. Pick one of [8, 20, 27]")


def _trilinear8(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The linear hexahedron (corners ``HEX27_NODES[:8]``, VTK order)."""
    q = len(xi)
    N = np.empty((q, 8))
    dN = np.empty((q, 8, 3))
    for a, c in enumerate(HEX27_NODES[:8]):
        f = [xi[:, d] if c[d] else 1 - xi[:, d] for d in range(3)]
        df = [1.0 if c[d] else -1.0 for d in range(3)]
        N[:, a] = f[0] * f[1] * f[2]
        for d in range(3):
            dN[:, a, d] = df[d] * np.prod([f[e] for e in range(3) if e != d], axis=0)
    return N, dN


def _serendipity20(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = 2 * xi - 1  # to [-1, 1]
    q = len(s)
    N = np.empty((q, 20))
    dN = np.empty((q, 20, 3))
    for a, node in enumerate(HEX27_NODES[:20]):
        c = 2 * node - 1
        if a < 8:
            f = [(1 + c[d] * s[:, d]) for d in range(3)]
            g = c[0] * s[:, 0] + c[1] * s[:, 1] + c[2] * s[:, 2] - 2
            N[:, a] = f[0] * f[1] * f[2] * g / 8
            for d in range(3):
                others = np.prod([f[e] for e in range(3) if e != d], axis=0)
                dN[:, a, d] = c[d] * others * (g + f[d]) / 8
        else:
            zero = int(np.nonzero(c == 0)[0][0])
            f = [(1 - s[:, d] ** 2) if d == zero else (1 + c[d] * s[:, d]) for d in range(3)]
            df = [(-2 * s[:, d]) if d == zero else np.full(q, c[d]) for d in range(3)]
            N[:, a] = f[0] * f[1] * f[2] / 4
            for d in range(3):
                dN[:, a, d] = np.prod([df[e] if e == d else f[e] for e in range(3)], axis=0) / 4
    return N, 2 * dN  # chain rule d/dxi = 2 d/ds


def gauss_points(order: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Tensor Gauss-Legendre rule on ``[0, 1]^3`` with ``order`` points per direction."""
    t, w = np.polynomial.legendre.leggauss(order)
    t, w = (t + 1) / 2, w / 2
    X = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
    W = np.einsum("i,j,k->ijk", w, w, w).ravel()
    return X, W


def jacobians(points: np.ndarray, cells: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Jacobian determinants ``(E, q)`` of every cell at reference points ``xi (q, 3)``."""
    return determinants(points, cells, shape_functions(xi, cells.shape[1])[1])


def determinants(points: np.ndarray, cells: np.ndarray, dN: np.ndarray) -> np.ndarray:
    """``det J`` (E, q) of every cell from the reference gradients ``dN`` (q, n, 3) of any element."""
    return np.linalg.det(np.einsum("enk,qnd->eqkd", points[cells], dN))


def volume(points: np.ndarray, cells: np.ndarray, order: int = 4) -> float:
    """Volume of a quadratic hexahedral mesh by Gauss quadrature."""
    xi, w = gauss_points(order)
    return float(np.sum(jacobians(points, cells, xi) @ w))
