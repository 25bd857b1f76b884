"""Geometry generators for stepnf's reference models (pure numpy, no FE library).

:func:`spherical_cap` meshes free-edge shallow spherical caps and flat plates
with curved quadratic hexahedra; :class:`VolumeMesh` holds the result in
meshio's naming and VTK's node order; :class:`ModeLabeler` gives the (k, n)
labels of the modes of axisymmetric shells from any solid model's nodes.
Users' meshes: :mod:`stepnf.geometry.inp` is the one ``.inp`` reader of every
solver route, :mod:`stepnf.geometry.mesh_sets` the named sets of a meshio mesh.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from stepnf.runtime.lazy import lazy_exports

if TYPE_CHECKING:
    from stepnf.geometry.cap import VolumeMesh, disk_quad9, outward_normals, shell_volume, spherical_cap
    from stepnf.geometry.hexahedra import jacobians, shape_functions, volume
    from stepnf.geometry.labels import ModeLabeler

_NAMES = {"VolumeMesh": "cap", "spherical_cap": "cap", "shell_volume": "cap", "outward_normals": "cap",
          "disk_quad9": "cap", "jacobians": "hexahedra", "shape_functions": "hexahedra", "volume": "hexahedra",
          "ModeLabeler": "labels"}
__getattr__ = lazy_exports(__name__, _NAMES, globals())
__all__ = ["VolumeMesh", "spherical_cap", "shell_volume", "outward_normals", "disk_quad9",
           "jacobians", "shape_functions", "volume", "ModeLabeler"]
