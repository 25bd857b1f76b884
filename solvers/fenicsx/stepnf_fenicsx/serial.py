"""The serial ``fenicsx`` adapter: a St Venant-Kirchhoff solid assembled by FEniCSx on one process.

:class:`FenicsxAdapter` (the entry point ``stepnf_fenicsx:FenicsxAdapter``)
and :func:`read_mesh` (:mod:`stepnf_fenicsx.meshfile`). Under ``mpirun -n N`` (N > 1) the builders
:meth:`FenicsxAdapter.cap` and :meth:`FenicsxAdapter.from_config` return the
distributed variant instead, the subclass declared with ``distributed=True``
(:class:`stepnf_fenicsx.parallel.DistributedFenicsxAdapter`, whose dof order
is PETSc's global one). This module does not import that subclass: it
declares itself when :mod:`stepnf_fenicsx.parallel` is imported, which the
package does (:mod:`stepnf_fenicsx.adapter`), so no module imports back up.

Dofs are FEniCSx's own order of the vector P2/Q2 space: node-major,
``(ux, uy, uz)`` of node 0, then node 1, ... (``dof_directions`` = 0, 1, 2
repeated); ``dof_coordinates`` gives each dof's node. Without boundary
conditions the solid is free (six rigid-body modes); ``boundary`` (the scene's
``[[model.boundary]]``) fixes directions of the nodes of named sets or boxes
(:mod:`stepnf_fenicsx.constraints`) and those dofs are removed: every array
the adapter exposes covers the free dofs, :meth:`FenicsxAdapter.free_dof_map`
maps them into the whole space. Materials: one isotropic :class:`Material`
everywhere, or with a mesh file an orthotropic one and one per named cell set
(``materials``; :mod:`stepnf_fenicsx.regions`, the forms' per-cell C and rho in
:class:`stepnf_fenicsx.model.MaterialField`). Units are those of the mesh and
material (SI for the bundled examples).
"""
from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from stepnf.plugin.boundary import BoundaryCondition, FreeDofs
from stepnf.errors import SceneError
from stepnf.geometry import ModeLabeler, VolumeMesh, outward_normals
from stepnf.geometry.rim import cap_for_conditions
from stepnf.runtime.progress import thousands

from . import _compat
from ._forms_adapter import FormsAdapter
from .config import MODEL_KEYS, parse_model
from .constraints import as_conditions, describe_conditions, dof_node_mask, free_dofs_of, point_mask
from .labels import count_edge_circle, edge_is_held
from .meshfile import read_mesh
from .model import Material, SvkForms
from .regions import CellMaterials, assign_materials, describe_material


class FenicsxAdapter(FormsAdapter):
    """St Venant-Kirchhoff 3D solid (Green-Lagrange strain, linear elastic stress) with FEniCSx.

    Parameters
    ----------
    mesh : the volume mesh (``hexahedron27``, ``tetra10``, or linear cells); a mesh file's
        (:func:`~stepnf_fenicsx.meshfile.read_mesh`) has named cell sets ``cell_sets``
    material : :class:`Material` (E, nu, rho) or :class:`stepnf.plugin.materials.Material` (isotropic or
        orthotropic): every cell no set of ``materials`` names (``None``: the sets must cover the mesh)
    materials : ``{cell set: material}``, the regions of ``[model.materials.<set>]``
        (:func:`~stepnf_fenicsx.regions.assign_materials`: a set the mesh lacks, a cell in two sets or
        unnamed cells without ``material`` are :class:`~stepnf.errors.SceneError` s)
    degree : polynomial degree of the displacement (2: Q2 on hexahedra, P2 on tetrahedra)
    geometry : optional ``{a, R, h}`` of a shallow spherical cap (shell scales, labels)
    quadrature_degree : quadrature degree of every form (4: 3x3x3 Gauss points on hexahedra)
    boundary : zero-displacement conditions on the mesh's node sets (``mesh.node_sets``) or boxes:
        :class:`stepnf.plugin.boundary.BoundaryCondition` s or ``[[model.boundary]]`` tables
        (``{"set": "edge"}``); their dofs are removed
    scene_file : the scene, named by messages about ``boundary``
    """

    name = "fenicsx"
    model_keys = MODEL_KEYS
    provides_intrusive_tensors = True

    def __init__(self, mesh: VolumeMesh, material: Any, *, degree: int = 2,
                 geometry: Mapping[str, float] | None = None, quadrature_degree: int = 4,
                 boundary: Sequence[BoundaryCondition | Mapping[str, Any]] = (), scene_file: Path | None = None,
                 materials: Mapping[str, Any] | None = None):
        t0 = time.perf_counter()
        self.mesh = mesh
        self.material = material
        #: the materials of the cells when ``materials`` names cell sets (else ``material`` everywhere)
        self.regions: CellMaterials | None = None
        if materials:
            self.regions = assign_materials(mesh.n_cells, getattr(mesh, "cell_sets", {}), material, materials,
                                            scene_file, mesh.info.get("file"))
        elif material is None:
            raise SceneError(scene_file, "model.material", "missing: give [model.material] (every cell) or "
                             "[model.materials.<set>] for named cell sets")
        self.geometry = None if geometry is None else dict(geometry)
        self.degree = int(degree)
        self.quadrature_degree = int(quadrature_degree)
        self.boundary = as_conditions(boundary, scene_file)
        # the sets and boxes are resolved first: a bad one is refused before any compilation
        mask, self._bc_nodes = point_mask(self.boundary, mesh.points, mesh.node_sets, scene_file,
                                          mesh.info.get("file"))
        msh, input_index = _compat.create_mesh(mesh.points, mesh.cells, mesh.cell_type, comm=self._mesh_comm())
        self._V = _compat.vector_space(msh, self.degree)
        self._nodes, bs = _compat.dof_layout(self._V)
        assert bs == 3
        self._free = self._free_dofs(dof_node_mask(self._V, input_index, mask)) if self.boundary else None
        self._forms = SvkForms(self._V, material if self.regions is None else self.regions, self.quadrature_degree)
        self._n = 3 * len(self._nodes) if self._free is None else self._free.n_free
        self._labeler: ModeLabeler | None = None
        self.timings: dict[str, float] = {"setup": time.perf_counter() - t0}

    def _free_dofs(self, local_mask: np.ndarray) -> FreeDofs:
        """The free dofs, from the fixed directions of this process's dof nodes (serial: all of them)."""
        return free_dofs_of(local_mask)

    def _mesh_comm(self):
        """Communicator of the dolfinx mesh: ``None`` (``COMM_SELF``, serial) here."""
        return None

    # ------------------------------------------------------------ construction
    #: What the builders return under ``mpirun -n N>1``: the subclass declared with ``distributed=True``
    #: (:class:`~stepnf_fenicsx.parallel.DistributedFenicsxAdapter`, imported with the package).
    _distributed: ClassVar[type["FenicsxAdapter"] | None] = None

    def __init_subclass__(cls, *, distributed: bool = False, **kwargs: Any):
        super().__init_subclass__(**kwargs)
        if distributed:
            FenicsxAdapter._distributed = cls

    @classmethod
    def _class_for_world(cls) -> type["FenicsxAdapter"]:
        """This class, or the distributed variant when it is :class:`FenicsxAdapter` under ``mpirun -n N>1``.

        ``STEPNF_FENICSX_SERIAL=1`` keeps one serial model per process even
        under MPI (e.g. Dask workers started by ``dask-mpi``). Subclasses
        (the distributed variant included) build themselves.
        """
        if cls is FenicsxAdapter and not os.environ.get("STEPNF_FENICSX_SERIAL") and _compat.world_size() > 1:
            return FenicsxAdapter._distributed
        return cls

    @classmethod
    def cap(cls, a: float, R: float, h: float, *, E: float, nu: float, rho: float, element: str = "hex27",
            quadrature_degree: int = 4, boundary: Sequence[BoundaryCondition | Mapping[str, Any]] = (),
            scene_file: Path | None = None, **resolution: Any) -> "FenicsxAdapter":
        """A spherical cap (``R = inf``: flat plate), free unless ``boundary`` holds it (its node set ``"edge"``:
        every node of the lateral face); see :func:`stepnf.geometry.spherical_cap`. Conditions that hold the
        whole rim refine the mesh towards it unless ``resolution`` says otherwise
        (:mod:`stepnf.geometry.rim`: more rings, graded)."""
        if element not in ("hex27", "tet10"):
            raise ValueError(f"Unknown element {element!r}. Pick one of ['hex27', 'tet10']")
        boundary = as_conditions(boundary, scene_file)
        mesh, _ = cap_for_conditions(a, R, h, boundary, element="hex27", scene_file=scene_file, **resolution)
        if element == "tet10":
            from stepnf.geometry.tets import hex27_to_tetra

            mesh = hex27_to_tetra(mesh)  # its node sets are the hexahedra's, less the nodes it drops
        return cls._class_for_world()(mesh, Material(E, nu, rho), geometry={"a": a, "R": R, "h": h},
                                      quadrature_degree=quadrature_degree, boundary=boundary,
                                      scene_file=scene_file)

    @classmethod
    def validate_config(cls, config: Mapping[str, Any], *, base_dir: str | Path,
                        scene_file: str | Path | None = None) -> dict[str, Any]:
        """The ``[model]`` keys (:data:`~stepnf_fenicsx.config.MODEL_KEYS`) and a mesh or a generated cap
        (:func:`~stepnf_fenicsx.config.parse_model`)."""
        return parse_model(config, base_dir=Path(base_dir), scene_file=scene_file)

    @classmethod
    def from_config(cls, config: Mapping[str, Any], *, base_dir: Path, scene_file: Path | None = None
                    ) -> "FenicsxAdapter":
        p = cls.validate_config(config, base_dir=base_dir, scene_file=scene_file)
        from stepnf.geometry.checks import units_warning

        mat = p["material"]
        thickness = (p["geometry"] or {}).get("h")
        if p["mesh"] is None:
            g = dict(p["geometry"])
            try:
                ad = cls.cap(g.pop("a"), g.pop("R"), g.pop("h"), element=p["element"],
                             quadrature_degree=p["quadrature_degree"], boundary=p["boundary"],
                             scene_file=scene_file, **mat, **g)
            except ValueError as exc:
                raise SceneError(scene_file, "model.geometry", str(exc)) from exc
            if getattr(ad, "mesh", None) is not None:
                units_warning(ad.mesh.points, mat, source=scene_file, thickness=thickness)
            return ad
        try:
            mesh = read_mesh(p["mesh"])
        except Exception as exc:  # meshio raises many kinds
            raise SceneError(scene_file, "model.mesh", f"cannot read {str(p['mesh'])!r}: {exc}") from exc
        named = {k: m for k, m in p["materials"].items() if k is not None}
        default = p["materials"].get(None)
        if default is not None and default.isotropic:
            default = Material(*(float(default.constants[k]) for k in ("E", "nu", "rho")))
        units_warning(mesh.points, (default or next(iter(named.values()))).constants, source=p["mesh"],
                      thickness=thickness)
        return cls._class_for_world()(mesh, default, materials=named, geometry=p["geometry"],
                                      quadrature_degree=p["quadrature_degree"], boundary=p["boundary"],
                                      scene_file=scene_file)

    # ------------------------------------------------------------ geometry
    def dof_coordinates(self) -> np.ndarray:
        return self._free_rows(np.repeat(self._nodes, 3, axis=0))

    def dof_directions(self) -> np.ndarray:
        return self._free_rows(np.tile(np.arange(3), len(self._nodes)))

    def output_mesh(self):
        """The input volume mesh, for the ParaView fields (:mod:`stepnf_fenicsx.fields_mesh`)."""
        from .fields_mesh import volume_output_mesh

        return volume_output_mesh(self.mesh)

    def characteristic_length(self) -> float | None:
        if self.geometry is not None:
            return float(self.geometry["h"])
        return super().characteristic_length()

    def shell_scales(self):
        """The shell scales of a plate or cap (``geometry``) of one isotropic material (else ``None``)."""
        if self.geometry is None or self.regions is not None or not self.material.isotropic:
            return None
        from stepnf.plugin.shell_scales import ShellScales

        g, m = self.geometry, self.material.constants
        return ShellScales.from_geometry(a=g["a"], R=g["R"], h=g["h"], E=m["E"], nu=m["nu"], rho=m["rho"])

    def _R(self) -> float:
        return math.inf if self.geometry is None else float(self.geometry["R"])

    def _midsurface_nodes(self) -> np.ndarray:
        """Indices of the dof nodes on the mid-surface (all nodes when it is unknown); found once."""
        if getattr(self, "_mid_cache", None) is None:
            self._mid_cache = self._find_midsurface_nodes()
        return self._mid_cache

    def _midsurface_normals(self) -> np.ndarray:
        """Outward normals at :meth:`_midsurface_nodes` (the transverse direction there); found once."""
        if getattr(self, "_mid_normals_cache", None) is None:
            self._mid_normals_cache = outward_normals(self._nodes[self._midsurface_nodes()], self._R())
        return self._mid_normals_cache

    def _find_midsurface_nodes(self) -> np.ndarray:
        X = self._nodes
        if self.mesh.midsurface is not None:
            from scipy.spatial import cKDTree

            mid_pts = self.mesh.points[self.mesh.midsurface]
            dist, idx = cKDTree(X).query(mid_pts)
            scale = float(np.ptp(X, axis=0).max())
            if np.all(dist <= 1e-9 * scale):
                return np.unique(idx)
        return np.arange(len(X))

    def _node_displacements(self, phi: np.ndarray) -> np.ndarray:
        """(dof nodes, 3) displacements of a free field (zeros where fixed)."""
        return self._expand(np.asarray(phi, dtype=float)).reshape(-1, 3)

    def transverse_amplitude(self, phi: np.ndarray) -> float:
        return float(np.max(np.abs(self.transverse_displacements(np.asarray(phi)[:, None]))))

    def transverse_displacements(self, Phi: np.ndarray) -> np.ndarray:
        """Normal displacements (mid-surface nodes, k) of the fields ``Phi`` (n, k): the dof nodes' ``u . n``."""
        Phi = np.asarray(Phi, dtype=float)
        mid = self._midsurface_nodes()
        U = np.stack([self._node_displacements(Phi[:, j])[mid] for j in range(Phi.shape[1])], axis=-1)
        return np.einsum("ijk,ij->ik", U, self._midsurface_normals())

    def mode_labels(self, Phi: np.ndarray) -> list[Any]:
        """(k, n) of each mode; with the rim held (:meth:`edge_is_held`) n counts the edge as a nodal circle
        (:mod:`stepnf_fenicsx.labels`)."""
        Phi = np.asarray(Phi, dtype=float)
        if self.geometry is None:  # a user's mesh without a, R, h: no axis, (k, n) would mean nothing
            return [None] * Phi.shape[1]
        if self._labeler is None:
            mid = self._midsurface_nodes()
            radius = float(self.geometry["a"]) if self.geometry else float(
                np.hypot(self._nodes[:, 0], self._nodes[:, 1]).max())
            self._labeler = ModeLabeler(self._nodes[mid, :2], mid, outward_normals(self._nodes, self._R()), radius)
        labels = [self._labeler.label(self._node_displacements(Phi[:, j])) for j in range(Phi.shape[1])]
        return count_edge_circle(labels) if self.edge_is_held() else labels

    def edge_is_held(self) -> bool:
        """True for a plate or shell (``geometry`` known) whose boundary conditions zero the normal displacement
        at every mid-surface node of its rim (plan radius ``a``): a clamped or simply supported edge."""
        if self._free is None or self.geometry is None:
            return False
        fixed = np.zeros(self._free.n_full, dtype=bool)
        fixed[self._free.fixed] = True
        return edge_is_held(self._nodes, self._midsurface_nodes(), fixed, self.geometry["a"], self._R())

    def summary(self) -> str:
        """The run's first line about the model: ``mesh: 800 hex8 cells, order 2 elements (Q2, the hex8 mesh
        promoted to order 2), 73 000 dofs`` (a linear mesh gets quadratic elements: :attr:`degree`)."""
        shape, order, nodes = _compat.CELLS[self.mesh.cell_type]
        name = f"{ {'hexahedron': 'hex', 'tetrahedron': 'tet'}.get(shape, shape)}{nodes}"
        completed = " (hex20 in the file, completed to hex27)" if self.mesh.info.get("cells_in_file") else ""
        promoted = f", the {name} mesh promoted to order {self.degree}" if self.degree > order else ""
        family = "Q" if shape == "hexahedron" else "P"
        free = " free" if self.boundary else ""
        return (f"mesh: {thousands(self.mesh.n_cells)} {name} cells{completed}, order {self.degree} elements "
                f"({family}{self.degree}{promoted}), {thousands(self.n_dofs)}{free} dofs")

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d.update({"cell_type": self.mesh.cell_type, "n_cells": self.mesh.n_cells, "degree": self.degree,
                  "quadrature_degree": self.quadrature_degree,
                  "material": None if self.material is None else describe_material(self.material),
                  "mesh": {k: v for k, v in self.mesh.info.items()}, "model": "St Venant-Kirchhoff 3D solid"})
        if self.geometry is not None:
            d["geometry"] = {k: (str(v) if isinstance(v, float) and math.isinf(v) else v)
                             for k, v in self.geometry.items()}
        d["mesh"] = {k: (str(v) if isinstance(v, float) and math.isinf(v) else v) for k, v in d["mesh"].items()}
        if self.regions is not None:
            d["materials"] = self.regions.describe()
        if self.boundary:
            d["boundary"] = describe_conditions(self.boundary, self._bc_nodes, self._free)
        return d
