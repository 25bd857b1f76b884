"""Quadratic and cubic terms applied to known vectors, from the black-box internal force only.

For ``f(x) = K x + G(x, x) + H(x, x, x)`` (G, H symmetric multilinear) and a
probe scale ``s > 0``::

    G(z, z) = [f(s z) + f(-s z)] / (2 s^2)                     (2 evaluations)
    H3(z)  = H(z, z, z) = [f(s z) - f(-s z) - 2 s K z] / (2 s^3)  (2 evaluations)
    G(u, v) = [G(u+v, u+v) - G(u-v, u-v)] / 4                  (4 evaluations, 2 if u is v)
    H(u, u, v) = [H3(u+v) - H3(u-v) - 2 H3(v)] / 6              (6 evaluations)
    H(u, v, w) = (1/24) sum_{s2, s3 = +-1} s2 s3 H3(u + s2 v + s3 w)   (8 evaluations)

All exact for a cubic f (round-off aside); the DPIM reuses these formulas with probe directions
shared across its orders (:mod:`stepnf.dpim.nonlinear_terms`). Every field of one request goes
to the black box in ONE batched call ``forces(U)``, ``U`` of shape ``(m, n)``
(one field per row: the convention of
:meth:`stepnf.plugin.adapter.SolverAdapter.internal_forces` and of
:class:`stepnf.step.forces.ForceEvaluator`, which counts them).

**Scaling and round-off.** Multilinearity lets each term be computed on unit
vectors: ``G(u, v) = |u| |v| G(u/|u|, v/|v|)``, so that polarisation never
subtracts terms of very different sizes (without it, ``G(u, v)`` with
``|v| << |u|`` would lose ``|u|/|v|`` digits). The probe fields ``z`` of one
term are then sent as ``s z``, one ``s`` for all of them, with the largest
``max_i |s z_i| = probe`` (a displacement in model units). With one ``s``
per term, the linear parts ``s K z`` of the H3 values cancel in the term's
sum (the fields' weights sum to the zero vector: ``(a+c) - (a-c) - 2c``,
``sum s2 s3 (a + s2 b + s3 c)``), so ``K z`` is computed only for a lone
``H(z, z, z)`` (a sparse product per field saved: it cost as much as the
force evaluation on the 38k-dof cap). With ``eps`` the relative precision of one force evaluation (1.1e-16
for an exact polynomial in float64; the solver's printed digits otherwise)
and ``l = probe``, the absolute error of a recovered term is about::

    G: eps (|K| l + |G| l^2 + |H| l^3) / l^2      H: eps (|K| l + |G| l^2 + |H| l^3) / l^3

i.e. relative to the term itself::

    G: eps (|K| / (|G| l) + 1 + |H| l / |G|)      H: eps (|K| / (|H| l^2) + |G| / (|H| l) + 1)

(measured on a random 9-dof system with |K|, |G|, |H| ~ 10: G 7e-13 and H
1.0e-9 at l = 1e-3, both ~2e-15 at l = 1, G 2.4e-13 at l = 1e3; with a scale
per field and K z removed from each, 5e-13, 7.5e-10, 2e-15 and 2.5e-13). The best
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

from stepnf.errors import NumericalError

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
        self.forces = forces
        self.K = K
        self.probe = checked_probe(probe)
        self.stats = PolarisationStats()

    # ------------------------------------------------------------ public API
    def terms(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]],
              triples: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        """``(Gs, Hs)``: ``Gs[i] = G(*pairs[i])`` (len(pairs), n), ``Hs[j] = H(*triples[j])`` (len(triples), n).

        One batched call of ``forces`` for everything. A pair ``(u, u)`` or a
        triple with repeated entries (the same object, or equal arrays) uses
        the cheaper formulas of the module docstring. Zero vectors give zero
        terms without evaluation. A vector given several times as the same
        object is normalised once.
        """
        plan = _ProbePlan()
        recipes_g = [self._quadratic_recipe(u, v, plan) for u, v in pairs]
        recipes_h = [self._cubic_recipe(u, v, w, plan) for u, v, w in triples]
        self.stats.quadratic_terms += len(pairs)
        self.stats.cubic_terms += len(triples)
        values = self._evaluate(plan)
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
    def _quadratic_recipe(u, v, plan: "_ProbePlan") -> tuple[float, list[tuple[float, int]]]:
        (nu, a), (nv, b) = plan.unit(u), plan.unit(v)
        if nu == 0 or nv == 0:
            return 0.0, []
        if plan.same(a, b):
            return nu * nv, [(1.0, plan.probe([(1.0, a)], False))]
        plan.new_recipe()
        return nu * nv, [(0.25, plan.probe([(1.0, a), (1.0, b)], False)),
                         (-0.25, plan.probe([(1.0, a), (-1.0, b)], False))]

    @staticmethod
    def _cubic_recipe(u, v, w, plan: "_ProbePlan") -> tuple[float, list[tuple[float, int]]]:
        units = [plan.unit(x) for x in (u, v, w)]
        scale = float(np.prod([s for s, _ in units]))
        if scale == 0:
            return 0.0, []
        a, b, c = (j for _, j in units)
        if plan.same(a, b) and plan.same(b, c):  # H3 alone: its K z is removed (linear=True)
            return scale, [(1.0, plan.probe([(1.0, a)], True, linear=True))]
        # bring a repeated vector first: H(x, x, y)
        if plan.same(a, c):
            b, c = c, b
        elif plan.same(b, c):
            a, c = c, a
        plan.new_recipe()  # the fields of one recipe share one probe scale: their K z cancel in the sum
        if plan.same(a, b):  # H(a, a, c) = [H3(a + c) - H3(a - c) - 2 H3(c)] / 6
            return scale, [(1 / 6, plan.probe([(1.0, a), (1.0, c)], True)),
                           (-1 / 6, plan.probe([(1.0, a), (-1.0, c)], True)),
                           (-1 / 3, plan.probe([(1.0, c)], True))]
        return scale, [(wt, plan.probe([(1.0, a), (s2, b), (s3, c)], True)) for wt, s2, s3 in _H_UVW]

    def _evaluate(self, plan: "_ProbePlan") -> np.ndarray:
        """G(z, z), or H3(z) (+ K z / s^2 where it cancels in its recipe), of every probe direction, from ONE
        call with the fields +-s z; (fields, n), the rows of the call's own array."""
        m = len(plan.directions)
        if not m:
            return np.zeros((0, 0))
        n = len(plan.units[0])
        U = np.empty((2 * m, n))  # +s z, then -s z; the forces are written over it where the caller allows
        peak = np.empty(m)
        for i, combo in enumerate(plan.directions):
            row = U[i]
            np.multiply(plan.units[combo[0][1]], combo[0][0], out=row)
            for coef, j in combo[1:]:
                row += coef * plan.units[j]
            peak[i] = np.abs(row).max()
        group = np.asarray(plan.group)
        top = np.zeros(int(group.max()) + 1)
        np.maximum.at(top, group, peak)  # one scale per recipe (a zero field, u - v of equal u and v: 1)
        s = self.probe / np.where(top == 0, 1.0, top)[group]
        U[:m] *= s[:, None]
        np.negative(U[:m], out=U[m:])
        lin = np.flatnonzero(plan.linear)
        KZ = np.asarray(self.K @ U[lin].T).T if lin.size else None  # K (s z) of the lone H3 fields
        F = probe_forces(self.forces, U, self.stats)
        out, fm = F[:m], F[m:]
        k = 0
        for i in range(m):  # row by row, in place: no (m, n) temporaries
            if plan.odd[i]:
                out[i] -= fm[i]
                if plan.linear[i]:
                    out[i] -= 2.0 * KZ[k]
                    k += 1
                out[i] *= 1.0 / (2.0 * s[i] ** 3)  # H3(z) [+ K z / s^2, cancelled by its recipe]
            else:
                out[i] += fm[i]
                out[i] *= 1.0 / (2.0 * s[i] ** 2)  # G(z, z)
        return out

    @staticmethod
    def _n(pairs, triples) -> int:
        first = next(iter(pairs), None) or next(iter(triples), None)
        return 0 if first is None else len(first[0])


class _ProbePlan:
    """The probe directions of one request, each a short combination of unit input vectors.

    ``units``: the inputs scaled to a peak of 1, each object once; ``directions[i]``: ``[(coef, unit)]``;
    ``odd[i]``: H3 wanted (else G(z, z)); ``linear[i]``: its ``K z`` removed (a lone H3; in the other
    recipes the ``K z`` of the fields sum to zero: ``(a+c) - (a-c) - 2c = 0``, ``sum s2 s3 (a + s2 b + s3 c)
    = 0``); ``group[i]``: the recipe it serves, whose fields share one probe scale.
    """

    def __init__(self):
        self.units: list[np.ndarray] = []
        self._ids: dict[int, tuple[float, int]] = {}
        self._keep: list[np.ndarray] = []  # the inputs whose ids are keys (alive while the plan is)
        self.directions: list[list[tuple[float, int]]] = []
        self.odd: list[bool] = []
        self.linear: list[bool] = []
        self.group: list[int] = []
        self._recipe = -1

    def unit(self, x: np.ndarray) -> tuple[float, int]:
        """``(|x|_inf, index of x / |x|_inf in units)``; ``(0, -1)`` for a zero vector."""
        kept = self._ids.get(id(x))
        if kept is not None:
            return kept
        nx, u = _unit(x)
        out = (nx, -1)
        if nx > 0:
            self.units.append(u)
            out = (nx, len(self.units) - 1)
        self._ids[id(x)] = out
        self._keep.append(x)
        return out

    def same(self, i: int, j: int) -> bool:
        return i == j or np.array_equal(self.units[i], self.units[j])

    def new_recipe(self) -> None:
        self._recipe += 1

    def probe(self, combo: list[tuple[float, int]], odd: bool, *, linear: bool = False) -> int:
        """A probe direction (``new_recipe`` first for a recipe of several fields); its index."""
        if len(combo) == 1 and (linear or not odd):
            self.new_recipe()  # a field alone: its own scale
        self.directions.append(combo)
        self.odd.append(odd)
        self.linear.append(linear)
        self.group.append(self._recipe)
        return len(self.directions) - 1


def checked_probe(probe: float) -> float:
    """The probe displacement as a float; NumericalError unless a positive finite length."""
    if not (probe > 0 and np.isfinite(probe)):
        raise NumericalError(f"polarisation: the probe displacement must be a positive length, got {probe!r}")
    return float(probe)


def probe_forces(forces: ForceBatch, U: np.ndarray, stats: PolarisationStats) -> np.ndarray:
    """The internal forces of the probe fields ``U`` (m, n) in ONE call, checked and counted in ``stats``.

    A ``forces`` with ``accepts_out`` (:class:`stepnf.step.forces.ForceEvaluator`) writes them over ``U``.
    NumericalError for a wrong shape or a NaN / inf, unless ``forces`` is ``checked`` (an adapter's, checked
    where they leave it: :mod:`stepnf.step.forces`).
    """
    F = forces(U, out=U) if getattr(forces, "accepts_out", False) else forces(U)
    if not getattr(forces, "checked", False):
        F = np.asarray(F, dtype=float)
        if F.shape != U.shape:
            raise NumericalError(f"polarisation: forces returned shape {F.shape} for fields {U.shape}")
        if not np.all(np.isfinite(F)):
            raise NumericalError("polarisation: the internal forces contain NaN or inf")
    stats.force_evaluations += len(U)
    stats.calls += 1
    stats.history.append(len(U))
    return F


def _unit(x: np.ndarray) -> tuple[float, np.ndarray]:
    """(|x|_inf, x / |x|_inf), (0, x) for a zero vector."""
    x = np.asarray(x, dtype=float)
    nx = float(np.abs(x).max()) if x.size else 0.0
    return (nx, x / nx) if nx > 0 else (0.0, x)


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
