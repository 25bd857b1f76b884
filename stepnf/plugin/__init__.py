"""What a solver-adapter author imports: the adapter protocol and everything an adapter builds on.

:class:`SolverAdapter` (:mod:`.adapter`)
    the protocol: matrices, batched internal forces, dof geometry, ``from_config``.
:class:`LazyMatrices` (:mod:`.lazy_matrices`)
    K and M built once, on first use.
:func:`boundary_conditions`, :func:`fixed_dofs`, :class:`FreeDofs`, :data:`BOUNDARY_KEY` (:mod:`.boundary`)
    one vocabulary of boundary conditions for every FE adapter.
:func:`translation_mask`, :func:`rotation_mask`, :func:`node_vectors` (:mod:`.dofs`)
    translations and rotations among the dofs (a shell's ``rx ry rz``): what measures displacements reads.
:class:`Material`, :func:`assign_cells`, :data:`MATERIALS_KEY` (:mod:`.materials`)
    isotropic and orthotropic materials per named cell set.
:class:`Key`, :class:`Schema`, :class:`FromScene` (:mod:`stepnf.keys.schema`)
    the declared ``[model]`` keys an adapter accepts, and the class methods that tie it to a scene.
:class:`OutputMesh` (:mod:`.output_mesh`)
    the mesh an adapter offers for the field files.
:class:`ModalModel` (:mod:`.modal_model`)
    a model given directly in modal coordinates.
:mod:`stepnf.external`
    what every adapter of an external program shares: templates, work folders, processes, ``[model]`` keys.
:class:`ShellScales` (:mod:`.shell_scales`)
    the nondimensional figures of a shallow spherical shell an adapter may report.
:mod:`.registry`
    discovery of the adapters registered under the entry-point group ``stepnf.solvers``.

The conformance harness of an adapter is :mod:`stepnf.testing`; the guide is ``docs/adapters.md``.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from stepnf.runtime.lazy import lazy_exports

if TYPE_CHECKING:
    from stepnf.keys.schema import FromScene, Key, Schema
    from stepnf.plugin.adapter import SolverAdapter
    from stepnf.plugin.boundary import BOUNDARY_KEY, FreeDofs, boundary_conditions, fixed_dofs
    from stepnf.plugin.dofs import node_vectors, rotation_mask, translation_mask
    from stepnf.plugin.lazy_matrices import LazyMatrices
    from stepnf.plugin.materials import MATERIALS_KEY, Material, assign_cells
    from stepnf.plugin.modal_model import ModalModel
    from stepnf.plugin.output_mesh import OutputMesh
    from stepnf.plugin.shell_scales import ShellScales

_NAMES = {"SolverAdapter": "adapter", "LazyMatrices": "lazy_matrices", "ModalModel": "modal_model",
          "OutputMesh": "output_mesh", "ShellScales": "shell_scales",
          "BOUNDARY_KEY": "boundary", "FreeDofs": "boundary", "boundary_conditions": "boundary", "fixed_dofs": "boundary",
          "translation_mask": "dofs", "rotation_mask": "dofs", "node_vectors": "dofs",
          "MATERIALS_KEY": "materials", "Material": "materials", "assign_cells": "materials",
          "Key": "stepnf.keys.schema", "Schema": "stepnf.keys.schema", "FromScene": "stepnf.keys.schema"}
__getattr__ = lazy_exports(__name__, _NAMES, globals())
__all__ = sorted(_NAMES)
