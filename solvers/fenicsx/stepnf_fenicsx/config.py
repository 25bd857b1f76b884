"""Validation of the ``[model]`` table of a FEniCSx scene (no dolfinx import).

::

    [model]
    solver = "fenicsx"
    element = "hex27"            # or "tet10"
    mesh = "part.msh"            # optional: any mesh meshio reads, instead of [model.geometry]
    quadrature_degree = 4        # optional
    [model.geometry]
    shape = "spherical_cap"
    a = 0.15                     # projected outer radius
    R = 1.5                      # radius of curvature, "inf" for the flat plate
    h = 0.003                    # thickness
    n_core = 14                  # optional resolution keys (defaults shown)
    n_ring = 5
    n_thick = 1
    core = 0.5                   # half-width of the square core, fraction of a
    [model.material]
    E = 1.04e11
    nu = 0.3
    rho = 4400.0

With ``mesh``, ``[model.geometry]`` may still give ``a``, ``R``, ``h``
(without ``shape``) so that shell scales, Gamma and mode labels are
available; the mesh must then be placed like the generator's caps (apex at
the origin, centre of curvature at ``(0, 0, -R)``, axis ``z``). Without them,
labels use ``e_z`` as the normal and every node as the mid-surface (fine for
plates), and the characteristic length is the smallest bounding-box extent.

Allowed ranges (with their reasons) of the material, geometry and resolution
keys are those of every cap model, in :mod:`stepnf.geometry.keys` (e.g. h >=
a/1000, a generated mesh of at most 2 million dofs); ``quadrature_degree`` lies
in [2, 12].
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from stepnf.errors import SceneError, allowed
from stepnf.scene import check_number, check_text, describe_value
from stepnf.geometry import keys as cap_keys

ELEMENTS = ("hex27", "tet10")
SHAPES = ("spherical_cap",)
MODEL_KEYS = ("element", "geometry", "material", "mesh", "quadrature_degree")
GEOMETRY_KEYS = ("shape", "a", "R", "h", "n_core", "n_ring", "n_thick", "core")
MATERIAL_KEYS = ("E", "nu", "rho")
RESOLUTION_KEYS = ("n_core", "n_ring", "n_thick")


def _table(config: Mapping[str, Any], name: str, keys, file, *, required: bool = False) -> dict[str, Any]:
    table = config.get(name)
    if table is None:
        if required:
            raise SceneError(file, f"model.{name}", f"missing table; it needs the keys {allowed(keys)}")
        table = {}
    if not isinstance(table, Mapping):
        raise SceneError(file, f"model.{name}", f"expected a table, got {table!r}")
    unknown = sorted(set(table) - set(keys))
    if unknown:
        raise SceneError(file, f"model.{name}", f"unknown keys {unknown}. Allowed keys: {allowed(keys)}")
    return dict(table)


def parse_model(config: Mapping[str, Any], *, base_dir: Path, scene_file=None) -> dict[str, Any]:
    """Check the keys and return ``{element, material, geometry (or None), mesh (Path or None), quadrature_degree}``."""
    f = scene_file
    unknown = sorted(set(config) - set(MODEL_KEYS))
    if unknown:
        raise SceneError(f, "model", f"unknown keys {unknown} for solver 'fenicsx'. Allowed keys: "
                         f"{allowed(('solver',) + MODEL_KEYS)}")
    element = config.get("element", "hex27")
    if element not in ELEMENTS:
        raise SceneError(f, "model.element", f"unknown element {describe_value(element)}. Pick one of "
                         f"{allowed(ELEMENTS)}")
    qd = config.get("quadrature_degree", 4)
    check_number(f, "model.quadrature_degree", qd, integer=True, lo=2, hi=12)  # 12: exact for any used element

    if "material" not in config:
        raise SceneError(f, "model.material", f"missing table; a material needs {allowed(MATERIAL_KEYS)}")
    mat = cap_keys.material(config, f)  # the keys every cap adapter shares
    E, nu, rho = mat["E"], mat["nu"], mat["rho"]

    geo = _table(config, "geometry", GEOMETRY_KEYS, f)
    mesh = config.get("mesh")
    if mesh is not None:
        check_text(f, "model.mesh", mesh, "a mesh file name")
        path = Path(mesh)
        path = path if path.is_absolute() else Path(base_dir) / path
        try:
            is_file = path.is_file()
        except OSError:  # a name too long for the file system
            is_file = False
        if not is_file:
            raise SceneError(f, "model.mesh", f"mesh file {str(path)!r} does not exist (or is not a file)")
        if "shape" in geo or any(k in geo for k in RESOLUTION_KEYS + ("core",)):
            raise SceneError(f, "model.geometry", "give either model.mesh or a generated geometry "
                             "(model.geometry.shape and resolution keys), not both; with a mesh, "
                             "model.geometry may only hold a, R, h")
        mesh = path
    elif not geo:
        raise SceneError(f, "model.geometry", "missing: give model.geometry (shape = 'spherical_cap', a, R, h) "
                         "or model.mesh (a file meshio reads)")
    else:
        shape = geo.get("shape")
        if shape not in SHAPES:
            raise SceneError(f, "model.geometry.shape", f"unknown or missing shape {shape!r}. Pick one of "
                             f"{allowed(SHAPES)}")
        missing = [k for k in ("a", "R", "h") if k not in geo]
        if missing:
            raise SceneError(f, "model.geometry", f"missing keys {missing}; a spherical cap needs ['a', 'R', 'h']")
    geometry = None
    if any(k in geo for k in ("a", "R", "h")):
        a, R, h = cap_keys.cap_dimensions(geo, f, what="the shell scaling (kappa, Gamma)")
        geometry = {"a": a, "R": R, "h": h}
        geometry.update(cap_keys.cap_resolution(geo, f))  # ranges and the mesh-size limit of every cap
    return {"element": element, "material": {"E": E, "nu": nu, "rho": rho}, "geometry": geometry,
            "mesh": mesh, "quadrature_degree": qd}
