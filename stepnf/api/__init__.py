"""The package's face for Python: run a scene and read a stored run as typed, read-only results.

``stepnf.run(scene)`` (:mod:`.runner`) takes a scene file or a dict of the same content, checks it with
the same key checks as ``stepnf run`` (the same messages, raised as :class:`stepnf.errors.SceneError`)
and runs the same pipeline; ``stepnf.open(path)`` (:mod:`.reader`) reads a results file back. Both
return a :class:`~stepnf.api.view.RunView` (:mod:`.view`): modes, T per method, Gamma, flags,
backbones, the table, the JSON document, a pandas DataFrame (:mod:`.frame`) and the figures
(:mod:`.plots`). Light: the names are imported when first asked for (:mod:`stepnf.runtime.lazy`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from stepnf.runtime.lazy import lazy_exports

_EXPORTS = {"run": "runner", "open_run": "reader", "RunView": "view", "ModeView": "view", "MethodView": "view",
            "BackboneView": "view"}
__getattr__ = lazy_exports(__name__, _EXPORTS, globals())

if TYPE_CHECKING:
    from stepnf.api.reader import open_run
    from stepnf.api.runner import run
    from stepnf.api.view import BackboneView, MethodView, ModeView, RunView

__all__ = sorted(_EXPORTS)
