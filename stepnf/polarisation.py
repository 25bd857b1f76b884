"""Quadratic and cubic terms applied to known vectors, from the black-box internal force only.

For ``f(x) = K x + G(x, x) + H(x, x, x)`` (G, H symmetric multilinear) and a
probe scale ``s > 0``::

    G(z, z) = [f(s z) + f(-s z)] / (2 s^2)                     (2 evaluations)
    H3(z)  = H(z, z, z) = [f(s z) - f(-s z) - 2 s K z] / (2 s^3)  (2 evaluations)
    G(u, v) = [G(u+v, u+v) - G(u-v, u-v)] / 4                  (4 evaluations, 2 if u is v)
    H(u, u, v) = [H3(u+v) - H3(u-v) - 2 H3(v)] / 6              (6 evaluations)
    H(u, v, w) = (1/24) sum_{s2, s3 = +-1} s2 s3 H3(u + s2 v + s3 w)   (8 evaluations)

All exact for a cubic f (round-off aside). Every field of one request goes
to the black box in ONE batched call ``forces(U)``, ``U`` of shape ``(m, n)``
(one field per row: the convention of
:meth:`stepnf.adapter.SolverAdapter.internal_forces` and of
:class:`stepnf.step.ForceEvaluator`, which counts them).

**Scaling and round-off.** Multilinearity lets each term be computed on unit
vectors: ``G(u, v) = |u| |v| G(u/|u|, v/|v|)``, so that polarisation never
subtracts terms of very different sizes (without it, ``G(u, v)`` with
``|v| << |u|`` would lose ``|u|/|v|`` digits). Each probe field ``z`` is then
sent as ``s z`` with ``max_i |s z_i| = probe`` (a displacement in model
units). With ``eps`` the relative precision of one force evaluation (1.1e-16
for an exact polynomial in float64; the solver's printed digits otherwise)
and ``l = probe``, the absolute error of a recovered term is about::

    G: eps (|K| l + |G| l^2 + |H| l^3) / l^2      H: eps (|K| l + |G| l^2 + |H| l^3) / l^3

i.e. relative to the term itself::

    G: eps (|K| / (|G| l) + 1 + |H| l / |G|)      H: eps (|K| / (|H| l^2) + |G| / (|H| l) + 1)

(measured on a random 9-dof system with |K|, |G|, |H| ~ 10: G 3.6e-13 and H
1.7e-10 at l = 1e-3, both ~5e-16 at l = 1, G 1.1e-13 at l = 1e3). The best
probe is of the order of the lengths ``|K|/|G|`` and ``sqrt(|K|/|H|)`` at
which the nonlinear forces equal the linear one (a shell's thickness; STEP's
amplitude). For an f that is not an exact cubic (shells with finite
rotations) the quartic and quintic parts contaminate G and H by
``O(l^2)`` relative: then ``probe`` trades truncation against round-off, as
STEP's check amplitude measures.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from .errors import NumericalError

ForceBatch = Callable[[np.ndarray], np.ndarray]

#: Polarisation weights: (coefficient, sign of v, sign of w) of H3 combinations, per pattern.
_H_UVW = [(s2 * s3 / 24.0, s2, s3) for s2 in (1, -1) for s3 in (1, -1)]


@dataclass
class PolarisationStats:
    """Work of one :class:`Polariser` request: fields sent, terms returned, batched calls."""

    force_evaluations: int = 0
    calls: int = 0
    quadratic_terms: int = 0
    cubic_terms: int = 0
    history: list[int] = field(default_factory=list)


class Polariser:
    """``G(u, v)`` and ``H(u, v, w)`` of batches of vectors from ``forces`` (see the module docstring).

    ``forces(U)``: internal forces (m, n) of the fields ``U`` (m, n), model
    units. ``K``: linear stiffness (n, n), used to remove ``K z`` from the odd
    part. ``probe``: the largest displacement of each probe field (model
    length units, > 0).
    """

    def __init__(self, forces: ForceBatch, K: sp.spmatrix | np.ndarray, probe: float):
        if not (probe > 0 and np.isfinite(probe)):
            raise NumericalError(f"polarisation: the probe displacement must be a positive length, got {probe!r}")
        self.forces = forces
        self.K = K
        self.probe = float(probe)
        self.stats = PolarisationStats()

    # ------------------------------------------------------------ public API
    def terms(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]],
              triples: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        """``(Gs, Hs)``: ``Gs[i] = G(*pairs[i])`` (len(pairs), n), ``Hs[j] = H(*triples[j])`` (len(triples), n).

        One batched call of ``forces`` for everything. A pair ``(u, u)`` or a
        triple with repeated entries (the same object, or equal arrays) uses
        the cheaper formulas of the module docstring. Zero vectors give zero
        terms without evaluation.
        """
        fields: list[np.ndarray] = []   # unit-size probe directions z (before the +-s scaling)
        odd: list[bool] = []            # H3 wanted (odd part) rather than G(z, z) (even part)
        recipes_g: list[tuple[float, list[tuple[float, int]]]] = []
        recipes_h: list[tuple[float, list[tuple[float, int]]]] = []

        def probe(z: np.ndarray, want_odd: bool) -> int:
            fields.append(z)
            odd.append(want_odd)
            return len(fields) - 1

        for u, v in pairs:
            (nu, u1), (nv, v1) = _unit(u), _unit(v)
            if nu == 0 or nv == 0:
                recipes_g.append((0.0, []))
            elif _same(u1, v1):
                recipes_g.append((nu * nv, [(1.0, probe(u1, False))]))
            else:
                recipes_g.append((nu * nv, [(0.25, probe(u1 + v1, False)), (-0.25, probe(u1 - v1, False))]))
        for u, v, w in triples:
            recipes_h.append(self._cubic_recipe(u, v, w, probe))
        self.stats.quadratic_terms += len(pairs)
        self.stats.cubic_terms += len(triples)
        values = self._evaluate(fields, odd)
        n = self._n(pairs, triples)
        return _combine(recipes_g, values, n), _combine(recipes_h, values, n)

    def quadratic(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """``G(u, v)`` for each pair, (len(pairs), n): :meth:`terms` without cubic terms."""
        return self.terms(pairs, [])[0]

    def cubic(self, triples: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
        """``H(u, v, w)`` for each triple, (len(triples), n): :meth:`terms` without quadratic terms."""
        return self.terms([], triples)[1]

    # -------------------------------------------------------------- internals
    @staticmethod
    def _cubic_recipe(u, v, w, probe) -> tuple[float, list[tuple[float, int]]]:
        units = [_unit(x) for x in (u, v, w)]
        scale = float(np.prod([s for s, _ in units]))
        if scale == 0:
            return 0.0, []
        a, b, c = (x for _, x in units)
        if _same(a, b) and _same(b, c):
            return scale, [(1.0, probe(a, True))]
        # bring a repeated vector first: H(x, x, y)
        if _same(a, c):
            b, c = c, b
        elif _same(b, c):
            a, c = c, a
        if _same(a, b):  # H(a, a, c) = [H3(a + c) - H3(a - c) - 2 H3(c)] / 6
            return scale, [(1 / 6, probe(a + c, True)), (-1 / 6, probe(a - c, True)), (-1 / 3, probe(c, True))]
        return scale, [(wt, probe(a + s2 * b + s3 * c, True)) for wt, s2, s3 in _H_UVW]

    def _evaluate(self, fields: list[np.ndarray], odd: list[bool]) -> np.ndarray:
        """G(z, z) or H3(z) of every probe direction, from ONE call with the fields +-s z."""
        if not fields:
            return np.zeros((0, 0))
        Z = np.asarray(fields)
        peak = np.abs(Z).max(axis=1)
        if np.any(peak == 0):  # u - v = 0 for two equal unit vectors given as different objects
            peak = np.where(peak == 0, 1.0, peak)
        s = self.probe / peak
        U = np.concatenate([s[:, None] * Z, -s[:, None] * Z])
        F = np.asarray(self.forces(U), dtype=float)
        m = len(Z)
        if F.shape != U.shape:
            raise NumericalError(f"polarisation: forces returned shape {F.shape} for fields {U.shape}")
        if not np.all(np.isfinite(F)):
            raise NumericalError("polarisation: the internal forces contain NaN or inf")
        self.stats.force_evaluations += len(U)
        self.stats.calls += 1
        self.stats.history.append(len(U))
        fp, fm = F[:m], F[m:]
        out = (fp + fm) / (2 * s[:, None] ** 2)  # G(z, z)
        o = np.asarray(odd)
        if o.any():
            KZ = np.asarray(self.K @ Z[o].T).T
            out[o] = (fp[o] - fm[o] - 2 * s[o, None] * KZ) / (2 * s[o, None] ** 3)
        return out

    @staticmethod
    def _n(pairs, triples) -> int:
        first = next(iter(pairs), None) or next(iter(triples), None)
        return 0 if first is None else len(first[0])


def _unit(x: np.ndarray) -> tuple[float, np.ndarray]:
    """(|x|_inf, x / |x|_inf), (0, x) for a zero vector."""
    x = np.asarray(x, dtype=float)
    nx = float(np.abs(x).max()) if x.size else 0.0
    return (nx, x / nx) if nx > 0 else (0.0, x)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a is b or np.array_equal(a, b)


def _combine(recipes: list[tuple[float, list[tuple[float, int]]]], values: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros((len(recipes), n))
    for i, (scale, parts) in enumerate(recipes):
        for wt, j in parts:
            out[i] += wt * values[j]
        out[i] *= scale
    return out


def count_evaluations(n_pairs_distinct: int, n_pairs_square: int, n_cubes: int, n_uuv: int, n_uvw: int) -> int:
    """Force evaluations a request costs.

    4 per G(u, v), 2 per G(u, u) and H(u, u, u), 6 per H(u, u, v), 8 per H(u, v, w).
    """
    return 4 * n_pairs_distinct + 2 * n_pairs_square + 2 * n_cubes + 6 * n_uuv + 8 * n_uvw
