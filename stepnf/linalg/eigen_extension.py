"""Shift-invert Lanczos on one factorisation, extended batch by batch with the found modes projected out.

The sparse eigen-solve (:func:`stepnf.linalg.modal_analysis.modal_analysis`) factorises ``K - sigma M`` once
(``sigma`` a tiny negative shift) and runs ARPACK (``scipy.sparse.linalg.eigsh``, mode 3,
``OPinv`` the factorisation) for a first batch of modes. When the run needs more modes (a labelled
master not found yet, the modes just above the highest master), it does not start over: an
*extension* computes the next ones with every mode already found, ``Q = [R, Phi]`` (rigid and
elastic, M-orthonormal), projected out M-orthogonally::

    OP b = P (K - sigma M)^-1 P^T b,    P = I - Q Q^T M

``P`` is the M-orthogonal projector on the complement of span(Q), an invariant subspace of the
pencil; OP is M-self-adjoint, zero on span(Q) and equal to the shift-inverted operator on its
complement, so ARPACK's dominant eigenpairs of OP are the lowest eigenpairs of ``(K, M)`` not in
``Q``. Found modes with residual ``eps`` (ARPACK ``tol`` 1e-12) leave span(Q) an invariant subspace
to ``eps``: the new eigenvalues move by ``O(eps^2 / gap)``, the new vectors by ``O(eps / gap)``,
the accuracy of a single run.

A mode a batch missed (ARPACK returns the wanted number of converged Ritz pairs, which in rare
cases skips one of a cluster) is not in ``Q``: the next batch finds it first, below the highest
mode found so far, and the merge (:func:`merged_modes`, sorted) puts it in its place. The merged set
is then the lowest modes of the model whenever the last batch missed none, the guarantee of a
single run of that size; a final check that every new mode lies above the old ones would refuse
exactly the case the merge repairs. A degenerate pair split between two batches (one twin the last
mode of a batch, the other not found) is the same case without the miss: the second twin is the
lowest mode of the complement, M-orthogonal to the first, and the merged basis spans the pair's
eigenspace; the degenerate groups are recomputed on the merged frequencies.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from stepnf.linalg.block_lanczos import BLOCK_MIN_DOFS, BlockBreakdown, block_shift_invert_modes

#: Modes asked for beyond a known need: a degenerate twin of the last needed mode and a few above it.
TWIN_MARGIN = 4
#: Smallest extension batch. ARPACK builds a Krylov space of ``ncv = max(2k + 1, 20)`` vectors,
#: one shifted solve each, before its first restart: up to k = 9 a batch costs about the same.
MIN_EXTENSION = 9
#: Seed of ARPACK's starting vector (:func:`start_vector`).
START_SEED = 20261201
#: ARPACK's convergence tolerance (residual relative to the Ritz value of the shift-inverted operator).
ARPACK_TOL = 1e-12


def shift_invert_modes(K, M, sigma: float, fac, k: int, Q: np.ndarray | None,
                       calls: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` eigenpairs nearest ``sigma`` in the M-orthogonal complement of span(Q), increasing.

    ``fac.solve`` applies ``(K - sigma M)^-1``; ``Q`` (n, q) holds M-orthonormal columns (rigid
    modes, modes already found) or is ``None``; ``calls[0]`` counts the shifted solves. Returns
    ``(lam, vec)``: eigenvalues ``w^2`` (k,) and M-orthonormal vectors (n, k). Requires
    ``k + q < n``. A MUMPS factorisation of :data:`~stepnf.linalg.block_lanczos.BLOCK_MIN_DOFS` dofs or
    more runs the block iteration of :mod:`stepnf.linalg.block_lanczos` (ARPACK when it breaks down).
    """
    n = K.shape[0]
    if getattr(fac, "backend", None) == "mumps" and n >= BLOCK_MIN_DOFS:  # block solves (block_lanczos)
        try:
            return block_shift_invert_modes(M, sigma, lambda B: fac.solve(B, count=False), k, Q, calls,
                                            tol=ARPACK_TOL, seed=START_SEED)
        except BlockBreakdown:  # an invariant subspace reached, or no convergence in its basis: ARPACK
            pass
    if Q is None or Q.shape[1] == 0:
        def opinv(b: np.ndarray) -> np.ndarray:
            calls[0] += 1
            return fac.solve(b, count=False)
    else:
        MQ = M @ Q

        def opinv(b: np.ndarray) -> np.ndarray:
            calls[0] += 1
            x = fac.solve(b - MQ @ (Q.T @ b), count=False)
            return x - Q @ (MQ.T @ x)

    Op = spla.LinearOperator((n, n), matvec=opinv, dtype=float)
    lam, vec = spla.eigsh(sp.csr_matrix(K), k=k, M=sp.csr_matrix(M), sigma=sigma, which="LM", OPinv=Op,
                          tol=ARPACK_TOL, v0=start_vector(M, Q))
    order = np.argsort(lam)
    return lam[order], vec[:, order]


def start_vector(M, Q: np.ndarray | None, seed: int = START_SEED) -> np.ndarray:
    """ARPACK's starting vector: Gaussian from a fixed seed, M-orthogonal to span(Q).

    Without one, ARPACK draws it from a generator whose state persists between calls in a
    process, so the same model gave modes (and T, through them) that differed at round-off level
    with the eigen-solves run before it (measured: DPIM against DNF on a small cap, 3e-9 to 6e-8
    relative over ten histories). A fixed start makes every eigen-solve repeatable.
    """
    v = np.random.default_rng(seed).standard_normal(M.shape[0])
    if Q is not None and Q.shape[1]:
        v = v - Q @ ((M @ Q).T @ v)
    return v


def extension_size(found: int, need: int) -> int:
    """Modes the next batch asks for, ``found`` elastic modes in hand and ``need`` known to be needed.

    The known deficit plus :data:`TWIN_MARGIN`; when the need is a frequency or a labelled mode
    its count is unknown, and the batch is at least :data:`MIN_EXTENSION` (a smaller one costs as
    many solves) and half the modes found: the basis grows by at least 1.5x per batch, so it
    overshoots the modes needed by at most half and reaches them in ``log_1.5`` batches. On the
    38k-dof shell cap (rigid modes projected) a batch of 9 modes on top of 6 costs 37 solves,
    of 12 to 22 modes about 60; a single run of 6 modes 32, of 15 about 41, of 28 about 73.
    """
    return max(need - found + TWIN_MARGIN, MIN_EXTENSION, found // 2)


def merged_modes(omega: np.ndarray, phi: np.ndarray, omega_new: np.ndarray,
                 phi_new: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Found modes and a batch of new ones (M-orthogonal to them), sorted by frequency (stable:
    equal frequencies keep the found mode first). ``omega`` (m,), ``phi`` (n, m)."""
    w = np.concatenate([omega, omega_new])
    order = np.argsort(w, kind="stable")
    return w[order], np.column_stack([phi, phi_new])[:, order]
