"""Models given in modal coordinates (no FE library): the von Karman shallow shell."""
from __future__ import annotations

from typing import TYPE_CHECKING

from stepnf.runtime.lazy import lazy_exports

if TYPE_CHECKING:
    from stepnf.models.vonkarman import VonKarmanShell

__getattr__ = lazy_exports(__name__, {"VonKarmanShell": "vonkarman"}, globals())
__all__ = ["VonKarmanShell"]
