"""The ``stepnf`` console script and ``python -m stepnf``: the command line, imported inside a guard.

Under an address-space limit (``ulimit -v``, ``RLIMIT_AS``) below ~105 MB Python cannot even import numpy
and scipy (:mod:`stepnf.runtime.limits`): the ``MemoryError`` (or a library that fails to map) comes from importing
:mod:`stepnf.cli.main`, before its own handling runs. This module imports nothing heavy at its top (``import
stepnf`` neither: its numpy-based names load lazily), imports the command line inside a ``try`` and makes
such a failure one line naming the limit, exit 3 (:func:`stepnf.runtime.limits.reserve_blas_buffer`, which the
command line calls first and which imports numpy and scipy, does the same for a failure there).
"""
from __future__ import annotations

import sys
from typing import Sequence

from stepnf.runtime.limits import address_space_limit, numpy_does_not_fit, short_of_memory


def main(argv: Sequence[str] | None = None) -> int:
    """Run :func:`stepnf.cli.main.main`; a want of memory while importing it, or before its own handling starts
    (building the argument parser), is one line on stderr, exit 3."""
    said = f"stepnf: error: {numpy_does_not_fit(address_space_limit())}"  # made while there is room for it
    try:
        from stepnf.cli.main import main as cli_main

        return cli_main(argv)
    except (MemoryError, ImportError, RuntimeError) as exc:
        if not short_of_memory(exc):
            raise
        print(said, file=sys.stderr)
        return 3

