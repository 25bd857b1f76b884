"""Regions of the ``fenicsx`` solid: the material of every cell, from the mesh's named cell sets.

::

    [model.material]             # every cell not named below (optional when the sets cover the mesh)
    E = 2.1e11
    nu = 0.3
    rho = 7800.0
    [model.materials.CORE]       # the cells of the named cell set CORE (isotropic or orthotropic keys)
    E1 = 1.3e11
    ...

The tables are :mod:`stepnf.plugin.materials`' (checked when the scene is read); the
cell sets are the mesh file's (:func:`stepnf.geometry.mesh_sets.read_cell_sets`:
meshio cell sets such as an Abaqus ``*ELSET``, Gmsh physical groups of volume
cells, MED groups of cells). :func:`assign_materials` gives each cell the
material of the set naming it, the default to a cell no set names, and refuses
(:class:`~stepnf.errors.SceneError`, naming the key) a set the mesh does not
have (listing those it has), a cell in two named sets (naming both) and
unnamed cells without a default. No dolfinx here: the forms
(:class:`stepnf_fenicsx.model.MaterialField`) carry the result onto dolfinx's
cells. A material is either kind of the package (:class:`stepnf_fenicsx.model.Material`,
isotropic, or :class:`stepnf.plugin.materials.Material`): both have ``C``, ``rho``,
``constants`` and ``isotropic``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from stepnf.plugin.materials import assign_cells


@dataclass(frozen=True)
class CellMaterials:
    """The materials of a mesh's cells: cell ``c`` (row ``c`` of the mesh's cells) has ``materials[index[c]]``.

    ``names[k]`` is the cell set of material ``k`` (``None``: the default ``[model.material]``).
    """

    materials: tuple[Any, ...]
    names: tuple[str | None, ...]
    index: np.ndarray

    def used(self) -> tuple[list[Any], np.ndarray]:
        """The materials some cell has, and each cell's index among them."""
        present, index = np.unique(self.index, return_inverse=True)
        return [self.materials[k] for k in present], index.astype(np.int64)

    def describe(self) -> dict[str, Any]:
        """``{set name: {cells, constants...}}`` of the named materials (JSON-serialisable)."""
        counts = np.bincount(self.index, minlength=len(self.materials))
        return {name: {"cells": int(n), **describe_material(m)}
                for name, m, n in zip(self.names, self.materials, counts) if name is not None}


def describe_material(material: Any) -> dict[str, Any]:
    """The constants of a material as given (axes as lists), for ``describe``."""
    return {k: ([list(a) for a in v] if k == "axes" else v) for k, v in dict(material.constants).items()}


def assign_materials(n_cells: int, cell_sets: Mapping[str, np.ndarray], default: Any, named: Mapping[str, Any],
                     scene_file: str | Path | None = None, mesh_name: str | Path | None = None) -> CellMaterials:
    """Each cell's material: that of the named set holding it (``named``: ``{set: material}``), else ``default``
    (:func:`stepnf.plugin.materials.assign_cells`: the SceneErrors of a set the mesh lacks, a cell in two
    named sets and cells in none without a default)."""
    names = list(named)
    owner = assign_cells(n_cells, cell_sets, names, default is not None, scene_file, mesh_name)
    return CellMaterials((default, *named.values()), (None, *names), owner)
