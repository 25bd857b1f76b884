"""What the FEniCSx adapters share: an adapter whose operators are assembled from UFL forms.

A subclass sets ``self._forms`` (an object with ``mass()``, ``stiffness()``,
``internal_force(u)``, ``quadratic(u, v)``, ``cubic(u, v, w)``), ``self._n``
(number of dofs) and ``self.timings``; M and K are assembled once, on first use.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from stepnf.adapter import SolverAdapter


class FormsAdapter(SolverAdapter):
    provides_intrusive_tensors = True
    _K: sp.csr_matrix | None = None
    _M: sp.csr_matrix | None = None

    @property
    def n_dofs(self) -> int:
        return self._n

    def mass_matrix(self) -> sp.csr_matrix:
        if self._M is None:
            t0 = time.perf_counter()
            self._M = self._forms.mass()
            self.timings["mass"] = time.perf_counter() - t0
        return self._M

    def stiffness_matrix(self) -> sp.csr_matrix:
        if self._K is None:
            t0 = time.perf_counter()
            self._K = self._forms.stiffness()
            self.timings["stiffness"] = time.perf_counter() - t0
        return self._K

    def _internal_force(self, u: np.ndarray) -> np.ndarray:
        return self._forms.internal_force(u)

    def quadratic_force(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return self._forms.quadratic(self._check_field(u), self._check_field(v))

    def cubic_force(self, u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        return self._forms.cubic(self._check_field(u), self._check_field(v), self._check_field(w))
