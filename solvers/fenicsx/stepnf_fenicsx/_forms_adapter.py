"""What the FEniCSx adapters share: an adapter whose operators are assembled from UFL forms.

A subclass sets ``self._forms`` (an object with ``mass()``, ``stiffness()``,
``internal_force(u)``, ``quadratic(u, v)``, ``cubic(u, v, w)``), ``self._n``
(number of dofs) and ``self.timings``; M and K are assembled once, on first use
(:class:`stepnf.lazy_matrices.LazyMatrices`, timings ``"mass"`` and ``"stiffness"``).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stepnf.adapter import SolverAdapter
from stepnf.lazy_matrices import LazyMatrices


class FormsAdapter(LazyMatrices, SolverAdapter):
    provides_intrusive_tensors = True

    @property
    def n_dofs(self) -> int:
        return self._n

    def _build_mass(self) -> sp.csr_matrix:
        return self._forms.mass()

    def _build_stiffness(self) -> sp.csr_matrix:
        return self._forms.stiffness()

    def _internal_force(self, u: np.ndarray) -> np.ndarray:
        return self._forms.internal_force(u)

    def quadratic_force(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return self._forms.quadratic(self._check_field(u), self._check_field(v))

    def cubic_force(self, u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        return self._forms.cubic(self._check_field(u), self._check_field(v), self._check_field(w))
