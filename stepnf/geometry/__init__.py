"""Geometry generators for stepnf's reference models (pure numpy, no FE library).

:func:`spherical_cap` meshes free-edge shallow spherical caps and flat plates
with curved quadratic hexahedra; :class:`VolumeMesh` holds the result in
meshio's naming and VTK's node order; :class:`ModeLabeler` gives the (k, n)
labels of the modes of axisymmetric shells from any solid model's nodes.
"""
from __future__ import annotations

from .cap import VolumeMesh, disk_quad9, outward_normals, shell_volume, spherical_cap
from .hexahedra import jacobians, shape_functions, volume
from .labels import ModeLabeler

__all__ = ["VolumeMesh", "spherical_cap", "shell_volume", "outward_normals", "disk_quad9",
           "jacobians", "shape_functions", "volume", "ModeLabeler"]
