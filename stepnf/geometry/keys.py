"""Scene keys shared by every adapter that meshes the spherical cap (issue 3: one vocabulary).

``[model.material]`` E, nu, rho and ``[model.geometry]`` shape, a, R (a number
or "inf"), h and the O-grid resolution keys. Errors name the key and what is
allowed, in the scene's file.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

from ..errors import SceneError, allowed

MATERIAL_KEYS = ("E", "nu", "rho")
SHAPES = ("spherical_cap",)
RESOLUTION_KEYS = ("n_core", "n_ring", "n_thick", "core")
GEOMETRY_KEYS = ("shape", "a", "R", "h") + RESOLUTION_KEYS


def check_keys(table: Mapping[str, Any], known: Sequence[str], where: str, scene_file) -> None:
    """Refuse keys outside ``known`` in the table at ``where``."""
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise SceneError(scene_file, where, f"unknown key(s) {unknown}. Pick from {allowed(known)}")


def number(table: Mapping[str, Any], where: str, key: str, scene_file, *, allow_inf: bool = False) -> float:
    """``table[key]`` as a finite float (or ``inf`` when allowed, written ``"inf"``)."""
    v = table.get(key)
    if allow_inf and isinstance(v, str) and v.strip().lower() in ("inf", "infinity"):
        return math.inf
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        kind = "a number" + (' or "inf"' if allow_inf else "")
        raise SceneError(scene_file, f"{where}.{key}", f"expected {kind}, got {v!r}")
    return float(v)


def positive_int(table: Mapping[str, Any], where: str, key: str, scene_file) -> int:
    """``table[key]`` as an integer >= 1."""
    v = table.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise SceneError(scene_file, f"{where}.{key}", f"expected a positive integer, got {v!r}")
    return v


def positive_number(table: Mapping[str, Any], where: str, key: str, scene_file, *,
                    allow_inf: bool = False) -> float:
    """``table[key]`` as a float > 0 (or ``inf`` when allowed, written ``"inf"``)."""
    v = table.get(key)
    if allow_inf and isinstance(v, str) and v.strip().lower() in ("inf", "infinity"):
        return math.inf
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        kind = "a positive number" + (' or "inf"' if allow_inf else "")
        raise SceneError(scene_file, f"{where}.{key}", f"expected {kind}, got {v!r}")
    return float(v)


def material(config: Mapping[str, Any], scene_file, *, required: bool = True) -> dict[str, float]:
    """``[model.material]``: E > 0, -1 < nu < 0.5, rho > 0 (all three when ``required``)."""
    mat = config.get("material", {})
    if not isinstance(mat, Mapping):
        raise SceneError(scene_file, "model.material", "expected a table with E, nu, rho")
    check_keys(mat, MATERIAL_KEYS, "model.material", scene_file)
    missing = [k for k in MATERIAL_KEYS if k not in mat]
    if required and missing:
        raise SceneError(scene_file, f"model.material.{missing[0]}",
                         f"missing (also missing: {missing[1:]}); the model needs E, nu, rho" if missing[1:]
                         else "missing; the model needs E, nu, rho")
    out = {}
    for k in MATERIAL_KEYS:
        if k not in mat:
            continue
        if k == "nu":
            v = mat[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not -1 < v < 0.5:
                raise SceneError(scene_file, "model.material.nu", f"Poisson's ratio must lie in (-1, 0.5), got {v!r}")
            out[k] = float(v)
        else:
            out[k] = positive_number(mat, "model.material", k, scene_file)
    return out


def cap_dimensions(geom: Mapping[str, Any], scene_file, *, what: str = "a spherical cap") -> tuple[float, float, float]:
    """``a``, ``R`` (a number or "inf") and ``h`` of ``[model.geometry]``, checked.

    Refuses an impossible cap: R must be at least a (a sphere of radius R has
    no cap wider than it), and h must be positive and below a.
    """
    missing = [k for k in ("a", "R", "h") if k not in geom]
    if missing:
        raise SceneError(scene_file, "model.geometry", f"missing keys {missing}; {what} needs ['a', 'R', 'h']")
    a = number(geom, "model.geometry", "a", scene_file)
    R = number(geom, "model.geometry", "R", scene_file, allow_inf=True)
    h = number(geom, "model.geometry", "h", scene_file)
    if a <= 0:
        raise SceneError(scene_file, "model.geometry.a", f"outer radius must be > 0, got {a}")
    if h <= 0:
        raise SceneError(scene_file, "model.geometry.h", f"thickness must be > 0, got {h}")
    if h >= a:
        raise SceneError(scene_file, "model.geometry.h", f"thickness must be smaller than a = {a}, got {h}")
    if R < a:
        raise SceneError(scene_file, "model.geometry.R", f"radius of curvature must be >= a = {a} "
                         f"(or \"inf\" for the flat plate), got {R}")
    return a, R, h


def cap_geometry(config: Mapping[str, Any], scene_file) -> dict[str, Any]:
    """``[model.geometry]`` of a generated cap: ``{"shape", "a", "R", "h", "resolution"}`` (see
    :func:`cap_dimensions`)."""
    geom = config.get("geometry")
    if not isinstance(geom, Mapping):
        raise SceneError(scene_file, "model.geometry", "expected a table with shape, a, R, h")
    check_keys(geom, GEOMETRY_KEYS, "model.geometry", scene_file)
    shape = geom.get("shape", "spherical_cap")
    if shape not in SHAPES:
        raise SceneError(scene_file, "model.geometry.shape", f"got {shape!r}. Pick one of {allowed(SHAPES)}")
    a, R, h = cap_dimensions(geom, scene_file)
    return {"shape": shape, "a": a, "R": R, "h": h,
            "resolution": {k: geom[k] for k in RESOLUTION_KEYS if k in geom}}
