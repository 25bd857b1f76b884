"""Scenes: what to compute, in TOML. The reader and its checks (:mod:`.parse`: :func:`load_scene`,
:func:`parse_scene`: every key checked before any model is built, on the declared keys of :mod:`stepnf.keys`),
and the key under which a scene's result is stored and resumed (:mod:`.model_key`)."""
from __future__ import annotations

from typing import TYPE_CHECKING

from stepnf.runtime.lazy import lazy_exports

if TYPE_CHECKING:
    from stepnf.scene.parse import Scene, load_scene, parse_label, parse_scene

_NAMES = {"Scene": "parse", "load_scene": "parse", "parse_scene": "parse", "parse_label": "parse"}
__getattr__ = lazy_exports(__name__, _NAMES, globals())
__all__ = sorted(_NAMES)
