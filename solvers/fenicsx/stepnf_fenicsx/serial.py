"""The serial ``fenicsx`` adapter: a St Venant-Kirchhoff solid assembled by FEniCSx on one process.

:class:`FenicsxAdapter` (the entry point ``stepnf_fenicsx:FenicsxAdapter``)
and :func:`read_mesh`. Under ``mpirun -n N`` (N > 1) the builders
:meth:`FenicsxAdapter.cap` and :meth:`FenicsxAdapter.from_config` return the
distributed variant instead, the subclass declared with ``distributed=True``
(:class:`stepnf_fenicsx.parallel.DistributedFenicsxAdapter`, whose dof order
is PETSc's global one). This module does not import that subclass: it
declares itself when :mod:`stepnf_fenicsx.parallel` is imported, which the
package does (:mod:`stepnf_fenicsx.adapter`), so no module imports back up.

Dofs are FEniCSx's own order of the vector P2/Q2 space: node-major,
``(ux, uy, uz)`` of node 0, then node 1, ... (``dof_directions`` = 0, 1, 2
repeated); ``dof_coordinates`` gives each dof's node. No boundary conditions
(free edge: six rigid-body modes). Units are those of the mesh and material
(SI for the bundled examples).
"""
from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np

from stepnf.errors import SceneError
from stepnf.geometry import ModeLabeler, VolumeMesh, outward_normals, spherical_cap

from . import _compat
from ._forms_adapter import FormsAdapter
from .config import MODEL_KEYS, parse_model
from .model import Material, SvkForms


def read_mesh(path: str | Path) -> VolumeMesh:
    """Read the volume cells of any file meshio reads (one supported cell type).

    Every defect :func:`stepnf.geometry.checks.check_volume_mesh` knows (no
    cells, NaN coordinates, dangling node numbers, flat meshes, coincident
    nodes, degenerate, tangled or overlapping cells) is a
    :class:`~stepnf.errors.MeshError` naming the file and the cell or node
    (0-based positions in the file, cells counted within their type).
    """
    import meshio

    from stepnf.errors import MeshError
    from stepnf.geometry.checks import check_volume_mesh

    try:
        m = meshio.read(str(path))
    except SystemExit as exc:  # meshio exits (!) on a file it cannot identify
        raise MeshError(path, "meshio cannot read this file (unknown or corrupt format)") from exc
    found = [c.type for c in m.cells]
    kinds = [c.type for c in m.cells if c.type in _compat.CELLS]
    if not kinds:
        raise MeshError(path, f"no volume cells dolfinx can use; found {found or 'no cells at all'}, "
                              f"supported {list(_compat.CELLS)}")
    if len(set(kinds)) > 1:
        raise MeshError(path, f"mixed volume cell types {sorted(set(kinds))}; give one cell type")
    cells = np.concatenate([np.asarray(c.data) for c in m.cells if c.type == kinds[0]])
    pts = np.asarray(m.points)
    check_volume_mesh(pts, [(kinds[0], cells)], source=path, supported=list(_compat.CELLS))
    cells = cells.astype(np.int64)
    used = np.unique(cells)
    renum = np.full(len(pts), -1)
    renum[used] = np.arange(len(used))
    return VolumeMesh(points=np.asarray(pts, dtype=float)[used], cells=renum[cells], cell_type=kinds[0],
                      info={"file": str(path)})


class FenicsxAdapter(FormsAdapter):
    """St Venant-Kirchhoff 3D solid (Green-Lagrange strain, linear elastic stress) with FEniCSx.

    Parameters
    ----------
    mesh : the volume mesh (``hexahedron27``, ``tetra10``, or linear cells)
    material : :class:`Material` (E, nu, rho)
    degree : polynomial degree of the displacement (2: Q2 on hexahedra, P2 on tetrahedra)
    geometry : optional ``{a, R, h}`` of a shallow spherical cap (shell scales, labels)
    quadrature_degree : quadrature degree of every form (4: 3x3x3 Gauss points on hexahedra)
    """

    name = "fenicsx"
    model_keys = MODEL_KEYS
    provides_intrusive_tensors = True

    def __init__(self, mesh: VolumeMesh, material: Material, *, degree: int = 2,
                 geometry: Mapping[str, float] | None = None, quadrature_degree: int = 4):
        t0 = time.perf_counter()
        self.mesh = mesh
        self.material = material
        self.geometry = None if geometry is None else dict(geometry)
        self.degree = int(degree)
        self.quadrature_degree = int(quadrature_degree)
        msh, _ = _compat.create_mesh(mesh.points, mesh.cells, mesh.cell_type, comm=self._mesh_comm())
        self._V = _compat.vector_space(msh, self.degree)
        self._nodes, bs = _compat.dof_layout(self._V)
        assert bs == 3
        self._forms = SvkForms(self._V, material, self.quadrature_degree)
        self._n = 3 * len(self._nodes)
        self._labeler: ModeLabeler | None = None
        self.timings: dict[str, float] = {"setup": time.perf_counter() - t0}

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
            quadrature_degree: int = 4, **resolution: Any) -> "FenicsxAdapter":
        """A free-edge spherical cap (``R = inf``: flat plate); see :func:`stepnf.geometry.spherical_cap`."""
        if element not in ("hex27", "tet10"):
            raise ValueError(f"Unknown element {element!r}. Pick one of ['hex27', 'tet10']")
        mesh = spherical_cap(a, R, h, element="hex27", **resolution)
        if element == "tet10":
            from stepnf.geometry.tets import hex27_to_tetra

            mesh = hex27_to_tetra(mesh)
        return cls._class_for_world()(mesh, Material(E, nu, rho), geometry={"a": a, "R": R, "h": h},
                                      quadrature_degree=quadrature_degree)

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
                             quadrature_degree=p["quadrature_degree"], **mat, **g)
            except ValueError as exc:
                raise SceneError(scene_file, "model.geometry", str(exc)) from exc
            if getattr(ad, "mesh", None) is not None:
                units_warning(ad.mesh.points, mat, source=scene_file, thickness=thickness)
            return ad
        try:
            mesh = read_mesh(p["mesh"])
        except Exception as exc:  # meshio raises many kinds
            raise SceneError(scene_file, "model.mesh", f"cannot read {str(p['mesh'])!r}: {exc}") from exc
        units_warning(mesh.points, mat, source=p["mesh"], thickness=thickness)
        return cls._class_for_world()(mesh, Material(**mat), geometry=p["geometry"],
                                      quadrature_degree=p["quadrature_degree"])

    # ------------------------------------------------------------ geometry
    def dof_coordinates(self) -> np.ndarray:
        return np.repeat(self._nodes, 3, axis=0)

    def dof_directions(self) -> np.ndarray:
        return np.tile(np.arange(3), len(self._nodes))

    def characteristic_length(self) -> float | None:
        if self.geometry is not None:
            return float(self.geometry["h"])
        return super().characteristic_length()

    def shell_scales(self):
        if self.geometry is None:
            return None
        from stepnf.shell import ShellScales

        g, m = self.geometry, self.material
        return ShellScales.from_geometry(a=g["a"], R=g["R"], h=g["h"], E=m.E, nu=m.nu, rho=m.rho)

    def _R(self) -> float:
        return math.inf if self.geometry is None else float(self.geometry["R"])

    def _midsurface_nodes(self) -> np.ndarray:
        """Indices of the dof nodes on the mid-surface (all nodes when it is unknown)."""
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
        return np.asarray(phi, dtype=float).reshape(-1, 3)

    def transverse_amplitude(self, phi: np.ndarray) -> float:
        mid = self._midsurface_nodes()
        U = self._node_displacements(phi)[mid]
        w = np.einsum("ij,ij->i", U, outward_normals(self._nodes[mid], self._R()))
        return float(np.max(np.abs(w)))

    def mode_labels(self, Phi: np.ndarray) -> list[Any]:
        Phi = np.asarray(Phi, dtype=float)
        if self._labeler is None:
            mid = self._midsurface_nodes()
            radius = float(self.geometry["a"]) if self.geometry else float(
                np.hypot(self._nodes[:, 0], self._nodes[:, 1]).max())
            self._labeler = ModeLabeler(self._nodes[mid, :2], mid, outward_normals(self._nodes, self._R()), radius)
        return [self._labeler.label(self._node_displacements(Phi[:, j])) for j in range(Phi.shape[1])]

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d.update({"cell_type": self.mesh.cell_type, "n_cells": self.mesh.n_cells, "degree": self.degree,
                  "quadrature_degree": self.quadrature_degree, "material": vars(self.material).copy(),
                  "mesh": {k: v for k, v in self.mesh.info.items()}, "model": "St Venant-Kirchhoff 3D solid"})
        if self.geometry is not None:
            d["geometry"] = {k: (str(v) if isinstance(v, float) and math.isinf(v) else v)
                             for k, v in self.geometry.items()}
        d["mesh"] = {k: (str(v) if isinstance(v, float) and math.isinf(v) else v) for k, v in d["mesh"].items()}
        return d
