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
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .cap import outward_normals
from .labels import ModeLabeler
from .midsurface import midsurface_sampler

from .keys import MATERIAL_KEYS


class CapSolid:
    points: np.ndarray
    geometry: dict
    material: dict
    midsurface: np.ndarray | None = None
    hex20_cells: np.ndarray | None = None
    _sampler: tuple | None = None
    _labeler: ModeLabeler | None = None

    @classmethod
    def from_cap(cls, *, a: float, R: float, h: float, E: float, nu: float, rho: float,
                 resolution: dict | None = None, **kw: Any):
        """A free-edge spherical cap (``R = inf``: flat plate) meshed with 20-node bricks
        (:func:`stepnf.geometry.spherical_cap`), through the adapter's ``from_volume_mesh``."""
        from .cap import spherical_cap

        mesh = spherical_cap(a, R, h, element="hex20", **dict(resolution or {}))
        geom = {"shape": "spherical_cap", "a": a, "R": R, "h": h, **dict(resolution or {})}
        return cls.from_volume_mesh(mesh, material={"E": E, "nu": nu, "rho": rho}, geometry=geom, **kw)

    def _is_cap(self) -> bool:
        return self.geometry.get("shape") == "spherical_cap"

    @property
    def n_dofs(self) -> int:
        return 3 * len(self.points)

    def dof_coordinates(self) -> np.ndarray:
        return np.repeat(self.points, 3, axis=0)

    def dof_directions(self) -> np.ndarray:
        return np.tile(np.arange(3), len(self.points))

    def characteristic_length(self) -> float | None:
        if "h" in self.geometry:
            return float(self.geometry["h"])
        return super().characteristic_length()  # type: ignore[misc]

    def shell_scales(self):
        g, m = self.geometry, self.material
        if not self._is_cap() or not all(k in m for k in MATERIAL_KEYS):
            return None
        from ..shell import ShellScales

        return ShellScales.from_geometry(a=g["a"], R=g["R"], h=g["h"], E=m["E"], nu=m["nu"], rho=m["rho"])

    def transverse_amplitude(self, phi: np.ndarray) -> float | None:
        """Largest |normal displacement| of a mode over the mid-surface."""
        if not self._is_cap() or self.midsurface is None:
            return None
        R = float(self.geometry["R"])
        U = np.asarray(phi, dtype=float).reshape(-1, 3)
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
        return [self._labeler.label(Phi[:, j].reshape(-1, 3)) for j in range(Phi.shape[1])]
