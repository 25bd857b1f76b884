"""The ``fenicsx`` adapter: serial by default, distributed under ``mpirun -n N`` (N > 1).

:class:`FenicsxAdapter` (entry point ``stepnf_fenicsx:FenicsxAdapter``) is the
serial solid of :mod:`stepnf_fenicsx.serial`; under ``mpirun -n N>1`` its
builders :meth:`~FenicsxAdapter.cap` and :meth:`~FenicsxAdapter.from_config`
return :class:`DistributedFenicsxAdapter` (:mod:`stepnf_fenicsx.parallel`), a
subclass, so ``isinstance(adapter, FenicsxAdapter)`` holds for both.
``STEPNF_FENICSX_SERIAL=1`` keeps the serial one under MPI.

This module imports both variants, which declares the distributed one to the
builders before any of them runs; only the package imports it. Imports run
one way: ``serial`` <- ``parallel`` <- ``adapter`` <- ``stepnf_fenicsx``.
"""
from __future__ import annotations

from .parallel import DistributedFenicsxAdapter, is_root
from .serial import FenicsxAdapter, read_mesh

__all__ = ["DistributedFenicsxAdapter", "FenicsxAdapter", "is_root", "read_mesh"]
