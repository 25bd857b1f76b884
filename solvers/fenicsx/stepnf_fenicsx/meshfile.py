"""A user's mesh file for the ``fenicsx`` adapter: its volume cells, named node sets and cell sets, through meshio.

:func:`read_mesh` keeps the volume cells of one type dolfinx can use
(``hexahedron27``, ``tetra10``, ``hexahedron``, ``tetra``) or serendipity
``hexahedron20`` (a CalculiX ``C3D20`` mesh), which :func:`hex20_to_hex27`
completes into quadratic hexahedra, so that the same mesh file serves both
solvers. :func:`read_node_sets` gives the named node sets boundary conditions
refer to (:mod:`stepnf.plugin.boundary`), :func:`read_cell_sets` the named sets of
volume cells ``[model.materials.<set>]`` refer to (:mod:`stepnf_fenicsx.regions`).
Units: those of the file.
"""
from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from stepnf.geometry import VolumeMesh

from . import _compat

#: topological dimension of meshio cell types (by name prefix)
_DIMS = (("vertex", 0), ("line", 1), ("triangle", 2), ("quad", 2), ("polygon", 2), ("tetra", 3),
         ("hexahedron", 3), ("wedge", 3), ("pyramid", 3))
#: the faces of a VTK hexahedron20/27 (-x +x -y +y -z +z): corners then mid-edge nodes; face centre 20 + i
HEX_FACES = np.array([(0, 3, 7, 4, 11, 19, 15, 16), (1, 2, 6, 5, 9, 18, 13, 17), (0, 1, 5, 4, 8, 17, 12, 16),
                      (3, 2, 6, 7, 10, 18, 14, 19), (0, 1, 2, 3, 8, 9, 10, 11), (4, 5, 6, 7, 12, 13, 14, 15)])
#: cell types :func:`read_mesh` accepts: dolfinx's, and hexahedron20 completed to hexahedron27
READABLE = (*_compat.CELLS, "hexahedron20")


def cell_dimension(cell_type: str) -> int | None:
    """Topological dimension of a meshio cell type (``None`` when unknown)."""
    return next((d for p, d in _DIMS if cell_type.startswith(p)), None)


def read_mesh(path: str | Path) -> "MeshFile":
    """Read the volume cells of any file meshio reads (one supported cell type) and its named node sets.

    ``node_sets``: :func:`read_node_sets` (point sets, cell sets, Gmsh physical groups, MED groups),
    numbered like the returned points; ``cell_sets``: :func:`read_cell_sets`, the named sets of its
    volume cells, numbered like the returned cells. Every defect :func:`stepnf.geometry.checks.check_volume_mesh`
    knows (no cells, NaN coordinates, dangling node numbers, flat meshes, coincident nodes,
    degenerate, tangled or overlapping cells) is a :class:`~stepnf.errors.MeshError` naming the file
    and the cell or node (0-based positions in the file, cells counted within their type).
    """
    import meshio

    from stepnf.errors import MeshError
    from stepnf.geometry.checks import check_volume_mesh

    said = io.StringIO()  # meshio prints the errors of the readers it tries (.msh: ANSYS first) on stdout
    try:
        with contextlib.redirect_stdout(said):
            m = meshio.read(str(path))
    except SystemExit as exc:  # meshio exits (!) on a file it cannot identify
        why = " ".join(said.getvalue().split())
        raise MeshError(path, "meshio cannot read this file (unknown or corrupt format)"
                        + (f": {why}" if why else "")) from exc
    found = [c.type for c in m.cells]
    kinds = [c.type for c in m.cells if c.type in READABLE]
    if not kinds:
        raise MeshError(path, f"no volume cells dolfinx can use; found {found or 'no cells at all'}, "
                              f"supported {list(READABLE)}")
    if len(set(kinds)) > 1:
        raise MeshError(path, f"mixed volume cell types {sorted(set(kinds))}; give one cell type")
    cells = np.concatenate([np.asarray(c.data) for c in m.cells if c.type == kinds[0]])
    pts = np.asarray(m.points)
    check_volume_mesh(pts, [(kinds[0], cells)], source=path, supported=list(READABLE))
    cells = cells.astype(np.int64)
    used = np.unique(cells)
    renum = np.full(len(pts), -1)
    renum[used] = np.arange(len(used))
    mesh = MeshFile(points=np.asarray(pts, dtype=float)[used], cells=renum[cells], cell_type=kinds[0],
                    info={"file": str(path)}, node_sets=read_node_sets(m, renum), cell_sets=read_cell_sets(m, kinds[0]))
    return hex20_to_hex27(mesh) if mesh.cell_type == "hexahedron20" else mesh


def named_cells(m: Any) -> Iterator[tuple[str, int, np.ndarray]]:
    """``(name, block, positions)`` of every named group of cells of a meshio mesh: meshio cell sets (an
    Abaqus ``*ELSET``...), Gmsh physical groups (``gmsh:physical`` cell data named by ``field_data``: the
    cells of that tag in the blocks of the group's dimension), MED groups of cells (families of
    ``cell_tags``); ``positions`` are the cells' rows within block ``block`` of ``m.cells``."""
    cell_data: Mapping[str, Any] = getattr(m, "cell_data", None) or {}
    for name, per_block in (getattr(m, "cell_sets", None) or {}).items():
        if not str(name).startswith("gmsh:"):
            for b, idx in enumerate(per_block):
                if idx is not None and len(idx) and b < len(m.cells):
                    yield str(name), b, np.asarray(idx, dtype=np.int64).ravel()
    groups: list[tuple[str, Any, Any, int | None]] = []  # (name, cell data, tag, dimension)
    if "gmsh:physical" in cell_data:
        for name, value in (getattr(m, "field_data", None) or {}).items():
            value = np.asarray(value).ravel()
            groups.append((name, cell_data["gmsh:physical"], int(value[0]), int(value[1]) if len(value) > 1 else None))
    for tag, names in (getattr(m, "cell_tags", None) or {}).items() if "cell_tags" in cell_data else ():
        groups += [(name, cell_data["cell_tags"], tag, None) for name in names]
    for name, tags, tag, dim in groups:
        for b, t in enumerate(tags):
            if b < len(m.cells) and (dim is None or cell_dimension(m.cells[b].type) == dim):
                yield str(name), b, np.flatnonzero(np.asarray(t) == tag)


def read_node_sets(m: Any, renum: np.ndarray) -> dict[str, np.ndarray]:
    """Named node sets ``{name: sorted node indices}`` of a meshio mesh, numbered by ``renum`` (file
    node -> mesh node, -1 for nodes no volume cell uses, which are dropped).

    Point sets; the nodes of every named group of cells (:func:`named_cells`, whatever their dimension:
    a Gmsh physical group of facets names the nodes of those facets); MED groups of nodes (families of
    ``point_tags``). A name found in several of these gets the union.
    """
    found: dict[str, list[np.ndarray]] = {}

    def add(name: str, nodes: Any) -> None:
        found.setdefault(str(name), []).append(np.asarray(nodes, dtype=np.int64).ravel())

    for name, idx in (getattr(m, "point_sets", None) or {}).items():
        add(name, idx)
    for name, b, idx in named_cells(m):
        add(name, np.asarray(m.cells[b].data)[idx])
    point_tags = (getattr(m, "point_data", None) or {}).get("point_tags")
    for tag, names in (getattr(m, "point_tags", None) or {}).items() if point_tags is not None else ():
        for name in names:
            add(name, np.flatnonzero(np.asarray(point_tags) == tag))
    out = {}
    for name, parts in found.items():
        nodes = np.unique(np.concatenate(parts))
        nodes = renum[nodes[(nodes >= 0) & (nodes < len(renum))]]
        out[name] = np.unique(nodes[nodes >= 0])
    return out


def read_cell_sets(m: Any, kind: str) -> dict[str, np.ndarray]:
    """Named sets of volume cells ``{name: sorted cell indices}`` of a meshio mesh (:func:`named_cells`
    holding cells of type ``kind``), numbered like :func:`read_mesh`'s cells: the cells of type ``kind``
    in file order. A name holding only facets (or other cells) is no cell set."""
    offset, n = {}, 0
    for b, block in enumerate(m.cells):
        if block.type == kind:
            offset[b], n = n, n + len(block.data)
    found: dict[str, list[np.ndarray]] = {}
    for name, b, idx in named_cells(m):
        if b in offset and len(idx):
            found.setdefault(name, []).append(offset[b] + idx)
    return {name: np.unique(np.concatenate(parts)) for name, parts in found.items()}


@dataclass
class MeshFile(VolumeMesh):
    """A user's mesh file (:func:`read_mesh`): a :class:`~stepnf.geometry.VolumeMesh` with its named cell
    sets ``cell_sets`` ``{name: sorted rows of cells}`` (:func:`read_cell_sets`), the regions of
    ``[model.materials.<set>]``."""

    cell_sets: dict[str, np.ndarray] = field(default_factory=dict)


def hex20_to_hex27(mesh: VolumeMesh) -> VolumeMesh:
    """Quadratic hexahedra from serendipity ones: each face centre (one node per face, shared by its two
    cells) and body centre added at the image of its reference point by the cell's 20-node map.

    The geometry is the same where the 20-node map is quadratic along the new nodes (every affine cell,
    and curved ones to the map's own accuracy). Node sets keep their nodes; a face centre joins a set
    holding all eight nodes of its face, a body centre one holding all twenty of its cell.
    """
    from stepnf.geometry.hexahedra import HEX27_NODES, shape_functions

    P, C = mesh.points, mesh.cells
    N, _ = shape_functions(HEX27_NODES[20:], 20)  # (7, 20)
    X = np.einsum("qn,cnd->cqd", N, P[C])  # (cells, 7, 3): six face centres, body centre
    keys = np.sort(C[:, HEX_FACES[:, :4]], axis=2).reshape(-1, 4)
    faces, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    face_nodes = C[:, HEX_FACES].reshape(-1, 8)[first]  # (faces, 8)
    n0, nf = len(P), len(faces)
    points = np.concatenate([P, X[:, :6].reshape(-1, 3)[first], X[:, 6]])
    cells = np.column_stack([C, n0 + inverse.reshape(-1, 6), n0 + nf + np.arange(len(C))])
    sets = {}
    for name, nodes in mesh.node_sets.items():
        member = np.zeros(len(points), dtype=bool)
        member[nodes] = True
        member[n0:n0 + nf] = member[face_nodes].all(axis=1)
        member[n0 + nf:] = member[C].all(axis=1)
        sets[name] = np.flatnonzero(member)
    info = dict(mesh.info, cells_in_file="hexahedron20")
    # the same class (a MeshFile keeps its cell sets: the cells keep their rows)
    return replace(mesh, points=points, cells=cells, cell_type="hexahedron27", info=info, node_sets=sets)
