"""Sparse pencils (K, M) with known spectra for the eigen-solve's tests.

Square membranes (5-point Laplacian, uniform mass :data:`RHO` per node; clamped, or free with the constant
as rigid mode), whose spectrum is known in closed form (``(mu_i + mu_j) / RHO``, exact twin pairs
``i != j``), and a braced spring lattice on a grid (six rigid modes, square symmetry: exact pairs).
"""
from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp

RHO = 3.0


def membrane(m: int, free: bool):
    """(K, M, omega) of an m x m membrane: 5-point Laplacian, mass RHO per node; ``omega`` exact (sorted,
    rigid mode of the free membrane included as 0)."""
    if free:
        d = sp.diags([-np.ones(m - 1), np.r_[1.0, 2 * np.ones(m - 2), 1.0], -np.ones(m - 1)], [-1, 0, 1])
        mu = 2 - 2 * np.cos(np.arange(m) * np.pi / m)
    else:
        d = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
        mu = 2 - 2 * np.cos(np.arange(1, m + 1) * np.pi / (m + 1))
    eye = sp.identity(m)
    K = (sp.kron(d, eye) + sp.kron(eye, d)).tocsr()
    M = (RHO * sp.identity(m * m)).tocsr()
    return K, M, np.sqrt(np.sort(np.add.outer(mu, mu).ravel()) / RHO)


def lattice(a: int = 8, b: int = 8, c: int = 3, h=(1.0, 1.0, 0.5)):
    """(K, M, X, D): nodes on an a x b x c grid (spacings h) joined by axial springs (stiffness 1/length)
    across every edge, face and body diagonal of each cell: braced, six rigid modes; mass 2 per dof."""
    idx = np.arange(a * b * c).reshape(a, b, c)
    X = np.stack(np.meshgrid(*(np.arange(s) * hh for s, hh in zip((a, b, c), h)), indexing="ij"), -1).reshape(-1, 3)
    offsets = [d for d in itertools.product((0, 1), repeat=3) if any(d)]
    offsets += [(1, -1, 0), (1, 0, -1), (0, 1, -1), (1, 1, -1), (1, -1, 1), (-1, 1, 1)]
    rows, cols, vals = [], [], []
    for i, j, k in itertools.product(range(a), range(b), range(c)):
        for d in offsets:
            p, q, r = i + d[0], j + d[1], k + d[2]
            if not (0 <= p < a and 0 <= q < b and 0 <= r < c):
                continue
            n1, n2 = idx[i, j, k], idx[p, q, r]
            e = X[n2] - X[n1]
            length = np.linalg.norm(e)
            ke = np.outer(e, e) / length**3
            for s, t, sign in ((n1, n1, 1), (n2, n2, 1), (n1, n2, -1), (n2, n1, -1)):
                for u, v in itertools.product(range(3), repeat=2):
                    rows.append(3 * s + u)
                    cols.append(3 * t + v)
                    vals.append(sign * ke[u, v])
    n = 3 * a * b * c
    K = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
    return (K + K.T) / 2, (2.0 * sp.identity(n)).tocsr(), np.repeat(X, 3, axis=0), np.tile([0, 1, 2], a * b * c)


def outside(A: np.ndarray, B: np.ndarray, M) -> float:
    """Largest M-norm of a column of A outside span(B) (B M-orthonormal): sin of the largest angle."""
    E = A - B @ (B.T @ (M @ A))
    return float(np.sqrt(np.max(np.einsum("ij,ij->j", E, M @ E))))


def eigenspaces(values: np.ndarray, tol: float) -> list[list[int]]:
    """Runs of increasing ``values`` (frequencies or eigenvalues) equal to ``tol`` (relative): the eigenspaces."""
    out = [[0]]
    for s in range(1, len(values)):
        if values[s] - values[s - 1] <= tol * values[s]:
            out[-1].append(s)
        else:
            out.append([s])
    return out
