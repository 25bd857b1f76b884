"""What the FEniCSx adapters share: an adapter whose operators are assembled from UFL forms.

A subclass sets ``self._forms`` (an object with ``mass()``, ``stiffness()``,
``internal_force(u)``, ``quadratic(u, v)``, ``cubic(u, v, w)``, all over the
whole space), ``self._n`` (number of free dofs), ``self._free`` (a
:class:`stepnf.plugin.boundary.FreeDofs` when boundary conditions fix dofs, else
``None``) and ``self.timings``; M and K are assembled once, on first use
(:class:`stepnf.plugin.lazy_matrices.LazyMatrices`, timings ``"mass"`` and ``"stiffness"``).

Constrained dofs are removed (the adapter protocol): M and K are restricted to
the free rows and columns; a free field is expanded (zeros on the fixed dofs),
the forms are assembled over the whole space and the free entries returned, so
f, G and H stay the exact polynomials of the constrained model.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.adapter import SolverAdapter
from stepnf.plugin.boundary import FreeDofs
from stepnf.plugin.lazy_matrices import LazyMatrices


class FormsAdapter(LazyMatrices, SolverAdapter):
    provides_intrusive_tensors = True
    uses_mpi = True  # dolfinx starts MPI: stepnf checks first that Open MPI can (stepnf.runtime.mpi_env)
    #: the free dofs once the boundary conditions' dofs are removed (``None``: every dof is free)
    _free: FreeDofs | None = None

    @property
    def n_dofs(self) -> int:
        return self._n

    def free_dof_map(self) -> FreeDofs | None:
        """The free dofs within the whole space's dofs (``None`` when no boundary condition fixes one)."""
        return self._free

    # ------------------------------------------------------------ free <-> whole space
    def _expand(self, u: np.ndarray) -> np.ndarray:
        """A free field over the whole space (zeros on the fixed dofs)."""
        return u if self._free is None else self._free.expand(u)

    def _restrict(self, f: np.ndarray) -> np.ndarray:
        """The free entries of a whole-space vector (or of the rows of a whole-space array, last axis)."""
        return f if self._free is None else self._free.restrict(f)

    def _free_rows(self, X: np.ndarray) -> np.ndarray:
        """The rows of the free dofs of a per-dof table over the whole space (coordinates, directions)."""
        return X if self._free is None else X[self._free.free]

    # ------------------------------------------------------------ operators
    def _build_mass(self) -> sp.csr_matrix:
        M = self._forms.mass()
        return M if self._free is None else self._free.restrict_matrix(M)

    def _build_stiffness(self) -> sp.csr_matrix:
        K = self._forms.stiffness()
        return K if self._free is None else self._free.restrict_matrix(K)

    def _internal_force(self, u: np.ndarray) -> np.ndarray:
        return self._restrict(self._forms.internal_force(self._expand(u)))

    def quadratic_force(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        u, v = (self._expand(self._check_field(x)) for x in (u, v))
        return self._restrict(self._forms.quadratic(u, v))

    def cubic_force(self, u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        u, v, w = (self._expand(self._check_field(x)) for x in (u, v, w))
        return self._restrict(self._forms.cubic(u, v, w))
