"""Boundary conditions of the FEniCSx adapters: named node sets and boxes of a mesh -> dofs of dolfinx's space.

A scene's ``[[model.boundary]]`` tables (:mod:`stepnf.plugin.boundary`, the one
vocabulary of every FE adapter) select *mesh nodes*: a named set of the mesh
file (:func:`stepnf.geometry.mesh_sets.read_node_sets`: meshio point sets, cell
sets and their nodes, Gmsh physical groups of any dimension, MED groups), the
set ``"edge"`` of a generated cap (every node of its lateral face), or the
nodes inside a box.
:func:`point_mask` turns them into a table ``(mesh nodes, 3)`` of fixed
directions, and :func:`dof_node_mask` carries it to the dof nodes of the
vector space, cell by cell, without any coordinate tolerance:

* isoparametric meshes (``hexahedron27``, ``tetra10`` with the degree-2
  space): the dofs of a cell *are* its geometry nodes, in the same local order
  (same Lagrange element), so a dof node is fixed in the directions of its mesh
  node (``geometry.input_global_indices`` is each geometry node's row in the file);
* linear cells (``hexahedron``, ``tetra``) under the degree-2 space: a vertex
  dof takes its vertex's directions; a dof inside an edge, a face or a cell is
  fixed in the directions fixed at *every* vertex of that entity (a face whose
  corners are all clamped is clamped, mid-edge dofs included).

Under MPI every rank reads the same mesh, selects the same nodes and marks its
local (owned and ghost) dof nodes; the global fixed dofs are their union
(:meth:`stepnf_fenicsx.parallel.DistributedFenicsxAdapter`). Units: those of the mesh.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from stepnf.plugin.boundary import (BOUNDARY_KEY, DOF_NAMES, BoundaryCondition, FreeDofs, boundary_conditions,
                             select_nodes)

from . import _compat


def as_conditions(boundary: Sequence[BoundaryCondition | Mapping[str, Any]] | None,
                  scene_file: str | Path | None = None) -> list[BoundaryCondition]:
    """Boundary conditions from :class:`~stepnf.plugin.boundary.BoundaryCondition` s, or from
    ``[[model.boundary]]``-like tables (checked by :data:`stepnf.plugin.boundary.BOUNDARY_KEY`)."""
    items = list(boundary or ())
    if all(isinstance(b, BoundaryCondition) for b in items):
        return items
    entries = BOUNDARY_KEY.check(items, file=scene_file, where="model", base_dir=".")
    return boundary_conditions(entries, scene_file)


def point_mask(bcs: Sequence[BoundaryCondition], points: np.ndarray, node_sets: Mapping[str, np.ndarray],
               scene_file: str | Path | None, mesh_name: str | Path | None = None) -> tuple[np.ndarray, list[int]]:
    """``(mask, counts)``: ``mask[i, d]`` when direction ``d`` of mesh node ``i`` is fixed, and the number
    of nodes each condition selects; a :class:`~stepnf.errors.SceneError` naming the condition for an
    unknown set (listing the sets the mesh has) or a box holding no node."""
    mask = np.zeros((len(points), 3), dtype=bool)
    counts = []
    for bc in bcs:
        nodes = select_nodes(bc, points, node_sets, scene_file, mesh_name)
        mask[np.ix_(nodes, np.asarray(bc.dofs))] = True
        counts.append(int(nodes.size))
    return mask, counts


def dof_node_mask(V: Any, input_index: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``(local dof nodes, 3)`` bool: the fixed directions at each dof node (owned and ghost) of the blocked
    space ``V``, from ``mask`` over the mesh file's nodes (see the module docstring);
    ``input_index[g]`` is the file node of geometry node ``g``."""
    msh = V.mesh
    n_cells = _compat.num_cells(msh)
    geo = _compat.geometry_dofmap(msh)[:n_cells]
    dofs = _compat.cell_dofmap(V)[:n_cells]
    im = V.dofmap.index_map
    out = np.zeros((im.size_local + im.num_ghosts, 3), dtype=bool)
    at_geo = mask[np.asarray(input_index)[geo]]  # (cells, geometry nodes, 3)
    if geo.shape[1] == dofs.shape[1]:  # isoparametric: dof k of a cell is its geometry node k
        for k in range(dofs.shape[1]):
            out[dofs[:, k]] |= at_geo[:, k]
        return out
    import basix

    layout = V.dofmap.dof_layout
    topology = basix.topology(getattr(basix.CellType, _compat.cell_name(msh)))
    for dim, entities in enumerate(topology):
        for i, vertices in enumerate(entities):
            fixed = np.logical_and.reduce(at_geo[:, vertices], axis=1)  # (cells, 3): every vertex fixed
            for k in layout.entity_dofs(dim, i):
                out[dofs[:, k]] |= fixed
    return out


def free_dofs_of(local_mask: np.ndarray) -> FreeDofs:
    """The free dofs of a serial space whose node-major dof ``3 i + d`` is fixed where ``local_mask[i, d]``."""
    return FreeDofs(local_mask.size, np.flatnonzero(local_mask.ravel()))


def describe_conditions(bcs: Sequence[BoundaryCondition], counts: Sequence[int], free: FreeDofs | None,
                        **extra: Any) -> dict[str, Any]:
    """What :meth:`describe` stores about the conditions (JSON-serialisable)."""
    rows = []
    for bc, n in zip(bcs, counts):
        row: dict[str, Any] = {"set": bc.set} if bc.set is not None else {"box": [list(c) for c in bc.box]}
        row.update(dofs=[DOF_NAMES[d] for d in bc.dofs], nodes=int(n))
        rows.append(row)
    out: dict[str, Any] = {"conditions": rows, **extra}
    if free is not None:
        out.update(free.describe())
    return out
