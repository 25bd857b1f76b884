"""Boundary conditions: zero displacements on named node sets or boxes, one vocabulary for every FE adapter.

A scene gives them as an array of tables in ``[model]``::

    [[model.boundary]]
    set = "LEFT"                       # a named node set of the mesh ("edge": the rim of a generated cap)
    dofs = ["ux", "uy", "uz"]          # optional; default every translation (clamped)

    [[model.boundary]]
    box = [[0.0, -1.0, -1.0], [0.0, 1.0, 1.0]]   # or: the nodes inside this box (corners, model units)
    dofs = ["uz"]

A shell's nodes have rotational dofs too (``rx ry rz``): ``dofs = ["ux", "uy", "uz", "rx", "ry", "rz"]``
clamps an edge (the default there), the translations alone simply support it. A rotation named
for a solver whose nodes have translations only (a solid) is a :class:`SceneError` naming the key
(exit 2): an adapter accepts rotations by calling :func:`boundary_conditions` with ``rotations=True``.

Only homogeneous conditions exist (the displacement is zero): STEP prescribes
displacement fields on the free dofs, and the tangent of a zero condition is
the same condition. An adapter removes the constrained dofs from the dofs it
exposes (:class:`FreeDofs`), so M, K, forces and mode shapes cover the free
dofs only; :meth:`FreeDofs.expand` maps a field back to the whole mesh.

A named set is whatever the mesh file calls one: an Abaqus/CalculiX ``*NSET``
(or the nodes of an ``*ELSET``), a Gmsh physical group, a meshio point or cell
set, a MED group; the adapter reads them into ``{name: node indices}`` and
:func:`select_nodes` resolves a condition against it. A box selects the
nodes within :func:`box_tolerance` of it (a round-off margin, so that
``x0 = x1 = 0`` picks the nodes of the plane ``x = 0``).

Dofs are numbered node-major (dof ``k i + d`` is direction ``d`` of node ``i``, ``k = 3`` dofs per
node for a solid, ``d`` in 0..2 for ux, uy, uz; ``k = 6`` for a shell, 3..5 for rx, ry, rz), as in
:mod:`stepnf.plugin.adapter`'s :data:`~stepnf.plugin.adapter.DIRECTIONS`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.keys.checks import check_number, describe_value
from stepnf.errors import SceneError, allowed
from stepnf.keys.schema import Key, Schema
from stepnf.plugin.adapter import DIRECTIONS

#: Dof names a condition may fix on a solid (the translations of its nodes).
DOF_NAMES = ("ux", "uy", "uz")
#: Coordinates of a box corner: lengths in model units, as the geometry keys allow.
COORDINATE_LIMIT = 1e12


def _box(file: str | Path | None, key: str, value: Any) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``[[x0, y0, z0], [x1, y1, z1]]``: two finite corners, each coordinate ``lo <= hi``."""
    ok = (isinstance(value, list) and len(value) == 2
          and all(isinstance(c, list) and len(c) == 3 for c in value))
    if not ok:
        raise SceneError(file, key, "expected two corners [[x0, y0, z0], [x1, y1, z1]] (model length units), got "
                         f"{describe_value(value)}")
    lo, hi = ([float(check_number(file, f"{key}[{i}][{j}]", c, lo=-COORDINATE_LIMIT, hi=COORDINATE_LIMIT))
               for j, c in enumerate(corner)] for i, corner in enumerate(value))
    bad = [j for j in range(3) if lo[j] > hi[j]]
    if bad:
        raise SceneError(file, key, f"the first corner must be the lower one: coordinate {'xyz'[bad[0]]} has "
                         f"{lo[bad[0]]:g} > {hi[bad[0]]:g}")
    return tuple(lo), tuple(hi)


#: One ``[[model.boundary]]`` table.
BOUNDARY = Schema(
    Key("set", "text", 'a named node set of the mesh ("edge": the outer rim of a generated cap)',
        what="a set name"),
    Key("box", "custom", "the nodes inside the box [[x0, y0, z0], [x1, y1, z1]] (instead of a set)",
        check_value=_box, what="[[x0, y0, z0], [x1, y1, z1]]"),
    Key("dofs", "list", "the fixed dofs (default: every dof of the node, a clamp: ux, uy, uz on a solid, and rx, "
        "ry, rz on a shell)", default=list(DOF_NAMES), choices=DIRECTIONS),
)
#: The ``boundary`` key every FE adapter includes in its ``[model]`` keys.
BOUNDARY_KEY = Key("boundary", "tables", "zero-displacement conditions on node sets or boxes ([[model.boundary]])",
                   table=BOUNDARY)


@dataclass(frozen=True)
class BoundaryCondition:
    """One homogeneous condition: the nodes of ``set`` (or inside ``box``) have ``dofs`` fixed at zero.

    ``where`` names its table in messages (``"model.boundary[0]"``); ``dofs`` are direction codes
    (0, 1, 2 for ux, uy, uz; 3, 4, 5 for a shell's rx, ry, rz).
    """

    where: str
    dofs: tuple[int, ...]
    set: str | None = None
    box: tuple[tuple[float, ...], tuple[float, ...]] | None = None


def boundary_conditions(entries: Sequence[Mapping[str, Any]] | None, file: str | Path | None,
                        where: str = "model.boundary", *, rotations: bool = False) -> list[BoundaryCondition]:
    """The conditions of ``[[model.boundary]]`` tables already checked by :data:`BOUNDARY_KEY`
    (each names exactly one of ``set`` and ``box``).

    ``rotations``: the solver's nodes have rotational dofs (a shell: ``dofs`` may name rx, ry, rz, and
    the default clamp fixes them too); otherwise (a solid) a rotation is a :class:`SceneError` naming
    ``<where>[i].dofs[j]``."""
    out = []
    names = DIRECTIONS if rotations else DOF_NAMES
    for i, e in enumerate(entries or ()):
        key = f"{where}[{i}]"
        if ("set" in e) == ("box" in e):
            raise SceneError(file, key, "give exactly one of set = \"<name>\" or box = [[x0, y0, z0], [x1, y1, z1]]")
        given = e.get("dofs", names)
        for j, d in enumerate(given):
            if d not in names:
                raise SceneError(file, f"{key}.dofs[{j}]", f"{d!r} is a rotation, and this solver's nodes have "
                                 f"translations only (a solid model, no rotational dofs); expected one of "
                                 f"{list(DOF_NAMES)}")
        dofs = tuple(DIRECTIONS.index(d) for d in given)
        out.append(BoundaryCondition(key, tuple(sorted(dofs)), set=e.get("set"), box=e.get("box")))
    return out


def box_tolerance(points: np.ndarray) -> float:
    """Margin (model units) of a box: 1e-6 of the mesh's bounding-box diagonal, far above the round-off
    of node coordinates (1e-16 relative) and far below any element size of a mesh of fewer than a
    million elements along a line."""
    P = np.asarray(points, dtype=float)
    return 1e-6 * float(np.linalg.norm(np.ptp(P, axis=0))) if len(P) else 0.0


def select_nodes(bc: BoundaryCondition, points: np.ndarray, node_sets: Mapping[str, np.ndarray],
                 file: str | Path | None, mesh: str | Path | None = None) -> np.ndarray:
    """Indices (0-based, sorted) of the nodes ``bc`` applies to; a SceneError naming the condition when
    the set does not exist (listing those that do) or the box holds no node."""
    if bc.set is not None:
        if bc.set not in node_sets:
            where = f" of {mesh}" if mesh else ""
            raise SceneError(file, f"{bc.where}.set", f"no node set {bc.set!r} in the mesh{where}; it has "
                             f"{allowed(sorted(node_sets)) if node_sets else 'no named sets (select nodes with box)'}")
        nodes = np.unique(np.asarray(node_sets[bc.set], dtype=np.int64))
        if nodes.size == 0:
            raise SceneError(file, f"{bc.where}.set", f"node set {bc.set!r} is empty")
        return nodes
    assert bc.box is not None
    P = np.asarray(points, dtype=float)
    tol = box_tolerance(P)
    lo, hi = np.asarray(bc.box[0]) - tol, np.asarray(bc.box[1]) + tol
    nodes = np.flatnonzero(np.all((P >= lo) & (P <= hi), axis=1))
    if nodes.size == 0:
        ext = np.ptp(P, axis=0) if len(P) else np.zeros(3)
        raise SceneError(file, f"{bc.where}.box", f"the box {list(map(list, bc.box))} holds no node of the mesh "
                         f"(its nodes span {np.min(P, axis=0).tolist()} .. {np.max(P, axis=0).tolist()}, "
                         f"extents {ext.tolist()}; margin {tol:.3g})")
    return nodes


def fixed_dofs(bcs: Sequence[BoundaryCondition], points: np.ndarray, node_sets: Mapping[str, np.ndarray],
               file: str | Path | None, mesh: str | Path | None = None, dofs_per_node: int = 3) -> np.ndarray:
    """Sorted indices of the node-major dofs (``dofs_per_node i + d``) the conditions fix."""
    codes = [d for bc in bcs for d in bc.dofs]
    if codes and max(codes) >= dofs_per_node:
        raise ValueError(f"a condition fixes direction {DIRECTIONS[max(codes)]}, but the nodes have "
                         f"{dofs_per_node} dofs ({', '.join(DIRECTIONS[:dofs_per_node])})")
    fixed = [select_nodes(bc, points, node_sets, file, mesh)[:, None] * dofs_per_node + np.asarray(bc.dofs)[None, :]
             for bc in bcs]
    return np.unique(np.concatenate([f.ravel() for f in fixed])) if fixed else np.zeros(0, dtype=np.int64)


class FreeDofs:
    """The free dofs of ``n_full`` dofs once ``fixed`` are removed, and the maps between the two numberings.

    ``free`` (sorted) are the full-numbering indices of the free dofs: free dof ``j`` is full dof
    ``free[j]``. Fields may be single (n,) or batches (m, n) along the last axis.
    """

    def __init__(self, n_full: int, fixed: np.ndarray | Sequence[int] = ()):
        fixed = np.unique(np.asarray(fixed, dtype=np.int64))
        if fixed.size and (fixed[0] < 0 or fixed[-1] >= n_full):
            raise ValueError(f"fixed dofs must lie in [0, {n_full}), got {fixed[0]} .. {fixed[-1]}")
        keep = np.ones(n_full, dtype=bool)
        keep[fixed] = False
        self.n_full = int(n_full)
        self.fixed = fixed
        self.free = np.flatnonzero(keep)

    @property
    def n_free(self) -> int:
        return int(self.free.size)

    @property
    def all_free(self) -> bool:
        return self.fixed.size == 0

    def restrict(self, u_full: np.ndarray) -> np.ndarray:
        """The free part of full fields."""
        return u_full if self.all_free else np.asarray(u_full)[..., self.free]

    def expand(self, u_free: np.ndarray) -> np.ndarray:
        """Full fields with zeros on the fixed dofs."""
        if self.all_free:
            return np.asarray(u_free)
        u_free = np.asarray(u_free)
        out = np.zeros(u_free.shape[:-1] + (self.n_full,), dtype=u_free.dtype)
        out[..., self.free] = u_free
        return out

    def restrict_matrix(self, A: sp.spmatrix) -> sp.csr_matrix:
        """``A[free][:, free]`` (the rows and columns of the fixed dofs removed)."""
        A = sp.csr_matrix(A)
        return A if self.all_free else A[self.free][:, self.free].tocsr()

    def describe(self) -> dict[str, Any]:
        return {"n_full": self.n_full, "n_fixed": int(self.fixed.size)}


def check_mechanism(n_rigid: int, has_conditions: bool) -> str | None:
    """Why a model with boundary conditions that still has ``n_rigid`` rigid-body modes is suspect
    (``None`` when fine): conditions meant to hold a structure usually leave none."""
    if not has_conditions or n_rigid == 0:
        return None
    what = "one rigid-body mode" if n_rigid == 1 else f"{n_rigid} rigid-body modes"
    return (f"the boundary conditions (the scene's and a deck's own) leave {what} (a mechanism: the "
            f"structure can move without deforming); constrain more dofs, or set analysis.rigid_modes = "
            f"{n_rigid} to accept {'it' if n_rigid == 1 else 'them'}")


__all__ = ["DOF_NAMES", "BOUNDARY", "BOUNDARY_KEY", "BoundaryCondition", "boundary_conditions", "box_tolerance",
           "select_nodes", "fixed_dofs", "FreeDofs", "check_mechanism"]
