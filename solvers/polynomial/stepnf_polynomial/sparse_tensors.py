"""Sparse force tensors as coordinate lists: checking, canonical form and O(nnz) evaluation.

Convention (SSMTool's / YetAnotherFEcode's ``sptensor`` one: ``expand_tensor`` contracts every index but
the first with the field): a quadratic tensor of ``k`` entries ``(i, j, l) -> g`` and a cubic one of
entries ``(i, j, l, p) -> h`` give the internal force

    f_i(x) = sum_j K_ij x_j + sum_{(i, j, l) in G} g x_j x_l + sum_{(i, j, l, p) in H} h x_j x_l x_p

Entries with the same subscripts add up. The lists need not be symmetric in the lower indices: only f
matters (STEP sees nothing else), so an entry and its permutations in the lower indices are one monomial
of f. :class:`CooTensor` keeps that f-equivalent canonical form (lower indices sorted, duplicates summed,
zeros dropped), which also makes a symmetrised list 2x (G) or 6x (H) shorter. The exact bilinear and
trilinear forms it offers (:meth:`CooTensor.polar`) are the symmetric ones, those STEP recovers.
"""
from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp

#: Products of gathered columns are formed for at most this many (entry, field) pairs at once (32 MB):
#: a batch of m fields is cut so that memory stays O(nnz + m n) plus this constant.
CHUNK_ENTRIES = 2**22


class ArrayError(ValueError):
    """An array of a system file (or given in memory) is unusable; the message names the file and the array."""


def coo_lists(subs, vals, n: int, order: int, *, name: str, source: str, base: int = 0):
    """Checked ``(subs (k, order) int64 0-based, vals (k,) float)`` of the tensor ``name`` (``"G"``, ``"H"``).

    ``base`` is 0 (numpy, HDF5) or 1 (MATLAB). Raises ValueError naming ``source`` and the array for:
    a wrong shape, lengths that differ, non-integer or out-of-range subscripts (a 0 in 1-based ones
    included) and non-finite values (an :class:`ArrayError`).
    """
    sk, vk = f"{name}_subs", f"{name}_vals"
    s = np.asarray(subs)
    v = np.asarray(vals)
    if s.size == 0 and v.size == 0:  # an empty tensor (MATLAB's empty sptensor: zeros(0, d)), in whatever
        s, v = s.reshape(0, order), v.reshape(0)  # empty shape it was stored (v7.3: (d, 0) or (0, d))
    if s.ndim != 2 or s.shape[1] != order:
        raise ArrayError(f"{source}: array {sk!r} has shape {s.shape}, expected (k, {order}): one row of "
                         f"{order} subscripts per entry of {name}")
    if v.ndim == 2 and 1 in v.shape:  # a MATLAB column (k, 1) or row (1, k)
        v = v.ravel()
    if v.ndim != 1 or len(v) != len(s):
        raise ArrayError(f"{source}: arrays {sk!r} and {vk!r} differ in length: {len(s)} rows of subscripts, "
                         f"values of shape {np.asarray(vals).shape}; expected one value per row")
    if s.dtype.kind not in "iuf" or v.dtype.kind not in "biuf":
        raise ArrayError(f"{source}: arrays {sk!r} and {vk!r} must hold numbers (got {s.dtype}, {v.dtype})")
    v = v.astype(float)
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        raise ArrayError(f"{source}: array {vk!r} holds NaN or inf (entry {bad[0] + int(base)}, {bad.size} in all)")
    if s.dtype.kind == "f":
        off = ~np.isfinite(s) | (s != np.round(s))
        if off.any():
            r = int(np.flatnonzero(off.any(axis=1))[0])
            raise ArrayError(f"{source}: array {sk!r} holds a non-integer subscript {s[r].tolist()} (row {r + base})")
        huge = np.abs(s) >= 2.0 ** 62  # beyond int64: range-checked as floats, no cast warning
        if huge.any():
            r = int(np.flatnonzero(huge.any(axis=1))[0])
            raise ArrayError(f"{source}: array {sk!r} row {r + base} holds subscripts {s[r].tolist()} outside "
                             f"{base}..{n - 1 + base} ({'1' if base else '0'}-based, n = {n} dofs, the size of M)")
    s = s.astype(np.int64) - int(base)
    out = (s < 0) | (s >= n)
    if out.any():
        r = int(np.flatnonzero(out.any(axis=1))[0])
        got = (s[r] + base).tolist()
        why = " (.mat subscripts are MATLAB's, 1-based: a 0 is never one)" if base == 1 and 0 in got else ""
        raise ArrayError(f"{source}: array {sk!r} row {r + base} holds subscripts {got} outside "
                         f"{base}..{n - 1 + base} ({'1' if base else '0'}-based, n = {n} dofs, the size of M){why}")
    return s, v


class CooTensor:
    """The f-equivalent canonical form of a force tensor of order ``d + 1`` (d = 2: G, d = 3: H).

    Built by :meth:`from_lists` (0-based checked lists, e.g. from :func:`coo_lists`) or :meth:`from_dense`;
    holds ``rows`` (k,), ``lower`` (k, d) sorted ascending in each row, ``vals`` (k,) and the scatter
    matrix ``R`` (n, k) (``R[rows[e], e] = vals[e]``), so that ``f = R @ prod_c x[lower[:, c]]``.
    """

    def __init__(self, rows: np.ndarray, lower: np.ndarray, vals: np.ndarray, n: int):
        self.n, self.degree = int(n), lower.shape[1]
        self.rows, self.lower, self.vals = rows, lower, vals
        self.R = sp.csr_matrix((vals, (rows, np.arange(len(rows)))), shape=(self.n, len(rows)))

    @classmethod
    def from_lists(cls, subs: np.ndarray, vals: np.ndarray, n: int) -> "CooTensor":
        """Canonical form of checked 0-based lists: lower indices sorted, duplicates summed, zeros dropped."""
        d = subs.shape[1] - 1
        if not len(subs):
            return cls(np.zeros(0, np.int64), np.zeros((0, d), np.int64), np.zeros(0), n)
        key = np.concatenate([subs[:, :1], np.sort(subs[:, 1:], axis=1)], axis=1)
        if n ** (d + 1) < 2**63:  # one int64 per entry: a flat sort, ~6x faster than unique rows
            flat = np.zeros(len(key), np.int64)
            for c in range(d + 1):
                flat = flat * n + key[:, c]
            ufl, inverse = np.unique(flat, return_inverse=True)
            uniq = np.empty((len(ufl), d + 1), np.int64)
            for c in range(d, -1, -1):
                ufl, uniq[:, c] = np.divmod(ufl, n)
        else:
            uniq, inverse = np.unique(key, axis=0, return_inverse=True)
        summed = np.bincount(inverse.ravel(), weights=vals, minlength=len(uniq))
        keep = summed != 0
        return cls(uniq[keep, 0], uniq[keep, 1:], summed[keep], n)

    @classmethod
    def from_dense(cls, T: np.ndarray) -> "CooTensor":
        """The same f as a dense tensor (n, ..., n)."""
        subs = np.argwhere(T)
        return cls.from_lists(subs.astype(np.int64), T[tuple(subs.T)].astype(float), T.shape[0])

    @property
    def nnz(self) -> int:
        return len(self.vals)

    def forces(self, U: np.ndarray) -> np.ndarray:
        """The tensor's part of f for fields U (m, n), one per row: (m, n), in O(nnz m) time."""
        out = np.empty((len(U), self.n))
        if not self.nnz:
            out[:] = 0.0
            return out
        step = max(1, CHUNK_ENTRIES // self.nnz)
        for a in range(0, len(U), step):
            Ut = np.ascontiguousarray(U[a:a + step].T)  # (n, mc): gathering rows keeps each product contiguous
            P = Ut[self.lower[:, 0]]
            for c in range(1, self.degree):
                P *= Ut[self.lower[:, c]]
            out[a:a + step] = (self.R @ P).T
        return out

    def polar(self, *fields: np.ndarray) -> np.ndarray:
        """The symmetric multilinear form ``T(u, v[, w])`` (n,) whose diagonal ``T(u, u[, u])`` is this part of f."""
        assert len(fields) == self.degree
        perms = list(itertools.permutations(range(self.degree)))
        P = np.zeros(self.nnz)
        for p in perms:
            term = np.ones(self.nnz)
            for c, f in zip(p, fields):
                term *= f[self.lower[:, c]]
            P += term
        return self.R @ (P / len(perms))

    def tangent(self, u: np.ndarray) -> sp.csr_matrix:
        """The derivative of this part of f at ``u``: a sparse (n, n) matrix (not symmetric for a
        non-conservative f)."""
        cols, vals = [], []
        for c in range(self.degree):
            rest = np.ones(self.nnz)
            for o in range(self.degree):
                if o != c:
                    rest *= u[self.lower[:, o]]
            cols.append(self.lower[:, c])
            vals.append(self.vals * rest)
        rows = np.tile(self.rows, self.degree)
        return sp.csr_matrix((np.concatenate(vals), (rows, np.concatenate(cols))), shape=(self.n, self.n))
