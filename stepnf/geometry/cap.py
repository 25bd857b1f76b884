"""Free-edge shallow spherical caps (and the flat plate) meshed with curved quadratic hexahedra.

Geometry and conventions
------------------------
* Plan view: a disk of radius ``a`` (the *projected* outer radius of the cap),
  meshed by a structured O-grid ("butterfly"): a square core of ``n_core x
  n_core`` quadrilaterals (half-width ``core * a``) and four ring blocks of
  ``n_core x n_ring`` quadrilaterals joining the core to the circle, in equal
  radial steps or (``grading`` > 1) steps shrinking geometrically towards the
  circle, for a held rim (:mod:`.rim`).
* Mid-surface: the sphere of radius ``R`` centred at ``(0, 0, -R)``, i.e. a
  dome whose apex is the origin and which curves **downwards**:
  ``z_mid(r) = sqrt(R^2 - r^2) - R <= 0`` (sag ``R - sqrt(R^2 - a^2)`` at the
  edge). A plan-view point ``(x, y)`` goes to the sphere point above it.
* Thickness: every mid-surface point is moved along the outward unit normal
  ``n = (X - C) / R`` (``n = e_z`` at the apex) by ``zeta`` in ``[-h/2, h/2]``.
  The solid is therefore exactly the part of the spherical shell
  ``R - h/2 <= |X - C| <= R + h/2`` inside the cone of half-angle
  ``asin(a / R)``; its edge face is conical. ``R = inf`` gives the flat plate
  ``x^2 + y^2 <= a^2, |z| <= h/2``.
* Elements: every node (corners, edge mid-nodes, face and body centres) is
  placed on the exact map, so the elements are curved (isoparametric
  quadratic geometry). Node order is VTK's (see :mod:`.hexahedra`); every
  element has a positive Jacobian with its reference ``zeta`` axis along the
  outward normal.

Units are those of ``a``, ``R`` and ``h`` (any consistent length unit).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stepnf.geometry.hexahedra import HEX27_NODES  # noqa: F401  (documentation of the node order)

#: meshio cell-type names of the supported elements.
CELL_TYPES = {"hex27": "hexahedron27", "hex20": "hexahedron20"}

#: Default resolution of :func:`spherical_cap`: 17 649 dofs with Q2 (hex27); free-plate
#: frequencies of the (2,0), (0,1), (3,0) modes within 0.04% of Kirchhoff theory.
DEFAULT_N_CORE = 14
DEFAULT_N_RING = 5
DEFAULT_N_THICK = 1
DEFAULT_CORE = 0.5
#: Largest ring grading (first over last radial element width), a bound on the ring elements' aspect
#: ratios (a held rim's default is 2, :mod:`.rim`; on the clamped plate 5 or 8 already do worse than 2).
MAX_GRADING = 100.0


@dataclass
class VolumeMesh:
    """A volume mesh of one cell type.

    ``points`` (N, 3) float; ``cells`` (E, k) int in meshio/VTK node order;
    ``cell_type`` a meshio name (``"hexahedron27"``, ``"hexahedron20"``,
    ``"tetra10"``...); ``midsurface`` (N,) bool, True for nodes on the
    mid-surface (``zeta = 0``) when known; ``info`` free-form facts (a, R, h,
    resolution) for reports; ``node_sets`` named node sets ``{name: node indices}``
    (a generated cap has ``"edge"``, every node of its lateral face, for boundary
    conditions: :mod:`stepnf.plugin.boundary`).
    """

    points: np.ndarray
    cells: np.ndarray
    cell_type: str
    midsurface: np.ndarray | None = None
    info: dict[str, Any] = field(default_factory=dict)
    node_sets: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_points(self) -> int:
        return int(len(self.points))

    @property
    def n_cells(self) -> int:
        return int(len(self.cells))

    def to_meshio(self):
        """A :class:`meshio.Mesh` (needs the optional dependency ``meshio``)."""
        import meshio

        point_data = {} if self.midsurface is None else {"midsurface": self.midsurface.astype(np.int8)}
        return meshio.Mesh(self.points, [(self.cell_type, self.cells)], point_data=point_data)


# ---------------------------------------------------------------- plan view
def _grid(f, n_p: int, n_q: int, p_range, q_range, p_nodes: np.ndarray | None = None) -> np.ndarray:
    """Nodes ``(2 n_p + 1, 2 n_q + 1, 2)`` of a block mapped by ``f(p, q)`` (``p_nodes``: the ``2 n_p + 1``
    values of ``p`` instead of equal steps over ``p_range``)."""
    p = np.linspace(*p_range, 2 * n_p + 1) if p_nodes is None else p_nodes
    q = np.linspace(*q_range, 2 * n_q + 1)
    P, Q = np.meshgrid(p, q, indexing="ij")
    return np.stack(f(P, Q), axis=-1)


def _block_quads(n_p: int, n_q: int) -> np.ndarray:
    """Local 9-node quadrilaterals (quad9 order: 4 corners, 4 edge mids, centre) of a block grid."""
    ny = 2 * n_q + 1
    i, j = np.meshgrid(np.arange(n_p), np.arange(n_q), indexing="ij")
    i, j = 2 * i.ravel(), 2 * j.ravel()
    offs = [(0, 0), (2, 0), (2, 2), (0, 2), (1, 0), (2, 1), (1, 2), (0, 1), (1, 1)]
    return np.stack([(i + di) * ny + (j + dj) for di, dj in offs], axis=1)


def graded_nodes(n: int, grading: float) -> np.ndarray:
    """The ``2 n + 1`` quad9 node positions in ``[0, 1]`` of ``n`` elements whose widths fall geometrically
    from the first to the last by the factor ``grading`` (>= 1; 1: equal widths, :func:`numpy.linspace`
    exactly); every mid-node halfway between its element's ends."""
    if grading == 1.0 or n == 1:
        return np.linspace(0.0, 1.0, 2 * n + 1)
    widths = grading ** (-np.arange(n) / (n - 1))
    ends = np.concatenate([[0.0], np.cumsum(widths) / widths.sum()])
    ends[-1] = 1.0
    out = np.empty(2 * n + 1)
    out[0::2], out[1::2] = ends, 0.5 * (ends[:-1] + ends[1:])
    return out


def disk_quad9(n_core: int, n_ring: int, core: float = DEFAULT_CORE, grading: float = 1.0
               ) -> tuple[np.ndarray, np.ndarray]:
    """O-grid of the unit disk: points (P, 2) and counter-clockwise quad9 cells (Q, 9); ``grading`` (>= 1)
    shrinks the ring's radial steps geometrically towards the circle (:func:`graded_nodes`)."""
    if not 0.0 < core < 1.0 / math.sqrt(2.0):
        raise ValueError(f"core half-width must lie in (0, 1/sqrt(2)), got {core}")
    if not 1.0 <= grading <= MAX_GRADING:
        raise ValueError(f"grading must lie in [1, {MAX_GRADING:g}], got {grading}")
    radial = graded_nodes(n_ring, float(grading))
    blocks = [(_grid(lambda u, v: (core * u, core * v), n_core, n_core, (-1, 1), (-1, 1)), n_core, n_core)]
    for k in range(4):
        c, s = math.cos(k * math.pi / 2), math.sin(k * math.pi / 2)

        def ring(t, w, c=c, s=s):  # t radial in [0, 1], w along the core side in [-1, 1]
            x = (1 - t) * core + t * np.cos(w * math.pi / 4)
            y = (1 - t) * core * w + t * np.sin(w * math.pi / 4)
            return c * x - s * y, s * x + c * y

        blocks.append((_grid(ring, n_ring, n_core, (0, 1), (-1, 1), radial), n_ring, n_core))
    pts, quads, offset = [], [], 0
    for grid, n_p, n_q in blocks:
        pts.append(grid.reshape(-1, 2))
        quads.append(_block_quads(n_p, n_q) + offset)
        offset += grid.shape[0] * grid.shape[1]
    P = np.concatenate(pts)
    Q = np.concatenate(quads)
    # merge the nodes shared by neighbouring blocks
    key = np.round(P / 1e-9).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)  # keep the generation order
    renum = np.empty_like(order)
    renum[order] = np.arange(len(order))
    P = P[first[order]]
    Q = renum[inverse.ravel()][Q]
    # counter-clockwise orientation
    a, b, d = P[Q[:, 0]], P[Q[:, 1]], P[Q[:, 3]]
    cw = (b[:, 0] - a[:, 0]) * (d[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (d[:, 0] - a[:, 0]) < 0
    Q[cw] = Q[cw][:, [0, 3, 2, 1, 7, 6, 5, 4, 8]]
    return P, Q


# ------------------------------------------------------------------- volume
def _map_to_shell(xy: np.ndarray, zeta: np.ndarray, R: float) -> np.ndarray:
    """Points at plan position ``xy`` (n, 2) and normal offset ``zeta`` (n,)."""
    if math.isinf(R):
        return np.column_stack([xy, zeta])
    z_mid = np.sqrt(R**2 - np.sum(xy**2, axis=1)) - R
    mid = np.column_stack([xy, z_mid])
    normal = (mid - np.array([0.0, 0.0, -R])) / R
    return mid + zeta[:, None] * normal


def extruded_hex27(Q: np.ndarray, n_layers: int) -> np.ndarray:
    """Hex27 cells (VTK order) of quad9 cells ``Q`` (counter-clockwise) extruded through ``n_layers``
    layers: node ``q (2 n_layers + 1) + level`` is plan node ``q`` at level ``level`` (0 at the
    bottom), the numbering of :func:`spherical_cap` (and of any extruded block)."""
    n_lev = 2 * n_layers + 1

    def node(q: np.ndarray, lev: int) -> np.ndarray:
        return q * n_lev + lev

    cells = []
    for layer in range(n_layers):
        b, m, t = 2 * layer, 2 * layer + 1, 2 * layer + 2
        cols = (
            [node(Q[:, i], b) for i in range(4)] + [node(Q[:, i], t) for i in range(4)]
            + [node(Q[:, i], b) for i in range(4, 8)] + [node(Q[:, i], t) for i in range(4, 8)]
            + [node(Q[:, i], m) for i in range(4)]
            + [node(Q[:, 7], m), node(Q[:, 5], m), node(Q[:, 4], m), node(Q[:, 6], m),
               node(Q[:, 8], b), node(Q[:, 8], t), node(Q[:, 8], m)]
        )
        cells.append(np.stack(cols, axis=1))
    return np.concatenate(cells)


def spherical_cap(
    a: float,
    R: float,
    h: float,
    *,
    element: str = "hex27",
    n_core: int = DEFAULT_N_CORE,
    n_ring: int = DEFAULT_N_RING,
    n_thick: int = DEFAULT_N_THICK,
    core: float = DEFAULT_CORE,
    grading: float = 1.0,
) -> VolumeMesh:
    """Mesh of a free-edge spherical cap (see the module docstring for the conventions).

    Parameters
    ----------
    a : projected outer radius (> 0)
    R : radius of curvature of the mid-surface (>= a), ``float("inf")`` for the flat plate
    h : thickness (> 0)
    element : ``"hex27"`` (triquadratic) or ``"hex20"`` (serendipity)
    n_core : elements along a side of the square core (the ring has ``4 n_core`` elements around)
    n_ring : elements across the ring, radially
    n_thick : elements through the thickness
    core : half-width of the core square as a fraction of ``a``
    grading : the ring's first radial element width over its last (>= 1, at most :data:`MAX_GRADING`):
        ``1`` equal steps; more refines towards the rim, for a held edge (:func:`graded_nodes`)
    """
    if element not in CELL_TYPES:
        raise ValueError(f"Unknown element {element!r}. Pick one of {list(CELL_TYPES)}")
    if not (a > 0 and h > 0):
        raise ValueError(f"need a > 0 and h > 0, got a={a}, h={h}")
    if not R >= a:
        raise ValueError(f"need R >= a (R = inf for the plate), got R={R}, a={a}")
    if not math.isinf(R) and h >= 2 * R:
        raise ValueError(f"need h < 2 R, got h={h}, R={R}")
    for name, val in (("n_core", n_core), ("n_ring", n_ring), ("n_thick", n_thick)):
        if int(val) != val or val < 1:
            raise ValueError(f"{name} must be a positive integer, got {val!r}")
    P2, Q = disk_quad9(int(n_core), int(n_ring), core, float(grading))
    n_lev = 2 * int(n_thick) + 1
    zeta = np.linspace(-h / 2, h / 2, n_lev)
    xy = np.repeat(P2 * a, n_lev, axis=0)
    points = _map_to_shell(xy, np.tile(zeta, len(P2)), float(R))

    cells = extruded_hex27(Q, int(n_thick))
    midsurface = np.tile(np.arange(n_lev) == int(n_thick), len(P2))
    # the lateral face: every level of the plan points on the unit circle (exactly 1 up to round-off)
    rim = np.repeat(np.abs(np.hypot(P2[:, 0], P2[:, 1]) - 1.0) < 1e-9, n_lev)
    if element == "hex20":
        cells = cells[:, :20]
        used = np.unique(cells)
        renum = np.full(len(points), -1)
        renum[used] = np.arange(len(used))
        points, midsurface, rim, cells = points[used], midsurface[used], rim[used], renum[cells]
    info = {"shape": "spherical_cap", "a": float(a), "R": float(R), "h": float(h), "element": element,
            "n_core": int(n_core), "n_ring": int(n_ring), "n_thick": int(n_thick), "core": float(core)}
    if grading != 1.0:  # (a uniform ring's info is the one it always was)
        info["grading"] = float(grading)
    return VolumeMesh(points=points, cells=cells, cell_type=CELL_TYPES[element], midsurface=midsurface, info=info,
                      node_sets={"edge": np.flatnonzero(rim)})


def shell_volume(a: float, R: float, h: float) -> float:
    """Exact volume of the solid :func:`spherical_cap` meshes."""
    if math.isinf(R):
        return math.pi * a**2 * h
    cos_alpha = math.sqrt(1.0 - (a / R) ** 2)
    return 2.0 * math.pi / 3.0 * (1.0 - cos_alpha) * ((R + h / 2) ** 3 - (R - h / 2) ** 3)


def outward_normals(points: np.ndarray, R: float) -> np.ndarray:
    """Unit normals (n, 3) of the mid-surface family at ``points`` (``e_z`` for the plate)."""
    points = np.asarray(points, dtype=float)
    if math.isinf(R):
        return np.tile([0.0, 0.0, 1.0], (len(points), 1))
    d = points - np.array([0.0, 0.0, -R])
    return d / np.linalg.norm(d, axis=1, keepdims=True)
