"""The nonlinear terms of every DPIM order from the black box (the right-hand sides of its homological
equations, called its "forcing" in the DPIM literature; no external force): probe directions shared across orders.

Order p of :meth:`stepnf.dpim.parametrisation.DPIM.parametrise` needs, at its phase nodes ``theta_l``, the
``rho^p`` part of ``G(x, x) + H(x, x, x)`` on the manifold (ordered sums)::

    F_p(theta) = sum_{q + r = p} G(w_q, w_r) + sum_{a + b + c = p} H(w_a, w_b, w_c),
    w_q(theta) = sum_m Y[q, m] cos(m theta)

Every term comes from the internal force by polarisation (:mod:`stepnf.dpim.polarisation`) on the unit
vectors ``u_q = w_q / |w_q|_inf`` of each node: a probe direction ``z``, a short sum of units (``u_1``,
``u_1 - u_4``, ``u_1 + u_2 + u_4``), sent as ``+-s z`` (``|s z|_inf = probe``), gives both::

    G(z, z) = [f(s z) + f(-s z)] / (2 s^2)          H3(z) = [f(s z) - f(-s z) - 2 s K z] / (2 s^3)

and the terms are sums of those values (exact for a cubic f)::

    G(u, v)    = [G(u+v) - G(u-v)] / 4  =  [G(u+v) - G(u) - G(v)] / 2
    H(u, u, v) = [H3(u+v) - H3(u-v) - 2 H3(v)] / 6
    H(u, v, w) = [H3(u+v+w) - H3(u+v) - H3(u+w) - H3(v+w) + H3(u) + H3(v) + H3(w)] / 6

**Shared directions.** Every order uses the same ``J = (N + 1) / 2`` nodes
``theta_l = pi (2l + 1) / (4J)`` (:func:`stepnf.dpim.parametrisation.phase_nodes` of orders N and N - 1: DCT-IV nodes
for the odd harmonics 1..N, DCT-II nodes in ``2 theta`` for the even ones 0..N-1, so every order's
cosine coefficients are exact from them), so a direction is the same vector at every order and is sent
once: the pair (q, r) of order q + r sends ``u_q +- u_r``, whose H3 the triples (q, q, r) of order
2q + r and (q, r, t) of order q + r + t reuse; ``u_q`` alone serves ``G(w_q, w_q)`` at order 2q and
``H3(u_q)`` wherever a triple needs it. New at an order: two directions per pair, one per triple of
three different orders, and the lone units not sent yet. A pair whose ``u_q - u_r`` no triple of the run
reads (2q + r > N) takes ``G(u, v) = [G(u+v) - G(u) - G(v)] / 2`` from the units instead
(:class:`OrderTerms`). For one master this is 176 force evaluations to order 7 and 2336 to order 15,
against 368 and 5920 with new directions for every term and nodes per order (200 and 2624 with ``u - v``
for every pair; :func:`planned_evaluations`; the lower orders pay for the shared nodes, the higher ones gain).
``K z`` is a sum of ``K u_q``, themselves from ``K Y[q, m]``: one sparse product per coefficient.

A value is kept while a later order needs it (known in advance: the plan of every order depends on N
only), then dropped. Each order's new directions go to the black box in ONE batched call
(``forces(U)``, or ``forces(U, out=U)`` for a ``forces`` with ``accepts_out``: the forces then replace
the fields in the same array), or in several of whole directions when the fields exceed :data:`CALL_BYTES`.

Round-off: each direction is probed at its own scale (its largest entry at ``probe``) with its ``K z``
removed explicitly, so the estimates of :mod:`stepnf.dpim.polarisation` hold per value; H(u, v, w) sums seven
values instead of four, and a direction sums at most three units (``|z|_inf <= 3``). Measured against
the exact tensors on a random 9-dof cubic, orders 2..9: 2.8e-15 of the largest term.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from stepnf.linalg.block_product import block_product
from stepnf.dpim.polarisation import ForceBatch, PolarisationStats, checked_probe, probe_forces
from stepnf.plugin.dofs import MAX_ROTATION

#: The largest batch of probe fields one call of ``forces`` gets (bytes): a multi-mode manifold's order sends
#: ``2 x nodes x directions`` fields (order 5 of two modes on the 38k-dof cap: 12672 fields, 3.6 GiB, then as
#: much again for their G and H3); single-mode runs stay one call per order up to ~1M dofs.
CALL_BYTES = 2 ** 30
#: A probe direction ``sum_i coef_i u_{q_i}``: ``((q, coef), ...)`` sorted by q, the first coefficient +1.
Direction = tuple[tuple[int, int], ...]


def direction(*terms: tuple[int, int]) -> tuple[Direction, float]:
    """``(canonical direction, sign)`` with ``sum coef u_q = sign * canonical``."""
    t = sorted(terms)
    sign = 1 if t[0][1] > 0 else -1
    return tuple((q, c * sign) for q, c in t), float(sign)


@dataclass(frozen=True)
class OrderTerms:
    """The terms of order p: ``pairs`` (q < r, q + r = p), ``square`` (q with 2q = p, or None), ``cubes``
    (a with 3a = p), ``uuv`` ((a, c): H(u_a, u_a, u_c), a != c), ``uvw`` ((a, b, c), a < b < c).

    ``split``: the pairs whose G comes from ``u + v`` and the lone units, ``G(u, v) = [G(u+v) - G(u) -
    G(v)] / 2``, because no triple of an order up to the run's N reads ``H3(u - v)`` (a pair (q, r) is
    read by the triple (q, q, r) of order 2q + r): ``u - v`` is then not sent at all, while the units
    mostly are for other terms anyway (176 evaluations instead of 200 per master at order 7).
    """

    p: int
    pairs: tuple[tuple[int, int], ...]
    square: int | None
    cubes: tuple[int, ...]
    uuv: tuple[tuple[int, int], ...]
    uvw: tuple[tuple[int, int, int], ...]
    split: frozenset[tuple[int, int]]

    @classmethod
    def of(cls, p: int, order: int) -> "OrderTerms":
        """The terms of order ``p`` in a run to ``order`` (the run's N decides which pairs are split)."""
        pairs = tuple((q, p - q) for q in range(1, (p + 1) // 2))
        trip = [(a, b, p - a - b) for a in range(1, p // 3 + 1) for b in range(a, (p - a) // 2 + 1)]
        uuv = tuple((a, c) if a == b else (c, a) for a, b, c in trip if (a == b) != (b == c))
        split = frozenset(pr for pr in pairs if 2 * pr[0] + pr[1] > order)
        return cls(p, pairs, p // 2 if p % 2 == 0 else None, tuple(a for a, b, c in trip if a == c), uuv,
                   tuple(t for t in trip if t[0] < t[1] < t[2]), split)

    def g_directions(self) -> set[Direction]:
        """The directions whose G(z, z) this order reads."""
        out = {direction((self.square, 1))[0]} if self.square else set()
        for q, r in self.pairs:
            others = [((q, 1),), ((r, 1),)] if (q, r) in self.split else [((q, 1), (r, -1))]
            out |= {direction((q, 1), (r, 1))[0]} | {direction(*t)[0] for t in others}
        return out

    def h_directions(self) -> set[Direction]:
        """The directions whose H3(z) this order reads."""
        out = {direction((a, 1))[0] for a in self.cubes}
        for a, c in self.uuv:
            out |= {direction((a, 1), (c, 1))[0], direction((a, 1), (c, -1))[0], direction((c, 1))[0]}
        for t in self.uvw:
            ones = [(q, 1) for q in t]
            out |= {direction(*ones)[0]} | {direction(x, y)[0] for i, x in enumerate(ones) for y in ones[i + 1:]}
            out |= {direction(x)[0] for x in ones}
        return out


def planned_evaluations(order: int) -> list[int]:
    """Force evaluations of orders 2..order (what :class:`OrderForcing` sends when no node vector is zero):
    two per new direction and phase node."""
    J = (int(order) + 1) // 2
    sent: set[Direction] = set()
    out = []
    for p in range(2, int(order) + 1):
        t = OrderTerms.of(p, int(order))
        new = (t.g_directions() | t.h_directions()) - sent
        sent |= new
        out.append(2 * J * len(new))
    return out


class OrderForcing:
    """``F[p, m]`` for p = 2..order, one order at a time (module docstring).

    ``forces(U)``: internal forces (m, n) of the fields ``U`` (m, n), model units; ``K``: linear
    stiffness (n, n); ``probe``: the largest displacement of each probe field (model length units);
    ``order``: the DPIM's odd order N (fixes what is kept); ``nodes``: ``(theta (J,), {parity: (harmonics,
    B (J, J))})`` of :func:`stepnf.dpim.parametrisation.shared_nodes` for that order. ``rotations`` (bool (n,),
    or ``None``): a shell's rotation dofs (radians): ``probe`` then bounds the largest translation, and the
    largest rotation of each probe field is at most :data:`~stepnf.plugin.dofs.MAX_ROTATION`, as in STEP.
    """

    def __init__(self, forces: ForceBatch, K: Any, probe: float, order: int, nodes: tuple[np.ndarray, dict],
                 rotations: np.ndarray | None = None):
        self.forces, self.K, self.probe, self.order = forces, K, checked_probe(probe), int(order)
        self.rotations = None if rotations is None or not np.any(rotations) else np.asarray(rotations, dtype=bool)
        self.theta, self.bases = nodes  # (J,), {parity: (harmonics, B (J, J))}
        self._K_block = block_product(K)
        self.stats = PolarisationStats()
        self._units: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}  # q -> (norms, units, K units)
        self._g: dict[Direction, np.ndarray] = {}
        self._h: dict[Direction, np.ndarray] = {}
        self._sent: set[Direction] = set()
        self._last_g: dict[Direction, int] = {}
        self._last_h: dict[Direction, int] = {}
        for p in range(2, self.order + 1):
            t = OrderTerms.of(p, self.order)
            self._last_g.update(dict.fromkeys(t.g_directions(), p))
            self._last_h.update(dict.fromkeys(t.h_directions(), p))

    def __call__(self, Y: dict[tuple[int, int], np.ndarray], p: int) -> tuple[np.ndarray, np.ndarray]:
        """``(ms, F)``: ``F[j]`` (n,) the ``cos(ms[j] theta)`` coefficient of order p's forcing, ms = p, p-2, ..."""
        for q in range(1, p):
            self._unit_vectors(Y, q)
        Fn = self.node_forcing(p)
        ms, B = self.bases[p % 2]
        coef = np.linalg.solve(B, Fn)  # every harmonic of the parity the nodes resolve; those above p are 0
        keep = ms <= p
        return ms[keep], coef[keep]

    def node_forcing(self, p: int, fields: dict[int, tuple[np.ndarray, np.ndarray]] | None = None) -> np.ndarray:
        """``F_p`` at the nodes (J, n), from the fields of orders 1..p-1 at the nodes: those of :meth:`__call__`,
        or ``fields`` ``{q: (w_q, K w_q)}`` (each (J, n), real) given here for the orders not given yet (the
        multi-mode manifold, :mod:`stepnf.dpim.multimode.monomials`, whose nodes are its sample points)."""
        for q, (W, KW) in (fields or {}).items():
            if q not in self._units:
                self._set_units(q, W, KW)
        t = OrderTerms.of(p, self.order)
        new = sorted((t.g_directions() | t.h_directions()) - self._sent)
        self._evaluate(new, p)
        self._sent.update(new)
        Fn = self._node_values(t)
        self._forget(p)
        self.stats.quadratic_terms += len(t.pairs) + (t.square is not None)
        self.stats.cubic_terms += len(t.cubes) + len(t.uuv) + len(t.uvw)
        return Fn

    # ------------------------------------------------------------ internals
    def _unit_vectors(self, Y: dict[tuple[int, int], np.ndarray], q: int) -> None:
        """``|w_q|_inf``, ``u_q`` and ``K u_q`` at the nodes (J,), (J, n), (J, n), once per q."""
        if q in self._units:
            return
        mq = np.arange(q % 2, q + 1, 2)
        C = np.cos(np.outer(self.theta, mq))
        Yq = np.stack([Y[(q, m)] for m in mq])
        self._set_units(q, C @ Yq, C @ (self._K_block @ Yq.T).T)

    def _set_units(self, q: int, W: np.ndarray, KW: np.ndarray) -> None:
        """Keep ``|w_q|_inf``, ``u_q`` and ``K u_q`` at the nodes from ``w_q`` and ``K w_q`` (J, n)."""
        norms = np.abs(W).max(axis=1)
        inv = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 0.0)[:, None]
        self._units[q] = (norms, W * inv, KW * inv)

    def _peaks(self, Z: np.ndarray) -> np.ndarray:
        """The size of each probe field (row of ``Z``) the probe scales to: its largest entry, or with rotation dofs
        the larger of its largest translation and its largest rotation times ``probe / MAX_ROTATION``.

        The rule of :func:`stepnf.plugin.dofs.bounded_scale` (``probe / size`` = the smaller of
        ``probe / max|z_t|`` and ``MAX_ROTATION / max|z_r|``), kept in this form: ``bounded_scale`` rounds the
        second differently (one unit in the last place in about a third of the probes the rotation bounds),
        and the DPIM's forces stay bit for bit what they were."""
        if self.rotations is None:
            return np.maximum(Z.max(axis=1), -Z.min(axis=1))  # max |z|, without an |Z| array
        A = np.abs(Z)
        return np.maximum(A[:, ~self.rotations].max(axis=1, initial=0.0),
                          A[:, self.rotations].max(axis=1, initial=0.0) * self.probe / MAX_ROTATION)

    def _evaluate(self, new: list[Direction], p: int) -> None:
        """G and H3 of the new directions at every node: ONE call of ``forces`` with the fields +-s z (several
        calls, whole directions each, when the fields would exceed :data:`CALL_BYTES`)."""
        J, n = len(self.theta), self._n()
        for d in new:
            if self._last_g.get(d, 0) >= p:
                self._g[d] = np.zeros((J, n))
            if self._last_h.get(d, 0) >= p:
                self._h[d] = np.zeros((J, n))
        per_call = max(1, CALL_BYTES // (16 * J * max(n, 1)))
        for k in range(0, len(new), per_call):
            self._evaluate_chunk(new[k:k + per_call], J, n)

    def _evaluate_chunk(self, new: list[Direction], J: int, n: int) -> None:
        """One call for the directions ``new``: per direction its fields at every node at once (rows ``+s z``
        first, then their negatives, built in place); a node where the direction is zero (zero units, or
        ``u - v`` of equal units) is not sent, its values stay zero. In-place arithmetic on one scratch array:
        the values are those of the expressions in the comments, bit for bit (a multi-mode manifold's arrays are
        L x n each, 46 MB on the 38k-dof cap: a temporary per operation cost as much as the operation)."""
        U = np.empty((2 * J * len(new), n))
        tmp = np.empty((J, n))
        blocks = []  # (direction, nodes sent, their scales s, first row)
        R = 0
        for d in new:
            Z = U[R:R + J]
            np.multiply(self._units[d[0][0]][1], d[0][1], out=Z)  # z = sum_q c_q u_q
            for q, c in d[1:]:
                Z += np.multiply(self._units[q][1], c, out=tmp)
            peaks = self._peaks(Z)
            live = np.flatnonzero(peaks > 0)
            if len(live) < J:
                Z[:len(live)] = Z[live]
            s = self.probe / peaks[live]
            Z[:len(live)] *= s[:, None]
            blocks.append((d, live, s, R))
            R += len(live)
        if not R:
            return
        U = U[:2 * R]
        np.negative(U[:R], out=U[R:])
        F = probe_forces(self.forces, U, self.stats)
        for d, live, s, r0 in blocks:
            k = len(live)
            fp, fm = F[r0:r0 + k], F[R + r0:R + r0 + k]
            every = k == J  # then straight into the kept array, else through tmp
            if d in self._g:  # G = (fp + fm) / (2 s^2)
                out = self._g[d] if every else tmp[:k]
                np.add(fp, fm, out=out)
                out /= (2.0 * s * s)[:, None]
                if not every:
                    self._g[d][live] = out
            if d in self._h:  # H3 = (fp - fm - 2 s K z) / (2 s^3),  K z = sum_q c_q K u_q
                out = self._h[d] if every else tmp[:k]
                Kz = self._units[d[0][0]][2][live] * d[0][1]
                for q, c in d[1:]:
                    Kz += np.multiply(self._units[q][2][live], c, out=out)
                Kz *= (2.0 * s)[:, None]
                np.subtract(fp, fm, out=out)
                out -= Kz
                out /= (2.0 * s ** 3)[:, None]
                if not every:
                    self._h[d][live] = out

    def _n(self) -> int:
        return next(iter(self._units.values()))[1].shape[1]

    def G(self, *terms: tuple[int, int]) -> np.ndarray:
        """``G(z, z)`` (J, n) of ``z = sum coef u_q`` (even in z)."""
        return self._g[direction(*terms)[0]]

    def H3(self, *terms: tuple[int, int]) -> np.ndarray:
        """``H3(z)`` (J, n) of ``z = sum coef u_q`` (odd in z)."""
        d, sign = direction(*terms)
        return sign * self._h[d]

    def _node_values(self, t: OrderTerms) -> np.ndarray:
        """``F_p(theta_l)`` (J, n): the terms of order p (ordered sums: 2 per pair, 3 per H(u, u, v), 6 per
        H(u, v, w)), each scaled back from unit vectors by the product of the norms at the node."""
        nrm = {q: self._units[q][0][:, None] for q in self._units}
        Fn = np.zeros((len(self.theta), self._n()))
        for q, r in t.pairs:
            if (q, r) in t.split:
                g = (self.G((q, 1), (r, 1)) - self.G((q, 1)) - self.G((r, 1))) / 2.0
            else:
                g = (self.G((q, 1), (r, 1)) - self.G((q, 1), (r, -1))) / 4.0
            Fn += 2.0 * nrm[q] * nrm[r] * g
        if t.square:
            Fn += nrm[t.square] ** 2 * self.G((t.square, 1))
        for a in t.cubes:
            Fn += nrm[a] ** 3 * self.H3((a, 1))
        for a, c in t.uuv:
            Fn += 3.0 * nrm[a] ** 2 * nrm[c] * (self.H3((a, 1), (c, 1)) - self.H3((a, 1), (c, -1))
                                                - 2.0 * self.H3((c, 1))) / 6.0
        for a, b, c in t.uvw:
            h = (self.H3((a, 1), (b, 1), (c, 1)) - self.H3((a, 1), (b, 1)) - self.H3((a, 1), (c, 1))
                 - self.H3((b, 1), (c, 1)) + self.H3((a, 1)) + self.H3((b, 1)) + self.H3((c, 1)))
            Fn += 6.0 * nrm[a] * nrm[b] * nrm[c] * h / 6.0
        return Fn

    def _forget(self, p: int) -> None:
        """Drop the values no later order reads."""
        for kept, last in ((self._g, self._last_g), (self._h, self._last_h)):
            for d in [d for d in kept if last.get(d, 0) <= p]:
                del kept[d]
