"""Scene keys shared by every adapter that meshes the spherical cap (issue 3: one vocabulary).

``[model.material]`` E, nu, rho and ``[model.geometry]`` shape, a, R (a number
or "inf"), h and the O-grid resolution keys. Every key has an allowed range
(the constants below, each with its reason), checked when the scene is read:
errors name the key, what was given and what is allowed, in the scene's file.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

from ..errors import SceneError, allowed
from ..scene import check_number, check_text, describe_value
from .cap import DEFAULT_N_CORE, DEFAULT_N_RING, DEFAULT_N_THICK

MATERIAL_KEYS = ("E", "nu", "rho")
SHAPES = ("spherical_cap",)
RESOLUTION_KEYS = ("n_core", "n_ring", "n_thick", "core")
GEOMETRY_KEYS = ("shape", "a", "R", "h") + RESOLUTION_KEYS

#: Lengths (any consistent unit): 1e-12 .. 1e12 spans nanometres in metres to kilometres in
#: micrometres; the assembled stiffness holds up to the fourth power of lengths times E, which must
#: stay far inside float range.
LENGTH_RANGE = (1e-12, 1e12)
#: E and rho in any consistent units (E: 1e3 Pa for a gel to 1e12 Pa for diamond; rho: 8e-9 t/mm^3
#: in the mm-t-s system to 2e4 kg/m^3): 1e-20 .. 1e20 keeps their products with lengths finite.
MATERIAL_RANGE = (1e-20, 1e20)
#: Thinnest cap: h >= a / 1000. Then kappa = a^4/(R^2 h^2) <= (a/h)^2 <= 1e6 (R >= a), the range of
#: the von Karman model (:data:`stepnf.models.vonkarman.RANGES`); thinner solids lock and no mesh
#: of a few million dofs resolves them.
MAX_SLENDERNESS = 1000.0
#: Flattest finite cap: R <= 1e10 h. The mid-surface height sqrt(R^2 - r^2) - R is computed with an
#: error ~1e-16 R, which must stay below 1e-6 h; a flatter cap is the plate R = "inf".
MAX_R_OVER_H = 1e10
#: O-grid resolution: each key's own range, then the whole mesh at most MAX_CAP_DOFS dofs (the
#: defaults give 17 649, the paper's mesh 38k; 2 million quadratic-solid dofs need tens of GiB to
#: factorise, beyond any workstation).
RESOLUTION_RANGES: dict[str, tuple[int, int]] = {"n_core": (1, 400), "n_ring": (1, 400), "n_thick": (1, 50)}
CORE_RANGE = (0.0, 1.0 / math.sqrt(2.0))  # open interval: the core square must fit inside the disk
MAX_CAP_DOFS = 2_000_000


def check_keys(table: Mapping[str, Any], known: Sequence[str], where: str, scene_file) -> None:
    """Refuse keys outside ``known`` in the table at ``where``."""
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise SceneError(scene_file, where, f"unknown key(s) {unknown}. Pick from {allowed(known)}")


def finite_or_inf(scene_file, key: str, value: Any, *, allow_inf: bool = False,
                  lo: float | None = None, hi: float | None = None) -> float:
    """``value`` as a finite float in ``[lo, hi]`` (or ``inf`` when allowed, written ``"inf"``)."""
    if allow_inf and isinstance(value, str) and value.strip().lower() in ("inf", "infinity"):
        return math.inf
    why = ' (or "inf")' if allow_inf else ""
    return float(check_number(scene_file, key, value, lo=lo, hi=hi, why=why))


def number(table: Mapping[str, Any], where: str, key: str, scene_file, *, allow_inf: bool = False,
           lo: float | None = None, hi: float | None = None) -> float:
    """``table[key]`` as :func:`finite_or_inf` checks it."""
    return finite_or_inf(scene_file, f"{where}.{key}", table.get(key), allow_inf=allow_inf, lo=lo, hi=hi)


def material(config: Mapping[str, Any], scene_file, *, required: bool = True) -> dict[str, float]:
    """``[model.material]``: E > 0, -1 < nu < 0.5, rho > 0 (all three when ``required``)."""
    mat = config.get("material", {})
    if not isinstance(mat, Mapping):
        raise SceneError(scene_file, "model.material", f"expected a table with E, nu, rho, got {describe_value(mat)}")
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
            out[k] = float(check_number(scene_file, "model.material.nu", mat[k], lo=-1.0, hi=0.5, lo_open=True,
                                        hi_open=True, why=" (Poisson's ratio)"))
        else:
            out[k] = number(mat, "model.material", k, scene_file, lo=MATERIAL_RANGE[0], hi=MATERIAL_RANGE[1])
    return out


def cap_dimensions(geom: Mapping[str, Any], scene_file, *, what: str = "a spherical cap") -> tuple[float, float, float]:
    """``a``, ``R`` (a number or "inf") and ``h`` of ``[model.geometry]``, checked.

    Refuses an impossible cap: R must be at least a (a sphere of radius R has
    no cap wider than it), and h must lie in [a / :data:`MAX_SLENDERNESS`, a); and
    lengths outside :data:`LENGTH_RANGE` or R above :data:`MAX_R_OVER_H` h.
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
    lo, hi = LENGTH_RANGE
    for key, value in (("a", a), ("h", h)) + ((("R", R),) if math.isfinite(R) else ()):
        check_number(scene_file, f"model.geometry.{key}", value, lo=lo, hi=hi, why=" (a length in model units)")
    if h * MAX_SLENDERNESS < a:
        raise SceneError(scene_file, "model.geometry.h", f"thickness must be at least a/{MAX_SLENDERNESS:g} = "
                         f"{a / MAX_SLENDERNESS:g} (kappa = a^4/(R^2 h^2) <= (a/h)^2 stays <= 1e6), got {h}")
    if math.isfinite(R) and R > MAX_R_OVER_H * h:
        raise SceneError(scene_file, "model.geometry.R", f"radius of curvature must be <= {MAX_R_OVER_H:g} h = "
                         f"{MAX_R_OVER_H * h:g} (flatter caps lose their shape to round-off); write R = \"inf\" "
                         f"for the flat plate, got {R}")
    return a, R, h


def cap_dofs(n_core: int, n_ring: int, n_thick: int) -> int:
    """Dofs of the hex27 O-grid cap (:func:`stepnf.geometry.cap.spherical_cap`; hex20 and tet10 have no more):
    ``(2 n_core + 1)^2 + 16 n_core n_ring`` nodes per level, ``2 n_thick + 1`` levels, 3 dofs a node."""
    return 3 * (2 * n_thick + 1) * ((2 * n_core + 1) ** 2 + 16 * n_core * n_ring)


def cap_resolution(geom: Mapping[str, Any], scene_file) -> dict[str, Any]:
    """The resolution keys given in ``[model.geometry]`` (n_core, n_ring, n_thick, core), each within
    its range and the whole mesh within :data:`MAX_CAP_DOFS` dofs."""
    out: dict[str, Any] = {}
    for key, (lo, hi) in RESOLUTION_RANGES.items():
        if key in geom:
            out[key] = int(check_number(scene_file, f"model.geometry.{key}", geom[key], integer=True, lo=lo, hi=hi))
    if "core" in geom:
        out["core"] = float(check_number(scene_file, "model.geometry.core", geom["core"], lo=CORE_RANGE[0],
                                         hi=CORE_RANGE[1], lo_open=True, hi_open=True,
                                         why=" (half-width of the core square, a fraction of a)"))
    n = {"n_core": DEFAULT_N_CORE, "n_ring": DEFAULT_N_RING, "n_thick": DEFAULT_N_THICK, **out}
    dofs = cap_dofs(n["n_core"], n["n_ring"], n["n_thick"])
    if dofs > MAX_CAP_DOFS:
        key = max(("n_core", "n_ring", "n_thick"), key=lambda k: (k in out, n[k] / RESOLUTION_RANGES[k][1]))
        raise SceneError(scene_file, f"model.geometry.{key}", f"the mesh (n_core = {n['n_core']}, n_ring = "
                         f"{n['n_ring']}, n_thick = {n['n_thick']}) would have about {dofs:,} dofs; at most "
                         f"{MAX_CAP_DOFS:,} are allowed (tens of GiB to factorise). Lower the resolution")
    return out


def cap_geometry(config: Mapping[str, Any], scene_file) -> dict[str, Any]:
    """``[model.geometry]`` of a generated cap: ``{"shape", "a", "R", "h", "resolution"}`` (see
    :func:`cap_dimensions` and :func:`cap_resolution`)."""
    geom = config.get("geometry")
    if not isinstance(geom, Mapping):
        raise SceneError(scene_file, "model.geometry", f"expected a table with shape, a, R, h, got "
                         f"{describe_value(geom)}")
    check_keys(geom, GEOMETRY_KEYS, "model.geometry", scene_file)
    shape = geom.get("shape", "spherical_cap")
    if shape not in SHAPES:
        raise SceneError(scene_file, "model.geometry.shape", f"got {describe_value(shape)}. Pick one of "
                         f"{allowed(SHAPES)}")
    a, R, h = cap_dimensions(geom, scene_file)
    return {"shape": shape, "a": a, "R": R, "h": h, "resolution": cap_resolution(geom, scene_file)}


def text_value(config: Mapping[str, Any], key: str, scene_file, what: str = "a file name") -> str:
    """``config[key]`` as a non-empty string without NUL (a file or folder name, a command)."""
    return check_text(scene_file, f"model.{key}", config.get(key), what)
