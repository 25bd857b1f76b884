"""Factorisations of ``K - sigma M`` for successive shifts ``sigma``, on one sparsity pattern built once.

``K`` and ``M`` (n, n) are symmetric by construction (the caller says so: no symmetry probe), sparse
or dense, in the model's units; ``sigma`` is in ``K``'s units over ``M``'s (rad^2/s^2 for a
stiffness and a mass). The union of their patterns is formed once and their values are placed on
it once (``data_K``, ``data_M``); the values of ``K - sigma M`` are then one vector operation,
``data_K - sigma * data_M``, without a sparse sum, a copy or a sort.

:class:`ShiftedFactorizer` gives two kinds of :class:`~stepnf.linalg.factorization.Factorization`:

``refactor(sigma, label)``
    one PETSc matrix and one KSP/MUMPS instance for every shift: the values are written in place
    (same nonzero pattern), so PETSc redoes only MUMPS's numeric factorisation and keeps its
    analysis (ordering, symbolic factorisation; measured with ``-log_view``: one
    ``MatCholFctrSym`` for six shifts). The previous factorisation of ``refactor`` is
    *superseded*: solving with it raises ``RuntimeError`` (its factors are gone), never wrong
    numbers. ``release()`` of the current one destroys the KSP and MUMPS's factors (their memory
    is returned); the next ``refactor`` analyses again. Only the matrix (the union pattern and one
    value array, ~12 bytes per stored entry) stays, until :meth:`close`.
``factorizer(sigma, label)``
    an independent factorisation (its own value array and KSP; the index arrays shared): for
    callers that keep several shifts alive at once. Each one analyses.

A :class:`Slot` keeps one live factorisation of successive shifts (a ``refactor``, or any factory whose
factorisations it releases one by one): the pipeline's context has one, the backbone a second.

Both: MUMPS LDL^T (PETSc ``cholesky``), as :func:`stepnf.linalg.factorization.factorize` (:func:`stepnf.linalg.factorization.mumps_ksp`);
an exactly singular shift is a :class:`~stepnf.errors.NumericalError`; ``counters`` get one
factorisation and its seconds per call (``linear_solves`` counted by the solves). The ``dense`` and
``superlu`` back ends take the same calls and factorise ``K - sigma M`` afresh (no reuse); their
``refactor`` supersedes the previous one too (released).
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np
import scipy.sparse as sp

from stepnf.runtime.counters import Counters
from stepnf.errors import NumericalError
from stepnf.linalg.factorization import (Factorization, choose_backend, factorize, ksp_solve_function, mumps_ksp, mumps_setup,
                     petsc_aij)


def canonical_csr(A: sp.spmatrix | np.ndarray) -> sp.csr_matrix:
    """``A`` as a float64 CSR with sorted indices and no duplicates (no copy when it already is one)."""
    A = sp.csr_matrix(A, dtype=float)
    if not A.has_canonical_format:
        A = A.copy()
        A.sum_duplicates()
    return A


def union_pattern(K: sp.csr_matrix, M: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``indptr, indices, data_K, data_M`` of the union of the patterns of two canonical CSR (n, n).

    Structural: an entry stored in either is kept (explicit zeros too, no cancellation).
    ``data_K``, ``data_M`` are the values of ``K``, ``M`` at those entries (0 where absent). Indices
    in PETSc's integer type. When both patterns are equal the values are ``K.data``, ``M.data``
    themselves (no copy).
    """
    from petsc4py import PETSc

    itype = PETSc.IntType
    if np.array_equal(K.indptr, M.indptr) and np.array_equal(K.indices, M.indices):
        return np.asarray(K.indptr, dtype=itype), np.asarray(K.indices, dtype=itype), K.data, M.data
    n = K.shape[0]
    ones = [sp.csr_matrix((np.ones(X.nnz), X.indices, X.indptr), shape=X.shape) for X in (K, M)]
    P = (ones[0] + ones[1]).tocsr()  # entries 1 or 2: never cancel
    P.sort_indices()
    keys = _entry_keys(P.indptr, P.indices, n)
    datas = []
    for X in (K, M):
        d = np.zeros(P.nnz)
        d[np.searchsorted(keys, _entry_keys(X.indptr, X.indices, n))] = X.data
        datas.append(d)
    return P.indptr.astype(itype), P.indices.astype(itype), datas[0], datas[1]


def _entry_keys(indptr: np.ndarray, indices: np.ndarray, n: int) -> np.ndarray:
    """``row * n + column`` of the entries of a CSR (increasing for sorted indices)."""
    rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
    return rows * n + indices.astype(np.int64)


class ShiftedFactorizer:
    """Factorisations of ``K - sigma M`` sharing one pattern (module docstring).

    ``backend`` as :func:`stepnf.linalg.factorization.factorize` (``"auto"``: dense up to 2000 dofs, else MUMPS
    when petsc4py is there, else SuperLU).
    """

    def __init__(self, K: sp.spmatrix | np.ndarray, M: sp.spmatrix | np.ndarray, *,
                 counters: Counters | None = None, backend: str = "auto"):
        n = K.shape[0]
        if K.shape != (n, n) or M.shape != (n, n):
            raise ValueError(f"K {K.shape} and M {M.shape} must be square of the same size")
        self.n = n
        self.counters = counters
        self.backend = choose_backend(n, backend)
        self._current: Factorization | None = None
        self._slot: tuple | None = None  # (matrix, value array) of refactor, kept until close()
        self._ksp = None  # refactor's KSP while its factorisation lives
        self.K, self.M = K, M
        self._union: tuple | None = None  # (indptr, indices, data_K, data_M), made at the first MUMPS call

    # ------------------------------------------------------------------ API
    def __call__(self, sigma: float, label: str = "") -> Factorization:
        """An independent factorisation of ``K - sigma M`` (alias of :meth:`factorizer`)."""
        return self.factorizer(sigma, label)

    def factorizer(self, sigma: float, label: str = "") -> Factorization:
        """An independent factorisation of ``K - sigma M``: lives until its own ``release()``."""
        label = label or f"K - {sigma:.6g} M"
        if self.backend != "mumps":
            return self._fresh(sigma, label)
        t0 = time.perf_counter()
        data = self.values(sigma)
        indptr, indices = self.pattern()[:2]
        P = petsc_aij(indptr, indices, data, copy=False)
        ksp = mumps_ksp(P, symmetric=True)
        mumps_setup(ksp, label)
        xv, bv = P.createVecs()
        fac = Factorization(ksp_solve_function(ksp, xv, bv, self.n), self.n, "mumps", self.counters, label,
                            resources=(ksp, P, xv, bv, data))  # P reads data: kept alive with it
        self._count(t0)
        return fac

    def refactor(self, sigma: float, label: str = "") -> Factorization:
        """The factorisation of ``K - sigma M`` in the one reused instance; supersedes the previous one."""
        label = label or f"K - {sigma:.6g} M"
        self._supersede(f"was superseded by the factorisation of {label}")
        if self.backend != "mumps":
            fac = self._fresh(sigma, label)
            self._current = fac
            return fac
        t0 = time.perf_counter()
        P, data = self._matrix()
        _, _, data_K, data_M = self.pattern()
        np.multiply(data_M, -float(sigma), out=data)
        data += data_K
        P.assemble()  # a new state of the same nonzero pattern: PETSc refactorises, numeric phase only
        if self._ksp is None:
            self._ksp = mumps_ksp(P, symmetric=True)
        else:
            self._ksp.setOperators(P)
        try:
            mumps_setup(self._ksp, label)
        except NumericalError:
            self._free_instance()  # start afresh at the next shift
            raise
        xv, bv = P.createVecs()
        fac = Factorization(ksp_solve_function(self._ksp, xv, bv, self.n), self.n, "mumps", self.counters,
                            label, resources=(xv, bv), on_release=self._release_current)
        self._current = fac
        self._count(t0)
        return fac

    def pattern(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``indptr, indices, data_K, data_M`` of the union pattern (:func:`union_pattern`), made once."""
        if self._union is None:
            self._union = union_pattern(canonical_csr(self.K), canonical_csr(self.M))
        return self._union

    def values(self, sigma: float) -> np.ndarray:
        """The stored values of ``K - sigma M`` on the union pattern, a new array."""
        _, _, data_K, data_M = self.pattern()
        return data_K - float(sigma) * data_M

    def close(self) -> None:
        """Free everything: the current factorisation of :meth:`refactor` (superseded) and the matrix."""
        self._supersede("was freed by ShiftedFactorizer.close()")
        self._free_instance()
        if self._slot is not None:
            self._slot[0].destroy()
        self._slot = None

    # ------------------------------------------------------------ internals
    def _fresh(self, sigma: float, label: str) -> Factorization:
        """Dense / SuperLU: ``K - sigma M`` factorised as a new matrix (counted by :func:`factorize`)."""
        A = (sp.csr_matrix(self.K) - float(sigma) * sp.csr_matrix(self.M)).tocsr()
        return factorize(A, counters=self.counters, backend=self.backend, label=label)

    def _supersede(self, why: str) -> None:
        """Make the current factorisation of :meth:`refactor` unusable (its factors are being replaced);
        ``why`` ends the message of its solves."""
        old, self._current = self._current, None
        if old is None:
            return
        if old.backend == "mumps":  # the instance now serves the new shift: not freed here
            old.supersede(why)
        else:
            old.release()
            old.disable(why)

    def _matrix(self) -> tuple:
        """The reused PETSc matrix on the union pattern and its value array (made at the first call)."""
        if self._slot is None:
            indptr, indices = self.pattern()[:2]
            data = np.empty(len(indices))
            self._slot = (petsc_aij(indptr, indices, data, copy=False), data)
        return self._slot

    def _release_current(self) -> None:
        """``release()`` of the current factorisation of :meth:`refactor`: its factors freed now."""
        self._current = None
        self._free_instance()

    def _free_instance(self) -> None:
        """Destroy refactor's KSP, and with it MUMPS's factors and analysis (the matrix stays)."""
        if self._ksp is not None:
            self._ksp.destroy()
        self._ksp = None

    def _count(self, t0: float) -> None:
        if self.counters is not None:
            self.counters.factorizations += 1
            self.counters.factorization_seconds += time.perf_counter() - t0


class Slot:
    """One live factorisation of ``K - sigma M`` at a time, made by ``make(sigma, label)``.

    ``refactor=True``: ``make`` is a :meth:`~stepnf.linalg.shifted.ShiftedFactorizer.refactor`, which supersedes
    its previous factorisation in place (MUMPS keeps its analysis); releasing it first would destroy the
    instance and analyse again. Otherwise (an adapter's factorisations) the previous one is released
    before the next is made.
    """

    def __init__(self, make: Callable[[float, str], Factorization], close: Callable[[], None] | None = None,
                 *, refactor: bool = False):
        self._make, self._close, self._refactor = make, close, refactor
        self._held: tuple[float, Factorization] | None = None

    @classmethod
    def over(cls, factory, close: Callable[[], None] | None = None) -> "Slot":
        """The slot of ``factory``: its ``refactor`` when it has one (a :class:`ShiftedFactorizer`), else
        ``factory(sigma, label)`` itself (an adapter's factorisations)."""
        refactor = getattr(factory, "refactor", None)
        return cls(refactor or factory, close, refactor=refactor is not None)

    def factorization(self, sigma: float, label: str) -> Factorization:
        if self._held is not None and self._held[0] == sigma:
            return self._held[1]
        if not self._refactor:
            self.release()
        self._held = None  # a failed make leaves nothing held (a refactor's old factorisation is superseded)
        self._held = (sigma, self._make(sigma, label))
        return self._held[1]

    def holds(self, sigma: float) -> bool:
        """Whether the slot holds the factorisation of ``sigma`` now."""
        return self._held is not None and self._held[0] == sigma

    def release(self) -> None:
        """Free the held factorisation (for a refactor: the instance, so the next one analyses again)."""
        if self._held is not None:
            self._held[1].release()
        self._held = None

    def close(self) -> None:
        """Free the factorisation and whatever the slot keeps for the next one (a refactor's matrix)."""
        self.release()
        if self._close is not None:
            self._close()
