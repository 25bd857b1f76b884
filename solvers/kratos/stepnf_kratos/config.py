"""The ``[model]`` keys of the ``kratos`` adapter (no Kratos import).

::

    [model]
    solver = "kratos"
    element = "dkt"              # ShellThinElementCorotational3D3N; "dkq": ...3D4N (quadrilaterals)
    mesh = "plate.msh"           # a mid-surface mesh meshio reads (triangles for dkt, quads for dkq)...
    thickness = 0.003            # ...and the shell's thickness (model length unit): needed with mesh
    [model.geometry]             # ...or a generated cap (the solid adapters' keys; h is the thickness)
    shape = "spherical_cap"
    a = 0.15
    R = "inf"
    h = 0.003
    n_core = 14                  # mesh size: the O-grid's resolution (each quad9 of the solid cap's plan
    n_ring = 5                   # view gives 4 quadrilaterals or 8 triangles; 14 x 5: 11 700 dofs)
    [model.material]             # isotropic E, nu, rho
    [model.materials.SKIN]       # with mesh: the cells of a named cell set (isotropic)
    [[model.boundary]]           # zero dofs on a node set or box; dofs may name rx ry rz
    set = "edge"
    dofs = ["ux", "uy", "uz", "rx", "ry", "rz"]
    threads = 1                  # OMP_NUM_THREADS of the Kratos worker (default 1, or the environment's)
    timeout = 3600               # seconds one request to the worker may take

With ``mesh``, ``[model.geometry]`` may still give ``a``, ``R``, ``h`` (no ``shape``) for the shell
scales (kappa, w_bar, Gamma), as for the solid adapters. Orthotropic materials are refused (Kratos's
shell sections take them through a composite layup, not wired here).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from stepnf.errors import SceneError
from stepnf.external.keys import RUN_KEYS, THREADS
from stepnf.geometry import keys as cap_keys
from stepnf.keys.schema import Key, Schema
from stepnf.plugin.boundary import BOUNDARY_KEY, boundary_conditions
from stepnf.plugin.materials import MATERIALS_KEY, materials

from .shellmesh import CELL_TYPE, KRATOS_ELEMENT

ELEMENTS = tuple(KRATOS_ELEMENT)
MODEL_KEYS = Schema(
    Key("element", "choice", "shell element: dkt (ShellThinElementCorotational3D3N, triangles), dkq "
        "(ShellThinElementCorotational3D4N, quadrilaterals)", default="dkt", choices=ELEMENTS),
    Key("mesh", "file", "a mid-surface mesh meshio reads: triangles (dkt) or quadrilaterals (dkq)",
        what="a mesh file name"),
    Key("thickness", "number", "shell thickness with mesh (a generated cap's is geometry.h)",
        lo=cap_keys.LENGTH_RANGE[0], hi=cap_keys.LENGTH_RANGE[1], why=" (a length in model units)"),
    *cap_keys.CAP_TABLES,
    MATERIALS_KEY,
    BOUNDARY_KEY,
    THREADS,
    RUN_KEYS["timeout"],
)


def parse_model(config: Mapping[str, Any], *, base_dir: Path, scene_file=None) -> dict[str, Any]:
    """Check the keys; ``{element, mesh, thickness, geometry, materials, boundary, threads, timeout}`` with
    ``materials`` ``{None: default, set: Material}`` (isotropic) and ``geometry`` ``{a, R, h, resolution...}``
    or ``None``."""
    f = scene_file
    c = MODEL_KEYS.check(config, file=f, where="model", base_dir=base_dir, reserved=("solver",))
    element, mesh, geo = c.get("element", "dkt"), c.get("mesh"), c.get("geometry", {})
    if "material" not in c and (mesh is None or not c.get("materials")):
        raise SceneError(f, "model.material", "missing table; a material needs ['E', 'nu', 'rho']"
                         + (" (or, with a mesh, [model.materials.<set>] for its cell sets)" if mesh else ""))
    by_set = materials(config, f)
    for name, m in by_set.items():
        if not m.isotropic:
            key = "model.material" if name is None else f"model.materials.{name}"
            raise SceneError(f, key, "the kratos adapter takes isotropic materials (E, nu, rho); orthotropic "
                             "shells are not supported")
    if mesh is None and c.get("materials"):
        raise SceneError(f, "model.materials", "a generated geometry has no cell sets: give one [model.material]")
    geometry = None
    if mesh is not None:
        if "shape" in geo or any(k in geo for k in cap_keys.RESOLUTION_KEYS):
            raise SceneError(f, "model.geometry", "give either model.mesh or a generated geometry, not both; with a "
                             "mesh, model.geometry may only hold a, R, h (the shell scales)")
        if "thickness" not in c:
            raise SceneError(f, "model.thickness", f"missing: the shell elements of {Path(mesh).name} need a "
                             f"thickness (element = {element!r}, {CELL_TYPE[element]} cells of the mid-surface)")
        if any(k in geo for k in ("a", "R", "h")):
            a, R, h = cap_keys.cap_dimensions(geo, f, what="the shell scaling (kappa, Gamma)")
            geometry = {"a": a, "R": R, "h": h}
        thickness = float(c["thickness"])
    else:
        if not geo:
            raise SceneError(f, "model.geometry", "missing: give model.geometry (shape = 'spherical_cap', a, R, h) "
                             "or model.mesh (a mid-surface mesh) with model.thickness")
        if "thickness" in c:
            raise SceneError(f, "model.thickness", "a generated cap's thickness is model.geometry.h: remove "
                             "model.thickness")
        if "n_thick" in geo:
            raise SceneError(f, "model.geometry.n_thick", "a shell has no elements through its thickness: remove it")
        g = cap_keys.cap_geometry(config, f)
        thickness = g["h"]
        geometry = {"a": g["a"], "R": g["R"], "h": g["h"], **g["resolution"]}
    return {"element": element, "mesh": mesh, "thickness": thickness, "geometry": geometry, "materials": by_set,
            "boundary": boundary_conditions(c.get("boundary"), f, rotations=True), "threads": c.get("threads"),
            "timeout": c.get("timeout", 3600.0)}
