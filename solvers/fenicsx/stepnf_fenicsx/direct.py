"""A distributed MUMPS factorisation, held by a PETSc KSP, as the ``solve(b)`` of stepnf's adapter protocol.

``b`` and ``x`` are global vectors in the adapter's numbering, the same on every rank (a
:class:`~stepnf_fenicsx.layout.RankBlocks` scatters and gathers them). A block ``b`` (n, k) goes to
MUMPS in ONE ``MatMatSolve`` (distributed dense right-hand sides, :func:`stepnf.linalg.factorization.factor_block_solve`,
the serial core's too), so its forward and backward substitutions read the factors once for the k
columns: the lockstep conjugate gradients of the deflated solves
(:meth:`stepnf.linalg.deflation.DeflatedSolver.solve_many`) send their columns together. The solve declares
this with ``takes_columns = True`` (:func:`stepnf.linalg.factorization.apply_columns` then passes blocks through)
and frees what it owns with ``release()``, which stepnf calls when it no longer needs the
factorisation (one live shifted factorisation at a time instead of all of them until ``close()``).
Every call is collective.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from stepnf.errors import NumericalError
from stepnf.linalg.factorization import factor_block_solve


class DirectSolve:
    """``solve(b)`` with the factorisation of ``ksp`` (set up, ``preonly`` + Cholesky/LU by MUMPS).

    ``layout``: the adapter's :class:`~stepnf_fenicsx.layout.RankBlocks`; ``what``: the matrix, for
    messages (e.g. ``"K - 1.2e6 M"``); ``owned``: PETSc objects this solve owns (its KSP and matrix),
    destroyed by :meth:`release` (an eigen-solver's KSP is not: SLEPc owns it).
    """

    takes_columns = True

    def __init__(self, ksp: Any, layout: Any, what: str, owned: Sequence[Any] = ()):
        self.ksp, self.layout, self.what = ksp, layout, what
        self._owned = list(owned)
        self._vecs: tuple[Any, Any] | None = None

    def __call__(self, rhs: np.ndarray) -> np.ndarray:
        if self.ksp is None:
            raise NumericalError(f"solve with {self.what} after its factorisation was released")
        rhs = np.asarray(rhs, dtype=float)
        return self._block(rhs) if rhs.ndim == 2 else self._column(rhs)

    def _column(self, rhs: np.ndarray) -> np.ndarray:
        if self._vecs is None:
            self._vecs = self.ksp.getOperators()[0].createVecs()
        x, b = self._vecs
        b.array[:] = self.layout.owned(rhs)
        self.ksp.solve(b, x)
        if self.ksp.getConvergedReason() < 0:
            raise NumericalError(f"MUMPS solve with {self.what} failed (KSP reason {self.ksp.getConvergedReason()})")
        return self.layout.gather(x.array)

    def _block(self, rhs: np.ndarray) -> np.ndarray:
        lay = self.layout
        local = factor_block_solve(self.ksp.getPC().getFactorMatrix(), lay.owned(rhs), comm=lay.comm,
                                   n_global=rhs.shape[0])
        return np.column_stack([lay.gather(local[:, j]) for j in range(rhs.shape[1])])

    def release(self) -> None:
        """Destroy the factorisation's PETSc objects (collective); solving afterwards is an error."""
        for obj in [*self._owned, *(self._vecs or ())]:
            obj.destroy()
        self._owned, self._vecs, self.ksp = [], None, None
