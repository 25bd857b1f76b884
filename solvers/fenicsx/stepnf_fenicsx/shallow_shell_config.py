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
    [[model.boundary]]           # optional: the edge held (default: free)
    set = "edge"                 # the only set: the rim of the disk
    dofs = ["ux", "uy", "uz"]    # clamped (default), or ["uz"]: simply supported

Edge conditions (:mod:`stepnf_fenicsx.shallow_shell`): ``set = "edge"`` with
every dof (the default) clamps the edge (``u = v = w = 0`` at its dofs, the
normal slope ``dw/dn = 0`` weakly by a Nitsche term); ``dofs = ["uz"]``
supports it simply (``w = 0``; in-plane displacements and slope free, so the
three in-plane rigid motions remain). Other sets, boxes and other dof lists
are refused when the model is built.

The geometry keys are the 3D adapter's ``a``, ``R``, ``h`` (``shape``, if
given, must be ``"spherical_cap"``), with the ranges of :mod:`stepnf.geometry.keys`;
the resolution keys are this model's own (``n_rings`` in [2, 200]: at most ~3.2
million dofs with P3).
"""
from __future__ import annotations

from typing import Any, Mapping

from stepnf.plugin.boundary import BOUNDARY_KEY, boundary_conditions
from stepnf.geometry import keys as cap_keys
from stepnf.keys.schema import Key, Schema

#: Defaults of the optional keys (``quadrature_degree``: ``2 * degree``). Resolution: 12 rings, P3,
#: 11 991 dofs: frequencies of the first 24 modes within 3e-5 of the von Karman model, Gamma of the
#: six test modes within 0.01% (0.13% for (0,2), 0.9% for (2,1) near a 1:2 resonance).
DEFAULTS: dict[str, Any] = {"inplane_inertia": False, "penalty": 10.0, "degree": 3, "quadrature_degree": None,
                            "n_rings": 12, "grading": 1.0}

#: ``[model.geometry]``: the 3D caps' a, R, h and this model's own resolution keys.
GEOMETRY = Schema(
    Key("shape", "choice", "the shape", default="spherical_cap", choices=cap_keys.SHAPES),
    *cap_keys.CAP_DIMENSIONS,
    # about 81 n_rings^2 dofs with P3 (11 991 at 12 rings): 200 rings is 3.2 million, the ceiling of the 3D caps
    Key("n_rings", "integer", "rings of vertices from the centre to the edge", default=DEFAULTS["n_rings"],
        lo=2, hi=200),
    Key("grading", "number", "outer ring spacing / mean ring spacing", default=DEFAULTS["grading"], lo=0.0,
        hi=1.0, lo_open=True),
)
#: The keys of ``[model]`` (``stepnf solvers --keys fenicsx_shell``).
MODEL_KEYS = Schema(
    Key("inplane_inertia", "bool", "keep the in-plane inertia (false: von Karman's quasi-static in-plane motion)",
        default=DEFAULTS["inplane_inertia"]),
    Key("penalty", "number", "interior-penalty factor alpha of the bending term", default=DEFAULTS["penalty"],
        lo=2.0, hi=1000.0),
    Key("degree", "choice", "polynomial degree of (u, v, w)", default=DEFAULTS["degree"], choices=(2, 3)),
    Key("quadrature_degree", "integer", "quadrature degree of the forms (default 2 degree)", lo=2, hi=12),
    Key("material", "table", "the material", table=cap_keys.MATERIAL, required=True),
    Key("geometry", "table", "the shallow cap and its mesh resolution", table=GEOMETRY, required=True),
    BOUNDARY_KEY,
)


def parse_shell_model(config: Mapping[str, Any], scene_file=None) -> dict[str, Any]:
    """Check the keys; return ``{a, R, h, n_rings, grading, E, nu, rho, inplane_inertia, penalty,
    quadrature_degree, boundary}`` with defaults filled in (:data:`DEFAULTS`; ``boundary``: a list of
    :class:`stepnf.plugin.boundary.BoundaryCondition`, empty for the free edge)."""
    f = scene_file
    c = MODEL_KEYS.check(config, file=f, where="model", reserved=("solver",))
    out = {k: c.get(k, DEFAULTS[k]) for k in ("inplane_inertia", "penalty", "degree")}
    out["quadrature_degree"] = c.get("quadrature_degree", 2 * out["degree"])
    out.update(cap_keys.material(c, f))  # all three constants
    geo = c["geometry"]
    a, R, h = cap_keys.cap_dimensions(geo, f, what="a shallow shell")
    out.update(a=a, R=R, h=h, n_rings=geo.get("n_rings", DEFAULTS["n_rings"]),
               grading=geo.get("grading", DEFAULTS["grading"]), boundary=boundary_conditions(c.get("boundary"), f))
    return out
