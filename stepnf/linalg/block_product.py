"""Products of one fixed sparse matrix with blocks of vectors: ``A @ X``, ``X`` (n,) or (n, k).

scipy's CSR times a dense block (``csr_matvecs``) is slow for a few columns: measured on the 38k-dof
cap (5.4M stored entries, one thread) 14.7 ms for 2 columns and 23 ms for 8, against 2.6 ms for one
column. PETSc's ``MatMatMult`` (SeqAIJ times SeqDense, the matrix read once for four columns at a
time) takes 3.0 ms for 2 columns and 1.7 ms per column for 8 or 16, and gives the same numbers (each
entry of ``A X`` summed over its row in the same order: equal bit for bit in that measurement).

:class:`BlockProduct` wraps a matrix once (PETSc reads scipy's own arrays: no copy) and uses PETSc for
two columns or more when petsc4py is there and the matrix's index arrays are of PETSc's integer
type with sorted columns, the matrix has :data:`PETSC_MIN_ROWS` rows or more and MPI can start
(:mod:`stepnf.runtime.mpi_env`); otherwise, and for one column or complex numbers, scipy. Sequential only
(each MPI rank multiplies its own copy, ``PETSc.COMM_SELF``). The PETSc matrix is destroyed with its
:class:`BlockProduct`: petsc4py would otherwise only park it for ``PETSc.garbage_cleanup``, holding
PETSc's row arrays and the scipy matrix for the rest of the process.
"""
from __future__ import annotations

import weakref
from typing import Any

import numpy as np
import scipy.sparse as sp

#: Columns per PETSc product: its kernel takes four at a time (1.5-1.7 ms per column at 38k dofs for 2 to
#: 16 columns), so chunks of four cost no speed and bound the copies made beside the result (two chunks:
#: 64 MB at 1M dofs).
CHUNK = 4
#: Fewer rows: scipy's product, and petsc4py (so MPI) is never imported for it. At the size below which
#: :func:`stepnf.linalg.factorization.factorize` is dense LAPACK (:data:`stepnf.linalg.factorization.DENSE_LIMIT`) nothing else of a run
#: needs PETSc, and PETSc's speed-up cannot matter: a 2000-row product with 8 columns takes well under a
#: millisecond either way. The numbers are the same (each entry summed over its row in the same order;
#: measured equal bit for bit at 2000 and 5000 rows, 8 columns, and for a whole 12-dof backbone run's output).
PETSC_MIN_ROWS = 2000


class BlockProduct:
    """``A @ X`` for the fixed sparse (or dense) matrix ``A`` (n, m); see the module docstring.

    ``A`` is kept as given when it is a canonical CSR; PETSc's wrapper (made at the first block
    product) reads its arrays, so ``A`` must not be changed in place afterwards.
    """

    def __init__(self, A: Any):
        self.A = A
        self.shape = A.shape
        self._petsc: Any = None  # the PETSc AIJ matrix on A's arrays, or False when PETSc is not used

    def __matmul__(self, X: np.ndarray) -> np.ndarray:
        return self.product(X)

    def product(self, X: np.ndarray) -> np.ndarray:
        """``A @ X`` (float64), ``X`` (m,) or (m, k); for k >= 2 by PETSc when usable (complex: scipy's)."""
        if np.iscomplexobj(X) or np.iscomplexobj(self.A):
            return self.A @ X
        X = np.asarray(X, dtype=float)
        if X.ndim == 2 and X.shape[1] == 1:  # scipy's vector kernel, not its block one
            return np.asarray(self.A @ X[:, 0], dtype=float).reshape(-1, 1)
        if X.ndim != 2 or X.shape[1] == 0 or not self._uses_petsc():
            return np.asarray(self.A @ X, dtype=float)
        return self._petsc_product(X)

    # ------------------------------------------------------------ internals
    def _uses_petsc(self) -> bool:
        if self._petsc is None:
            self._petsc = _petsc_wrapper(self.A) or False
            if self._petsc is not False:
                weakref.finalize(self, self._petsc.destroy).atexit = False  # not after PETSc's own exit
        return self._petsc is not False

    def _petsc_product(self, X: np.ndarray) -> np.ndarray:
        """``A @ X`` by PETSc, :data:`CHUNK` columns at a time (at most two chunk-sized copies beside the
        result: the chunk in Fortran order and PETSc's product)."""
        from petsc4py import PETSc

        n, k = self.shape[0], X.shape[1]
        out = np.empty((n, k))
        for j in range(0, k, CHUNK):
            part = np.asfortranarray(X[:, j:j + CHUNK])
            B = PETSc.Mat().createDense(part.shape, array=part, comm=PETSc.COMM_SELF)
            C = None
            try:
                C = self._petsc.matMult(B)
                out[:, j:j + part.shape[1]] = C.getDenseArray()
            finally:
                B.destroy()
                if C is not None:
                    C.destroy()
        return out


def _petsc_wrapper(A: Any) -> Any:
    """A sequential PETSc AIJ matrix reading ``A``'s CSR arrays, or None when that is not possible."""
    if not sp.issparse(A) or A.format != "csr" or A.dtype != np.float64 or not A.has_canonical_format:
        return None
    if A.shape[0] < PETSC_MIN_ROWS:
        return None
    from stepnf.runtime.mpi_env import mpi_tmpdir_problem

    if mpi_tmpdir_problem() is not None:  # Open MPI would abort the process: scipy's product, same numbers
        return None
    try:
        from petsc4py import PETSc
    except ImportError:
        return None
    itype = np.dtype(PETSc.IntType)
    if A.indptr.dtype != itype or A.indices.dtype != itype:
        return None
    P = PETSc.Mat().createAIJWithArrays(A.shape, (A.indptr, A.indices, A.data), comm=PETSc.COMM_SELF)
    P.assemble()
    return P


def block_product(A: Any) -> BlockProduct:
    """``A`` as a :class:`BlockProduct` (``A`` itself when it already is one)."""
    return A if isinstance(A, BlockProduct) else BlockProduct(A)
