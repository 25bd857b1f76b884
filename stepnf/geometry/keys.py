"""Scene keys shared by every adapter that meshes the spherical cap (one vocabulary).

``[model.material]`` E, nu, rho (:data:`MATERIAL`) and ``[model.geometry]``
shape, a, R (a number or "inf"), h and the O-grid resolution keys
(:data:`CAP_GEOMETRY`), declared as :class:`~stepnf.keys.schema.Schema` s that
every cap adapter includes in its own ``[model]`` keys. Every key has an
allowed range (the constants below, each with its reason), checked when the
scene is read; :func:`material`, :func:`cap_dimensions`,
:func:`cap_resolution` and :func:`cap_geometry` add the checks across keys
(an impossible cap, a mesh too large).
"""
from __future__ import annotations

import math
from typing import Any, Mapping

from stepnf.errors import SceneError
from stepnf.plugin.materials import MATERIAL as ANY_MATERIAL
from stepnf.keys.schema import Key, Schema
from stepnf.geometry.cap import DEFAULT_CORE, DEFAULT_N_CORE, DEFAULT_N_RING, DEFAULT_N_THICK, MAX_GRADING
from stepnf.geometry.rim import HELD_GRADING, HELD_N_RING

MATERIAL_KEYS = ("E", "nu", "rho")
SHAPES = ("spherical_cap",)
RESOLUTION_KEYS = ("n_core", "n_ring", "n_thick", "core", "grading")
GEOMETRY_KEYS = ("shape", "a", "R", "h") + RESOLUTION_KEYS

#: Lengths (any consistent unit): 1e-12 .. 1e12 spans nanometres in metres to kilometres in
#: micrometres; the assembled stiffness holds up to the fourth power of lengths times E, which must
#: stay far inside float range.
LENGTH_RANGE = (1e-12, 1e12)
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

_LENGTH = dict(lo=LENGTH_RANGE[0], hi=LENGTH_RANGE[1], why=" (a length in model units)")

#: ``[model.material]``: a linear elastic isotropic material (all three keys, unless the adapter
#: reads the material from the user's own deck).
MATERIAL = Schema(*(ANY_MATERIAL[k] for k in MATERIAL_KEYS))  # the isotropic keys of stepnf.plugin.materials
#: ``[model.geometry]`` of the three a, R, h (the shell scaling of a user's mesh, and of every cap).
CAP_DIMENSIONS = Schema(
    Key("a", "number", "projected outer radius", **_LENGTH),
    Key("R", "number", 'radius of curvature ("inf": the flat plate), >= a', allow_inf=True, **_LENGTH),
    Key("h", "number", "thickness, in [a/1000, a)", **_LENGTH),
)
#: The O-grid resolution of a generated 3D cap (:func:`stepnf.geometry.cap.spherical_cap`).
CAP_RESOLUTION = Schema(
    Key("n_core", "integer", "elements across the half-width of the core square", default=DEFAULT_N_CORE,
        lo=RESOLUTION_RANGES["n_core"][0], hi=RESOLUTION_RANGES["n_core"][1]),
    Key("n_ring", "integer", f"element rings from the core square to the edge (fenicsx, calculix, code_aster: "
        f"{HELD_N_RING} when [[model.boundary]] holds the whole rim)", default=DEFAULT_N_RING,
        lo=RESOLUTION_RANGES["n_ring"][0], hi=RESOLUTION_RANGES["n_ring"][1]),
    Key("n_thick", "integer", "elements through the thickness", default=DEFAULT_N_THICK,
        lo=RESOLUTION_RANGES["n_thick"][0], hi=RESOLUTION_RANGES["n_thick"][1]),
    Key("core", "number", "half-width of the core square, a fraction of a", default=DEFAULT_CORE,
        lo=CORE_RANGE[0], hi=CORE_RANGE[1], lo_open=True, hi_open=True),
    Key("grading", "number", f"the rings' innermost radial width over the outermost, >= 1 (default 1; fenicsx, "
        f"calculix, code_aster: {HELD_GRADING:g} when [[model.boundary]] holds the whole rim)", lo=1.0, hi=MAX_GRADING),
)
#: ``[model.geometry]`` of a generated 3D cap: its shape, a, R, h and the resolution.
CAP_GEOMETRY = Schema(Key("shape", "choice", "the generated shape", default="spherical_cap", choices=SHAPES),
                      *CAP_DIMENSIONS, *CAP_RESOLUTION)
#: The ``material`` and ``geometry`` tables of a cap adapter's ``[model]``.
CAP_TABLES = Schema(
    Key("material", "table", "the material of every cell (isotropic E, nu, rho; with a mesh also orthotropic: "
        "stepnf.plugin.materials)", table=ANY_MATERIAL),
    Key("geometry", "table", "a generated cap, free-edged unless [[model.boundary]] holds its \"edge\" set (or, "
        "beside a mesh, its a, R, h)", table=CAP_GEOMETRY),
)


def material(config: Mapping[str, Any], scene_file, *, required: bool = True) -> dict[str, float]:
    """``[model.material]`` checked: E > 0, -1 < nu < 0.5, rho > 0 (all three when ``required``)."""
    out = ANY_MATERIAL.check(config.get("material", {}), file=scene_file, where="model.material")
    ortho = sorted(set(out) - set(MATERIAL_KEYS))
    if ortho:
        raise SceneError(scene_file, f"model.material.{ortho[0]}", "this model needs an isotropic material (E, nu, "
                         "rho: a generated cap's shell scales, the shell model); orthotropic constants are taken "
                         "with a user's mesh")
    missing = [k for k in MATERIAL_KEYS if k not in out]
    if required and missing:
        raise SceneError(scene_file, f"model.material.{missing[0]}",
                         f"missing (also missing: {missing[1:]}); the model needs E, nu, rho" if missing[1:]
                         else "missing; the model needs E, nu, rho")
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
    d = CAP_DIMENSIONS.check({k: geom[k] for k in ("a", "R", "h")}, file=scene_file, where="model.geometry")
    a, R, h = d["a"], d["R"], d["h"]
    if h >= a:
        raise SceneError(scene_file, "model.geometry.h", f"thickness must be smaller than a = {a}, got {h}")
    if R < a:
        raise SceneError(scene_file, "model.geometry.R", f"radius of curvature must be >= a = {a} "
                         f"(or \"inf\" for the flat plate), got {R}")
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
    its range and the whole mesh within :data:`MAX_CAP_DOFS` dofs (with a held rim's rings when ``n_ring``
    is not given)."""
    out = CAP_RESOLUTION.check({k: geom[k] for k in RESOLUTION_KEYS if k in geom}, file=scene_file,
                               where="model.geometry")
    # rings not given: a held rim gets HELD_N_RING (stepnf.geometry.rim), known only once the conditions
    # are applied to a mesh, so the bound assumes the larger count
    n = {"n_core": DEFAULT_N_CORE, "n_ring": max(DEFAULT_N_RING, HELD_N_RING), "n_thick": DEFAULT_N_THICK, **out}
    dofs = cap_dofs(n["n_core"], n["n_ring"], n["n_thick"])
    if dofs > MAX_CAP_DOFS:
        key = max(("n_core", "n_ring", "n_thick"), key=lambda k: (k in out, n[k] / RESOLUTION_RANGES[k][1]))
        raise SceneError(scene_file, f"model.geometry.{key}", f"the mesh (n_core = {n['n_core']}, n_ring = "
                         f"{n['n_ring']}, n_thick = {n['n_thick']}) would have about {dofs:,} dofs; at most "
                         f"{MAX_CAP_DOFS:,} are allowed (tens of GiB to factorise). Lower the resolution")
    return out


def cap_geometry(config: Mapping[str, Any], scene_file) -> dict[str, Any]:
    """``[model.geometry]`` of a generated cap: ``{"shape", "a", "R", "h", "resolution"}`` (see
    :data:`CAP_GEOMETRY`, :func:`cap_dimensions` and :func:`cap_resolution`)."""
    geom = CAP_GEOMETRY.check(config.get("geometry"), file=scene_file, where="model.geometry")
    a, R, h = cap_dimensions(geom, scene_file)
    return {"shape": geom.get("shape", "spherical_cap"), "a": a, "R": R, "h": h,
            "resolution": cap_resolution(geom, scene_file)}
