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
    [model.material]             # every cell (with mesh: those no [model.materials.<set>] names)
    E = 1.04e11
    nu = 0.3
    rho = 4400.0
    [model.materials.CORE]       # with mesh, optional: the cells of the mesh's cell set CORE
    E1 = 1.3e11                  # isotropic (E, nu) or orthotropic (E1 E2 E3 nu12 nu13 nu23 G12 G13 G23)
    ...                          # constants, rho, optional axes (stepnf.plugin.materials)
    [[model.boundary]]           # optional, repeated: zero displacements (stepnf.plugin.boundary)
    set = "edge"                 # a named node set: "edge" on a generated cap, the file's sets with mesh
    dofs = ["ux", "uy", "uz"]    # optional (default: clamped)

Boundary conditions: ``set`` names a node set (a generated cap has
``"edge"``, every node of its lateral face; a mesh file has the point sets,
cell sets, Gmsh physical groups and MED groups meshio reads), or ``box =
[[x0, y0, z0], [x1, y1, z1]]`` selects the nodes inside; the dofs they fix
are removed (:mod:`stepnf_fenicsx.constraints`). Sets and boxes are resolved
when the model is built (the mesh is read then).

Materials: a generated cap takes one isotropic ``[model.material]`` (its
shell scales need E and nu). With ``mesh``, ``[model.material]`` may be
orthotropic (the nine engineering constants, ``rho``, optional material
``axes``) and ``[model.materials.<set>]`` gives the cells of a named cell set
of the mesh (an ``*ELSET``, a Gmsh physical group of volume cells, a meshio
cell set, a MED group of cells) their own material
(:mod:`stepnf_fenicsx.regions`); ``[model.material]`` is then needed only for
the cells no set names. Every material is St Venant-Kirchhoff (``S = C : E``).

With ``mesh``, ``[model.geometry]`` may still give ``a``, ``R``, ``h``
(without ``shape``) so that shell scales, Gamma and mode labels are
available; the mesh must then be placed like the generator's caps (apex at
the origin, centre of curvature at ``(0, 0, -R)``, axis ``z``). Without them
the modes have no labels ((k, n) means something only about an axis: give
master modes by index, ``stepnf modes`` lists them), Gamma needs ``[analysis]
thickness`` and ``transverse``, and the characteristic length is the smallest
bounding-box extent.

Allowed ranges (with their reasons) of the material, geometry and resolution
keys are those of every cap model, in :mod:`stepnf.geometry.keys` (e.g. h >=
a/1000, a generated mesh of at most 2 million dofs); ``quadrature_degree`` lies
in [2, 12].
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from stepnf.plugin.boundary import BOUNDARY_KEY, boundary_conditions
from stepnf.errors import SceneError
from stepnf.geometry import keys as cap_keys
from stepnf.plugin.materials import MATERIALS_KEY, materials
from stepnf.keys.schema import Key, Schema

ELEMENTS = ("hex27", "tet10")

#: The keys of ``[model]`` (``stepnf solvers --keys fenicsx``); geometry and material are those of
#: every cap adapter (:mod:`stepnf.geometry.keys`).
MODEL_KEYS = Schema(
    Key("element", "choice", "finite element of the generated cap or of the mesh", default="hex27",
        choices=ELEMENTS),
    Key("mesh", "file", "a user's solid mesh: an .inp (stepnf's reader, the calculix adapter's) or any format meshio "
        "reads (instead of a generated geometry)",
        what="a mesh file name"),
    # 12: exact for every element used
    Key("quadrature_degree", "integer", "quadrature degree of the forms", default=4, lo=2, hi=12),
    *cap_keys.CAP_TABLES,
    MATERIALS_KEY,
    BOUNDARY_KEY,
)


def parse_model(config: Mapping[str, Any], *, base_dir: Path, scene_file=None) -> dict[str, Any]:
    """Check the keys and return ``{element, material, materials, geometry (or None), mesh (Path or None),
    quadrature_degree, boundary}``: ``material`` the constants of ``[model.material]`` (a generated cap's E,
    nu, rho; ``None`` when a mesh's cell sets carry every material), ``materials`` (with a mesh)
    :func:`stepnf.plugin.materials.materials` ``{None: default, set: Material}``, ``boundary`` a list of
    :class:`stepnf.plugin.boundary.BoundaryCondition` (empty when none)."""
    f = scene_file
    c = MODEL_KEYS.check(config, file=f, where="model", base_dir=base_dir, reserved=("solver",))
    geo = c.get("geometry", {})
    mesh = c.get("mesh")
    if "material" not in c and (mesh is None or not c.get("materials")):
        raise SceneError(f, "model.material", f"missing table; a material needs {list(cap_keys.MATERIAL_KEYS)}"
                         + (" (or, with a mesh, [model.materials.<set>] for its cell sets)" if mesh else ""))
    if mesh is None and c.get("materials"):
        raise SceneError(f, "model.materials", "a generated geometry has no cell sets: give one isotropic "
                         "[model.material] (materials per cell set need model.mesh)")
    if mesh is None:
        mat, by_set = cap_keys.material(c, f), {}  # all three constants, isotropic
    else:
        by_set = materials(config, f)  # from the tables as written (the checked axes are tuples)
        mat = dict(by_set[None].constants) if None in by_set else None
    if mesh is not None:
        if "shape" in geo or any(k in geo for k in cap_keys.RESOLUTION_KEYS):
            raise SceneError(f, "model.geometry", "give either model.mesh or a generated geometry "
                             "(model.geometry.shape and resolution keys), not both; with a mesh, "
                             "model.geometry may only hold a, R, h")
    elif not geo:
        raise SceneError(f, "model.geometry", "missing: give model.geometry (shape = 'spherical_cap', a, R, h) "
                         "or model.mesh (a file meshio reads)")
    elif "shape" not in geo:
        raise SceneError(f, "model.geometry.shape", f"missing; a generated geometry needs shape, one of "
                         f"{list(cap_keys.SHAPES)} (or give model.mesh)")
    elif any(k not in geo for k in ("a", "R", "h")):
        missing = [k for k in ("a", "R", "h") if k not in geo]
        raise SceneError(f, "model.geometry", f"missing keys {missing}; a spherical cap needs ['a', 'R', 'h']")
    geometry = None
    if any(k in geo for k in ("a", "R", "h")):
        a, R, h = cap_keys.cap_dimensions(geo, f, what="the shell scaling (kappa, Gamma)")
        geometry = {"a": a, "R": R, "h": h}
        geometry.update(cap_keys.cap_resolution(geo, f))  # the mesh-size limit of every cap
    return {"element": c.get("element", "hex27"), "material": mat, "materials": by_set, "geometry": geometry,
            "mesh": mesh, "quadrature_degree": c.get("quadrature_degree", 4),
            "boundary": boundary_conditions(c.get("boundary"), f)}
