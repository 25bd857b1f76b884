"""Reading a user's mesh for the ``calculix`` adapter (the ``mesh`` key): an ``.inp`` or a Gmsh ``.msh`` file.

* ``.inp`` (Abaqus/CalculiX): stepnf's own reader, the one the ``fenicsx``
  adapter uses too (:func:`stepnf.geometry.inp.read_inp_mesh`): every
  ``*NODE``, the ``*ELEMENT`` blocks of solid types (``C3D*``), the ``*NSET``
  and ``*ELSET`` sets (for ``[[model.boundary]] set = "..."``: an ``*ELSET``
  names the nodes of its elements; for ``[model.materials.<set>]``: its
  elements). Surface and line elements beside the solids (Gmsh's ``.inp``
  export writes ``CPS6``/``CPS8``/``T3D3`` ... for its physical surfaces and
  curves) are no part of the model: their ``*ELSET`` s name node sets, and a
  :class:`~stepnf.errors.ModelWarning` says so. Materials, sections,
  boundary conditions and steps in the file are ignored (stepnf writes its
  own from the scene's materials, :mod:`.sections`; a whole model is read
  with ``deck =`` instead, :mod:`.userdeck`).
* ``.msh`` (Gmsh, any version meshio reads): the volume cells of the types of
  :data:`CCX_OF_MESHIO` become CalculiX elements (meshio gives them in VTK's
  node order, which is CalculiX's for these types: :data:`stepnf.geometry.inp.MESHIO_TYPES`),
  numbered 1, 2, ... in the file's order, nodes 1, 2, ... in the file's order
  of the nodes they use; Gmsh physical groups name node sets (any dimension:
  a group of surfaces names the nodes of its facets) and element sets (groups
  of volumes), by upper-case name as for ``.inp`` (looked up
  case-insensitively). Facets are said like those of an ``.inp``.
"""
from __future__ import annotations

import contextlib
import io
import warnings
from pathlib import Path

import numpy as np

from stepnf.errors import MeshError, ModelWarning
from stepnf.geometry.inp import MESHIO_TYPES, InpMesh, SetNames, facets_note, read_inp_mesh
from stepnf.geometry.mesh_sets import cell_dimension, named_cells, read_node_sets

__all__ = ["read_inp_mesh", "read_mesh_file", "read_msh", "InpMesh"]

#: meshio (VTK) volume cell type -> CalculiX element type (the same node order).
CCX_OF_MESHIO = {"tetra": "C3D4", "wedge": "C3D6", "hexahedron": "C3D8", "tetra10": "C3D10", "wedge15": "C3D15",
                 "hexahedron20": "C3D20"}
assert all(MESHIO_TYPES[c] == m for m, c in CCX_OF_MESHIO.items())
#: suffixes of the ``mesh`` key
MESH_SUFFIXES = (".inp", ".msh")


def read_mesh_file(path: str | Path) -> InpMesh:
    """The mesh of ``path`` (``.inp`` or ``.msh``, see the module docstring), facets said by a warning;
    a :class:`~stepnf.errors.MeshError` naming the file and what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise MeshError(path, f"mesh file {path} does not exist")
    mesh = read_msh(path) if path.suffix.lower() == ".msh" else read_inp_mesh(path)
    note = facets_note(mesh, path)
    if note:
        warnings.warn(note, ModelWarning, stacklevel=3)
    return mesh


def read_msh(path: str | Path) -> InpMesh:
    """A Gmsh ``.msh`` file as an :class:`~stepnf.geometry.inp.InpMesh` (see the module docstring), checked by
    :func:`stepnf.geometry.checks.check_volume_mesh`."""
    import meshio

    from stepnf.geometry.checks import check_volume_mesh

    said = io.StringIO()  # meshio prints the errors of the readers it tries on stdout
    try:
        with contextlib.redirect_stdout(said):
            m = meshio.read(str(path), file_format="gmsh")
    except (SystemExit, Exception) as exc:  # meshio raises many kinds (and exits on some files)
        why = " ".join((said.getvalue() + ("" if isinstance(exc, SystemExit) else f" {exc}")).split())
        raise MeshError(path, f"meshio cannot read this file as a Gmsh .msh file: {why or 'unknown or corrupt format'}"
                        ) from None
    volume = [b for b, c in enumerate(m.cells) if c.type in CCX_OF_MESHIO]
    found = sorted({c.type for c in m.cells})
    if not volume:
        raise MeshError(path, f"no volume cells CalculiX can use; found {found or 'no cells at all'}, supported "
                              f"{sorted(CCX_OF_MESHIO)}")
    pts = np.asarray(m.points, dtype=float)
    check_volume_mesh(pts, [(m.cells[b].type, np.asarray(m.cells[b].data)) for b in volume], source=path)
    used = np.unique(np.concatenate([np.asarray(m.cells[b].data).ravel() for b in volume]))
    renum = np.full(len(pts), -1)
    renum[used] = np.arange(len(used))
    blocks, first, start = [], {}, 1
    for b in volume:
        conn = renum[np.asarray(m.cells[b].data, dtype=np.int64)] + 1
        blocks.append((CCX_OF_MESHIO[m.cells[b].type], np.arange(start, start + len(conn)), conn))
        first[b], start = start, start + len(conn)
    element_sets: dict[str, list[int]] = {}
    for name, b, rows in named_cells(m):
        if b in first:
            element_sets.setdefault(name.upper(), []).extend((first[b] + rows).tolist())
    element_sets = {name: sorted(set(ids)) for name, ids in element_sets.items()}  # a group named twice by meshio
    node_sets = SetNames({name.upper(): nodes for name, nodes in read_node_sets(m, renum).items()})
    facets: dict[str, int] = {}
    for c in m.cells:
        if c.type not in CCX_OF_MESHIO and cell_dimension(c.type) in (1, 2):
            facets[c.type] = facets.get(c.type, 0) + len(c.data)
    return InpMesh(used + 1, pts[used], blocks, node_sets, element_sets, facets)
