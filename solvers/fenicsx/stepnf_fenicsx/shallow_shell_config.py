"""Validation of the ``[model]`` table of a ``fenicsx_shell`` scene (no dolfinx import).

::

    [model]
    solver = "fenicsx_shell"
    inplane_inertia = false      # optional: von Karman's quasi-static in-plane motion (default)
    penalty = 10.0               # optional: interior-penalty factor alpha of the bending term, in [2, 1000]
    degree = 3                   # optional: polynomial degree of (u, v, w), 2 or 3
    quadrature_degree = 6        # optional (default 2 * degree)
    [model.geometry]
    a = 0.15                     # projected outer radius
    R = 1.5                      # radius of curvature, "inf" for the flat plate
    h = 0.003                    # thickness
    n_rings = 12                 # optional: rings of vertices from the centre to the edge
    grading = 1.0                # optional: outer ring spacing / mean spacing, in (0, 1]
    [model.material]
    E = 1.04e11
    nu = 0.3
    rho = 4400.0

The geometry keys are the 3D adapter's ``a``, ``R``, ``h`` (``shape``, if
given, must be ``"spherical_cap"``), with the ranges of :mod:`stepnf.geometry.keys`;
the resolution keys are this model's own (``n_rings`` in [2, 200]: at most ~3.2
million dofs with P3).
"""
from __future__ import annotations

from typing import Any, Mapping

from stepnf.errors import SceneError, allowed
from stepnf.geometry import keys as cap_keys
from stepnf.scene import check_bool, check_number, describe_value

from .config import _table  # one parser for both FEniCSx models

MODEL_KEYS = ("geometry", "material", "inplane_inertia", "penalty", "degree", "quadrature_degree")
GEOMETRY_KEYS = ("shape", "a", "R", "h", "n_rings", "grading")
MATERIAL_KEYS = ("E", "nu", "rho")
#: Defaults of the optional keys (``quadrature_degree``: ``2 * degree``). Resolution: 12 rings, P3,
#: 11 991 dofs: frequencies of the first 24 modes within 3e-5 of the von Karman model, Gamma of the
#: six test modes within 0.01% (0.13% for (0,2), 0.9% for (2,1) near a 1:2 resonance).
DEFAULTS: dict[str, Any] = {"inplane_inertia": False, "penalty": 10.0, "degree": 3, "quadrature_degree": None,
                            "n_rings": 12, "grading": 1.0}


def parse_shell_model(config: Mapping[str, Any], scene_file=None) -> dict[str, Any]:
    """Check the keys; return ``{a, R, h, n_rings, grading, E, nu, rho, inplane_inertia, penalty,
    quadrature_degree}`` with defaults filled in (:data:`DEFAULTS`)."""
    f = scene_file
    unknown = sorted(set(config) - set(MODEL_KEYS))
    if unknown:
        raise SceneError(f, "model", f"unknown keys {unknown} for solver 'fenicsx_shell'. Allowed keys: "
                         f"{allowed(('solver',) + MODEL_KEYS)}")
    out: dict[str, Any] = {}
    out["inplane_inertia"] = check_bool(f, "model.inplane_inertia", config.get("inplane_inertia",
                                                                              DEFAULTS["inplane_inertia"]))
    pen = cap_keys.finite_or_inf(f, "model.penalty", config.get("penalty", DEFAULTS["penalty"]))
    if not 2.0 <= pen <= 1000.0:
        raise SceneError(f, "model.penalty", f"interior-penalty factor must lie in [2, 1000], got {pen}")
    out["penalty"] = pen
    deg = config.get("degree", DEFAULTS["degree"])
    if isinstance(deg, bool) or not isinstance(deg, int) or deg not in (2, 3):
        raise SceneError(f, "model.degree", f"polynomial degree of (u, v, w): pick one of [2, 3], got "
                         f"{describe_value(deg)}")
    out["degree"] = deg
    out["quadrature_degree"] = check_number(f, "model.quadrature_degree", config.get("quadrature_degree", 2 * deg),
                                            integer=True, lo=2, hi=12)

    if "material" not in config:
        raise SceneError(f, "model.material", f"missing table; a material needs {allowed(MATERIAL_KEYS)}")
    mat = cap_keys.material(config, f)  # the keys every cap adapter shares
    E, nu, rho = mat["E"], mat["nu"], mat["rho"]
    out.update(E=E, nu=nu, rho=rho)

    geo = _table(config, "geometry", GEOMETRY_KEYS, f, required=True)
    if "shape" in geo and geo["shape"] != "spherical_cap":
        raise SceneError(f, "model.geometry.shape", f"unknown shape {describe_value(geo['shape'])}. Pick one of "
                         f"{allowed(('spherical_cap',))}")
    a, R, h = cap_keys.cap_dimensions(geo, f, what="a shallow shell")
    # about 81 n_rings^2 dofs with P3 (11 991 at 12 rings): 200 rings is 3.2 million, the ceiling of the 3D caps
    nr = check_number(f, "model.geometry.n_rings", geo.get("n_rings", DEFAULTS["n_rings"]), integer=True, lo=2, hi=200)
    gr = cap_keys.finite_or_inf(f, "model.geometry.grading", geo.get("grading", DEFAULTS["grading"]))
    if not 0.0 < gr <= 1.0:
        raise SceneError(f, "model.geometry.grading", f"outer/mean ring spacing must lie in (0, 1], got {gr}")
    out.update(a=a, R=R, h=h, n_rings=nr, grading=gr)
    return out
