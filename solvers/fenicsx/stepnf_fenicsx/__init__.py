"""stepnf's reference solver adapter: St Venant-Kirchhoff solids assembled by FEniCSx (DOLFINx 0.5 or 0.9).

Registered under the entry-point group ``stepnf.solvers`` as ``fenicsx``.
Importing this package does not import dolfinx; the adapter does when built.
It imports both variants (:mod:`stepnf_fenicsx.adapter`): the serial
:class:`FenicsxAdapter` (:mod:`~stepnf_fenicsx.serial`) and the distributed one
its builders return under ``mpirun -n N>1`` (:mod:`~stepnf_fenicsx.parallel`).
"""
from __future__ import annotations

from .adapter import FenicsxAdapter, read_mesh
from .model import Material

__all__ = ["FenicsxAdapter", "Material", "read_mesh"]
