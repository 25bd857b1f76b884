"""Models given in modal coordinates (no FE library): the von Karman shallow shell."""
from .vonkarman import VonKarmanShell

__all__ = ["VonKarmanShell"]
