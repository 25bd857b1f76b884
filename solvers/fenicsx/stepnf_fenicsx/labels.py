"""Re-export of :class:`stepnf.geometry.labels.ModeLabeler` (kept for adapters that import it from here)."""
from __future__ import annotations

from stepnf.geometry.labels import ModeLabeler

__all__ = ["ModeLabeler"]
