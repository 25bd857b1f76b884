"""Mid-surface meshes of the ``kratos`` adapter: a user's triangles or quadrilaterals, or a generated cap.

:func:`read_shell_mesh` reads any mesh meshio reads and keeps its cells of the type the element needs
(``triangle`` for ``dkt``, ``quad`` for ``dkq``), with the file's named node sets
(:func:`stepnf.geometry.mesh_sets.read_node_sets`: boundary conditions) and cell sets
(:func:`~stepnf.geometry.mesh_sets.read_cell_sets`: materials). A mesh of solids, or one without cells
of that type, or with degenerate cells (:func:`degenerate_cells`), is a :class:`~stepnf.errors.SceneError`
naming the file and the key ``model.mesh``.

:func:`cap_surface` is the mid-surface of the generated free-edge caps of the solid adapters
(:func:`stepnf.geometry.cap.spherical_cap`, same ``a``, ``R``, ``n_core``, ``n_ring``, ``core``,
``grading``): every quad9 of the plan O-grid (:func:`~stepnf.geometry.cap.disk_quad9`) becomes four
quadrilaterals through its nine nodes, or eight triangles whose diagonals all meet at its centre
(a pattern symmetric under the grid's reflections); the nodes are the solid cap's mid-surface nodes
(on the sphere, apex at the origin, centre of curvature ``(0, 0, -R)``). Node set ``"edge"``: the rim.
Units: those of the file or of ``a``.
"""
from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stepnf.errors import SceneError

#: meshio cell type of each element name
CELL_TYPE = {"dkt": "triangle", "dkq": "quad"}
#: Kratos element of each element name
KRATOS_ELEMENT = {"dkt": "ShellThinElementCorotational3D3N", "dkq": "ShellThinElementCorotational3D4N"}
SOLID_TYPES = ("tetra", "hexahedron", "wedge", "pyramid", "tetra10", "hexahedron20", "hexahedron27", "wedge15")
#: the four quadrilaterals of a quad9 (VTK order: corners 0-3, mid-edges 4-7, centre 8), counter-clockwise
QUAD9_QUADS = np.array([(0, 4, 8, 7), (4, 1, 5, 8), (8, 5, 2, 6), (7, 8, 6, 3)])


@dataclass
class ShellMesh:
    """A mid-surface mesh: ``points`` (N, 3), ``cells`` (E, 3 or 4) 0-based, ``cell_type`` (meshio name),
    ``node_sets`` and ``cell_sets`` ``{name: sorted indices}``, ``info`` (facts for reports)."""

    points: np.ndarray
    cells: np.ndarray
    cell_type: str
    node_sets: dict[str, np.ndarray] = field(default_factory=dict)
    cell_sets: dict[str, np.ndarray] = field(default_factory=dict)
    info: dict = field(default_factory=dict)


def read_shell_mesh(path: str | Path, element: str, scene_file: str | Path | None = None) -> ShellMesh:
    """The cells of ``element``'s type in the mesh file ``path`` (see the module docstring)."""
    import meshio

    from stepnf.geometry.mesh_sets import read_cell_sets, read_node_sets

    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said):
            m = meshio.read(str(path))
    except SystemExit:
        raise SceneError(scene_file, "model.mesh", f"{path}: meshio cannot read this file (unknown or corrupt "
                         "format)") from None
    except Exception as exc:  # noqa: BLE001 - meshio raises many kinds
        raise SceneError(scene_file, "model.mesh", f"{path}: cannot read it: {exc}") from None
    kind = CELL_TYPE[element]
    found = sorted({c.type for c in m.cells})
    solids = [t for t in found if t in SOLID_TYPES]
    blocks = [np.asarray(c.data) for c in m.cells if c.type == kind]
    if solids and not blocks:
        raise SceneError(scene_file, "model.mesh", f"{path} holds solid cells {solids}: element = {element!r} is a "
                         f"shell element and needs a mid-surface mesh of {kind} cells (a solid mesh needs a solid "
                         "adapter: fenicsx or calculix)")
    if not blocks:
        other = CELL_TYPE["dkq" if element == "dkt" else "dkt"]
        hint = f" (element = {'dkq' if element == 'dkt' else 'dkt'!r} takes {other} cells)" if other in found else ""
        raise SceneError(scene_file, "model.mesh", f"{path} has no {kind} cells for element = {element!r}; it has "
                         f"{found or 'no cells'}{hint}")
    surface = [t for t in found if t not in (kind, "vertex", "line", "line3") and t not in SOLID_TYPES]
    if surface or solids:
        raise SceneError(scene_file, "model.mesh", f"{path} holds {sorted(surface + solids)} cells besides its {kind} "
                         f"cells; element = {element!r} models {kind} cells only, and none may be left out")
    cells = np.concatenate(blocks).astype(np.int64)
    pts = np.asarray(m.points, dtype=float)
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    if not np.all(np.isfinite(pts)):
        raise SceneError(scene_file, "model.mesh", f"{path}: node coordinates are not all finite")
    if cells.size and (cells.min() < 0 or cells.max() >= len(pts)):
        raise SceneError(scene_file, "model.mesh", f"{path}: {kind} cells reference nodes outside 0..{len(pts) - 1} "
                         f"(the mesh has {len(pts)} nodes)")
    bad = degenerate_cells(pts, cells)
    if bad.any():
        e = int(np.flatnonzero(bad)[0])
        raise SceneError(scene_file, "model.mesh", f"{path}: {kind} cell {e} (0-based, nodes {cells[e].tolist()}) is "
                         f"degenerate (a node used twice, an edge or the area of zero length); {int(bad.sum())} "
                         "cell(s) are; Kratos's shells give NaN stiffness for them")
    used = np.unique(cells)
    renum = np.full(len(pts), -1)
    renum[used] = np.arange(len(used))
    cells = renum[cells]
    info = {"file": str(path)}
    return ShellMesh(pts[used], cells, kind, read_node_sets(m, renum), read_cell_sets(m, kind), info)


def degenerate_cells(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Bool (E,): the cells (triangles or quadrilaterals, 0-based) that use a node twice, or whose shortest edge
    or vector area (a triangle's ``(b - a) x (c - a) / 2``, a quadrilateral's ``(c - a) x (d - b) / 2``) is at
    most :data:`stepnf.geometry.checks.DEGENERATE_RTOL` times the cell's bounding-box diagonal (squared for
    the area): the solid meshes' threshold, far above round-off (~1e-16) and below any usable aspect ratio."""
    from stepnf.geometry.checks import DEGENERATE_RTOL

    X = points[cells]  # (E, k, 3)
    srt = np.sort(cells, axis=1)
    twice = (srt[:, 1:] == srt[:, :-1]).any(axis=1)
    L = np.linalg.norm(X.max(axis=1) - X.min(axis=1), axis=1)
    edge = np.linalg.norm(np.roll(X, -1, axis=1) - X, axis=2).min(axis=1)
    if cells.shape[1] == 3:
        area = 0.5 * np.linalg.norm(np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), axis=1)
    else:
        area = 0.5 * np.linalg.norm(np.cross(X[:, 2] - X[:, 0], X[:, 3] - X[:, 1]), axis=1)
    return twice | (edge <= DEGENERATE_RTOL * L) | (area <= DEGENERATE_RTOL * L ** 2)


def cap_surface(a: float, R: float, element: str, *, n_core: int, n_ring: int, core: float,
                grading: float = 1.0) -> ShellMesh:
    """The mid-surface of the generated cap (see the module docstring)."""
    from stepnf.geometry.cap import disk_quad9, spherical_cap

    P2, Q9 = disk_quad9(n_core, n_ring, core, grading)
    solid = spherical_cap(a, R, min(a, R) * 1e-3, n_core=n_core, n_ring=n_ring, n_thick=1, core=core, grading=grading)
    points = solid.points[solid.midsurface]  # one per plan node, in the plan order
    quads = Q9[:, QUAD9_QUADS].reshape(-1, 4)
    if element == "dkq":
        cells = quads
    else:  # each quadrilateral cut along its diagonal through the quad9's centre (local corner 2 of 0, 3 of 1...)
        centre = np.tile([2, 3, 0, 1], len(Q9))
        rows = np.arange(len(quads))
        c, nxt, prv = centre, (centre + 1) % 4, (centre + 3) % 4
        opp = (centre + 2) % 4
        cells = np.concatenate([np.column_stack([quads[rows, opp], quads[rows, prv], quads[rows, c]]),
                                np.column_stack([quads[rows, opp], quads[rows, c], quads[rows, nxt]])])
    rim = np.flatnonzero(np.abs(np.hypot(P2[:, 0], P2[:, 1]) - 1.0) < 1e-9)
    info = {"shape": "spherical_cap", "a": float(a), "R": float(R), "n_core": int(n_core), "n_ring": int(n_ring),
            "core": float(core), **({"grading": float(grading)} if grading != 1.0 else {})}
    return ShellMesh(points, cells.astype(np.int64), CELL_TYPE[element], {"edge": rim}, {}, info)
