"""Shells in the ``code_aster`` adapter: ``element = "dkt"`` (modelisation ``DKT``) or ``"coque_3d"`` (``COQUE_3D``).

A user's MED mesh of the mid-surface (``mesh = "panel.med"``; ``TRIA3``/``QUAD4`` cells for DKT, ``TRIA7``/
``QUAD9`` for COQUE_3D, line cells of its edges allowed) with ``thickness`` (m, ``AFFE_CARA_ELEM`` ``COQUE``
``EPAIS``) and an isotropic ``[model.material]``. Dofs, node by node in the mesh's node order: ``ux uy uz rx
ry rz`` (code_aster's ``DX DY DZ DRX DRY DRZ``, codes 0..5 of :data:`stepnf.plugin.adapter.DIRECTIONS`; the
rotations are rotation vectors in radians) at every node of a shell cell, except the centre node of a
COQUE_3D cell (the 7th of a ``TRIA7``, the 9th of a ``QUAD9``), which carries ``DRX DRY DRZ`` only
(code_aster's U3.12.03 element description). Nodes in no shell cell carry no dof.

Jobs: ``forces_shell.comm`` (one ``STAT_NON_LINE`` per field from the reference state, ``DEFORMATION =
"GROT_GDEP"``, every dof imposed; ``FORC_NODA`` read back with its moments) and ``matrices_shell.comm``
(``RIGI_MECA``, ``MASS_MECA`` with the rotational dofs). Both are checked against code_aster 15's command
catalogue (``tests/solvers/code_aster/test_code_aster_catalogue.py``); code_aster cannot be installed here,
so neither was run by stepnf. What code_aster's documentation and sources say of DKT under large
displacements: ``solvers/code_aster/README.md``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.errors import SceneError
from stepnf.external import missing_output
from stepnf.plugin.boundary import FreeDofs, select_nodes

from .adapter import FIELD_IN, FIELD_OUT, REAL, CodeAsterAdapter, load_matrices_npz
from .materials import is_plain, python_str
from .med import MedError, add_nodal_field, read_groups, read_mesh_nodes

#: ``element`` -> (code_aster ``MODELISATION``, MED cell types of the shell, MED types whose last node is a
#: rotation-only centre node)
SHELLS = {"dkt": ("DKT", ("TR3", "QU4"), ()), "coque_3d": ("COQUE_3D", ("TR7", "QU9"), ("TR7", "QU9"))}
#: code_aster's nodal components of a shell node, in the order of DIRECTIONS
SHELL_COMPONENTS = ("DX", "DY", "DZ", "DRX", "DRY", "DRZ")
#: MED cell type -> nodes per cell (the surface and line types a shell mesh may hold)
MED_NODES = {"TR3": 3, "QU4": 4, "TR6": 6, "QU8": 8, "TR7": 7, "QU9": 9, "SE2": 2, "SE3": 3, "PO1": 1}
#: the cell group every shell cell is put in (``AFFE_CARA_ELEM`` ``COQUE`` takes groups, not ``TOUT``)
SHELL_GROUP = "STEPNF_SHELL"


def read_cells(path: str | Path, mesh: str) -> dict[str, np.ndarray]:
    """The cells of a MED mesh by MED type: ``{type: (n_cells, n_nodes) 0-based node positions}``."""
    import h5py

    out = {}
    try:
        with h5py.File(path, "r") as f:
            st = next(iter(f["ENS_MAA"][mesh].values()))
            for kind, grp in (st["MAI"].items() if "MAI" in st else ()):
                if "NOD" in grp:
                    n = int(grp["NOD"].attrs["NBR"])
                    out[kind] = np.asarray(grp["NOD"], dtype=np.int64).reshape(-1, n).T - 1  # stored node-major
    except (OSError, KeyError, ValueError, StopIteration) as exc:
        raise MedError(f"{path}: cannot read the cells of the MED mesh ({type(exc).__name__}: {exc})") from None
    return out


def shell_dofs(n_nodes: int, cells: Mapping[str, np.ndarray], element: str, source: Any) -> tuple[np.ndarray, ...]:
    """``(node, code)`` of every dof, node-major (codes ascending within a node), for ``element``'s cells;
    a ValueError naming ``source`` for a mesh without shell cells or with volume cells."""
    _, kinds, centred = SHELLS[element]
    other = sorted(k for k in cells if k not in kinds and k not in ("SE2", "SE3", "PO1"))
    if other or not any(k in cells for k in kinds):
        raise ValueError(f"{source}: element = {element!r} takes a MED mesh of {list(kinds)} cells (and their edges' "
                         f"line cells); this mesh has {sorted(cells) or 'no cells'}"
                         + (f" ({other} are not {element} cells)" if other else ""))
    codes = np.zeros((n_nodes, 6), dtype=bool)
    for k in kinds:
        c = cells.get(k)
        if c is None:
            continue
        if k in centred:
            codes[c[:, :-1].ravel(), :] = True
            codes[c[:, -1], 3:] = True
        else:
            codes[c.ravel(), :] = True
    node, code = np.nonzero(codes)
    return node.astype(np.int64), code.astype(np.int64)


class CodeAsterShellAdapter(CodeAsterAdapter):
    """A shell model run by code_aster (see the module docstring): dofs ``(node, code)`` of :func:`shell_dofs`."""

    def __init__(self, points: np.ndarray, *, element: str, thickness: float, cells: Mapping[str, np.ndarray],
                 **kw: Any):
        if element not in SHELLS:
            raise ValueError(f"element {element!r}: shells are {list(SHELLS)}")
        if not (isinstance(thickness, (int, float)) and np.isfinite(thickness) and thickness > 0):
            raise ValueError(f"thickness {thickness!r}: expected a positive length (m)")
        if kw.get("force_route", "stat_non_line") != "stat_non_line":
            raise ValueError("force_route: shells take the STAT_NON_LINE route only (forces_shell.comm: one run per "
                             "field from the reference state)")
        self.element, self.thickness = element, float(thickness)
        self.dof_node, self.dof_code = shell_dofs(len(points), cells, element, kw.get("mesh_file") or "the mesh")
        super().__init__(points, **kw)
        self.geometry = {**self.geometry, "h": self.thickness}
        self._index = {(int(n), int(c)): i for i, (n, c) in enumerate(zip(self.dof_node, self.dof_code))}

    @staticmethod
    def check_shell_keys(c: dict[str, Any], scene_file: Any) -> None:
        """SceneErrors for a shell element without a MED mesh or a thickness, or a thickness given to a solid;
        a shell's ``element`` becomes ``shell``, passed on to :meth:`CodeAsterAdapter.from_med`."""
        shell = c.get("element", "hex20") in SHELLS
        if shell and "mesh" not in c:
            raise SceneError(scene_file, "model.element", f"element = {c['element']!r} (a shell) takes mesh = "
                             "\"<MED mesh of the mid-surface>\" and thickness; the generated caps are volume meshes")
        if shell != ("thickness" in c):
            raise SceneError(scene_file, "model.thickness", "a shell (element = \"dkt\" or \"coque_3d\") needs "
                             "thickness = <m>" if shell else "thickness is a shell's: element = \"dkt\" or "
                             "\"coque_3d\" (a solid's thickness is its mesh's)")
        if shell:
            c["shell"] = c.pop("element")  # build_solid passes the other keys on to from_med

    @staticmethod
    def takes_rotations(config: Mapping[str, Any]) -> bool:
        """Whether ``config`` is a shell scene: its ``[[model.boundary]]`` may fix rotations, and clamps by default
        (:meth:`stepnf.external.SolidFromScene.rotational_dofs`)."""
        return config.get("element") in SHELLS

    @classmethod
    def from_shell_med(cls, path: str | Path, mesh_name: str, element: str, **kw: Any) -> "CodeAsterShellAdapter":
        """A user's MED mid-surface mesh ``mesh_name`` of ``element`` cells (``thickness`` among ``kw``)."""
        return cls(read_mesh_nodes(path, mesh_name), element=element, thickness=kw.pop("thickness"),
                   cells=read_cells(path, mesh_name), mesh_file=path, mesh_name=mesh_name,
                   node_sets=read_groups(path, mesh_name), **kw)

    def apply_materials(self, materials, *, scene_file: Any = None) -> None:
        if not is_plain(materials) or None not in materials:
            raise SceneError(scene_file, "model.materials" if len(materials) > 1 else "model.material",
                             f"element = {self.element!r}: shells take one isotropic [model.material] (E, nu, rho); "
                             "orthotropic constants and [model.materials] regions are for solids")
        super().apply_materials(materials, scene_file=scene_file)

    def _comm(self, job: str) -> str:
        return f"{job}_shell.comm"

    # ---------------------------------------------------------------- dofs
    @property
    def n_full(self) -> int:
        return len(self.dof_node)

    @property
    def n_dofs(self) -> int:
        return self.n_full if self.free_dofs is None else self.free_dofs.n_free

    def dof_coordinates(self) -> np.ndarray:
        X = self.points[self.dof_node]
        return X if self.free_dofs is None else X[self.free_dofs.free]

    def dof_directions(self) -> np.ndarray:
        return self.dof_code if self.free_dofs is None else self.dof_code[self.free_dofs.free]

    def characteristic_length(self) -> float:
        return self.thickness

    def nodal(self, phi: np.ndarray) -> np.ndarray:
        """A field over the exposed dofs as nodal values (N, 6): ux uy uz rx ry rz, zeros where no dof is."""
        phi = np.asarray(phi, dtype=float)
        full = phi if self.free_dofs is None else self.free_dofs.expand(phi)
        out = np.zeros((len(self.points), 6))
        out[self.dof_node, self.dof_code] = full
        return out

    def apply_boundary(self, conditions: Sequence[Any], *, scene_file: Any = None, mesh: Any = None) -> None:
        """Fix the dofs (translations and rotations) the conditions select (see the base class)."""
        if self._K is not None:
            raise RuntimeError("apply_boundary after K was built: the matrices kept cover the old dofs")
        fixed = [np.zeros(0, dtype=np.int64) if self.free_dofs is None else self.free_dofs.fixed]
        listed = list(self.applied_conditions)
        for c in conditions:
            nodes = select_nodes(c, self.points, self.node_sets, scene_file, mesh)
            hit = np.isin(self.dof_node, nodes) & np.isin(self.dof_code, np.asarray(c.dofs))
            fixed.append(np.flatnonzero(hit))
            where = {"set": c.set} if c.set is not None else {"box": [list(x) for x in c.box]}
            listed.append({"condition": c.where, **where, "dofs": [SHELL_COMPONENTS[d] for d in c.dofs],
                           "nodes": int(nodes.size)})
        all_fixed = np.unique(np.concatenate(fixed))
        self.free_dofs = FreeDofs(self.n_full, all_fixed) if all_fixed.size else None
        self.applied_conditions = tuple(listed)

    # ---------------------------------------------------------------- jobs
    def _values(self, workdir: Path, job: str, n_fields: int = 0) -> dict[str, Any]:
        vals = super()._values(workdir, job, n_fields)
        modelisation = SHELLS[self.element][0]
        vals.update(thickness=REAL % self.thickness, modelisation=modelisation, shell_group=SHELL_GROUP,
                    modelisation_py=python_str(modelisation), shell_group_py=python_str(SHELL_GROUP))
        return vals

    def _write_model(self, workdir: Path, U: np.ndarray | None = None) -> None:
        super()._write_model(workdir)  # the mesh (a user's MED file, copied)
        if U is not None:
            steps = [(0.0, np.zeros((len(self.points), 6)))] + [(float(i + 1), self.nodal(u)) for i, u in enumerate(U)]
            add_nodal_field(workdir / "model.med", FIELD_IN, SHELL_COMPONENTS, steps, mesh_name=self.mesh_name)

    def read_forces(self, workdir: Path, m: int) -> np.ndarray:
        return self.free_part(forces_from_steps(self.force_steps(workdir), self.dof_node, self.dof_code, len(self.points), m, workdir))

    def _read_matrices(self, path: Path, workdir: Path) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        n_eq, nodes, comps, K, M = load_matrices_npz(path)
        code = {c: i for i, c in enumerate(SHELL_COMPONENTS)}
        index = np.array([self._index.get((int(nd), code.get(c, -1)), -1) for nd, c in zip(nodes, comps)], np.int64)
        n = self.n_full
        if n_eq != n or len(index) != n or (n and index.min() < 0) or len(np.unique(index)) != n:
            raise missing_output(workdir, f"matrices.npz: {n_eq} equations ({sorted(set(comps))}), expected the {n} "
                                          f"shell dofs (DX DY DZ DRX DRY DRZ) of the mesh's {self.element} cells")
        perm = sp.csr_matrix((np.ones(n), (index, np.arange(n))), shape=(n, n))
        return (perm @ K @ perm.T).tocsr(), (perm @ M @ perm.T).tocsr()


def forces_from_steps(steps: Sequence[Any], dof_node: np.ndarray, dof_code: np.ndarray, n_nodes: int, m: int,
                      workdir: Path) -> np.ndarray:
    """The (m, n_dofs) forces of a MED nodal field's steps at times 1..m (the shell's dofs ``(node, code)``):
    forces on DX DY DZ, moments on DRX DRY DRZ. A missing step or component is a SolverRunError."""
    by_time = {int(round(s.time)): s for s in steps if abs(s.time - round(s.time)) < 1e-9}
    F = np.empty((m, len(dof_node)))
    for i in range(1, m + 1):
        s = by_time.get(i)
        if s is None:
            raise missing_output(workdir, f"forces.rmed: field {FIELD_OUT!r} has no step at time {i} (of {m}); "
                                          f"found times {sorted(by_time)[:10]}")
        need = sorted(set(int(c) for c in dof_code))
        missing = [SHELL_COMPONENTS[c] for c in need if SHELL_COMPONENTS[c] not in s.components]
        if missing:
            raise missing_output(workdir, f"forces.rmed: field {FIELD_OUT!r} lacks components {missing} (a shell's "
                                          "FORC_NODA has DX DY DZ DRX DRY DRZ)")
        have = [c for c in range(6) if SHELL_COMPONENTS[c] in s.components]
        full = np.zeros((n_nodes, 6))
        full[:, have] = s.full(n_nodes)[:, [s.components.index(SHELL_COMPONENTS[c]) for c in have]]
        F[i - 1] = full[dof_node, dof_code]
    return F


CodeAsterAdapter.shell_class = CodeAsterShellAdapter
