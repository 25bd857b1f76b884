"""stepnf's reference solver adapter: St Venant-Kirchhoff solids assembled by FEniCSx (dolfinx 0.5).

Registered under the entry-point group ``stepnf.solvers`` as ``fenicsx``.
Importing this package does not import dolfinx; the adapter does when built.
"""
from __future__ import annotations

from .adapter import FenicsxAdapter, read_mesh
from .model import Material

__all__ = ["FenicsxAdapter", "Material", "read_mesh"]
