"""Sparse direct factorisations with fill-reducing orderings, and solves that count themselves.

Back ends, chosen by :func:`factorize` (``backend="auto"``):

``dense``
    LAPACK LU for small matrices (n <= 2000).
``mumps``
    MUMPS through petsc4py, when petsc4py is importable (it is on Debian with
    ``python3-petsc4py``); the fastest here on 3D solid meshes.
``superlu``
    scipy's SuperLU with the ``MMD_AT_PLUS_A`` ordering (about 9x faster than
    scipy's default ``COLAMD`` on symmetric FE matrices).

petsc4py is imported only when that back end is used, so ``import stepnf``
stays light. Importing it starts MPI: where Open MPI cannot (an unusable
``TMPDIR``, :mod:`stepnf.runtime.mpi_env`), ``auto`` takes SuperLU with a warning and
``mumps`` is refused with a one-line message, instead of Open MPI's abort.
"""
from __future__ import annotations

import os
import time
import warnings
import weakref
from typing import Any, Callable, Protocol, Sequence

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from stepnf.runtime.counters import Counters
from stepnf.errors import NumericalError

BACKENDS = ("auto", "dense", "superlu", "mumps")
DENSE_LIMIT = 2000


class Solve(Protocol):
    def __call__(self, b: np.ndarray) -> np.ndarray: ...


class Factorization:
    """A factorised square matrix; ``solve(b)`` accepts (n,) or (n, k) and counts k solves.

    ``resources``: what the solve needs alive (PETSc objects, arrays a PETSc matrix reads); those with
    a ``destroy()`` are destroyed by :meth:`release`. ``on_release`` (optional) is called once by
    :meth:`release`: it frees factors that this object shares (those of
    :class:`stepnf.linalg.shifted.ShiftedFactorizer`), unless :meth:`supersede` came first.
    """

    def __init__(self, solve: Callable[[np.ndarray], np.ndarray], n: int, backend: str,
                 counters: Counters | None = None, label: str = "", *,
                 resources: tuple = (), on_release: Callable[[], None] | None = None):
        self._solve = solve
        self.n = n
        self.backend = backend
        self.counters = counters
        self.label = label
        self._petsc = resources
        self._on_release = on_release
        #: why solves raise now (:meth:`disable`), or None while the factors are usable
        self.disabled: str | None = None

    def solve(self, b: np.ndarray, *, count: bool = True) -> np.ndarray:
        b = np.asarray(b, dtype=float)
        if b.shape[0] != self.n:
            raise ValueError(f"right-hand side has {b.shape[0]} rows, the matrix {self.n}")
        x = self._solve(b)
        if count and self.counters is not None:
            self.counters.linear_solves += 1 if b.ndim == 1 else b.shape[1]
        if not np.all(np.isfinite(x)):
            raise NumericalError(f"solve with the factorisation of {self.label or 'a matrix'} gave NaN/inf: "
                                 "the matrix is singular")
        return x

    __call__ = solve

    def release(self) -> None:
        """Free the factors now: MUMPS's (through petsc4py) otherwise outlive this object (measured:
        about 220 MB kept per factorisation of the 38k-dof cap). Solving afterwards is an error."""
        free, self._on_release = self._on_release, None
        petsc, self._petsc = [r for r in self._petsc if hasattr(r, "destroy")], ()
        if free is not None:
            free()
        for obj in petsc:
            obj.destroy()
        self.disable("was released")
        if free is not None or petsc:
            return_free_memory()

    def supersede(self, why: str) -> None:
        """Another factorisation took over the shared factors: no ``on_release`` any more, solves raise."""
        self._on_release = None
        self.disable(why)

    def disable(self, why: str) -> None:
        """Make every later solve raise ``RuntimeError`` ("the factorisation of <label> <why>"); frees nothing."""
        message = f"the factorisation of {self.label or 'a matrix'} {why}"
        self.disabled = why

        def disabled(b: np.ndarray) -> np.ndarray:
            raise RuntimeError(message)

        self._solve = disabled


def return_free_memory() -> None:
    """Give the C heap's free pages back to the system (glibc's ``malloc_trim(0)``; elsewhere nothing).

    MUMPS's factors freed by ``destroy()`` otherwise stay in the process (measured at 38k dofs: resident
    memory 599 MB after a release, 213 MB with the trim, which took ~20 ms).
    """
    try:
        import ctypes
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _petsc_available() -> bool:
    if os.environ.get("STEPNF_NO_PETSC"):
        return False
    try:
        import petsc4py  # noqa: F401  (is it importable? This does not start MPI; petsc4py.PETSc does)
    except Exception:
        return False
    from stepnf.runtime.mpi_env import mpi_tmpdir_problem

    problem = mpi_tmpdir_problem()
    if problem is not None:
        warnings.warn(f"MUMPS (petsc4py) not used: Open MPI cannot start, its temporary folder {problem}; "
                      "SuperLU instead (slower on large models; set TMPDIR to a writable folder)", stacklevel=2)
        return False
    return True


def choose_backend(n: int, backend: str = "auto") -> str:
    """The back end :func:`factorize` uses for an (n, n) matrix."""
    if backend not in BACKENDS:
        raise ValueError(f"Unknown linear-solver back end {backend!r}. Pick one of {list(BACKENDS)}")
    if backend == "mumps":
        from stepnf.runtime.mpi_env import require_mpi

        require_mpi('linear_solver = "mumps" (MUMPS through petsc4py)')
    if backend != "auto":
        return backend
    if n <= DENSE_LIMIT:
        return "dense"
    return "mumps" if _petsc_available() else "superlu"


def factorize(A: sp.spmatrix | np.ndarray, *, counters: Counters | None = None,
              backend: str = "auto", label: str = "") -> Factorization:
    """Factorise a square matrix and return a counting :class:`Factorization`."""
    t0 = time.perf_counter()
    fac = _factorize(A, backend, counters, label)
    if counters is not None:
        counters.factorizations += 1
        counters.factorization_seconds += time.perf_counter() - t0
    return fac


def _factorize(A, backend: str, counters: Counters | None, label: str) -> Factorization:
    n = A.shape[0]
    kind = choose_backend(n, backend)
    if kind == "dense":
        Ad = A.toarray() if sp.issparse(A) else np.asarray(A, dtype=float)
        with warnings.catch_warnings():  # a singular matrix is reported below as a NumericalError
            warnings.simplefilter("ignore", sla.LinAlgWarning)
            lu = sla.lu_factor(Ad, check_finite=True)
        if np.min(np.abs(np.diag(lu[0]))) == 0.0:
            raise NumericalError(f"{label or 'matrix'} is exactly singular")
        return Factorization(lambda b: sla.lu_solve(lu, b), n, kind, counters, label)
    if kind == "superlu":
        try:
            lu = spla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A")
        except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
            raise NumericalError(f"{label or 'matrix'}: {exc}") from exc
        return Factorization(lu.solve, n, kind, counters, label)
    return _mumps(sp.csr_matrix(A), counters, label)


def _mumps(A: sp.csr_matrix, counters: Counters | None, label: str) -> Factorization:
    A = A.astype(float)
    A.sort_indices()
    n = A.shape[0]
    P = petsc_aij(A.indptr, A.indices, A.data, copy=True)
    # cheap probe (two products with A and A^T) instead of forming A - A^T, which took seconds at 100k dofs
    ksp = mumps_ksp(P, symmetric=symmetry_defect(A) <= 1e-13)
    mumps_setup(ksp, label)
    xv, bv = P.createVecs()
    return Factorization(ksp_solve_function(ksp, xv, bv, n), n, "mumps", counters, label,
                         resources=(P, ksp, xv, bv))


def petsc_aij(indptr: np.ndarray, indices: np.ndarray, data: np.ndarray, *, copy: bool):
    """A sequential PETSc AIJ matrix of a CSR (sorted column indices, float64 ``data``).

    ``copy=False``: the matrix reads and writes the given arrays (PETSc's ``MatCreateSeqAIJWithArrays``;
    they must be of PETSc's integer type and stay alive, the caller keeps them); writing ``data`` then
    changes the matrix (call ``assemble()`` afterwards so that PETSc sees a new state).
    """
    from petsc4py import PETSc

    n = len(indptr) - 1
    if copy:
        P = PETSc.Mat().createAIJ(size=(n, n), csr=(indptr, indices, data), comm=PETSc.COMM_SELF)
    else:
        P = PETSc.Mat().createAIJWithArrays((n, n), (indptr, indices, data), comm=PETSc.COMM_SELF)
    P.assemble()
    return P


def mumps_ksp(P, *, symmetric: bool):
    """A direct-solve KSP (``preonly``) with MUMPS on the PETSc matrix ``P``, not yet set up.

    Symmetric matrices (K - sigma M, also indefinite): MUMPS LDL^T (PETSc ``cholesky``), measured 1.45x
    faster than LU on a 16k-dof hex27 cap, with MUMPS's default ordering: PORD in Debian's build
    (INFOG(7) = 4; METIS and SCOTCH are not built in, AMF measured no faster nor smaller at 112k dofs,
    AMD and QAMD 4% more factor entries). (An ICNTL(7) set on the factor matrix before the set-up was
    not applied by PETSc 3.18: only the options database ``-mat_mumps_icntl_7`` is.)

    A METIS nested dissection is not used: PETSc (3.18 to 3.22) hands no ordering to MUMPS's LDL^T
    (``MatCholeskyFactorSymbolic_MUMPS`` ignores PCFactor's ordering; ``-mat_mumps_icntl_7 1`` is
    refused; only LU takes one), and given to MUMPS directly as PERM_IN (pymetis 2025.2.2 on the
    graph of equal-pattern dof groups, weighted, 3 separators) it was no better than PORD on the
    hex27 cap's ``K - sigma M`` (issue 35): factor entries +10% / +3% / +6% and factorisation
    memory (INFOG(22)) +10% / +6% / +8% at 38k / 250k / 1M dofs, flops +9% / -21% / -8%, numeric
    factorisation time within the noise (1M: 56-66 s either way, one thread).
    """
    from petsc4py import PETSc

    ksp = PETSc.KSP().create(PETSc.COMM_SELF)
    ksp.setOperators(P)
    ksp.setType("preonly")
    pc = ksp.getPC()
    pc.setType("cholesky" if symmetric else "lu")
    pc.setFactorSolverType("mumps")
    pc.setFactorSetUpSolverType()
    return ksp


def mumps_setup(ksp, label: str) -> None:
    """Factorise (``ksp.setUp()``); MUMPS's error INFOG(1) < 0 (-10: singular) is a :class:`NumericalError`."""
    ksp.setUp()
    info = ksp.getPC().getFactorMatrix().getMumpsInfog(1)
    if info < 0:
        why = "numerically singular" if info == -10 else "not factorised"
        raise NumericalError(f"{label or 'matrix'} is {why} (MUMPS INFOG(1) = {info})")


def ksp_solve_function(ksp, xv, bv, n: int) -> Callable[[np.ndarray], np.ndarray]:
    """``solve(b)`` for (n,) or (n, k) ``b`` with a set-up direct-solve KSP (work vectors ``xv``, ``bv``).

    Several columns go to MUMPS in one call (:func:`factor_block_solve`), not one by one.
    """
    def solve(b: np.ndarray) -> np.ndarray:
        cols = b.reshape(n, -1)
        if cols.shape[1] > 1:
            return factor_block_solve(ksp.getPC().getFactorMatrix(), cols).reshape(b.shape)
        bv.setArray(cols[:, 0])
        ksp.solve(bv, xv)
        return xv.getArray().copy().reshape(b.shape)
    return solve


def factor_block_solve(F, B: np.ndarray, *, comm: Any = None, n_global: int | None = None) -> np.ndarray:
    """``X`` (n, k) with ``A X = B`` for the factored matrix ``F`` of ``A``: one ``MatMatSolve``.

    MUMPS's forward and backward substitutions then read the factors once for all k columns
    (dense kernels): measured on the 112k-dof cap (one thread) 0.14 s for 6 columns and 0.25 s
    for 16, against 0.08 s per column one by one. The columns agree with one-by-one solves to
    round-off (2e-14 relative measured), not bit for bit. For a distributed ``F`` (``comm``, the
    matrix's ``n_global`` rows), ``B`` and ``X`` are this rank's rows of every column; the call is
    collective.
    """
    from petsc4py import PETSc

    n, k = B.shape
    comm = PETSc.COMM_SELF if comm is None else comm
    sizes = ((n, n if n_global is None else n_global), (PETSc.DECIDE, k))  # a rank holds its rows of all columns
    Bm = PETSc.Mat().createDense(sizes, array=np.asfortranarray(B, dtype=float), comm=comm)
    Xm = PETSc.Mat().createDense(sizes, comm=comm)
    Xm.setUp()
    try:
        F.matSolve(Bm, Xm)
        return np.array(Xm.getDenseArray(), copy=True)
    finally:
        Bm.destroy()
        Xm.destroy()


_DIAGONALS: dict[int, tuple[weakref.ref, np.ndarray]] = {}


def matrix_diagonal(A: sp.spmatrix | np.ndarray) -> np.ndarray:
    """The diagonal of ``A`` (n,) float, read once per matrix object and kept while the object lives.

    For the run's K and M, which are not modified after assembly: several diagnostics ask for
    their diagonals (26 times in the main job's run, 74 ms each at 250k dofs). Read-only: the
    caller must not modify it. (Keyed by the object's identity, dropped when it is collected:
    scipy's sparse matrices are not hashable.)
    """
    key = id(A)
    kept = _DIAGONALS.get(key)
    if kept is not None and kept[0]() is A:
        return kept[1]
    d = np.asarray(A.diagonal() if sp.issparse(A) else np.diag(np.asarray(A)), dtype=float).ravel()
    d.flags.writeable = False
    try:
        _DIAGONALS[key] = (weakref.ref(A, lambda _ref, key=key: _DIAGONALS.pop(key, None)), d)
    except TypeError:  # an object without weak references: not kept
        pass
    return d


def symmetry_defect(A: sp.spmatrix | np.ndarray, *, seed: int = 0, probes: int = 2) -> float:
    """Relative asymmetry of a square matrix from random probes, without forming ``A - A^T``.

    ``max_i |((A - A^T) x)_i| / max_i |(A x)_i|``, the largest over ``probes``
    Gaussian vectors ``x`` (a fixed seed: the same number on every run). It is
    0 for a symmetric matrix and, otherwise, of the order of the relative
    (root-mean-square per row) size of the antisymmetric part: a random ``x``
    cancels a nonzero ``A - A^T`` with probability 0. Cost: two products per
    probe, ~0.1 s at 24M stored entries (100k dofs), where
    ``abs(A - A.T).max()`` needs a transposed copy and a sparse subtraction
    (and ``abs(A)`` alone a copy of the entries: ~0.5 s each). Entries that
    are not finite give ``inf``.
    """
    n = A.shape[0]
    if len(A.shape) != 2 or A.shape != (n, n):
        return float("inf")
    if n == 0:
        return 0.0
    A = sp.csr_matrix(A) if sp.issparse(A) else np.asarray(A)
    rng = np.random.default_rng(seed)
    worst = 0.0
    with np.errstate(all="ignore"):
        for _ in range(max(1, probes)):
            x = rng.standard_normal(n)
            Ax = np.asarray(A @ x).ravel()
            num = float(np.max(np.abs(Ax - np.asarray(A.T @ x).ravel())))
            den = float(np.max(np.abs(Ax)))
            if not (np.isfinite(num) and np.isfinite(den)):
                return float("inf")
            if den > 0:
                worst = max(worst, num / den)
            elif num > 0:
                return float("inf")
    return worst


def isostatic_dofs(R: np.ndarray) -> np.ndarray:
    """Dofs whose fixing removes the rigid motions spanned by the columns of ``R`` (n, r).

    The r pivots of a column-pivoted QR of ``R^T`` give an r x r block of R
    that is as well conditioned as possible: holding those dofs at zero is an
    isostatic support (the 3-2-1 rule in general form). Returns sorted indices.
    """
    r = R.shape[1]
    if r == 0:
        return np.zeros(0, dtype=int)
    _, _, piv = sla.qr(R.T, mode="economic", pivoting=True)
    return np.sort(piv[:r])


class PseudoInverse:
    """``K^+ b`` on the M-orthogonal complement of the rigid-body modes ``R`` (M-normalised).

    ``b`` is first made self-equilibrated (``b - M R R^T b``), the system is
    solved with an isostatic support (one factorisation, reused for every
    right-hand side), and the rigid part of the solution is removed by
    M-orthogonal projection: ``x = sum_s phi_s phi_s^T b / w_s^2`` over the
    elastic modes.
    """

    def __init__(self, K: sp.spmatrix, M: sp.spmatrix, R: np.ndarray, *,
                 counters: Counters | None = None, backend: str = "auto",
                 fixed: Sequence[int] | None = None,
                 solver_factory: Callable[..., Callable[[np.ndarray], np.ndarray]] | None = None):
        self.M = M
        self.R = R
        n = K.shape[0]
        self.fixed = isostatic_dofs(R) if fixed is None else np.asarray(fixed, dtype=int)
        self.free = np.setdiff1d(np.arange(n), self.fixed)
        self.n = n
        if solver_factory is not None:  # the adapter's own shifted solver
            if counters is not None:
                counters.factorizations += 1
            self._fac = adapter_factorization(solver_factory(0.0, fixed_dofs=self.fixed), n, counters,
                                              "K (supported)")
            self._full = True
        else:
            Kc = sp.csr_matrix(K)[self.free][:, self.free]
            self._fac = factorize(Kc, counters=counters, backend=backend, label="K (isostatic support)")
            self._full = False

    def __call__(self, b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=float)
        if self.R.shape[1]:
            b = b - self.M @ (self.R @ (self.R.T @ b))
        if self._full:
            bb = b.copy()
            bb[self.fixed] = 0.0
            x = self._fac.solve(bb)
            x[self.fixed] = 0.0
        else:
            x = np.zeros_like(b)
            x[self.free] = self._fac.solve(b[self.free])
        if self.R.shape[1]:
            x = x - self.R @ (self.R.T @ (self.M @ x))
        return x


def adapter_factorization(solve: Callable[[np.ndarray], np.ndarray], n: int, counters: Counters | None,
                          label: str) -> Factorization:
    """An adapter's shifted ``solve`` as a :class:`Factorization`: columns through :func:`apply_columns`;
    releasing it calls the solve's ``release()`` when the adapter gives it one (its factors are freed then)."""
    return Factorization(lambda b: apply_columns(solve, b), n, "adapter", counters, label,
                         on_release=getattr(solve, "release", None))


def apply_columns(solve: Callable[[np.ndarray], np.ndarray], b: np.ndarray) -> np.ndarray:
    """``solve`` applied to ``b`` (n,), or to each column of ``b`` (n, k): a result of ``b``'s shape.

    ``solve`` takes one right-hand side (n,), such as an adapter's shifted
    solve of ``K - sigma M`` (in the adapter's units and dof order), unless it
    declares ``takes_columns = True`` (it then solves (n, k) at once, e.g. in
    one MUMPS call); the result is what :class:`Factorization` expects of its
    ``solve``: an (n,) float array, or the (n, k) columns stacked.
    """
    if b.ndim == 1 or getattr(solve, "takes_columns", False):
        return np.asarray(solve(b), dtype=float)
    return np.column_stack([solve(b[:, j]) for j in range(b.shape[1])])
