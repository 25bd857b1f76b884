"""The ``kratos`` solver adapter: thin shells of Kratos Multiphysics (10.4.4) driven as a black box.

Elements: ``element = "dkt"`` (``ShellThinElementCorotational3D3N``: DKT bending, ANDES membrane,
co-rotational) on triangles, ``element = "dkq"`` (``ShellThinElementCorotational3D4N``, Discrete
Kirchhoff Quadrilateral) on quadrilaterals; six dofs per node (ux uy uz rx ry rz). Scene keys:
:mod:`.config`. Kratos runs in a worker process (:mod:`.worker`, :mod:`.client`); the adapter is
:mod:`.adapter`, the meshes :mod:`.shellmesh`.
"""
from __future__ import annotations

from .adapter import KratosAdapter
from .shellmesh import ShellMesh, cap_surface, read_shell_mesh

__all__ = ["KratosAdapter", "ShellMesh", "cap_surface", "read_shell_mesh"]
