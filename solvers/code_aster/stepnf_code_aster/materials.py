"""The scene's materials as code_aster commands: ``${materials}`` and ``${cara_elem}`` of the templates.

``[model.material]`` and ``[model.materials.<group>]`` (:mod:`stepnf.plugin.materials`) become one
``DEFI_MATERIAU`` each (``ELAS`` or ``ELAS_ORTH``) and one ``AFFE_MATERIAU`` whose ``AFFE``
occurrences give the default to ``TOUT="OUI"`` and then each group's material to its
``GROUP_MA`` (later occurrences override earlier ones). Material axes become
``AFFE_CARA_ELEM(MASSIF=...)`` nautical angles ``ANGL_REP`` (degrees, :func:`nautical_angles`),
passed to ``STAT_NON_LINE`` and ``ASSEMBLAGE`` as ``CARA_ELEM``. One isotropic material on every
cell renders exactly the two lines the templates held before (``${E}``, ``${nu}``, ``${rho}``).
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from stepnf.plugin.materials import Material, rotation

REAL = "%.17g"
#: stepnf's engineering constants -> code_aster's ELAS_ORTH keywords (axes 1, 2, 3 = L, T, N).
ORTH_KEYWORDS = (("E1", "E_L"), ("E2", "E_T"), ("E3", "E_N"), ("nu12", "NU_LT"), ("nu13", "NU_LN"),
                 ("nu23", "NU_TN"), ("G12", "G_LT"), ("G13", "G_LN"), ("G23", "G_TN"), ("rho", "RHO"))
#: The cell group stepnf adds (DEFI_GROUP ... TOUT="OUI") when the default material has axes:
#: AFFE_CARA_ELEM/MASSIF reads GROUP_MA only (bibfor/modelisa/aceama.F90 ignores TOUT).
ALL_CELLS = "STEPNF_ALL"
PLAIN_LINES = ('material = DEFI_MATERIAU(ELAS=_F(E={E}, NU={nu}, RHO={rho}))\n\n'
               'fieldmat = AFFE_MATERIAU(MAILLAGE=mesh, AFFE=_F(TOUT="OUI", MATER=material))')


def nautical_angles(Q: np.ndarray) -> tuple[float, float, float]:
    """``(alpha, beta, gamma)`` in degrees of the rotation ``Q`` whose rows are the material axes
    e1, e2, e3 in global coordinates (:func:`stepnf.plugin.materials.rotation`), in code_aster's
    convention (``matrot``: alpha about Z0, beta about the new Y1 in the negative sense, gamma
    about the final X; the rows of its matrix are the final axes):
    ``e1 = (cos b cos a, cos b sin a, -sin b)``, ``e2 = sin g (sin b cos a, sin b sin a, cos b) + cos g
    (-sin a, cos a, 0)``, ``e3 = e1 x e2``."""
    cb = math.hypot(Q[0, 0], Q[0, 1])
    alpha = math.atan2(Q[0, 1], Q[0, 0]) if cb > 1e-12 else 0.0  # e1 along z: alpha is free, take 0
    beta = math.atan2(-Q[0, 2], cb)
    ca, sa, sb, cb = math.cos(alpha), math.sin(alpha), math.sin(beta), math.cos(beta)
    # e2 = sin g (sb ca, sb sa, cb) + cos g (-sa, ca, 0): project on both (also when cos b = 0)
    gamma = math.atan2(sb * (ca * Q[1, 0] + sa * Q[1, 1]) + cb * Q[1, 2], ca * Q[1, 1] - sa * Q[1, 0])
    return tuple(math.degrees(a) for a in (alpha, beta, gamma))  # type: ignore[return-value]


def defi_materiau(m: Material) -> str:
    """``DEFI_MATERIAU(ELAS=...)`` or ``DEFI_MATERIAU(ELAS_ORTH=...)`` with 17 significant digits."""
    c = m.constants
    if m.isotropic:
        return f"DEFI_MATERIAU(ELAS=_F(E={REAL % c['E']}, NU={REAL % c['nu']}, RHO={REAL % c['rho']}))"
    args = ", ".join(f"{kw}={REAL % c[key]}" for key, kw in ORTH_KEYWORDS)
    return f"DEFI_MATERIAU(ELAS_ORTH=_F({args}))"


def is_plain(materials: Mapping[str | None, Material]) -> bool:
    """One isotropic material on every cell: what ``${E}``, ``${nu}``, ``${rho}`` templates can hold."""
    return list(materials) == [None] and materials[None].isotropic


def has_axes(materials: Mapping[str | None, Material]) -> bool:
    return any("axes" in m.constants for m in materials.values())


def materials_text(materials: Mapping[str | None, Material]) -> tuple[str, str]:
    """``(${materials}, ${cara_elem})``: the command lines after ``AFFE_MODELE`` and the keyword line
    ``CARA_ELEM=cara,`` of ``STAT_NON_LINE`` and ``ASSEMBLAGE`` (empty without material axes)."""
    if is_plain(materials):
        c = materials[None].constants
        return PLAIN_LINES.format(**{k: REAL % c[k] for k in ("E", "nu", "rho")}), ""
    names = {key: "material" if key is None else f"material_{i}" for i, key in enumerate(materials)}
    lines = [f"{names[key]} = {defi_materiau(m)}\n" for key, m in materials.items()]
    affe = [f"_F({_where(key)}, MATER={names[key]})" for key in _default_first(materials)]
    lines.append(_call("fieldmat = AFFE_MATERIAU", "MAILLAGE=mesh", "AFFE", affe))
    if not has_axes(materials):
        return "\n".join(lines).rstrip("\n"), ""
    massif = []
    # the whole mesh starts with zero angles (aceama.F90): the default needs an entry only with axes
    with_axes = "axes" in materials[None].constants if None in materials else False
    for key in _default_first(materials)[0 if with_axes else (1 if None in materials else 0):]:
        angles = ", ".join(REAL % a for a in nautical_angles(rotation(materials[key].constants.get("axes"))))
        massif.append(f"_F(GROUP_MA={python_str(ALL_CELLS if key is None else key)}, ANGL_REP=({angles}))")
    if with_axes:
        lines.append(f'mesh = DEFI_GROUP(reuse=mesh, MAILLAGE=mesh, CREA_GROUP_MA=_F(NOM="{ALL_CELLS}", '
                     'TOUT="OUI"))\n')
    lines.append(_call("cara = AFFE_CARA_ELEM", "MODELE=model", "MASSIF", massif))
    return "\n".join(lines).rstrip("\n"), "\n    CARA_ELEM=cara,"


def _default_first(materials: Mapping[str | None, Material]) -> list[str | None]:
    return ([None] if None in materials else []) + [k for k in materials if k is not None]


def _where(key: str | None) -> str:
    return 'TOUT="OUI"' if key is None else f"GROUP_MA={python_str(key)}"


def python_str(value: str) -> str:
    """A Python string literal of exactly ``value`` (``repr``), between double quotes as the templates are
    written when ``value`` holds none: a value written into a command file (Python run by code_aster) is
    data whatever its characters, never code."""
    text = repr(str(value))
    # repr picks single quotes unless the value holds one; then, without a double quote, none is escaped
    return '"' + text[1:-1] + '"' if text[0] == "'" and '"' not in value else text


def _call(head: str, first: str, keyword: str, items: Sequence[str]) -> str:
    """``head(\\n    first,\\n    keyword=(\\n        item,\\n    ...),\\n)``: one item per line."""
    body = "".join(f"        {item},\n" for item in items)
    return f"{head}(\n    {first},\n    {keyword}=(\n{body}    ),\n)\n"
