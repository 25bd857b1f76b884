"""Names a package exports without importing them: loaded when first asked for (PEP 562).

A package face such as :mod:`stepnf.plugin` lists what it offers; importing the package (or one of
its modules, which imports the package first) stays as light as its ``__init__``, so that ``import
stepnf`` imports no numpy before the command line has checked the memory limit (:mod:`stepnf.runtime.limits`).
"""
from __future__ import annotations

from importlib import import_module
from typing import Any, Callable


def lazy_exports(package: str, names: dict[str, str], namespace: dict[str, Any]) -> Callable[[str], Any]:
    """The ``__getattr__`` of ``package``: ``names`` maps an exported name to the module that defines it,
    relative to the package (``"parse"``) or absolute (``"stepnf.keys.schema"``), followed by
    ``":attr"`` when the module calls it otherwise (``"api.reader:open_run"``); the value is cached in
    ``namespace`` on first use."""

    def __getattr__(name: str) -> Any:
        spec = names.get(name)
        if spec is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, _, attr = spec.partition(":")
        value = getattr(import_module(module if module.startswith("stepnf.") else f"{package}.{module}"), attr or name)
        namespace[name] = value
        return value

    return __getattr__
