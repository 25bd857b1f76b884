"""A user's mesh file for the ``fenicsx`` adapter: its volume cells, named node sets and cell sets.

:func:`read_mesh` keeps the volume cells of one type dolfinx can use
(``hexahedron27``, ``tetra10``, ``hexahedron``, ``tetra``) or serendipity
``hexahedron20`` (a CalculiX ``C3D20`` mesh), which :func:`hex20_to_hex27`
completes into quadratic hexahedra, so that the same mesh file serves both
solvers. An ``.inp`` file is read by stepnf's own reader (:func:`read_inp`,
:mod:`stepnf.geometry.inp`, the calculix adapter's), any other format by meshio,
whose named sets :func:`stepnf.geometry.mesh_sets.read_node_sets` (the node sets
boundary conditions refer to, :mod:`stepnf.plugin.boundary`) and
:func:`~stepnf.geometry.mesh_sets.read_cell_sets` (the cell sets
``[model.materials.<set>]`` refer to, :mod:`stepnf_fenicsx.regions`) give.
Units: those of the file.
"""
from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from stepnf.geometry import VolumeMesh
from stepnf.geometry.mesh_sets import read_cell_sets, read_node_sets

from . import _compat

#: the faces of a VTK hexahedron20/27 (-x +x -y +y -z +z): corners then mid-edge nodes; face centre 20 + i
HEX_FACES = np.array([(0, 3, 7, 4, 11, 19, 15, 16), (1, 2, 6, 5, 9, 18, 13, 17), (0, 1, 5, 4, 8, 17, 12, 16),
                      (3, 2, 6, 7, 10, 18, 14, 19), (0, 1, 2, 3, 8, 9, 10, 11), (4, 5, 6, 7, 12, 13, 14, 15)])
#: cell types :func:`read_mesh` accepts: dolfinx's, and hexahedron20 completed to hexahedron27
READABLE = (*_compat.CELLS, "hexahedron20")


def read_mesh(path: str | Path) -> "MeshFile":
    """Read the volume cells of a mesh file (one supported cell type) and its named node sets.

    An Abaqus/CalculiX ``.inp`` file is read by stepnf's own reader, the one the ``calculix`` adapter uses
    (:func:`read_inp`); any other format through meshio:

    ``node_sets``: :func:`read_node_sets` (point sets, cell sets, Gmsh physical groups, MED groups),
    numbered like the returned points; ``cell_sets``: :func:`read_cell_sets`, the named sets of its
    volume cells, numbered like the returned cells. Every defect :func:`stepnf.geometry.checks.check_volume_mesh`
    knows (no cells, NaN coordinates, dangling node numbers, flat meshes, coincident nodes,
    degenerate, tangled or overlapping cells) is a :class:`~stepnf.errors.MeshError` naming the file
    and the cell or node (0-based positions in the file, cells counted within their type).
    """
    if Path(path).suffix.lower() == ".inp":
        return read_inp(path)
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


def read_inp(path: str | Path) -> "MeshFile":
    """An ``.inp`` mesh through :func:`stepnf.geometry.inp.read_inp_mesh` (``*ELSET ... GENERATE``, sets of
    sets, ``*INCLUDE``; facet elements beside the solids taken as node sets and said by a
    :class:`~stepnf.errors.ModelWarning`): nodes sorted by id (the calculix adapter's order), cells in the
    order of the file's elements of one type, node and cell sets by upper-case name, looked up
    case-insensitively (as ccx does)."""
    import warnings

    from stepnf.errors import MeshError, ModelWarning
    from stepnf.geometry.inp import MESHIO_TYPES, SetNames, facets_note, read_inp_mesh

    m = read_inp_mesh(path)
    kinds = [MESHIO_TYPES[t] for t, _, _ in m.blocks]
    if any(k not in READABLE for k in kinds):
        raise MeshError(path, f"no volume cells dolfinx can use; found {[t for t, _, _ in m.blocks]}, supported "
                              f"{list(READABLE)}")
    if len(set(kinds)) > 1:
        raise MeshError(path, f"mixed volume cell types {sorted({t for t, _, _ in m.blocks})}; give one cell type")
    ids = np.concatenate([e for _, e, _ in m.blocks])
    cells = np.searchsorted(m.node_ids, np.concatenate([c for _, _, c in m.blocks]))
    cell_sets = SetNames()
    for name, members in m.element_sets.items():
        rows = np.flatnonzero(np.isin(ids, np.asarray(members, dtype=np.int64)))
        if rows.size:
            cell_sets[name] = rows
    note = facets_note(m, path)
    if note:
        warnings.warn(note, ModelWarning, stacklevel=2)
    info = {"file": str(path), **({"facets_ignored": dict(m.facets)} if m.facets else {})}
    mesh = MeshFile(points=np.asarray(m.points, dtype=float), cells=cells.astype(np.int64), cell_type=kinds[0],
                    info=info, node_sets=m.node_sets, cell_sets=cell_sets)
    return hex20_to_hex27(mesh) if mesh.cell_type == "hexahedron20" else mesh


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
    sets = type(mesh.node_sets)()  # a .inp file's keep their case-insensitive look-up
    for name, nodes in mesh.node_sets.items():
        member = np.zeros(len(points), dtype=bool)
        member[nodes] = True
        member[n0:n0 + nf] = member[face_nodes].all(axis=1)
        member[n0 + nf:] = member[C].all(axis=1)
        sets[name] = np.flatnonzero(member)
    info = dict(mesh.info, cells_in_file="hexahedron20")
    # the same class (a MeshFile keeps its cell sets: the cells keep their rows)
    return replace(mesh, points=points, cells=cells, cell_type="hexahedron27", info=info, node_sets=sets)
