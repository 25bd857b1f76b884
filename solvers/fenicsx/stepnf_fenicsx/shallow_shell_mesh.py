"""Quadratic-triangle (6-node) meshes of a disk, built with numpy/scipy only (no gmsh, no dolfinx).

The plan view of a free-edge shallow shell: the disk ``x^2 + y^2 <= a^2``.
Vertices lie on ``n_rings`` concentric circles (ring ``i`` at radius
``a * rho_i``, ``6 i`` equally spaced vertices, the centre is a vertex), joined
by scipy's Delaunay triangulation (all vertices are on the convex hull or
inside it, so the triangulation covers the inscribed polygon). Every edge gets
a mid-node; mid-nodes of boundary edges are moved radially onto the circle,
so boundary cells are curved (isoparametric P2 geometry) and the disk is
represented with an O(h^3) geometric error instead of the polygon's O(h^2).

Radii: ``rho_i = i / n`` for ``grading = 1``; ``grading < 1`` makes the
outer rings thinner (``rho_i = 1 - (1 - i/n)**p`` blended, see
:func:`ring_radii`), useful since free-edge modes peak at the edge.

Cells are counter-clockwise, in VTK/meshio ``triangle6`` node order:
vertices 0, 1, 2, then the mid-nodes of edges (0,1), (1,2), (2,0).
Units: those of ``a``.
"""
from __future__ import annotations

import math

import numpy as np


def ring_radii(n_rings: int, grading: float = 1.0) -> np.ndarray:
    """Ring radii on the unit disk, ``0 = rho_0 < ... < rho_n = 1``.

    ``grading`` in (0, 1]: ratio of the outermost ring spacing to the uniform
    spacing ``1/n`` (1: uniform). Spacings vary linearly from the centre to the edge.
    """
    if n_rings < 1:
        raise ValueError(f"n_rings must be >= 1, got {n_rings}")
    if not 0.0 < grading <= 1.0:
        raise ValueError(f"grading must lie in (0, 1], got {grading}")
    # spacings d_i = c (1 + s (i - 1)/(n - 1)), i = 1..n, with d_n / d_mean = grading
    n = int(n_rings)
    if n == 1 or grading == 1.0:
        return np.linspace(0.0, 1.0, n + 1)
    i = np.arange(n)
    # choose d_i ~ (1 - t i), t so that d_{n-1} / mean(d) = grading
    t = 2.0 * (1.0 - grading) / ((n - 1) * (2.0 - grading))  # last / mean = grading
    d = 1.0 - t * i
    return np.concatenate([[0.0], np.cumsum(d) / d.sum()])


def disk_triangle6(a: float, n_rings: int, grading: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Points (P, 2) and counter-clockwise ``triangle6`` cells (E, 6) of the disk of radius ``a``."""
    from scipy.spatial import Delaunay

    if not a > 0:
        raise ValueError(f"disk radius must be > 0, got {a}")
    rho = ring_radii(int(n_rings), grading)
    pts = [np.zeros((1, 2))]
    for i in range(1, len(rho)):
        m = 6 * i
        th = 2.0 * math.pi * (np.arange(m) + 0.5 * (i % 2)) / m
        pts.append(rho[i] * np.column_stack([np.cos(th), np.sin(th)]))
    V = np.concatenate(pts)
    n_outer = 6 * (len(rho) - 1)
    on_circle = np.zeros(len(V), dtype=bool)
    on_circle[len(V) - n_outer:] = True
    tri = Delaunay(V).simplices.astype(np.int64)
    # counter-clockwise
    p0, p1, p2 = V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]]
    area2 = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0])
    tri = tri[area2 > 1e-14]  # drop degenerate slivers (none expected)
    cw = area2[area2 > 1e-14] < 0
    tri[cw] = tri[cw][:, [0, 2, 1]]
    # mid-nodes
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    mids = 0.5 * (V[uniq[:, 0]] + V[uniq[:, 1]])
    # boundary edges: both ends on the circle and used by one cell only
    count = np.bincount(inv.ravel(), minlength=len(uniq))
    bnd = (count == 1) & on_circle[uniq[:, 0]] & on_circle[uniq[:, 1]]
    mids[bnd] /= np.linalg.norm(mids[bnd], axis=1, keepdims=True)
    mid_id = len(V) + inv.ravel().reshape(3, -1).T  # (E, 3): edges (0,1), (1,2), (2,0)
    points = np.concatenate([V, mids]) * float(a)
    cells = np.column_stack([tri, mid_id])
    return points, cells


def triangle6_area(points: np.ndarray, cells: np.ndarray) -> float:
    """Exact area of a ``triangle6`` mesh (6-point rule, exact for the quadratic map's Jacobian)."""
    # Jacobian determinant of a P2 map is quadratic: a degree-2 rule integrates it exactly
    qp = np.array([[1 / 6, 1 / 6], [2 / 3, 1 / 6], [1 / 6, 2 / 3]])
    qw = np.full(3, 1 / 6)
    X = points[cells]  # (E, 6, 2)
    total = 0.0
    for (s, t), wq in zip(qp, qw):
        l0 = 1 - s - t
        dNs = np.array([-(4 * l0 - 1), 4 * s - 1, 0.0, 4 * (l0 - s), 4 * t, -4 * t])
        dNt = np.array([-(4 * l0 - 1), 0.0, 4 * t - 1, -4 * s, 4 * s, 4 * (l0 - t)])
        Js = np.einsum("k,ekd->ed", dNs, X)
        Jt = np.einsum("k,ekd->ed", dNt, X)
        total += wq * np.sum(Js[:, 0] * Jt[:, 1] - Js[:, 1] * Jt[:, 0])
    return float(total)
