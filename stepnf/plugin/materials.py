"""Materials of a solid model: isotropic or orthotropic linear elasticity, one per named cell set.

Scene keys (every FE adapter with a user's mesh)::

    [model.material]               # every cell not named below: isotropic...
    E = 2.1e11
    nu = 0.3
    rho = 7800.0
    [model.materials.CORE]         # ...and the cells of the named cell set CORE: orthotropic
    E1 = 1.3e11                    # engineering constants in the material axes 1, 2, 3
    E2 = 9.0e9
    E3 = 9.0e9
    nu12 = 0.3                     # nu_ij = -eps_j / eps_i under a stress along i
    nu13 = 0.3
    nu23 = 0.45
    G12 = 5.0e9
    G13 = 5.0e9
    G23 = 3.1e9
    rho = 1600.0
    axes = [[1, 0, 0], [0, 1, 0]]  # optional: material axes 1 and 2 in global coordinates (default x, y)

A table is either isotropic (``E``, ``nu``, ``rho``) or orthotropic (the nine
engineering constants and ``rho``), never a mix. Either way the model stays St
Venant-Kirchhoff, ``S = C : E`` with the Green-Lagrange strain ``E``, so the
internal force is an exact cubic of the displacement and STEP is exact.

Conventions: Voigt order (11, 22, 33, 23, 13, 12) with engineering shear
strains (``gamma_ij = 2 E_ij``), as CalculiX and Abaqus; ``C`` maps strains to
stresses in the material axes (:func:`stiffness`), :func:`rotated` turns it to
global axes (``e1``, ``e2`` the given axes made orthonormal, ``e3 = e1 x e2``).
Units: the model's consistent ones (Pa and kg/m^3, or MPa and t/mm^3).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from stepnf.keys.checks import check_number, check_table, describe_value
from stepnf.errors import SceneError, allowed
from stepnf.keys.schema import Key, Schema

#: E, G and rho in any consistent units (E: 1e3 Pa for a gel to 1e12 Pa for diamond; rho: 8e-9 t/mm^3
#: in the mm-t-s system to 2e4 kg/m^3): 1e-20 .. 1e20 keeps their products with lengths finite.
MATERIAL_RANGE = (1e-20, 1e20)

#: Voigt order of stresses and strains: index pairs (11, 22, 33, 23, 13, 12).
VOIGT = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
ISOTROPIC = ("E", "nu")
ORTHOTROPIC = ("E1", "E2", "E3", "nu12", "nu13", "nu23", "G12", "G13", "G23")
_MOD = dict(lo=MATERIAL_RANGE[0], hi=MATERIAL_RANGE[1], why=" (in the model's consistent units)")
#: Poisson ratios of an orthotropic material may exceed 0.5 (e.g. nu23 of a composite): only their
#: magnitude is bounded here; positive definiteness of C is checked as a whole (:func:`stiffness`).
_POISSON = dict(lo=-10.0, hi=10.0, why=" (a Poisson ratio)")


def _axes(file: str | Path | None, key: str, value: Any) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``[[a1x, a1y, a1z], [a2x, a2y, a2z]]``: material axes 1 and 2, independent (made orthonormal later)."""
    # lists as TOML gives them; tuples when a checked table is checked again
    ok = (isinstance(value, (list, tuple)) and len(value) == 2
          and all(isinstance(v, (list, tuple)) and len(v) == 3 for v in value))
    if not ok:
        raise SceneError(file, key, "expected the material axes 1 and 2 as [[a1x, a1y, a1z], [a2x, a2y, a2z]], got "
                         f"{describe_value(value)}")
    a = np.array([[float(check_number(file, f"{key}[{i}][{j}]", c, lo=-1e12, hi=1e12)) for j, c in enumerate(v)]
                  for i, v in enumerate(value)])
    n1, n2 = np.linalg.norm(a, axis=1)
    if not (n1 > 0 and n2 > 0) or np.linalg.norm(np.cross(a[0], a[1])) <= 1e-8 * n1 * n2:
        raise SceneError(file, key, "the two axes must be nonzero and not parallel")
    return tuple(map(float, a[0])), tuple(map(float, a[1]))


#: One material table: isotropic or orthotropic keys, rho, optional axes.
MATERIAL = Schema(
    Key("E", "number", "Young's modulus (isotropic)", **_MOD),
    Key("nu", "number", "Poisson's ratio (isotropic)", lo=-1.0, hi=0.5, lo_open=True, hi_open=True,
        why=" (Poisson's ratio)"),
    *[Key(k, "number", "Young's modulus along axis " + k[1], **_MOD) for k in ("E1", "E2", "E3")],
    *[Key(k, "number", f"Poisson's ratio -eps_{k[3]}/eps_{k[2]} under stress along {k[2]}", **_POISSON)
      for k in ("nu12", "nu13", "nu23")],
    *[Key(k, "number", f"shear modulus in plane {k[1:]}", **_MOD) for k in ("G12", "G13", "G23")],
    Key("rho", "number", "density (mass per volume)", **_MOD),
    Key("axes", "custom", "material axes 1 and 2 in global coordinates (default x and y)", check_value=_axes,
        what="[[a1x, a1y, a1z], [a2x, a2y, a2z]]"),
)


@dataclass(frozen=True)
class Material:
    """A linear elastic material: ``C`` (6, 6) in global axes, Voigt order (11, 22, 33, 23, 13, 12) with
    engineering shear strains, density ``rho``; ``constants`` as given (for reports and solver decks)."""

    C: np.ndarray
    rho: float
    constants: Mapping[str, Any]

    @property
    def isotropic(self) -> bool:
        return "E" in self.constants


def isotropic_stiffness(E: float, nu: float) -> np.ndarray:
    """C (6, 6) of an isotropic material: lambda, mu = E nu / ((1 + nu)(1 - 2 nu)), E / (2 (1 + nu))."""
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    C = np.zeros((6, 6))
    C[:3, :3] = lam
    C[np.arange(3), np.arange(3)] += 2 * mu
    C[np.arange(3, 6), np.arange(3, 6)] = mu
    return C


def orthotropic_stiffness(c: Mapping[str, float]) -> np.ndarray:
    """C (6, 6) in the material axes from the engineering constants: the inverse of the compliance
    ``S`` with ``S_ii = 1/E_i``, ``S_ij = -nu_ij / E_i`` (symmetric: ``nu_ji / E_j = nu_ij / E_i``),
    ``S_44 = 1/G23``, ``S_55 = 1/G13``, ``S_66 = 1/G12``."""
    E = [c["E1"], c["E2"], c["E3"]]
    S = np.diag([1 / E[0], 1 / E[1], 1 / E[2], 1 / c["G23"], 1 / c["G13"], 1 / c["G12"]])
    for (i, j), nu in (((0, 1), c["nu12"]), ((0, 2), c["nu13"]), ((1, 2), c["nu23"])):
        S[i, j] = S[j, i] = -nu / E[i]
    return np.linalg.inv(S)


def rotation(axes: tuple | None) -> np.ndarray:
    """Q (3, 3) whose rows are the material axes e1, e2, e3 in global coordinates (Gram-Schmidt of the
    given axes 1 and 2, ``e3 = e1 x e2``); the identity without axes."""
    if axes is None:
        return np.eye(3)
    a1, a2 = (np.asarray(a, dtype=float) for a in axes)
    e1 = a1 / np.linalg.norm(a1)
    e2 = a2 - (a2 @ e1) * e1
    e2 /= np.linalg.norm(e2)
    return np.array([e1, e2, np.cross(e1, e2)])


def rotated(C: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """C in global axes, ``T^T C T``: the strain energy is the same in both frames, with ``T`` the
    Voigt strain transformation (engineering shear) of the rotation Q (rows: material axes),
    ``eps_material = T eps_global``: ``T[a, b] = w_a (Q_ik Q_jm + Q_im Q_jk)`` for the index pairs
    ``a = (i, j)``, ``b = (k, m)``, with ``w_a = 1/2`` for a normal strain and 1 for a shear."""
    T = np.zeros((6, 6))
    for a, (i, j) in enumerate(VOIGT):
        for b, (k, m) in enumerate(VOIGT):
            T[a, b] = (0.5 if i == j else 1.0) * (Q[i, k] * Q[j, m] + Q[i, m] * Q[j, k])
    return T.T @ C @ T


def material(table: Mapping[str, Any], file: str | Path | None, where: str) -> Material:
    """A checked material table (:data:`MATERIAL`): isotropic or orthotropic, complete, positive definite."""
    c = MATERIAL.check(table, file=file, where=where)
    iso = [k for k in ISOTROPIC if k in c]
    ortho = [k for k in ORTHOTROPIC if k in c]
    if iso and ortho:
        raise SceneError(file, where, f"give either the isotropic {list(ISOTROPIC)} or the orthotropic "
                         f"{list(ORTHOTROPIC)} constants, not a mix (got {iso + ortho})")
    need = (list(ISOTROPIC) if iso or not ortho else list(ORTHOTROPIC)) + ["rho"]
    missing = [k for k in need if k not in c]
    if missing:
        raise SceneError(file, f"{where}.{missing[0]}", f"missing; this material needs {need}")
    if iso and "axes" in c:
        raise SceneError(file, f"{where}.axes", "an isotropic material has no axes")
    C = isotropic_stiffness(c["E"], c["nu"]) if iso else orthotropic_stiffness(c)
    eig = np.linalg.eigvalsh((C + C.T) / 2)
    if not eig.min() > 0 or not np.all(np.isfinite(C)):
        raise SceneError(file, where, "the constants give a stiffness that is not positive definite (a material "
                         "that would release energy under some strain): check the Poisson ratios against "
                         "nu_ij^2 < E_i / E_j and 1 - nu12 nu21 - nu23 nu32 - nu13 nu31 - 2 nu21 nu32 nu13 > 0")
    return Material(rotated(C, rotation(c.get("axes"))), float(c["rho"]), dict(c))


def materials(config: Mapping[str, Any], file: str | Path | None) -> dict[str | None, Material]:
    """``{None: [model.material], set name: [model.materials.<set>]}`` of a ``[model]`` table."""
    out: dict[str | None, Material] = {}
    if "material" in config:
        out[None] = material(config["material"], file, "model.material")
    named = check_table(file, "model.materials", config.get("materials", {}))
    for name, table in named.items():
        out[str(name)] = material(table, file, f"model.materials.{name}")
    return out


def _check_materials(file: str | Path | None, key: str, value: Any) -> dict[str, Mapping[str, Any]]:
    table = check_table(file, key, value, "of material tables by cell-set name")
    for name, sub in table.items():
        material(sub, file, f"{key}.{name}")
    return dict(table)


#: The ``materials`` key of ``[model]``: one material table per named cell set.
MATERIALS_KEY = Key("materials", "custom", "a material per named cell set: [model.materials.<set>] (isotropic or "
                    "orthotropic keys of [model.material])", check_value=_check_materials,
                    what="tables [model.materials.<set>]")



def assign_cells(n_cells: int, cell_sets: Mapping[str, np.ndarray], named: list[str], has_default: bool,
                 file: str | Path | None, mesh: str | Path | None = None) -> np.ndarray:
    """Which material each cell takes: ``owner`` (n_cells,), 0 for the default ``[model.material]``, ``k``
    for ``named[k - 1]`` (a ``[model.materials.<set>]``).

    ``cell_sets``: the mesh's ``{name: cell positions (0-based)}``, looked up by the exact names of
    ``named``. A :class:`~stepnf.errors.SceneError` naming the key for a set the mesh lacks (listing the
    sets it has), a set that holds no cell, a cell in two named sets (naming both) and cells in none
    without a default.
    """
    of = f" of {mesh}" if mesh else ""
    owner = np.full(int(n_cells), -1, dtype=np.int64)
    for k, name in enumerate(named, 1):
        key = f"model.materials.{name}"
        if name not in cell_sets:
            has = allowed(sorted(cell_sets)) if cell_sets else ("no named cell sets (an *ELSET, a Gmsh physical "
                                                                "group of volume cells, a meshio cell set, a MED "
                                                                "group of cells)")
            raise SceneError(file, key, f"no cell set {name!r} in the mesh{of}; it has {has}")
        cells = np.unique(np.asarray(cell_sets[name], dtype=np.int64))
        if cells.size == 0:
            raise SceneError(file, key, f"the cell set {name!r}{of} holds no cell of the mesh")
        taken = cells[owner[cells] > 0]
        if taken.size:
            raise SceneError(file, key, f"{taken.size} cells{of} lie in both cell sets {named[owner[taken[0]] - 1]!r} "
                             f"and {name!r} (the first: cell {int(taken[0])}, 0-based); a cell takes one material: "
                             "name disjoint sets")
        owner[cells] = k
    rest = np.flatnonzero(owner < 0)
    if rest.size:
        if not has_default:
            raise SceneError(file, "model.material", f"missing: {rest.size} of the {n_cells} cells{of} lie in none "
                             f"of the cell sets {named} (the first: cell {int(rest[0])}, 0-based); give "
                             "[model.material] for them, or [model.materials.<set>] for sets that cover the mesh")
        owner[rest] = 0
    return owner
