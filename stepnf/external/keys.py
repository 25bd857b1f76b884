"""The ``[model]`` keys every template-driven adapter shares, and its one "mesh, deck or generated cap" build.

Run settings (:data:`RUN_KEYS`, :data:`EXECUTABLE`): how the solver is run.
Solid model (:func:`solid_model_keys`, :func:`check_solid_config`,
:func:`build_solid`, and :class:`SolidFromScene` that ties them to an adapter
class): either a user's mesh file (``mesh``), a solver deck (``deck``, for an
adapter whose schema declares it: the deck carries its own material), or a
generated free-edge cap (``[model.geometry]``), with ``[model.material]``
(:mod:`stepnf.geometry.keys`), for any adapter with the
:class:`~stepnf.geometry.solid.CapSolid` builders; with a mesh, for an adapter
whose schema declares :data:`~stepnf.plugin.materials.MATERIALS_KEY`, also
orthotropic materials and one material per named cell set
(``[model.materials.<set>]``, :mod:`stepnf.plugin.materials`), applied by the
adapter's ``apply_materials``; and the boundary conditions
of ``[[model.boundary]]`` (:mod:`stepnf.plugin.boundary`, for an adapter whose schema
declares :data:`~stepnf.plugin.boundary.BOUNDARY_KEY`), applied by
:meth:`SolidFromScene.apply_boundary` once the model is built.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, ClassVar, Mapping, Sequence

import numpy as np

from stepnf.plugin.boundary import DOF_NAMES, FreeDofs, boundary_conditions, select_nodes
from stepnf.keys.checks import describe_value
from stepnf.errors import SceneError
from stepnf.geometry import keys as cap_keys
from stepnf.geometry.checks import units_warning
from stepnf.geometry.rim import cap_for_conditions
from stepnf.plugin.materials import ISOTROPIC, materials
from stepnf.runtime.programs import check_allowed
from stepnf.keys.schema import Key, Schema
from stepnf.external.process import KEEP_POLICIES

#: Ranges of the run settings: a time-out above 1e7 s (four months) is no time-out, no machine has
#: more than 1024 cores for one solver run, 256 solver runs at once already exceed any node's memory,
#: and 2^24 MB is 16 TiB.
RUN_RANGES: dict[str, tuple[float, float]] = {"timeout": (0.0, 1e7), "threads": (1, 1024), "ncpus": (1, 1024),
                                              "parallel_runs": (1, 256), "memory_mb": (1, 2**24)}


#: The keys of an isotropic ``[model.material]``: any other (orthotropic constants, axes) asks for
#: :mod:`stepnf.plugin.materials`.
ISOTROPIC_KEYS = {*ISOTROPIC, "rho"}


def _count(name: str, doc: str, default: int) -> Key:
    lo, hi = RUN_RANGES[name]
    return Key(name, "integer", doc, default=default, lo=lo, hi=hi)


#: The executable (a name on PATH or a path); the adapter's program by default.
EXECUTABLE = Key("executable", "text", "the solver executable, a name on PATH or a path (relative: to the scene's "
                 "folder); a program the scene names runs only with --allow-programs",
                 what="an executable name or path")
#: Cores of one solver run: ``OMP_NUM_THREADS`` (CalculiX), ``ncpus`` of the export (code_aster).
THREADS = Key("threads", "integer", "OMP_NUM_THREADS of each solver run (default: the environment's)",
              lo=RUN_RANGES["threads"][0], hi=RUN_RANGES["threads"][1])
NCPUS = _count("ncpus", "cores of each solver run", 1)
MEMORY_MB = _count("memory_mb", "memory of each solver run, in MB", 4096)
#: The run settings of :class:`~stepnf.external.adapter.ExternalSolverAdapter`.
RUN_KEYS = Schema(
    Key("timeout", "number", "time-out of one solver run", default=3600.0, lo=RUN_RANGES["timeout"][0],
        hi=RUN_RANGES["timeout"][1], lo_open=True, why=" (seconds)"),
    Key("workdir", "path", "parent folder of the work folders (default: the system temp folder)",
        what="a folder path"),
    Key("keep", "choice", "which work folders are kept", default="on_error", choices=KEEP_POLICIES),
    _count("parallel_runs", "solver processes at a time, each on a share of a batch", 1),
)


def solid_model_keys(elements: Sequence[str], mesh_suffixes: Sequence[str], mesh_doc: str) -> Schema:
    """``element``, ``mesh`` (a file ending in one of ``mesh_suffixes``) and the cap adapters'
    ``material`` and ``geometry`` tables."""
    return Schema(
        Key("element", "choice", "finite element of the generated cap", default=elements[0], choices=tuple(elements)),
        Key("mesh", "file", mesh_doc + " (instead of [model.geometry])", suffixes=tuple(mesh_suffixes),
            what="a mesh file name"),
        *cap_keys.CAP_TABLES,
    )


def check_solid_config(schema: Schema, config: Mapping[str, Any], *, base_dir: str | Path,
                       scene_file: str | Path | None, mesh_needs_material: bool,
                       rotations: bool = False) -> dict[str, Any]:
    """``config`` checked against ``schema``, with exactly one of ``mesh``, ``deck`` (when the schema
    declares it) and ``[model.geometry]``.

    Returns the checked keys with ``material`` a complete ``{E, nu, rho}`` (for a generated cap,
    and for a mesh when ``mesh_needs_material``; else what was given; ``{}`` with a deck, which
    carries its own and refuses ``[model.material]`` and ``[model.materials]``). With a mesh and a
    schema declaring ``materials``, orthotropic constants or ``[model.materials.<set>]`` tables give
    ``materials`` (``{None: default, set: Material}``, :func:`stepnf.plugin.materials.materials`) and
    ``material`` the default's ``{E, nu, rho}`` when isotropic (else ``{}``); other adapters and
    generated caps take one isotropic material. ``geometry`` is replaced by
    :func:`stepnf.geometry.keys.cap_geometry`'s ``{shape, a, R, h, resolution}``. The
    ``[[model.boundary]]`` tables are checked (one of ``set`` and ``box`` each; rotations ``rx ry rz`` only
    with ``rotations``, a shell's nodes: :func:`stepnf.plugin.boundary.boundary_conditions`) and kept as given.
    """
    if "materials" in config and "materials" not in schema:
        raise SceneError(scene_file, "model.materials", "this adapter takes one isotropic [model.material] (E, nu, "
                         "rho) on every element; [model.materials] regions and orthotropic constants are taken by "
                         "the fenicsx and calculix adapters and by code_aster")
    c = schema.check(config, file=scene_file, where="model", base_dir=base_dir, reserved=("solver",))
    sources = [k for k in ("mesh", "deck", "geometry") if k in c]
    if len(sources) != 1:
        deck = ', deck = "<file>"' if "deck" in schema else ""
        raise SceneError(scene_file, "model", f'give exactly one of mesh = "<file>"{deck} or a [model.geometry] '
                         "table" + (f" (got {' and '.join(sources)})" if sources else ""))
    if "deck" in c:
        for key in ("material", "materials"):
            if key in c:
                raise SceneError(scene_file, f"model.{key}", f"the deck {c['deck']} carries its own *MATERIAL "
                                 f"blocks: remove [model.{key}] (or give the mesh with mesh = instead of deck =)")
        c["material"] = {}
    elif "mesh" in c and "materials" in schema and ("materials" in c or set(c.get("material", {})) - ISOTROPIC_KEYS):
        c["materials"] = materials(config, scene_file)  # the tables as written (checked again there)
        default = c["materials"].get(None)
        c["material"] = dict(default.constants) if default is not None and default.isotropic else {}
    else:
        if "materials" in c:
            raise SceneError(scene_file, "model.materials", "a generated cap has no named cell sets: one "
                             "[model.material] applies to it (regions need a user's mesh with cell sets)")
        _isotropic_only(c, scene_file, "materials" in schema)
        c["material"] = cap_keys.material(c, scene_file, required="geometry" in c or mesh_needs_material)
    if "geometry" in c:
        c["geometry"] = cap_keys.cap_geometry(c, scene_file)
    boundary_conditions(c.get("boundary"), scene_file, rotations=rotations)
    return c


def _isotropic_only(c: Mapping[str, Any], scene_file: str | Path | None, orthotropic_with_mesh: bool) -> None:
    """A SceneError for orthotropic constants where one isotropic material is taken."""
    extra = sorted(set(c.get("material", {})) - set(cap_keys.MATERIAL_KEYS))
    if extra:
        why = ("a generated cap takes an isotropic material (E, nu, rho; orthotropic constants need a user's mesh)"
               if orthotropic_with_mesh else "this adapter takes one isotropic material (E, nu, rho) on every "
               "element; orthotropic constants and [model.materials] regions are taken by the fenicsx and calculix "
               "adapters and by code_aster")
        raise SceneError(scene_file, f"model.material.{extra[0]}", why)


def build_solid(cls: Any, checked: Mapping[str, Any], *, read_mesh: Callable[..., Any],
                scene_file: str | Path | None, rotations: bool = False) -> Any:
    """The adapter ``cls`` for :func:`check_solid_config`'s keys: ``read_mesh(path, material=..., **run)``
    for a user's mesh, ``cls.from_deck_file(path, **run)`` for a deck, ``cls.from_cap`` for a
    generated cap (refined towards a rim the conditions hold, :mod:`stepnf.geometry.rim`); every other
    key is passed on as a run setting, and ``materials`` (when :func:`check_solid_config` gives it) to
    ``read_mesh``. Then the ``[[model.boundary]]`` (rotations allowed with ``rotations``)
    conditions (:meth:`SolidFromScene.apply_boundary`). Warns when the material's units and the
    mesh's sizes disagree; a model the adapter refuses (a ValueError) is a SceneError on ``[model]``."""
    model_data = ("element", "mesh", "deck", "geometry", "material", "materials", "boundary")
    run = {k: v for k, v in checked.items() if k not in model_data}
    material = checked["material"]
    conditions = boundary_conditions(checked.get("boundary"), scene_file, rotations=rotations)
    try:
        if "mesh" in checked:
            mats = checked.get("materials")
            if mats:
                run["materials"] = mats
                material = {"rho": next(iter(mats.values())).rho}
            adapter = read_mesh(checked["mesh"], material=checked["material"], **run)
            units_warning(adapter.points, material, source=checked["mesh"])
        elif "deck" in checked:
            adapter = cls.from_deck_file(checked["deck"], **run)
        else:
            g = checked["geometry"]
            # conditions holding the whole rim refine the cap towards it, as for fenicsx (stepnf.geometry.rim),
            # judged on the 20-node bricks from_cap builds (CapSolid.from_cap)
            _, resolution = cap_for_conditions(g["a"], g["R"], g["h"], conditions, element="hex20",
                                               scene_file=scene_file, **g["resolution"])
            adapter = cls.from_cap(a=g["a"], R=g["R"], h=g["h"], resolution=resolution, **material, **run)
            units_warning(adapter.points, material, source=scene_file, thickness=g["h"])
        if conditions:
            adapter.apply_boundary(conditions, scene_file=scene_file, mesh=checked.get("mesh") or checked.get("deck"))
        return adapter
    except SceneError as exc:
        if exc.file is None and scene_file is not None:  # raised by the adapter, which knows no scene file
            raise SceneError(scene_file, exc.key, exc.message) from None
        raise
    except ValueError as exc:
        raise SceneError(scene_file, "model", str(exc)) from exc


class SolidFromScene:
    """``validate_config`` and ``from_config`` of a template-driven solid adapter (a mixin placed before
    the adapter's other bases): the keys of :attr:`model_keys` (built with :func:`solid_model_keys`),
    a user's mesh read by :meth:`from_mesh_file`, a deck read by :meth:`from_deck_file` (when the keys
    declare ``deck``) or a cap generated by ``from_cap``; then the ``[[model.boundary]]`` conditions
    (when the keys declare :data:`~stepnf.plugin.boundary.BOUNDARY_KEY`) by :meth:`apply_boundary`. The keys of
    :attr:`program_keys` are refused unless the user allowed programs (:mod:`stepnf.runtime.programs`); when
    allowed, the adapter prints the command before its first run."""

    model_keys: ClassVar[Schema]
    #: The material is needed with a user's mesh too (False: a job template may carry its own).
    mesh_needs_material: ClassVar[bool] = True
    #: ``[model]`` keys that name a program stepnf runs, or files a program runs as code, with what they do
    #: (for the refusal): honoured only when the user allows it (:mod:`stepnf.runtime.programs`).
    program_keys: ClassVar[dict[str, str]] = {}
    #: The ``[[model.boundary]]`` conditions applied (:meth:`apply_boundary`), as ``describe`` reports them.
    applied_conditions: tuple[dict[str, Any], ...] = ()

    @classmethod
    def rotational_dofs(cls, config: Mapping[str, Any]) -> bool:
        """Whether the nodes of the model ``config`` describes have rotations (a shell's ``rx ry rz``): its
        ``[[model.boundary]]`` may fix them, and a condition without ``dofs`` clamps them too. A solid: False."""
        return False

    @classmethod
    def from_mesh_file(cls, path: Path, **kw: Any) -> Any:
        """The adapter for a user's mesh file (the ``mesh`` key)."""
        raise NotImplementedError

    @classmethod
    def from_deck_file(cls, path: Path, **kw: Any) -> Any:
        """The adapter for a user's solver deck (the ``deck`` key, when the schema declares it)."""
        raise NotImplementedError

    def apply_boundary(self, conditions: Sequence[Any], *, scene_file: str | Path | None = None,
                       mesh: str | Path | None = None) -> None:
        """Fix the dofs that ``conditions`` (:class:`~stepnf.plugin.boundary.BoundaryCondition`) select among
        ``self.points`` and ``self.node_sets``, besides those already fixed: ``self.free_dofs`` becomes
        the :class:`~stepnf.plugin.boundary.FreeDofs` of the ``3 N`` nodal dofs (what
        :class:`~stepnf.geometry.solid.CapSolid` exposes), and ``self.applied_conditions`` lists the
        conditions (for ``describe``). Call it before K, M or any force is computed: the adapter restricts
        them to the free dofs."""
        if getattr(self, "_K", None) is not None:
            raise RuntimeError("apply_boundary after K was built: the matrices kept cover the old dofs")
        points = np.asarray(self.points)  # type: ignore[attr-defined]
        sets = getattr(self, "node_sets", None) or {}
        old = getattr(self, "free_dofs", None)
        fixed = [np.zeros(0, dtype=np.int64) if old is None else old.fixed]
        listed = list(self.applied_conditions)
        for c in conditions:
            nodes = select_nodes(c, points, sets, scene_file, mesh)
            fixed.append((3 * nodes[:, None] + np.asarray(c.dofs)[None, :]).ravel())
            where = {"set": c.set} if c.set is not None else {"box": [list(x) for x in c.box]}
            listed.append({"condition": c.where, **where, "dofs": [DOF_NAMES[d] for d in c.dofs],
                           "nodes": int(nodes.size)})
        all_fixed = np.unique(np.concatenate(fixed))
        self.free_dofs = FreeDofs(3 * len(points), all_fixed) if all_fixed.size else None
        self.applied_conditions = tuple(listed)

    @classmethod
    def validate_config(cls, config: Mapping[str, Any], *, base_dir: str | Path,
                        scene_file: str | Path | None = None) -> dict[str, Any]:
        """The ``[model]`` keys: a mesh, a deck or a generated cap, the material, the boundary conditions, the run
        settings (:func:`check_solid_config`)."""
        c = check_solid_config(cls.model_keys, config, base_dir=base_dir, scene_file=scene_file,
                               mesh_needs_material=cls.mesh_needs_material, rotations=cls.rotational_dofs(config))
        for key in cls.named_programs(config):
            value = config[key]
            shown = repr(value) if isinstance(value, str) else describe_value(value)
            check_allowed(scene_file, f"model.{key}", f"{key} = {shown} {cls.program_keys[key]}")
        return c

    @classmethod
    def named_programs(cls, config: Mapping[str, Any]) -> list[str]:
        """The keys of :attr:`program_keys` that ``config`` gives, other than with their documented default (the
        adapter's defaults need no permission, written out or not: ``stepnf check`` fills them in)."""
        keys = {k.name: k for k in cls.model_keys}
        return [k for k in cls.program_keys
                if k in config and not (k in keys and keys[k].default is not None and config[k] == keys[k].default)]

    @classmethod
    def from_config(cls, config: Mapping[str, Any], *, base_dir: str | Path,
                    scene_file: str | Path | None = None) -> Any:
        """Build from the scene's ``[model]`` table (:func:`build_solid`)."""
        checked = cls.validate_config(config, base_dir=base_dir, scene_file=scene_file)
        adapter = build_solid(cls, checked, read_mesh=cls.from_mesh_file, scene_file=scene_file,
                              rotations=cls.rotational_dofs(config))
        named = cls.named_programs(config)
        if named:  # allowed (validate_config refused them otherwise): printed before the first run
            adapter.program_named_by = (", ".join(f"[model] {k}" for k in named)
                                        + (f" of {scene_file}" if scene_file is not None else ""))
        return adapter
