"""The FEniCSx adapter under ``mpirun -n N``: distributed mesh, assembly, SLEPc and MUMPS.

Design (SPMD, "global vectors on every rank")
---------------------------------------------
Every MPI rank runs the same stepnf pipeline on the same data. The adapter is
the only place where the ranks differ:

* the mesh is partitioned over ``MPI.COMM_WORLD`` by dolfinx; each rank
  assembles its cells (internal forces, K, M, intrusive tensors);
* the eigen-solve (SLEPc Krylov-Schur, shift-invert, MUMPS) and the shifted
  solves ``K - sigma M`` (PETSc KSP + parallel MUMPS) run on the distributed
  PETSc matrices;
* whatever crosses the adapter's interface is a *global* numpy array,
  identical (bit for bit, it comes from one ``Allgatherv``) on every rank:
  fields coming in are global, the adapter takes the entries its rank needs
  (owned and ghost dofs); results going out are gathered to every rank.

So the core never sees MPI, stays deterministic (the same inputs give the
same floating-point operations, hence the same branches, on every rank) and
every adapter call is collective: all ranks make the same calls in the same
order. For 1e4-1e5 dofs a global vector is 0.1-1 MB, and a gather costs far
less than the assembly or the solve that produced it. ``stiffness_matrix`` and
``mass_matrix`` are gathered too (the core uses them for products and
projections); they cost the memory of the serial run on each rank. The
factorisations, the expensive and memory-hungry part, stay distributed.

Shifted solves below the computed spectrum (``K^+``, the modal derivative's
``K - w^2 M``, DNF's ``K - 4 w^2 M`` when it lies inside) reuse the
eigen-solve's factorisation through :class:`stepnf.linalg.deflation.DeflatedSolver`,
as the serial core does; only shifts above the computed spectrum cost a new
parallel factorisation.

Dof order: PETSc's global order (the owned dofs of rank 0, then of rank 1,
...), node-major ``(ux, uy, uz)`` as in the serial adapter; with boundary
conditions, the same order without the fixed dofs (:mod:`stepnf_fenicsx.layout`):
each rank marks the fixed dofs among its local ones (the mesh's node sets are
read on every rank), their union is fixed, K and M are the PETSc sub-matrices
of the free dofs (the eigen-solve and the shifted solves run on them), and
fields are expanded to the whole space for the assembly of the forces. The
order differs from the serial run's and depends on the number of processes;
the results (T, Gamma, labels, frequencies) do not depend on it. Materials per
cell set follow the cells wherever the partitioner puts them: each rank sets its
cells' coefficients from their rows in the input mesh
(``topology.original_cell_index``, :class:`stepnf_fenicsx.model.MaterialField`). Rank 0 alone
writes files and prints: ``stepnf run`` handles that, a script using the
Python API should write only where :func:`is_root` holds. The adapter declares ``collective``,
so the pipeline keeps no force checkpoint (a rank reusing stored forces would
skip calls the other ranks make).
"""
from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from stepnf.plugin.boundary import FreeDofs
from stepnf.errors import NumericalError

from . import _compat
from .direct import DirectSolve
from .layout import FreeLayout, GlobalLayout, RankBlocks, gather_matrix
from .serial import FenicsxAdapter


def is_root() -> bool:
    """True on rank 0 of ``MPI.COMM_WORLD`` (and in a serial run)."""
    return _compat.comm_world().rank == 0


class DistributedFenicsxAdapter(FenicsxAdapter, distributed=True):
    """:class:`FenicsxAdapter` with its mesh distributed over ``MPI.COMM_WORLD`` (see the module docstring).

    Declares ``provides_eigenmodes`` (SLEPc, shift-invert with MUMPS, the
    rigid-body modes given as a deflation space) and
    ``provides_shifted_solves`` (deflation + CG preconditioned by the
    eigen-solve's factorisation below the computed spectrum, else parallel
    MUMPS ``LDL^T``). Every method is
    collective: all ranks must call it, in the same order, with the same
    arguments.
    """

    provides_eigenmodes = True
    provides_shifted_solves = True
    #: every call is collective over MPI ranks (a rank may not skip one, e.g. from a checkpoint)
    collective = True
    #: relative residual tolerance of the SLEPc eigen-solve
    eigen_tolerance = 1e-12
    #: shifted solves below the computed spectrum by deflation + CG (one factorisation for all shifts)
    use_deflation = True

    #: PETSc's numbering of the whole space (the assembly's); built with the space
    full_layout: GlobalLayout
    #: the adapter's numbering (the free dofs'), that of every array crossing its interface
    layout: RankBlocks

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        t0 = time.perf_counter()
        full = self._whole_space_layout()
        self._nodes = full.gather(self._nodes[: full.n_owned // 3].ravel()).reshape(-1, 3)
        self.layout = full if self._free is None else FreeLayout(full, self._free)
        self._n = self.layout.n
        self._Kp = None  # distributed PETSc matrices
        self._Mp = None
        self._solves: list[DirectSolve] = []  # factorisations handed out, released on close() at the latest
        self._eps = None  # the last SLEPc solver (its factorisation preconditions the deflated solves)
        self._deflated = None
        self._eigen_shift = 0.0
        #: shifted solvers handed out: by deflation + CG, and by a new MUMPS factorisation
        self.solver_counts = {"deflated": 0, "factorized": 0}
        self.timings["setup"] += time.perf_counter() - t0

    def _mesh_comm(self):
        return _compat.comm_world()

    def _whole_space_layout(self) -> GlobalLayout:
        if getattr(self, "full_layout", None) is None:
            self.full_layout = GlobalLayout(self._V)
        return self.full_layout

    def _free_dofs(self, local_mask: np.ndarray) -> FreeDofs:
        """The union over ranks of the dofs each fixes among its local ones (global numbering)."""
        return self._whole_space_layout().free_dofs(local_mask)

    # ------------------------------------------------------------ assembly
    def _assemble(self, form, fields: Sequence[tuple[Any, np.ndarray]]) -> np.ndarray:
        full = self.full_layout
        for fn, u in fields:
            _compat.set_values(fn, full.local(self._expand(np.asarray(u, dtype=float))))
        return self._restrict(full.gather(_compat.assemble_owned(form, full.n_owned)))

    def _petsc_matrices(self):
        if self._Kp is None:
            t0 = time.perf_counter()
            self._Kp = self._free_part(_compat.assemble_petsc_matrix(self._forms.K_form))
            self._Mp = self._free_part(_compat.assemble_petsc_matrix(self._forms.M_form))
            self.timings["assembly_petsc"] = time.perf_counter() - t0
        return self._Kp, self._Mp

    def _free_part(self, A):
        """The distributed ``A[free, free]`` of a whole-space PETSc matrix (``A`` itself when all are free)."""
        if self._free is None:
            return A
        try:
            return self.layout.submatrix(A)
        finally:
            A.destroy()

    def _build_stiffness(self) -> sp.csr_matrix:
        return gather_matrix(self._petsc_matrices()[0], self.layout)

    def _build_mass(self) -> sp.csr_matrix:
        return gather_matrix(self._petsc_matrices()[1], self.layout)

    def _internal_force(self, u: np.ndarray) -> np.ndarray:
        return self._assemble(self._forms.f_form, [(self._forms.u, u)])

    def quadratic_force(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        f = self._forms
        return self._assemble(f.G_form, [(f.a, self._check_field(u)), (f.b, self._check_field(v))])

    def cubic_force(self, u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        f = self._forms
        return self._assemble(f.H_form, [(f.a, self._check_field(u)), (f.b, self._check_field(v)),
                                         (f.c, self._check_field(w))])

    # ------------------------------------------------------------ PETSc helpers
    def _vec(self, u: np.ndarray | None = None):
        v = self._petsc_matrices()[0].createVecRight()
        if u is not None:
            v.array[:] = self.layout.owned(u)
        return v

    @staticmethod
    def _mumps_ksp(ksp, A) -> None:
        """``ksp`` as a direct solve of the symmetric ``A`` by parallel MUMPS ``LDL^T``."""
        from petsc4py import PETSc

        A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        ksp.setOperators(A)
        ksp.setType("preonly")
        pc = ksp.getPC()
        pc.setType("cholesky")
        pc.setFactorSolverType("mumps")

    def _rigid_modes(self) -> np.ndarray:
        """M-orthonormal rigid-body motions (n, r) of the free solid (global vectors)."""
        from stepnf.linalg.modal_analysis import lambda_scale, rigid_body_fields, rigid_modes_from

        K, M = self.stiffness_matrix(), self.mass_matrix()
        cands = rigid_body_fields(self.dof_coordinates(), self.dof_directions())
        return rigid_modes_from(K, M, cands, lambda_scale(K, M), 1e-11)

    # ------------------------------------------------------------ capabilities
    def eigenmodes(self, n_modes: int, shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The ``n_modes`` eigenpairs ``(w^2, Phi)`` nearest ``shift`` by SLEPc (rigid modes first).

        The rigid-body motions are computed from the dof coordinates and given
        to SLEPc as a deflation space, so the Krylov-Schur iteration (shift-
        invert at ``shift - 1e-10 lambda_scale``, MUMPS) sees only the elastic
        spectrum; they are returned too, with their Rayleigh quotients
        (round-off) as eigenvalues. The elastic pairs are then refined by
        :meth:`_refine`. Every vector is M-normalised.
        """
        from slepc4py import SLEPc

        from stepnf.linalg.modal_analysis import lambda_scale

        t0 = time.perf_counter()
        K, M = self.stiffness_matrix(), self.mass_matrix()
        Kp, Mp = self._petsc_matrices()
        R = self._rigid_modes()
        nev = max(int(n_modes) - R.shape[1], 1)
        sigma = float(shift) - 1e-10 * lambda_scale(K, M)
        eps = SLEPc.EPS().create(self.layout.comm)
        try:
            eps.setOperators(Kp, Mp)
            eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
            eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
            eps.setDimensions(nev=nev)
            eps.setTolerances(tol=self.eigen_tolerance, max_it=1000)
            eps.setPurify(False)  # its extra solve per vector is the first half of _refine
            eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
            eps.setTarget(sigma)
            st = eps.getST()
            st.setType(SLEPc.ST.Type.SINVERT)
            st.setShift(sigma)
            self._mumps_ksp(st.getKSP(), Kp)  # operators are replaced by K - sigma M in ST set-up
            if R.shape[1]:
                eps.setDeflationSpace([self._vec(R[:, j]) for j in range(R.shape[1])])
            eps.solve()
            nconv = eps.getConverged()
            if nconv < nev:
                raise NumericalError(f"SLEPc converged {nconv} of {nev} eigenpairs "
                                     f"(reason {eps.getConvergedReason()})")
            vr = self._vec()
            vecs = []
            for i in range(nconv):
                eps.getEigenpair(i, vr)
                vecs.append(self.layout.gather(vr.array))
            lam_e, V = self._refine(eps.getST(), np.column_stack(vecs), R, sigma)
        except BaseException:
            eps.destroy()
            raise
        self._keep_eigen_solver(eps, V[:, :nev], lam_e[:nev], R)
        self._eigen_shift = sigma
        lam_r = np.einsum("ij,ij->j", R, K @ R) / np.einsum("ij,ij->j", R, M @ R)  # round-off
        lam = np.concatenate([lam_r, lam_e])
        Phi = np.column_stack([R, V])
        order = np.argsort(np.abs(lam - shift), kind="stable")[: int(n_modes)]
        order = order[np.argsort(lam[order], kind="stable")]
        self.timings["eigen"] = self.timings.get("eigen", 0.0) + time.perf_counter() - t0
        return lam[order], Phi[:, order]

    def _refine(self, st, V: np.ndarray, R: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """One subspace-iteration step and Rayleigh-Ritz in the shift-inverted operator.

        ``W = (K - sigma M)^-1 M V`` (SLEPc's own factorisation), rigid part
        removed; the Ritz problem ``V^T M W y = theta V^T M V y`` uses M
        products and solves only, so near-equal frequencies (a split pair of
        twin modes, relative gap ~1e-4) are separated to round-off, where a
        Ritz problem in ``V^T K V`` would lose ~eps * lambda_max / lambda_1
        to cancellation. Returns ``lambda = sigma + 1/theta`` (ascending) and
        the vectors ``W y``.
        """
        M = self.mass_matrix()
        x, y = self._vec(), self._vec()
        W = np.empty_like(V)
        for j in range(V.shape[1]):
            x.array[:] = self.layout.owned(V[:, j])
            st.apply(x, y)
            W[:, j] = self.layout.gather(y.array)
        if R.shape[1]:
            W -= R @ (R.T @ (M @ W))
        MV = M @ V
        G = V.T @ MV
        T = MV.T @ W
        theta, Y = sla.eigh((T + T.T) / 2, (G + G.T) / 2)
        keep = theta > 0
        theta, Y = theta[keep][::-1], Y[:, keep][:, ::-1]
        Phi = W @ Y
        Phi /= np.sqrt(np.einsum("ij,ij->j", Phi, M @ Phi))  # M-normalised
        return sigma + 1.0 / theta, Phi

    def _keep_eigen_solver(self, eps, Phi: np.ndarray, lam: np.ndarray, R: np.ndarray) -> None:
        """Keep SLEPc's factorisation of ``K - sigma_0 M`` for the deflated shifted solves."""
        from stepnf.linalg.deflation import DeflatedSolver

        if self._eps is not None:
            self._eps.destroy()
        self._eps = eps
        # SLEPc owns the KSP (destroyed with eps); one column or a block of them per call
        precond = DirectSolve(eps.getST().getKSP(), self.layout, "K - sigma_0 M (eigen-solve)")
        self._deflated = DeflatedSolver(self.stiffness_matrix(), self.mass_matrix(), Phi, lam, R, precond)

    def _deflated_solve(self, sigma: float, fixed_dofs: Sequence[int] | None
                        ) -> Callable[[np.ndarray], np.ndarray] | None:
        """``(K - sigma M)^-1`` by deflation + CG (no new factorisation), or None when not applicable.

        Applicable below the computed spectrum (``stepnf.linalg.deflation``). With
        ``fixed_dofs`` (sigma = 0 only) the solve is the isostatically
        supported one, exactly: the reactions that equilibrate ``b`` are put
        back on the fixed dofs (``R_F^T`` is regular for an isostatic
        support), ``K^+`` is applied, and the rigid motion that zeroes the
        fixed dofs is added.
        """
        D = self._deflated
        if D is None or not self.use_deflation or not D.admissible(sigma):
            return None
        if fixed_dofs is None and abs(sigma - self._eigen_shift) <= 1e-9 * abs(self._eigen_shift):
            return D.precond  # the eigen-solve's own factorisation (the core's deflation preconditioner)
        if fixed_dofs is None or len(fixed_dofs) == 0:
            return lambda b: D.solve(np.asarray(b, dtype=float), sigma)
        F = np.asarray(fixed_dofs, dtype=np.int64)
        R = D.Psi[:, :D.n_rigid]
        if sigma != 0.0 or len(F) != R.shape[1]:
            return None
        RF = R[F]
        if np.linalg.cond(RF) > 1e8:  # not an isostatic support of this solid
            return None

        def solve(b: np.ndarray) -> np.ndarray:
            b = np.array(b, dtype=float)
            b[F] += np.linalg.solve(RF.T, -(R.T @ b))  # reactions: R^T b = 0 now
            x = D.pinv(b)
            x += R @ np.linalg.solve(RF, -x[F])
            x[F] = 0.0
            return x

        return solve

    def shifted_solver(self, sigma: float, *, fixed_dofs: Sequence[int] | None = None
                       ) -> Callable[[np.ndarray], np.ndarray]:
        """``solve(b)`` for ``(K - sigma M) x = b``, ``fixed_dofs`` (global indices) held at zero.

        Below the computed spectrum, by deflation with the computed modes and
        CG preconditioned by the eigen-solve's factorisation (as the serial
        core does, :mod:`stepnf.linalg.deflation`); otherwise a new parallel MUMPS
        ``LDL^T`` factorisation, a :class:`~stepnf_fenicsx.direct.DirectSolve`: blocks of right-hand
        sides in one MUMPS call, freed by its ``release()`` (stepnf's slot calls it before the next
        factorisation) or at :meth:`close`.
        """
        from petsc4py import PETSc

        deflated = self._deflated_solve(float(sigma), fixed_dofs)
        if deflated is not None:
            self.solver_counts["deflated"] += 1
            return deflated
        self.solver_counts["factorized"] += 1
        t0 = time.perf_counter()
        Kp, Mp = self._petsc_matrices()
        A = Kp.copy()
        if sigma != 0.0:
            A.axpy(-float(sigma), Mp, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
        if fixed_dofs is not None and len(fixed_dofs):
            fixed = np.asarray(fixed_dofs, dtype=np.int64)
            mine = fixed[(fixed >= self.layout.start) & (fixed < self.layout.start + self.layout.n_owned)]
            A.zeroRowsColumns(mine.astype(PETSc.IntType), diag=1.0)
        ksp = PETSc.KSP().create(self.layout.comm)
        solve = DirectSolve(ksp, self.layout, f"K - {sigma:.6g} M", owned=[ksp, A])
        self._solves = [s for s in self._solves if s.ksp is not None] + [solve]  # (released ones dropped)
        self._mumps_ksp(ksp, A)
        ksp.setUp()
        self.timings["factorizations"] = self.timings.get("factorizations", 0.0) + time.perf_counter() - t0
        return solve

    # ------------------------------------------------------------ bookkeeping
    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d["mpi_processes"] = int(self.layout.comm.size)
        d["shifted_solvers"] = dict(self.solver_counts)
        return d

    def close(self) -> None:
        self._deflated = None
        if self._eps is not None:
            self._eps.destroy()
            self._eps = None
        for solve in self._solves:
            solve.release()
        self._solves = []
        for A in (self._Kp, self._Mp):
            if A is not None:
                A.destroy()
        self._Kp = self._Mp = None
