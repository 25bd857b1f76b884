"""Sanity checks of user meshes, reported before any solve: the one checker every mesh reader calls.

:func:`check_volume_mesh` takes the nodes and cell blocks as a reader found
them and raises :class:`stepnf.errors.MeshError` (bad input, exit code 2)
naming the file and the first cell or node at fault, for

* an empty mesh (no points, no cells), a 2D mesh, an unsupported cell type or
  a cell with the wrong number of nodes;
* cells referencing nodes that do not exist (negative or past the last node)
  or using one node twice;
* NaN or inf coordinates (of a node some cell uses);
* a flat mesh: every node in one plane (zero thickness), or all at one point;
* coincident nodes: a seam meshed twice, parts not merged. They give extra
  zero-energy motions that surface much later as "negative eigenvalues" or,
  worse, as plausible but wrong modes;
* degenerate cells (zero volume: flat, or collapsed onto a line or a point);
* tangled cells, whose Jacobian changes sign inside them: most codes
  integrate ``|det J|`` and give a wrong stiffness without any error;
* inverted (folded) cells: two cells sharing a face lie on the same side of
  it, i.e. they overlap (a node was pushed through the opposite face). This
  test does not depend on the node order, so a mesh whose cells have mixed
  orientations (mirrored node order, ``det J < 0`` everywhere) stays valid,
  and it is the only way to see an inverted linear tetrahedron, whose
  Jacobian is constant.

:func:`units_warning` warns when the material constants are SI and the mesh
looks like millimetres (see its docstring for the heuristic).

Thresholds are relative, chosen by what produces them (see the constants).
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.spatial import cKDTree

from stepnf.errors import MeshError, UnitsWarning
from stepnf.geometry.hexahedra import HEX27_NODES, determinants, gauss_points, shape_functions

#: Cell types the checker knows (meshio names) and their number of nodes.
CELL_NODES = {"tetra": 4, "tetra10": 10, "hexahedron": 8, "hexahedron20": 20, "hexahedron27": 27,
              "wedge": 6, "wedge15": 15}
#: Coincident nodes: closer than this times the mesh size (bounding-box diagonal). Coordinates
#: written with 7 significant digits are already distinct at 1e-7; real meshes have cells of at
#: least 1e-5 of the part, so 1e-9 cannot merge two distinct nodes.
DUPLICATE_RTOL = 1e-9
#: Flat mesh: thickness (extent across the best-fit plane) below this times the largest extent.
#: Coordinates written with 7 digits (meshio's ASCII formats, single-precision VTU) carry 5e-7
#: relative noise, so a plane written that way is up to ~1e-6 thick; no 3D solid model is that thin.
FLAT_RTOL = 1e-6
#: Degenerate cell: every |det J| sample below this times L^3 (L: the cell's bounding-box
#: diagonal). Round-off of a zero volume is ~1e-16 L^3; an element with an aspect ratio of 1e8
#: (the least this would flag) has a stiffness matrix conditioned beyond double precision.
DEGENERATE_RTOL = 1e-9
#: Sign change of det J inside a cell: samples beyond this times the cell's largest |det J|.
TANGLED_RTOL = 1e-12
#: Overlapping neighbours: both cell centres more than this times the face size on the same side.
FOLDED_RTOL = 1e-9

#: Corner nodes of each face (cyclic) of the cell families with a Jacobian check.
_TET_FACES = [(1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)]
_HEX_FACES = [(0, 3, 7, 4), (1, 2, 6, 5), (0, 1, 5, 4), (3, 2, 6, 7), (0, 1, 2, 3), (4, 5, 6, 7)]


# --------------------------------------------------------------------- shape functions
def _tet_shape(xi: np.ndarray, n_nodes: int) -> np.ndarray:
    """Reference gradients dN (q, n, 3) of the linear (4) or quadratic (10) tetrahedron, VTK order."""
    xi = np.atleast_2d(xi)
    q = len(xi)
    L = np.column_stack([1 - xi.sum(axis=1), xi])  # barycentric (q, 4)
    dL = np.array([[-1, -1, -1], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)  # (4, 3)
    if n_nodes == 4:
        return np.broadcast_to(dL, (q, 4, 3)).copy()
    dN = np.empty((q, 10, 3))
    for a in range(4):
        dN[:, a] = (4 * L[:, a] - 1)[:, None] * dL[a]
    for k, (a, b) in enumerate([(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]):
        dN[:, 4 + k] = 4 * (L[:, a, None] * dL[b] + L[:, b, None] * dL[a])
    return dN


def _samples(cell_type: str) -> tuple[np.ndarray, np.ndarray] | None:
    """Sample points and reference gradients dN (q, n, 3) for the Jacobian checks (None: not checked)."""
    if cell_type.startswith("hexahedron"):
        xi_g, _ = gauss_points(4 if cell_type != "hexahedron" else 2)
        xi = np.vstack([xi_g, HEX27_NODES if cell_type != "hexahedron" else HEX27_NODES[:8]])
        return xi, shape_functions(xi, CELL_NODES[cell_type])[1]
    if cell_type.startswith("tetra"):
        corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
        mids = np.array([(corners[a] + corners[b]) / 2 for a in range(4) for b in range(a + 1, 4)])
        inner = 0.25 + 0.5 * (corners - 0.25)  # half-way between the centre and the corners
        xi = np.vstack([corners, mids, inner, [[0.25, 0.25, 0.25]]])
        return xi, _tet_shape(xi, CELL_NODES[cell_type])
    return None


def jacobian_determinants(points: np.ndarray, cells: np.ndarray, cell_type: str) -> np.ndarray | None:
    """det J (E, q) at the sample points of every cell, or ``None`` for a cell type without the check."""
    s = _samples(cell_type)
    if s is None:
        return None
    return determinants(points, cells, s[1])


# --------------------------------------------------------------------------- checks
def duplicate_nodes(points: np.ndarray, rtol: float = DUPLICATE_RTOL) -> np.ndarray:
    """Pairs (k, 2) of node indices closer than ``rtol`` times the mesh size (bounding-box diagonal)."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2:
        return np.zeros((0, 2), dtype=int)
    diag = float(np.linalg.norm(np.ptp(pts, axis=0)))
    pairs = cKDTree(pts).query_pairs(rtol * max(diag, 1e-300), output_type="ndarray")
    return np.asarray(pairs, dtype=int).reshape(-1, 2)


def tangled_cells(points: np.ndarray, cells: np.ndarray, n_nodes: int | str) -> np.ndarray:
    """Indices of cells whose Jacobian determinant changes sign (hexahedra and tetrahedra, VTK order).

    ``n_nodes`` is the number of nodes (20 or 27: quadratic hexahedra) or a
    cell type name. A uniformly negative determinant (mirrored node order) is
    a valid cell and is not reported.
    """
    cell_type = n_nodes if isinstance(n_nodes, str) else {20: "hexahedron20", 27: "hexahedron27",
                                                          8: "hexahedron", 10: "tetra10", 4: "tetra"}[n_nodes]
    det = jacobian_determinants(np.asarray(points, dtype=float), np.asarray(cells, dtype=int), cell_type)
    if det is None:
        return np.zeros(0, dtype=int)
    return np.nonzero(_tangled(det))[0]


def _tangled(det: np.ndarray) -> np.ndarray:
    scale = np.max(np.abs(det), axis=1, keepdims=True)
    return (det > TANGLED_RTOL * scale).any(axis=1) & (det < -TANGLED_RTOL * scale).any(axis=1)


def _name(kind: str, i: int, names: np.ndarray | None) -> str:
    return f"{kind} {int(names[i]) if names is not None else int(i)}"


def check_volume_mesh(points: Any, blocks: Sequence[tuple[str, Any]], *, source: str | Path | None,
                      node_ids: Any = None, cell_ids: Sequence[Any] | None = None,
                      cell_labels: Sequence[str] | None = None, supported: Sequence[str] | None = None) -> None:
    """Raise :class:`MeshError` naming ``source`` and the first cell or node at fault (module docstring).

    Parameters
    ----------
    points : (N, 3) node coordinates, as read
    blocks : ``[(meshio cell type, cells (E, k))]``: 0-based positions into ``points``, VTK node order
    source : the mesh file (for the messages)
    node_ids, cell_ids : the file's own numbers of the nodes (N,) and of each block's cells (E,),
        used in the messages instead of 0-based positions (e.g. the ids of an ``.inp`` file)
    cell_labels : how the messages call each block's cells (default ``"<cell type> cell"``),
        e.g. ``"C3D20 element"``
    supported : cell types the caller can use (default: every type of :data:`CELL_NODES`)
    """
    src = None if source is None else str(source)
    node_ids = None if node_ids is None else np.asarray(node_ids)
    numbering = "ids of the file" if node_ids is not None else "0-based"

    def fail(msg: str) -> None:
        raise MeshError(src, msg)

    supported = list(CELL_NODES) if supported is None else list(supported)
    try:
        pts = np.asarray(points, dtype=float)
    except (TypeError, ValueError) as exc:
        fail(f"node coordinates are not numbers: {exc}")
    if pts.ndim != 2 or len(pts) == 0:
        fail(f"the mesh has no nodes (points of shape {pts.shape})")
    if pts.shape[1] == 2:
        fail("a 2D mesh (points have 2 coordinates); stepnf needs volume cells in 3D")
    if pts.shape[1] != 3:
        fail(f"points have {pts.shape[1]} coordinates; expected 3")
    if not blocks or all(np.size(c) == 0 for _, c in blocks):
        fail(f"the mesh has no volume cells of a supported type {supported}")
    n = len(pts)
    used = np.zeros(n, dtype=bool)
    arrays = []
    for b, (ctype, cells) in enumerate(blocks):
        names = None if cell_ids is None or cell_ids[b] is None else np.asarray(cell_ids[b])
        label = cell_labels[b] if cell_labels is not None else f"{ctype} cell"
        if ctype not in supported:
            fail(f"cell type {ctype!r} is not supported. Pick one of {supported}")
        c = np.asarray(cells)
        k = CELL_NODES.get(ctype)
        if c.ndim != 2 or (k is not None and c.shape[1] != k):
            fail(f"{ctype} cells of shape {c.shape}; a {ctype} cell has {k} nodes")
        if c.dtype.kind not in "iu":
            fail(f"{ctype} cells hold non-integer node numbers (dtype {c.dtype})")
        c = c.astype(np.int64)
        out = (c < 0) | (c >= n)
        if out.any():
            e, j = (int(v[0]) for v in np.nonzero(out))
            ref = int(node_ids[c[e, j]]) if node_ids is not None and 0 <= c[e, j] < n else int(c[e, j])
            fail(f"{_name(label, e, names)} references node {ref}, which does not exist "
                 f"(the mesh has {n} nodes{', numbered 0..' + str(n - 1) if node_ids is None else ''}); "
                 f"{int(out.any(axis=1).sum())} cell(s) do")
        srt = np.sort(c, axis=1)
        twice = (srt[:, 1:] == srt[:, :-1]).any(axis=1)
        if twice.any():
            e = int(np.nonzero(twice)[0][0])
            row = srt[e]
            j = int(row[1:][row[1:] == row[:-1]][0])
            fail(f"{_name(label, e, names)} uses node {_name('', j, node_ids).strip()} twice "
                 f"(a collapsed, degenerate cell); {int(twice.sum())} cell(s) do")
        used[c.ravel()] = True
        arrays.append((ctype, c, names, label))

    bad = used & ~np.isfinite(pts).all(axis=1)
    if bad.any():
        i = int(np.nonzero(bad)[0][0])
        fail(f"node {_name('', i, node_ids).strip()} has coordinates {pts[i].tolist()} (NaN or inf); "
             f"{int(bad.sum())} node(s) do ({numbering} numbers)")

    upts = pts[used]
    uidx = np.nonzero(used)[0]
    centre = upts.mean(axis=0)
    _, sv, vt = np.linalg.svd(upts - centre, full_matrices=False)
    proj = (upts - centre) @ vt.T
    extents = np.ptp(proj, axis=0)
    if not extents.max() > 0:
        fail(f"all {len(upts)} nodes are at one point {upts[0].tolist()}")
    if extents[-1] <= FLAT_RTOL * extents.max():
        fail(f"the mesh is flat: all {len(upts)} nodes lie in one plane (thickness {extents[-1]:.3g} for an "
             f"extent of {extents.max():.3g}); a 3D solid model needs a thickness")

    dup = duplicate_nodes(upts)
    if len(dup):
        a, b = (int(uidx[v]) for v in dup[0])
        fail(f"{len(dup)} pairs of coincident (duplicate) nodes, e.g. nodes {_name('', a, node_ids).strip()} and "
             f"{_name('', b, node_ids).strip()} at {pts[a].tolist()}: parts of the mesh are not connected; "
             "merge them")

    for ctype, c, names, label in arrays:
        if _samples(ctype) is None:
            continue
        degen = np.zeros(len(c), dtype=bool)
        tang = np.zeros(len(c), dtype=bool)
        for i0 in range(0, len(c), 4096):  # in chunks: (cells, samples, 3, 3) Jacobians at once
            cc = c[i0:i0 + 4096]
            det = jacobian_determinants(pts, cc, ctype)
            L = np.linalg.norm(np.ptp(pts[cc], axis=1), axis=1)  # bounding-box diagonal of each cell
            degen[i0:i0 + len(cc)] = np.abs(det).max(axis=1) <= DEGENERATE_RTOL * L ** 3
            tang[i0:i0 + len(cc)] = _tangled(det)
        if degen.any():
            e = int(np.nonzero(degen)[0][0])
            fail(f"{_name(label, e, names)} is degenerate (zero volume: its nodes are in one plane, "
                 f"on a line or at one point); {int(degen.sum())} cell(s) are")
        if tang.any():
            e = int(np.nonzero(tang)[0][0])
            fail(f"{int(tang.sum())} tangled (inverted) cell(s), e.g. {_name(label, e, names)}: the "
                 "Jacobian changes sign inside it (a node pushed through the opposite face)")
        pair = _folded_pair(pts, c, ctype)
        if pair is not None:
            a, b, count = pair
            fail(f"{_name(label, a, names)} and {_name(label.split()[-1], b, names)} overlap: they lie on the same "
                 f"side of their shared face, so one of them is inverted (a node pushed through the opposite "
                 f"face); {count} such pair(s)")


def _folded_pair(pts: np.ndarray, cells: np.ndarray, cell_type: str) -> tuple[int, int, int] | None:
    """The first pair of cells that share a face and lie on the same side of it, and the number of such pairs.

    Faces are matched by their sorted corner nodes; the face's normal is the
    cross product of its diagonals (of two edges for a triangle), its plane goes
    through the mean of its corners, and the cell centres are the means of the
    cells' corners. Neighbours in a valid mesh are on opposite sides.
    """
    faces = _TET_FACES if cell_type.startswith("tetra") else _HEX_FACES if cell_type.startswith("hexa") else None
    if faces is None or len(cells) < 2:
        return None
    F = np.asarray(faces)  # (f, k)
    nf, k = F.shape
    fn = cells[:, F].reshape(-1, k)  # (E f, k) corner nodes of every face, cyclic
    owner = np.repeat(np.arange(len(cells)), nf)
    key = np.sort(fn, axis=1)
    order = np.lexsort(key.T[::-1])
    ks = key[order]
    same = np.all(ks[1:] == ks[:-1], axis=1)
    i1 = order[:-1][same]
    i2 = order[1:][same]
    if not len(i1):
        return None
    P = pts[fn[i1]]  # (m, k, 3) corners of each shared face, in the first cell's order
    if k == 3:
        nrm = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    else:
        nrm = np.cross(P[:, 2] - P[:, 0], P[:, 3] - P[:, 1])
    fc = P.mean(axis=1)
    ncorner = 4 if cell_type.startswith("tetra") else 8
    centres = pts[cells[:, :ncorner]].mean(axis=1)
    size = np.linalg.norm(np.ptp(P, axis=1), axis=1)
    unit = nrm / np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
    sa = np.einsum("ij,ij->i", centres[owner[i1]] - fc, unit)
    sb = np.einsum("ij,ij->i", centres[owner[i2]] - fc, unit)
    tol = FOLDED_RTOL * size
    bad = ((sa > tol) & (sb > tol)) | ((sa < -tol) & (sb < -tol))
    if not bad.any():
        return None
    j = int(np.nonzero(bad)[0][0])
    a, b = sorted((int(owner[i1[j]]), int(owner[i2[j]])))
    return a, b, int(bad.sum())


def units_warning(points: Any, material: Mapping[str, Any] | None, *, source: str | Path | None = None,
                  thickness: float | None = None) -> str:
    """Warn (:class:`UnitsWarning`) when SI material constants meet a mesh that looks like millimetres.

    Heuristic. The material tells its unit system without doubt: a solid's
    density is 100 .. 25 000 in kg/m^3 (SI), ~1e-9 .. 2e-8 in t/mm^3 (the
    consistent mm-N-s system, where E is in MPa) and ~1 .. 22 in g/cm^3; so
    ``rho >= 100`` means SI lengths in metres. stepnf models thin structures
    (shells, plates, blades) with 3D solids, whose thickness in metres is a
    few mm to a few cm. A mesh drawn in mm and read as metres is 1000x too
    large: its *thickness* reads as 0.1 .. 50 "m" and its extent as
    > 5 "m". The warning fires when the material is SI, the largest extent of
    the mesh exceeds 5 and its thickness (the ``thickness`` given, else the
    smallest extent of the nodes across their best-fit plane) exceeds 0.1:
    a part more than 5 m across and more than 10 cm thick, which in SI is a
    civil-engineering structure rather than the thin metal parts stepnf is
    for (it may still be right: hence a warning, not an error). Read in the
    wrong unit, every length is 1000x too large and, since omega scales as
    ``sqrt(E / rho) / L``, every frequency 1000x too low. Returns the
    message ('' when nothing is suspicious).
    """
    mat = dict(material or {})
    rho = mat.get("rho")
    try:
        rho = float(rho) if rho is not None else None
    except (TypeError, ValueError):
        return ""
    if rho is None or not rho >= 100:
        return ""
    pts = np.asarray(points, dtype=float)
    pts = pts[np.isfinite(pts).all(axis=1)] if pts.ndim == 2 else pts.reshape(0, 3)
    if len(pts) < 4:
        return ""
    c = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    ext = np.ptp(c @ vt.T, axis=0)
    largest = float(ext.max())
    t = float(thickness) if thickness is not None else float(ext.min())
    if largest > 5.0 and t > 0.1:
        where = f"{source}: " if source is not None else ""
        msg = (f"{where}the material constants are SI (rho = {rho:g} kg/m^3, E = {mat.get('E', '?')}) but the "
               f"mesh is {largest:.4g} across and {t:.4g} thick: as metres, a part {largest:.4g} m wide and "
               f"{t:.4g} m thick. If the mesh is in millimetres, every frequency will be 1000x off (too low): "
               "scale the mesh by 1e-3, or give E in MPa and rho in t/mm^3")
        warnings.warn(msg, UnitsWarning, stacklevel=2)
        return msg
    return ""
