"""The scene's materials on a mesh (``mesh =``): one material per named ``*ELSET``, written as CalculiX text.

:func:`assign_sections` gives every element the material of the named
element set it lies in (``[model.materials.<set>]``, :mod:`stepnf.plugin.materials`),
the default ``[model.material]`` when it lies in none; :func:`materials_text`
writes the matching model data, rendered into the job template's
``${materials}``:

* one ``*MATERIAL`` per material: ``*ELASTIC`` (``TYPE=ISO``, the default:
  ``E, nu``; or ``TYPE=ENGINEERING CONSTANTS``: ``E1, E2, E3, nu12, nu13,
  nu23, G12, G13`` and ``G23`` on the next line, ccx 2.20's order) and
  ``*DENSITY``;
* one ``*SOLID SECTION`` per element set (``EALL`` when the material covers
  every element, else an ``*ELSET`` stepnf writes), with ``ORIENTATION=`` and
  an ``*ORIENTATION, SYSTEM=RECTANGULAR`` holding the material axes 1 and 2
  when ``axes`` are given. ccx builds the local frame as
  :func:`stepnf.plugin.materials.rotation` does (axis 1 along the first vector, axis
  2 in the plane of both, axis 3 = 1 x 2), and in large deformation keeps ``S
  = C : E`` in that frame of the reference configuration.

Names are stepnf's: ``STEPNF_MAT``, ``STEPNF_OR`` for ``[model.material]`` and
``STEPNF_MAT<k>``, ``STEPNF_OR<k>``, ``STEPNF_E<k>`` for the k-th named set
(the mesh file stepnf writes holds the sets ``NALL`` and ``EALL`` only, so no
name can clash). One isotropic material on every element is written exactly
as the shipped template wrote it before ``${materials}`` existed (the same
deck, the same numbers).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from stepnf.plugin.materials import ORTHOTROPIC, Material, assign_cells, material

from .deck import REAL

#: Element ids per line of an ``*ELSET`` stepnf writes.
_PER_LINE = 16


@dataclass(frozen=True)
class Section:
    """A material on elements: ``label`` the scene's set (``None``: ``[model.material]``), ``elements`` the
    element ids (sorted; ``None``: every element, ``EALL``), ``index`` 0 for the default, k for the k-th set."""

    label: str | None
    material: Material
    elements: np.ndarray | None
    index: int

    @property
    def suffix(self) -> str:
        return "" if self.index == 0 else str(self.index)

    @property
    def elset(self) -> str:
        return "EALL" if self.elements is None else f"STEPNF_E{self.index}"

    def describe(self) -> dict:
        c = dict(self.material.constants)
        if "axes" in c:
            c["axes"] = [list(a) for a in c["axes"]]
        kind = "isotropic" if self.material.isotropic else "orthotropic"
        where = "[model.material]" if self.label is None else f"[model.materials.{self.label}]"
        n = None if self.elements is None else int(self.elements.size)
        return {"table": where, "type": kind, "elements": "all" if n is None else n, **c}


def isotropic_section(constants: Mapping[str, float]) -> Section:
    """``E``, ``nu``, ``rho`` on every element (what a generated cap and the legacy ``material`` argument give)."""
    mat = material({k: float(constants[k]) for k in ("E", "nu", "rho")}, None, "model.material")
    return Section(None, mat, None, 0)


def is_plain(sections: Sequence[Section]) -> bool:
    """One isotropic material on every element: what a job template's ``${E} ${nu} ${rho}`` can express."""
    return len(sections) == 1 and sections[0].elements is None and sections[0].material.isotropic


def assign_sections(element_ids: np.ndarray, element_sets: Mapping[str, Sequence[int]],
                    materials: Mapping[str | None, Material], *, scene_file: str | Path | None = None,
                    mesh: str | Path | None = None) -> list[Section]:
    """The sections of ``materials`` (``{None: default, set name: Material}``) over the elements
    ``element_ids`` and the mesh's named ``element_sets`` (``{NAME: ids}``, names upper-case, looked up
    case-insensitively as ccx does), through :func:`stepnf.plugin.materials.assign_cells` (its SceneErrors:
    a set the mesh lacks, a set without element, an element in two of the named sets, elements in
    none when no default is given)."""
    ids = np.sort(np.asarray(element_ids, dtype=np.int64))

    def positions(members: Sequence[int]) -> np.ndarray:
        members = np.unique(np.asarray(members, dtype=np.int64))
        pos = np.searchsorted(ids, members).clip(0, max(ids.size - 1, 0))
        return pos[ids[pos] == members]

    cells = {name: positions(members) for name, members in element_sets.items()}
    named = [name for name in materials if name is not None]
    cells.update({name: cells[name.upper()] for name in named if name.upper() in cells})
    owner = assign_cells(ids.size, cells, named, None in materials, scene_file, mesh)
    sections = [Section(name.upper(), materials[name], ids[owner == k], k) for k, name in enumerate(named, 1)]
    if np.any(owner == 0):
        sections.insert(0, Section(None, materials[None], None if np.all(owner == 0) else ids[owner == 0], 0))
    return sections


def _numbers(values: Sequence[float]) -> str:
    return ", ".join(REAL % float(v) for v in values)


def _elset(section: Section) -> list[str]:
    ids = section.elements
    rows = [", ".join(map(str, ids[i:i + _PER_LINE])) for i in range(0, ids.size, _PER_LINE)]
    return [f"*ELSET, ELSET={section.elset}", *rows]


def materials_text(sections: Sequence[Section]) -> str:
    """The ``*ORIENTATION``, ``*MATERIAL`` and ``*SOLID SECTION`` blocks of ``sections`` (the module
    docstring), without a final newline (the template's line ends it)."""
    out: list[str] = []
    for s in sections:
        c, name = s.material.constants, f"STEPNF_MAT{s.suffix}"
        section = f"*SOLID SECTION, ELSET={s.elset}, MATERIAL={name}"
        if s.label is not None or s.elements is not None:
            where = "[model.material]" if s.label is None else f"[model.materials.{s.label}]"
            out.append(f"** stepnf: {where}, {s.elements.size} elements")
            out += _elset(s)
        if "axes" in c:
            out += [f"*ORIENTATION, NAME=STEPNF_OR{s.suffix}, SYSTEM=RECTANGULAR", _numbers([*c["axes"][0],
                                                                                             *c["axes"][1]])]
            section += f", ORIENTATION=STEPNF_OR{s.suffix}"
        out.append(f"*MATERIAL, NAME={name}")
        if s.material.isotropic:
            out += ["*ELASTIC", _numbers([c["E"], c["nu"]])]
        else:
            out += ["*ELASTIC, TYPE=ENGINEERING CONSTANTS", _numbers([c[k] for k in ORTHOTROPIC[:8]]),
                    _numbers([c[ORTHOTROPIC[8]]])]
        out += ["*DENSITY", _numbers([c["rho"]]), section]
    return "\n".join(out)
