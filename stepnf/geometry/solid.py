"""What every nodal 3D-solid model of a spherical cap offers the pipeline, whatever its solver.

:class:`CapSolid` is a mixin for adapters whose dofs are the three nodal
translations of ``points`` (node order = dof order / 3): dof coordinates and
directions, the characteristic length (the thickness h), the shell scales
(kappa, w_bar, Gamma), the largest transverse mid-surface displacement of a
mode and its (k, n) label. The adapter sets ``points`` (N, 3), ``geometry``
(a, R, h and ``shape = "spherical_cap"`` for a generated cap), ``material``
(E, nu, rho), ``midsurface`` ((N,) bool or None) and ``hex20_cells`` ((E, 20)
VTK-ordered cells or None: then the mid-surface is sampled at the 3 x 3 points
of each element, like a 27-node mesh, instead of at its nodes).

Boundary conditions (:mod:`stepnf.plugin.boundary`): an adapter that fixes dofs sets
``free_dofs`` (a :class:`~stepnf.plugin.boundary.FreeDofs` over the ``3 N`` nodal
dofs); the dofs this mixin exposes are then the free ones, and mode shapes are
expanded to every node (zeros on the fixed dofs) before they are measured or
labelled.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.boundary import FreeDofs
from stepnf.geometry.cap import outward_normals
from stepnf.geometry.labels import ModeLabeler, count_edge_circle, edge_is_held
from stepnf.geometry.midsurface import midsurface_sampler

from stepnf.geometry.keys import MATERIAL_KEYS


class CapSolid:
    points: np.ndarray
    geometry: dict
    material: dict
    midsurface: np.ndarray | None = None
    hex20_cells: np.ndarray | None = None
    #: The free dofs when boundary conditions fix some (``None``: every nodal dof is free).
    free_dofs: FreeDofs | None = None
    _sampler: tuple | None = None
    _labeler: ModeLabeler | None = None

    @classmethod
    def from_cap(cls, *, a: float, R: float, h: float, E: float, nu: float, rho: float,
                 resolution: dict | None = None, **kw: Any):
        """A free-edge spherical cap (``R = inf``: flat plate) meshed with 20-node bricks
        (:func:`stepnf.geometry.spherical_cap`), through the adapter's ``from_volume_mesh``."""
        from stepnf.geometry.cap import spherical_cap

        mesh = spherical_cap(a, R, h, element="hex20", **dict(resolution or {}))
        geom = {"shape": "spherical_cap", "a": a, "R": R, "h": h, **dict(resolution or {})}
        return cls.from_volume_mesh(mesh, material={"E": E, "nu": nu, "rho": rho}, geometry=geom, **kw)

    def _is_cap(self) -> bool:
        return self.geometry.get("shape") == "spherical_cap"

    def free_dof_map(self) -> FreeDofs | None:
        """The free dofs among the ``3 N`` nodal dofs, ``None`` when nothing is fixed."""
        return self.free_dofs

    def free_part(self, A: Any) -> Any:
        """Fields (..., 3 N) or a sparse matrix (3 N, 3 N) over every nodal dof, restricted to the free dofs."""
        if self.free_dofs is None:
            return A
        return self.free_dofs.restrict_matrix(A) if sp.issparse(A) else self.free_dofs.restrict(A)

    def nodal(self, phi: np.ndarray) -> np.ndarray:
        """A field over the exposed dofs as nodal displacements (N, 3), zeros on the fixed dofs."""
        phi = np.asarray(phi, dtype=float)
        return (phi if self.free_dofs is None else self.free_dofs.expand(phi)).reshape(-1, 3)

    @property
    def n_dofs(self) -> int:
        return 3 * len(self.points) if self.free_dofs is None else self.free_dofs.n_free

    def dof_coordinates(self) -> np.ndarray:
        X = np.repeat(self.points, 3, axis=0)
        return X if self.free_dofs is None else X[self.free_dofs.free]

    def dof_directions(self) -> np.ndarray:
        D = np.tile(np.arange(3), len(self.points))
        return D if self.free_dofs is None else D[self.free_dofs.free]

    def characteristic_length(self) -> float | None:
        if "h" in self.geometry:
            return float(self.geometry["h"])
        return super().characteristic_length()  # type: ignore[misc]

    def shell_scales(self):
        g, m = self.geometry, self.material
        if not self._is_cap() or not all(k in m for k in MATERIAL_KEYS):
            return None
        from stepnf.plugin.shell_scales import ShellScales

        return ShellScales.from_geometry(a=g["a"], R=g["R"], h=g["h"], E=m["E"], nu=m["nu"], rho=m["rho"])

    def transverse_amplitude(self, phi: np.ndarray) -> float | None:
        """Largest |normal displacement| of a mode over the mid-surface."""
        if not self._is_cap() or self.midsurface is None:
            return None
        R = float(self.geometry["R"])
        U = self.nodal(phi)
        if self.hex20_cells is not None:
            if self._sampler is None:
                W, X = midsurface_sampler(self.points, self.hex20_cells, self.midsurface)
                self._sampler = (W, outward_normals(X, R))
            W, normals = self._sampler
            if W.shape[0]:
                return float(np.max(np.abs(np.einsum("ij,ij->i", W @ U, normals))))
        sel = self.midsurface
        return float(np.max(np.abs(np.einsum("ij,ij->i", U[sel], outward_normals(self.points[sel], R)))))

    def mode_labels(self, Phi: np.ndarray) -> list[Any]:
        """(k, n) labels of cap modes ("in-plane"/"thickness" for the others); ``None`` without a cap."""
        Phi = np.asarray(Phi, dtype=float)
        if not self._is_cap() or self.midsurface is None:
            return [None] * Phi.shape[1]
        if self._labeler is None:
            mid = np.nonzero(self.midsurface)[0]
            self._labeler = ModeLabeler(self.points[mid, :2], mid,
                                        outward_normals(self.points, float(self.geometry["R"])),
                                        float(self.geometry["a"]))
        labels = [self._labeler.label(self.nodal(Phi[:, j])) for j in range(Phi.shape[1])]
        return count_edge_circle(labels) if self.edge_is_held() else labels

    def edge_is_held(self) -> bool:
        """True for a cap whose fixed dofs zero the normal displacement at every mid-surface node of its rim
        (plan radius ``a``): a clamped or simply supported edge, which the labels count as a nodal circle
        (:func:`stepnf.geometry.labels.count_edge_circle`, as the FEniCSx adapters do)."""
        if not self._is_cap() or self.midsurface is None or self.free_dofs is None or self.free_dofs.all_free:
            return False
        fixed = np.zeros(self.free_dofs.n_full, dtype=bool)
        fixed[self.free_dofs.fixed] = True
        return edge_is_held(self.points, np.nonzero(self.midsurface)[0], fixed, self.geometry["a"],
                            self.geometry["R"])
