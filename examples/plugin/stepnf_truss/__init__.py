"""stepnf-truss: an example third-party solver adapter for stepnf (see docs/adapters.md).

Installing this distribution registers the solver name ``truss`` under the
entry-point group ``stepnf.solvers``; a scene then says ``solver = "truss"``.
"""
from __future__ import annotations

from .adapter import MODEL_KEYS, TrussAdapter
from .geometry import Truss, arched_box_truss

__all__ = ["MODEL_KEYS", "TrussAdapter", "Truss", "arched_box_truss"]
