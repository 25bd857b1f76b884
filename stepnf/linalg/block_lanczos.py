"""Block shift-invert Lanczos: the sparse eigen-solve's Krylov iteration with block solves.

ARPACK (:func:`stepnf.linalg.eigen_extension.shift_invert_modes`) applies the shift-inverted operator to
one vector at a time: on a large model each application reads MUMPS's factors once, and that is the
eigen-stage's cost (measured on the 250k-dof cap, one thread: 0.20 s per single solve, 80 of them,
against 0.49 s for a block of 16 columns: 6.6x less per column). Here the Krylov space is built a block
of ``b`` columns at a time::

    OP = P (K - sigma M)^-1 P^T M,     P = I - Q Q^T M  (the found modes Q projected out)

``OP`` is self-adjoint in the M-inner product. With ``V_j`` (n, b) the M-orthonormal blocks,
``W = OP V_j`` is M-orthogonalised against every previous block (classical Gram-Schmidt, twice: full
reorthogonalisation) and M-orthonormalised (Cholesky QR, twice) into ``V_{j+1}`` (one product with M per block, after the Gram-Schmidt); the coefficients make
the block tridiagonal projection ``H = V^T M OP V`` and the Krylov relation
``OP V = V H + V_{j+1} B E^T``. A Ritz pair ``(theta, V s)`` of ``H`` has the residual
``|| OP V s - theta V s ||_M = || B s_last ||``, ``s_last`` the last block's rows of ``s``: the
iteration stops when the ``k`` largest ``theta`` (the eigenvalues ``lam = sigma + 1 / theta`` nearest
``sigma`` from above) all have a residual at most ``tol * theta``, ARPACK's own criterion (its
``tol``). Their vectors are M-orthonormal Ritz vectors; the eigenvalues and vectors agree with ARPACK's
to the tolerance (a block method also finds both twins of a degenerate pair in one run).

A breakdown (the new block nearly inside the space built, so its Gram matrix is not positive definite:
an invariant subspace reached, or a model too small for the block) or no convergence within
``max_dim`` vectors raises :class:`BlockBreakdown`; the caller then runs ARPACK. Memory: the basis
``V`` and ``M V`` (2 m n doubles, ``m`` at most ``max_dim``), against ARPACK's ``2 k + 1`` vectors.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from stepnf.linalg.block_product import block_product

#: Columns per block. MUMPS's block solve costs per column 2.5x less at 6 columns and 5-6.6x less at 16
#: than one by one (112k and 250k dofs), but a block Krylov space of b columns per step reaches a lower
#: polynomial degree for its size: 24 modes of the 250k-dof cap took 92 / 136 / 192 solves with blocks of
#: 4 / 8 / 16 (unrestarted), 15.2 / 16.4 / 20.2 s, ARPACK 63 single solves 30.0 s (one thread, loaded
#: machine); at 1M dofs 71.6 s (4) and 70.4 s (8) against ARPACK's 115 s. Blocks of 4 need the smallest basis.
BLOCK = 4
#: Smallest model (dofs) whose MUMPS eigen-solve uses the block iteration; below it ARPACK, whose
#: single solves take milliseconds there. Measured (bench/eigen_block.py, 31 modes of the cap, one thread,
#: a loaded machine): the block iteration 2.05x / 1.87x / 1.94x / 2.69x / 1.86x faster at 10k / 22k / 44k /
#: 250k / 1M dofs (0.5 s gained at 10k); the threshold takes the main job's 38k-dof cap and keeps the small
#: models of the tests on ARPACK.
BLOCK_MIN_DOFS = 20_000
#: Restarts before giving up (the caller then runs ARPACK).
MAX_RESTARTS = 20


class BlockBreakdown(RuntimeError):
    """The block iteration cannot go on (see the module docstring): run ARPACK instead."""


def block_shift_invert_modes(M: sp.spmatrix, sigma: float, solve, k: int, Q: np.ndarray | None,
                             calls: list[int], *, tol: float, seed: int, block: int = BLOCK,
                             max_dim: int | None = None,
                             max_restarts: int = MAX_RESTARTS) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` eigenpairs of ``(K, M)`` nearest ``sigma`` (above it) in the M-orthogonal complement of
    span(Q), increasing: ``(lam (k,), vec (n, k))`` with M-orthonormal ``vec``.

    ``solve(B)`` applies ``(K - sigma M)^-1`` to the columns of ``B`` (n, c) in one call; ``Q`` (n, q)
    M-orthonormal columns or ``None``; ``calls[0]`` counts the columns solved; ``tol`` the residual
    bound relative to ``theta``; ``seed`` the starting block's. ``max_dim``: the basis's largest size
    (default :func:`basis_size`, at most ``n - q - b``), beyond which the iteration restarts from its
    best ``k + b`` Ritz vectors, at most ``max_restarts`` times. Raises :class:`BlockBreakdown`.
    """
    n = M.shape[0]
    q = 0 if Q is None else Q.shape[1]
    Mb = block_product(M)
    MQ = Mb @ Q if q else None
    b = max(1, min(block, k))
    keep = k + b  # Ritz vectors kept at a restart
    max_dim = min(basis_size(k, b) if max_dim is None else max_dim, n - q - b)
    if k <= 0 or max_dim < keep + b:
        raise BlockBreakdown(f"{n} dofs, {q} modes projected out, a basis of at most {max_dim}: no room for "
                             f"{k} modes in blocks of {b}")

    def project(X: np.ndarray) -> np.ndarray:  # P X: M-orthogonal to Q
        return X - Q @ (MQ.T @ X) if q else X

    V0 = project(np.random.default_rng(seed).standard_normal((n, b)))
    V0, MV0, _ = _orthonormal(V0, Mb @ V0)
    Vs, MVs = [V0], [MV0]  # blocks of the basis (the first one after a restart holds the kept Ritz vectors)
    H = np.zeros((max_dim + b, max_dim + b))
    m, restarts = b, 0
    while True:
        MVj = MVs[-1]
        W = project(solve(MVj - MQ @ (Q.T @ MVj) if q else MVj))  # OP V_j = P (K - sigma M)^-1 P^T M V_j
        calls[0] += b
        # the projection's last column block: c = V^T M W (twice: full reorthogonalisation)
        c = np.zeros((m, b))
        for _ in range(2):
            i = 0
            for V, MV in zip(Vs, MVs):
                ci = MV.T @ W
                W -= V @ ci
                c[i:i + V.shape[1]] += ci
                i += V.shape[1]
        H[:m, m - b:m] = c
        Vn, MVn, B = _orthonormal(W, Mb @ W)
        theta, S = np.linalg.eigh(0.5 * (H[:m, :m] + H[:m, :m].T))
        top = np.argsort(theta)[::-1][:k]
        res = np.linalg.norm(B @ S[m - b:m, top], axis=0)  # || OP y - theta y ||_M of each Ritz pair
        if len(top) == k and np.all(theta[top] > 0) and np.all(res <= tol * theta[top]):
            order = top[np.argsort(1.0 / theta[top])]
            return sigma + 1.0 / theta[order], _combine(Vs, S[:, order])
        if m + b <= max_dim:
            H[m:m + b, m - b:m] = B
            Vs.append(Vn)
            MVs.append(MVn)
            m += b
            continue
        if restarts == max_restarts or len(top) < k:
            worst = float(np.max(res / np.abs(theta[top])))
            raise BlockBreakdown(f"no convergence within {m} vectors and {restarts} restarts (worst relative "
                                 f"residual {worst:.1e})")
        # thick restart: the best ``keep`` Ritz vectors Y (OP Y = Y diag(theta) + V_n B S_last), then V_n
        best = np.argsort(theta)[::-1][:keep]
        Sk = S[:, best]
        Vs, MVs = [_combine(Vs, Sk), Vn], [_combine(MVs, Sk), MVn]
        H[:] = 0.0
        H[:keep, :keep] = np.diag(theta[best])
        H[keep:keep + b, :keep] = B @ Sk[m - b:m]
        m = keep + b
        restarts += 1


def basis_size(k: int, b: int) -> int:
    """The basis's default largest size for ``k`` modes in blocks of ``b``, past which it restarts:
    ``2 k + 2 b`` vectors, with ``M V`` beside twice ARPACK's ``2 k + 1`` (at 1M dofs and k = 24,
    56 vectors: 0.9 GB). Measured on the 250k-dof cap, 24 modes, blocks of 4: 112 solves in 12.7 s
    (``3 k + 2 b``: 92 solves, 10.9 s, 1.4x the memory)."""
    return 2 * k + 2 * b


def _combine(blocks: list[np.ndarray], S: np.ndarray) -> np.ndarray:
    """``[blocks] @ S`` without joining the blocks."""
    out, i = None, 0
    for X in blocks:
        part = X @ S[i:i + X.shape[1]]
        out = part if out is None else out + part
        i += X.shape[1]
    return out


def _orthonormal(W: np.ndarray, MW: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(V, M V, B)`` with ``W = V B``, ``V`` M-orthonormal and ``B`` upper triangular: Cholesky QR
    twice in the M-inner product (``MW = M W`` given; it follows ``W`` through the triangular factors,
    no further product with M). Raises :class:`BlockBreakdown` on a (nearly) rank-deficient ``W``."""
    B = np.eye(W.shape[1])
    for _ in range(2):
        G = W.T @ MW
        G = 0.5 * (G + G.T)
        scale = float(np.max(np.diag(G))) if G.size else 0.0
        try:
            L = np.linalg.cholesky(G)
        except np.linalg.LinAlgError as exc:
            raise BlockBreakdown("the new block is (nearly) inside the Krylov space built") from exc
        if not scale > 0 or float(np.min(np.diag(L))) ** 2 < 1e-24 * scale:
            raise BlockBreakdown("the new block is (nearly) rank deficient")
        Linv_T = np.linalg.inv(L).T  # W L^-T: M-orthonormal columns
        W = W @ Linv_T
        MW = MW @ Linv_T
        B = L.T @ B
    return W, MW, B
