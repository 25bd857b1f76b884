"""Global dof numberings of the distributed FEniCSx adapter, and the gathers they need (MPI).

Two numberings, both "rank blocks" (rank 0's owned dofs, then rank 1's, ...):

* :class:`GlobalLayout`: PETSc's global numbering of the whole blocked dolfinx
  space (the assembly's vectors and matrices);
* :class:`FreeLayout`: the same order with the dofs fixed by boundary
  conditions removed; a rank owns the free dofs among its owned ones, so the
  free dofs stay contiguous per rank in rank order, which is exactly the row
  layout of the PETSc sub-matrix ``A[free, free]`` (:meth:`FreeLayout.submatrix`).

The adapter's interface (K, M, forces, mode shapes) uses the free numbering:
every global vector crossing it is gathered with :meth:`RankBlocks.gather`.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.boundary import FreeDofs


def allgatherv(comm, x: np.ndarray, mpi_type) -> np.ndarray:
    """The concatenation, in rank order and on every rank, of each rank's ``x``."""
    counts = np.asarray(comm.allgather(len(x)), dtype=np.int64)
    displs = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    out = np.empty(int(counts.sum()), dtype=x.dtype)
    comm.Allgatherv(np.ascontiguousarray(x), [out, counts, displs, mpi_type])
    return out


class RankBlocks:
    """A global numbering in which rank ``r`` owns the contiguous range ``start .. start + n_owned``.

    ``n`` global dofs; ``counts``, ``displs``: every rank's ``n_owned`` and ``start``.
    """

    def __init__(self, comm, n_owned: int):
        from mpi4py import MPI

        self.comm = comm
        self.n_owned = int(n_owned)
        self.counts = np.asarray(comm.allgather(self.n_owned), dtype=np.int64)
        self.displs = np.concatenate([[0], np.cumsum(self.counts)[:-1]]).astype(np.int64)
        self.n = int(self.counts.sum())
        self.start = int(self.displs[comm.rank])
        self._double = MPI.DOUBLE

    def gather(self, owned: np.ndarray) -> np.ndarray:
        """The global vector (n,) on every rank from each rank's owned entries."""
        owned = np.ascontiguousarray(owned, dtype=float)
        out = np.empty(self.n)
        self.comm.Allgatherv(owned, [out, self.counts, self.displs, self._double])
        return out

    def owned(self, u: np.ndarray) -> np.ndarray:
        """This rank's owned entries of a global vector."""
        return u[self.start:self.start + self.n_owned]


class GlobalLayout(RankBlocks):
    """PETSc's global numbering of a blocked dolfinx space, and the gathers/scatters it needs.

    ``n`` global dofs; this rank owns ``start .. start + n_owned``;
    ``local_dofs[i]`` is the global dof of entry ``i`` of a function's local
    array (owned then ghost dofs).
    """

    def __init__(self, V):
        im, bs = V.dofmap.index_map, int(V.dofmap.index_map_bs)
        super().__init__(V.mesh.comm, im.size_local * bs)
        n_local = im.size_local + im.num_ghosts
        nodes = np.asarray(im.local_to_global(np.arange(n_local, dtype=np.int32)), dtype=np.int64)
        self.local_dofs = (nodes[:, None] * bs + np.arange(bs)).ravel()
        if self.n != im.size_global * bs or self.start != int(im.local_range[0] * bs):
            raise RuntimeError("dolfinx's owned dof ranges are not contiguous in rank order")

    def local(self, u: np.ndarray) -> np.ndarray:
        """This rank's local (owned + ghost) entries of a global vector."""
        return u[self.local_dofs]

    def free_dofs(self, local_mask: np.ndarray) -> FreeDofs:
        """The free dofs (same on every rank) when ``local_mask`` (local dof nodes, block size) marks the
        fixed dofs among this rank's owned and ghost ones: the union over ranks is fixed."""
        from mpi4py import MPI

        mine = self.local_dofs[np.asarray(local_mask, dtype=bool).ravel()]
        return FreeDofs(self.n, allgatherv(self.comm, mine.astype(np.int64), MPI.INT64_T))


class FreeLayout(RankBlocks):
    """The free dofs of a :class:`GlobalLayout` (see the module docstring); ``owned_full`` are the
    whole-space global indices of this rank's owned free dofs."""

    def __init__(self, full: GlobalLayout, free: FreeDofs):
        f = free.free
        self.owned_full = f[(f >= full.start) & (f < full.start + full.n_owned)]
        super().__init__(full.comm, len(self.owned_full))
        if self.n != free.n_free:
            raise RuntimeError("the ranks disagree on the free dofs")

    def submatrix(self, A):
        """``A[free, free]`` of a distributed PETSc matrix of the whole space, rows laid out like this numbering."""
        from petsc4py import PETSc

        index = PETSc.IS().createGeneral(self.owned_full.astype(PETSc.IntType), comm=self.comm)
        try:
            return A.createSubMatrix(index, index)
        finally:
            index.destroy()


def gather_matrix(A, layout: RankBlocks) -> sp.csr_matrix:
    """The global scipy CSR copy, on every rank, of a distributed PETSc AIJ matrix (global numbering)."""
    from mpi4py import MPI

    lo, hi = A.getOwnershipRange()
    if (lo, hi) != (layout.start, layout.start + layout.n_owned):
        raise RuntimeError(f"PETSc row range {(lo, hi)} differs from the dof layout's")
    indptr, indices, data = A.getValuesCSR()
    comm = layout.comm
    row_nnz = allgatherv(comm, np.diff(indptr).astype(np.int64), MPI.INT64_T)
    cols = allgatherv(comm, np.asarray(indices, dtype=np.int64), MPI.INT64_T)
    vals = allgatherv(comm, np.asarray(data, dtype=float), MPI.DOUBLE)
    ptr = np.concatenate([[0], np.cumsum(row_nnz)])
    return sp.csr_matrix((vals, cols, ptr), shape=(layout.n, layout.n))
