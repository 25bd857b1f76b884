"""K and M built once, on first use: the lazy-matrix helper of solver adapters (no FE import).

:class:`LazyMatrices` is a mixin for :class:`~stepnf.plugin.adapter.SolverAdapter`
subclasses whose matrices are expensive to get (an assembly, a solver run).
Its :meth:`~LazyMatrices.stiffness_matrix` and :meth:`~LazyMatrices.mass_matrix`
build a matrix on the first call, keep it in ``self._K`` or ``self._M``, and
return the kept object on every later call (callers must not modify it). List
it before ``SolverAdapter`` among the bases, whose two methods only raise::

    class MyAdapter(LazyMatrices, SolverAdapter):
        def _build_stiffness(self):
            return assemble(self.k_form)

Implement **either**

* :meth:`~LazyMatrices._build_stiffness` and :meth:`~LazyMatrices._build_mass`,
  each returning one matrix (one assembly per matrix), **or**
* :meth:`~LazyMatrices._build_matrices` returning ``(K, M)`` (one solver run
  gives both): the first of the two methods called builds and keeps both.

The matrices are kept as the hooks return them (scipy sparse, symmetric, in
the adapter's dof order and units): checking them is the core's job.
Timings: when the instance has a dict ``self.timings``, the wall-clock
duration of the build (seconds, :func:`time.perf_counter`) is stored under
``"stiffness"`` or ``"mass"`` (one-matrix hooks) or ``"matrices"`` (both at
once). A hook that raises keeps nothing, so the next call tries again.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

#: matrix -> attribute that keeps it
_KEPT = {"stiffness": "_K", "mass": "_M"}


class LazyMatrices:
    """Mixin: ``stiffness_matrix()`` and ``mass_matrix()`` built once by a hook (see the module docstring)."""

    _K: sp.spmatrix | None = None
    _M: sp.spmatrix | None = None

    def stiffness_matrix(self) -> sp.spmatrix:
        """Linear stiffness ``K`` (n, n), built on the first call."""
        return self._lazy("stiffness")

    def mass_matrix(self) -> sp.spmatrix:
        """Mass matrix ``M`` (n, n), built on the first call."""
        return self._lazy("mass")

    # hooks ------------------------------------------------------------
    def _build_stiffness(self) -> sp.spmatrix:
        """Hook: build ``K`` alone. Defaults to :meth:`_build_matrices`."""
        raise NotImplementedError

    def _build_mass(self) -> sp.spmatrix:
        """Hook: build ``M`` alone. Defaults to :meth:`_build_matrices`."""
        raise NotImplementedError

    def _build_matrices(self) -> tuple[sp.spmatrix, sp.spmatrix]:
        """Hook: build ``(K, M)`` at once, when one run gives both."""
        raise NotImplementedError(f"{type(self).__name__} implements neither _build_stiffness and "
                                  f"_build_mass nor _build_matrices")

    # machinery --------------------------------------------------------
    def _lazy(self, which: str) -> sp.spmatrix:
        kept = _KEPT[which]
        if getattr(self, kept) is None:
            t0 = time.perf_counter()
            hook = "_build_" + which
            if getattr(type(self), hook) is not getattr(LazyMatrices, hook):
                setattr(self, kept, getattr(self, hook)())
            else:
                which = "matrices"
                self._K, self._M = self._build_matrices()
            timings = getattr(self, "timings", None)
            if isinstance(timings, dict):
                timings[which] = time.perf_counter() - t0
            self._share_pattern()
        return getattr(self, kept)

    def _share_pattern(self) -> None:
        """Once both are built: when M has K's sparsity pattern (one function space: the usual case), M
        keeps K's index arrays instead of its own copy (4 bytes per stored entry: 145 MB at 250k dofs of
        hex27). The values are untouched."""
        K, M = self._K, self._M
        if not (sp.isspmatrix_csr(K) and sp.isspmatrix_csr(M)) or np.shares_memory(M.indices, K.indices):
            return
        # canonical (sorted, no duplicates) only: scipy sorts or sums a matrix's index arrays in place when it
        # needs to, which would scramble the other matrix's entries through the shared arrays
        if (K.shape == M.shape and K.has_canonical_format and M.has_canonical_format
                and np.array_equal(K.indptr, M.indptr) and np.array_equal(K.indices, M.indices)):
            self._M = sp.csr_matrix((M.data, K.indices, K.indptr), shape=M.shape)
