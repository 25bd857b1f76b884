"""Discovery of solver adapters through the entry-point group ``stepnf.solvers``.

Modelled on xarray's backend plugins: entry points are read once and cached; a
plugin that fails to load, is not an adapter, or repeats a name is a warning,
never a crash; an unknown name raises :class:`stepnf.errors.UnknownSolverError`
listing the installed ones.

A third party registers an adapter with, in its ``pyproject.toml``::

    [project.entry-points."stepnf.solvers"]
    mysolver = "my_package.adapter:MySolverAdapter"
"""
from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Iterable

from stepnf.plugin.adapter import SolverAdapter, implements_forces
from stepnf.errors import AdapterError, StepnfError, UnknownSolverError
from stepnf.plugin.modal_model import ModalModel

GROUP = "stepnf.solvers"


class PluginWarning(UserWarning):
    """A plugin under ``stepnf.solvers`` is broken or duplicated."""


@dataclass(frozen=True)
class SolverInfo:
    """One installed adapter: its name, class, distribution and capabilities."""

    name: str
    cls: type
    distribution: str
    version: str

    @property
    def kind(self) -> str:
        return "modal model" if issubclass(self.cls, ModalModel) else "FE adapter"

    @property
    def capabilities(self) -> list[str]:
        if issubclass(self.cls, ModalModel):
            return ["modal coefficients"]
        caps = ["forces (batch)" if self.cls.prefers_batches else "forces"]
        for flag, text in (
            ("provides_eigenmodes", "eigenmodes"),
            ("provides_shifted_solves", "shifted solves"),
            ("provides_intrusive_tensors", "intrusive tensors"),
            ("provides_tangent_stiffness", "tangent stiffness"),
            ("collective", "collective (MPI)"),
        ):
            if getattr(self.cls, flag, False):
                caps.append(text)
        return caps


def _dist_of(ep: EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "?", "?"
    return dist.metadata["Name"] or "?", dist.version or "?"


def build_registry(eps: Iterable[EntryPoint]) -> dict[str, SolverInfo]:
    """Load entry points into a name -> :class:`SolverInfo` mapping, warning on bad ones."""
    found: dict[str, SolverInfo] = {}
    for ep in eps:
        dist, version = _dist_of(ep)
        if ep.name in found:
            if found[ep.name].cls.__module__ + ":" + found[ep.name].cls.__qualname__ == ep.value:
                continue  # the same plugin seen twice (e.g. an editable install): harmless
            warnings.warn(
                f"stepnf solver plugin {ep.name!r} from {dist} ({ep.value}) duplicates the one from "
                f"{found[ep.name].distribution}; keeping the first",
                PluginWarning,
                stacklevel=2,
            )
            continue
        try:
            cls = ep.load()
        except Exception as exc:  # a broken plugin must not break stepnf
            warnings.warn(
                f"stepnf solver plugin {ep.name!r} ({ep.value}) from {dist} failed to load: "
                f"{type(exc).__name__}: {exc}",
                PluginWarning,
                stacklevel=2,
            )
            continue
        ok = isinstance(cls, type) and (
            (issubclass(cls, SolverAdapter) and implements_forces(cls)) or issubclass(cls, ModalModel)
        )
        if not ok:
            warnings.warn(
                f"stepnf solver plugin {ep.name!r} ({ep.value}) is not a SolverAdapter implementing "
                "_internal_force or _internal_forces, nor a ModalModel; ignored",
                PluginWarning,
                stacklevel=2,
            )
            continue
        found[ep.name] = SolverInfo(ep.name, cls, dist, version)
    return found


@functools.lru_cache(maxsize=1)
def _installed() -> dict[str, SolverInfo]:
    return build_registry(entry_points(group=GROUP))


def installed_solvers(refresh: bool = False) -> dict[str, SolverInfo]:
    """Installed adapters by name (cached; ``refresh=True`` rereads the entry points)."""
    if refresh:
        _installed.cache_clear()
    return dict(_installed())


def get_solver(name: str) -> type:
    """The adapter class registered as ``name``; raises ``UnknownSolverError`` listing the installed ones."""
    solvers = installed_solvers()
    if name not in solvers:
        raise UnknownSolverError(name, solvers)
    return solvers[name].cls


def build_model(scene: Any) -> Any:
    """The scene's adapter or modal model: ``from_config`` of its solver (``scene.solver``, ``.model``,
    ``.base_dir``, ``.file``, as :class:`stepnf.scene.parse.Scene` holds them).

    stepnf's own errors pass through (a SceneError names the key); anything else an adapter raises
    while it builds its model (a bug, or an input its constructor did not check) becomes an
    :class:`~stepnf.errors.AdapterError` naming the adapter, its class and the scene (exit code 3),
    never a bare traceback.
    """
    from stepnf.runtime.programs import allow_programs

    cls = get_solver(scene.solver)
    if getattr(cls, "uses_mpi", False):  # Open MPI would abort the process with ~50 lines (stepnf.runtime.mpi_env)
        from stepnf.runtime.mpi_env import require_mpi

        require_mpi(f"solver {scene.solver!r}")
    try:
        with allow_programs(getattr(scene, "allow_programs", None)):  # the user's, never the scene's
            return cls.from_config(scene.model, base_dir=scene.base_dir, scene_file=scene.file)
    except StepnfError:
        raise
    except Exception as exc:  # noqa: BLE001 - a third-party constructor may raise anything
        where = str(scene.file) if scene.file else "<scene>"
        raise AdapterError(f"{where}: the {scene.solver!r} adapter ({cls.__module__}.{cls.__qualname__}) failed "
                           f"while building the model: {type(exc).__name__}: {exc}") from exc
