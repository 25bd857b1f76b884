"""The ``kratos`` adapter: thin co-rotational shells of Kratos Multiphysics, driven as a black box.

Dofs: six per node, node-major (dof ``6 i + d``, ``d`` = ux uy uz rx ry rz, rotations in radians), the
ones fixed by ``[[model.boundary]]`` removed (:class:`stepnf.plugin.boundary.FreeDofs`: Kratos assembles
the free structure and the free rows and columns are kept, exact for homogeneous conditions). K and the
consistent M come from Kratos's elements at the undeformed state, the internal forces from its own
element routines at prescribed displacements and total rotation vectors, a whole batch of fields per
request to the worker process (:mod:`.worker`, :mod:`.client`). No element code here.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.errors import SceneError
from stepnf.plugin.adapter import SolverAdapter
from stepnf.plugin.boundary import BoundaryCondition, FreeDofs, fixed_dofs
from stepnf.plugin.dofs import translation_mask
from stepnf.plugin.lazy_matrices import LazyMatrices
from stepnf.runtime.progress import thousands

from .config import MODEL_KEYS, parse_model
from .shellmesh import KRATOS_ELEMENT, ShellMesh, cap_surface, read_shell_mesh

DOFS_PER_NODE = 6


class KratosAdapter(LazyMatrices, SolverAdapter):
    """A shell model of Kratos (``ShellThinElementCorotational3D3N`` or ``...3D4N``).

    Parameters
    ----------
    mesh : the mid-surface (:class:`~.shellmesh.ShellMesh`)
    element : ``"dkt"`` (triangles) or ``"dkq"`` (quadrilaterals)
    thickness : shell thickness (model length unit)
    material : ``{"E", "nu", "rho"}`` of every cell no ``materials`` set names
    materials : ``{cell set: {"E", "nu", "rho"}}`` for the mesh's named cell sets
    geometry : ``{"a", "R", "h"}`` (cap placement: shell scales, labels), or ``None``
    boundary : homogeneous conditions (:class:`~stepnf.plugin.boundary.BoundaryCondition`, dof codes 0-5)
    threads, timeout : ``OMP_NUM_THREADS`` of the worker (default 1) and seconds per request
    """

    name = "kratos"
    model_keys = MODEL_KEYS
    prefers_batches = True

    def __init__(self, mesh: ShellMesh, *, element: str = "dkt", thickness: float, material: Mapping[str, float] | None,
                 materials: Mapping[str, Mapping[str, float]] | None = None, geometry: Mapping[str, Any] | None = None,
                 boundary: Sequence[BoundaryCondition] = (), threads: int | None = None, timeout: float | None = 3600.0,
                 scene_file: str | Path | None = None):
        from stepnf.plugin.materials import assign_cells

        if element not in KRATOS_ELEMENT:
            raise ValueError(f"unknown element {element!r}; pick one of {list(KRATOS_ELEMENT)}")
        self.mesh, self.element, self.thickness = mesh, element, float(thickness)
        self.geometry = None if geometry is None else dict(geometry)
        named = dict(materials or {})
        owner = assign_cells(len(mesh.cells), mesh.cell_sets, list(named), material is not None, scene_file,
                             mesh.info.get("file"))
        self.materials = [dict(material) if material is not None else None, *map(dict, named.values())]
        self._cell_material = owner
        self.material = self.materials[0] if not named else None
        self.points = np.asarray(mesh.points, dtype=float)
        n_full = DOFS_PER_NODE * len(self.points)
        fixed = fixed_dofs(boundary, self.points, mesh.node_sets, scene_file, mesh.info.get("file"),
                           dofs_per_node=DOFS_PER_NODE)
        self.free_dofs = FreeDofs(n_full, fixed)
        if self.free_dofs.n_free == 0:
            raise SceneError(scene_file, "model.boundary", f"the conditions fix all {n_full} dofs of the mesh's "
                             f"{len(self.points)} nodes: nothing is left to vibrate; hold part of the mesh (a node "
                             "set or a box), or fewer dofs")
        self.applied_conditions = [bc.where for bc in boundary]
        self.threads, self.timeout = threads, timeout
        self._worker = None
        self.timings: dict[str, float] = {}
        self._labeler = None

    # ------------------------------------------------------------ scene
    @classmethod
    def validate_config(cls, config: Mapping[str, Any], *, base_dir: str | Path,
                        scene_file: str | Path | None = None) -> dict[str, Any]:
        return parse_model(config, base_dir=Path(base_dir), scene_file=scene_file)

    @classmethod
    def from_config(cls, config: Mapping[str, Any], *, base_dir: Path, scene_file: Path | None = None
                    ) -> "KratosAdapter":
        p = cls.validate_config(config, base_dir=base_dir, scene_file=scene_file)
        element, geo = p["element"], p["geometry"]
        if p["mesh"] is None:
            try:
                mesh = cap_surface(geo["a"], geo["R"], element, **_resolution(geo))
            except ValueError as exc:
                raise SceneError(scene_file, "model.geometry", str(exc)) from exc
        else:
            mesh = read_shell_mesh(p["mesh"], element, scene_file)
        mats = {k: dict(m.constants) for k, m in p["materials"].items()}
        default = mats.pop(None, None)
        geometry = None if geo is None else {k: geo[k] for k in ("a", "R", "h")}
        return cls(mesh, element=element, thickness=p["thickness"], material=default, materials=mats,
                   geometry=geometry, boundary=p["boundary"], threads=p["threads"], timeout=p["timeout"],
                   scene_file=scene_file)

    # ------------------------------------------------------------ worker
    def _call(self, command: str, payload: Any = None) -> Any:
        if self._worker is None:
            from .client import KratosWorker

            self._worker = KratosWorker(threads=self.threads, timeout=self.timeout)
            props = [{"E": m["E"], "nu": m["nu"], "rho": m["rho"], "h": self.thickness} if m is not None else
                     {"E": 1.0, "nu": 0.0, "rho": 1.0, "h": self.thickness} for m in self.materials]
            self._worker.call("build", {"points": self.points, "cells": self.mesh.cells,
                                        "element": KRATOS_ELEMENT[self.element], "properties": props,
                                        "cell_property": self._cell_material, "folder": str(self._worker.folder)})
        return self._worker.call(command, payload)

    def close(self) -> None:
        if self._worker is not None:
            self._worker.close()
            self._worker = None

    def _build_matrices(self) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        K, M = (self.free_dofs.restrict_matrix(A) for A in self._call("matrices"))
        for A in (K, M):  # Kratos's equation order leaves the columns unsorted: canonical CSR, so that M
            A.sort_indices()  # may share K's index arrays (LazyMatrices)
        return K, M

    def _internal_forces(self, U: np.ndarray) -> np.ndarray:
        F = self._call("forces", self.free_dofs.expand(np.asarray(U, dtype=float)))
        return self.free_dofs.restrict(F)

    # ------------------------------------------------------------ dofs
    @property
    def n_dofs(self) -> int:
        return self.free_dofs.n_free

    def free_dof_map(self) -> FreeDofs | None:
        return None if self.free_dofs.all_free else self.free_dofs

    def dof_coordinates(self) -> np.ndarray:
        return self.free_dofs.restrict(np.repeat(self.points, DOFS_PER_NODE, axis=0).T).T

    def dof_directions(self) -> np.ndarray:
        return self.free_dofs.restrict(np.tile(np.arange(DOFS_PER_NODE), len(self.points)))

    def characteristic_length(self) -> float:
        return self.thickness

    def output_mesh(self):
        from stepnf.plugin import OutputMesh

        return OutputMesh(self.points, [(self.mesh.cell_type, np.asarray(self.mesh.cells, np.int64))])

    # ------------------------------------------------------------ shells
    def shell_scales(self):
        """kappa, w_bar, Gamma of a cap or plate (``geometry``) of one material (else ``None``)."""
        if self.geometry is None or self.material is None:
            return None
        from stepnf.plugin.shell_scales import ShellScales

        g, m = self.geometry, self.material
        return ShellScales.from_geometry(a=g["a"], R=g["R"], h=self.thickness, E=m["E"], nu=m["nu"], rho=m["rho"])

    def _normals(self) -> np.ndarray:
        from stepnf.geometry.cap import outward_normals

        return outward_normals(self.points, math.inf if self.geometry is None else float(self.geometry["R"]))

    def transverse_displacements(self, Phi: np.ndarray) -> np.ndarray:
        """Normal translations (nodes, k) of the fields ``Phi`` (n, k) (rotations are no displacements)."""
        full = self.free_dofs.expand(np.asarray(Phi, dtype=float).T)  # (k, 6 N)
        U = full.reshape(len(full), -1, DOFS_PER_NODE)[:, :, :3]
        return np.einsum("kij,ij->ik", U, self._normals())

    def transverse_amplitude(self, phi: np.ndarray) -> float:
        return float(np.max(np.abs(self.transverse_displacements(np.asarray(phi)[:, None]))))

    def mode_labels(self, Phi: np.ndarray) -> list[Any]:
        """(k, n) from each mode's node translations (:class:`stepnf.geometry.labels.ModeLabeler`); with the
        whole rim held in uz, n counts the edge as a nodal circle (the solid adapters' convention)."""
        Phi = np.asarray(Phi, dtype=float)
        if self.geometry is None:
            return [None] * Phi.shape[1]
        from stepnf.geometry.labels import ModeLabeler, count_edge_circle

        if self._labeler is None:
            self._labeler = ModeLabeler.from_dofs(self.dof_coordinates(), self.dof_directions(),
                                                  float(self.geometry["a"]), float(self.geometry["R"]))
        labels = [self._labeler.label_dofs(phi) for phi in Phi.T]
        return count_edge_circle(labels) if self._edge_held() else labels

    def _edge_held(self) -> bool:
        """Whether the fixed dofs hold the normal displacement all along the rim
        (:func:`stepnf.geometry.labels.edge_is_held`)."""
        from stepnf.geometry.labels import edge_is_held

        if self.geometry is None or self.free_dofs.all_free:
            return False
        fixed = np.zeros(self.free_dofs.n_full, dtype=bool)
        fixed[self.free_dofs.fixed] = True
        return edge_is_held(self.points, np.arange(len(self.points)), fixed, float(self.geometry["a"]),
                            float(self.geometry["R"]))

    # ------------------------------------------------------------ reports
    def summary(self) -> str:
        free = " free" if not self.free_dofs.all_free else ""
        n_tr = int(np.count_nonzero(translation_mask(self.dof_directions())))
        return (f"mesh: {thousands(len(self.mesh.cells))} {self.element.upper()} shells "
                f"({KRATOS_ELEMENT[self.element]}, Kratos), {thousands(len(self.points))} nodes, "
                f"{thousands(self.n_dofs)}{free} dofs ({thousands(n_tr)} translations, "
                f"{thousands(self.n_dofs - n_tr)} rotations), thickness {self.thickness:g}")

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d.update(solver="Kratos Multiphysics", element=self.element, kratos_element=KRATOS_ELEMENT[self.element],
                 n_nodes=int(len(self.points)), n_cells=int(len(self.mesh.cells)), thickness=self.thickness,
                 materials=[m for m in self.materials if m is not None], mesh=_json_floats(self.mesh.info))
        if self.geometry is not None:
            d["geometry"] = _json_floats(self.geometry)
        if not self.free_dofs.all_free:
            d["boundary"] = {"conditions": list(self.applied_conditions), **self.free_dofs.describe()}
        return d


def _json_floats(table: Mapping[str, Any]) -> dict[str, Any]:
    """``table`` with infinite floats (a plate's ``R``) as text, for JSON."""
    return {k: (str(v) if isinstance(v, float) and math.isinf(v) else v) for k, v in table.items()}


def _resolution(geo: Mapping[str, Any]) -> dict[str, Any]:
    """The O-grid of a generated cap: the solid caps' defaults, then the scene's keys."""
    from stepnf.geometry.cap import DEFAULT_CORE, DEFAULT_N_CORE, DEFAULT_N_RING

    out = {"n_core": DEFAULT_N_CORE, "n_ring": DEFAULT_N_RING, "core": DEFAULT_CORE}
    out.update({k: geo[k] for k in ("n_core", "n_ring", "core", "grading") if k in geo})
    return out
