"""The ``[model]`` keys every template-driven adapter shares, and its one "mesh or generated cap" build.

Run settings (:data:`RUN_KEYS`, :data:`EXECUTABLE`): how the solver is run.
Solid model (:func:`solid_model_keys`, :func:`check_solid_config`,
:func:`build_solid`, and :class:`SolidFromScene` that ties them to an adapter class): either a user's mesh file (``mesh``) or a generated
free-edge cap (``[model.geometry]``), with ``[model.material]``
(:mod:`stepnf.geometry.keys`), for any adapter with the
:class:`~stepnf.geometry.solid.CapSolid` builders.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, ClassVar, Mapping, Sequence

from ..errors import SceneError
from ..geometry import keys as cap_keys
from ..geometry.checks import units_warning
from ..schema import Key, Schema
from .process import KEEP_POLICIES

#: Ranges of the run settings: a time-out above 1e7 s (four months) is no time-out, no machine has
#: more than 1024 cores for one solver run, 256 solver runs at once already exceed any node's memory,
#: and 2^24 MB is 16 TiB.
RUN_RANGES: dict[str, tuple[float, float]] = {"timeout": (0.0, 1e7), "threads": (1, 1024), "ncpus": (1, 1024),
                                              "parallel_runs": (1, 256), "memory_mb": (1, 2**24)}


def _count(name: str, doc: str, default: int) -> Key:
    lo, hi = RUN_RANGES[name]
    return Key(name, "integer", doc, default=default, lo=lo, hi=hi)


#: The executable (a name on PATH or a path); the adapter's program by default.
EXECUTABLE = Key("executable", "text", "the solver executable, a name on PATH or a path",
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
                       scene_file: str | Path | None, mesh_needs_material: bool) -> dict[str, Any]:
    """``config`` checked against ``schema``, with exactly one of ``mesh`` and ``[model.geometry]``.

    Returns the checked keys with ``material`` a complete ``{E, nu, rho}`` (for a generated cap,
    and for a mesh when ``mesh_needs_material``; else what was given) and ``geometry`` replaced by
    :func:`stepnf.geometry.keys.cap_geometry`'s ``{shape, a, R, h, resolution}``.
    """
    c = schema.check(config, file=scene_file, where="model", base_dir=base_dir, reserved=("solver",))
    if ("mesh" in c) == ("geometry" in c):
        raise SceneError(scene_file, "model", 'give exactly one of mesh = "<file>" or a [model.geometry] table')
    c["material"] = cap_keys.material(c, scene_file, required="geometry" in c or mesh_needs_material)
    if "geometry" in c:
        c["geometry"] = cap_keys.cap_geometry(c, scene_file)
    return c


def build_solid(cls: Any, checked: Mapping[str, Any], *, read_mesh: Callable[..., Any],
                scene_file: str | Path | None) -> Any:
    """The adapter ``cls`` for :func:`check_solid_config`'s keys: ``read_mesh(path, material=..., **run)``
    for a user's mesh, ``cls.from_cap`` for a generated cap; every other key is passed on as a run
    setting. Warns when the material's units and the mesh's sizes disagree; a mesh the adapter
    refuses (a ValueError) is a SceneError on ``[model]``."""
    run = {k: v for k, v in checked.items() if k not in ("element", "mesh", "geometry", "material")}
    material = checked["material"]
    try:
        if "mesh" in checked:
            adapter = read_mesh(checked["mesh"], material=material, **run)
            units_warning(adapter.points, material, source=checked["mesh"])
            return adapter
        g = checked["geometry"]
        adapter = cls.from_cap(a=g["a"], R=g["R"], h=g["h"], resolution=g["resolution"], **material, **run)
        units_warning(adapter.points, material, source=scene_file, thickness=g["h"])
        return adapter
    except SceneError:
        raise
    except ValueError as exc:
        raise SceneError(scene_file, "model", str(exc)) from exc


class SolidFromScene:
    """``validate_config`` and ``from_config`` of a template-driven solid adapter (a mixin placed before
    the adapter's other bases): the keys of :attr:`model_keys` (built with :func:`solid_model_keys`),
    a user's mesh read by :meth:`from_mesh_file` or a cap generated by ``from_cap``."""

    model_keys: ClassVar[Schema]
    #: The material is needed with a user's mesh too (False: a job template may carry its own).
    mesh_needs_material: ClassVar[bool] = True

    @classmethod
    def from_mesh_file(cls, path: Path, **kw: Any) -> Any:
        """The adapter for a user's mesh file (the ``mesh`` key)."""
        raise NotImplementedError

    @classmethod
    def validate_config(cls, config: Mapping[str, Any], *, base_dir: str | Path,
                        scene_file: str | Path | None = None) -> dict[str, Any]:
        """The ``[model]`` keys: a mesh or a generated cap, the material, the run settings (:func:`check_solid_config`)."""
        return check_solid_config(cls.model_keys, config, base_dir=base_dir, scene_file=scene_file,
                                  mesh_needs_material=cls.mesh_needs_material)

    @classmethod
    def from_config(cls, config: Mapping[str, Any], *, base_dir: str | Path,
                    scene_file: str | Path | None = None) -> Any:
        """Build from the scene's ``[model]`` table (:func:`build_solid`)."""
        checked = cls.validate_config(config, base_dir=base_dir, scene_file=scene_file)
        return build_solid(cls, checked, read_mesh=cls.from_mesh_file, scene_file=scene_file)
