"""Monomials of a manifold of several master modes, and the nonlinear forcing of each order projected onto them.

Normal coordinates ``z`` in C^{2m}, ``z_{j+m} = conj(z_j)`` on real motions (``docs/design.md``, "Manifolds of
several master modes"). A monomial is a multi-index ``alpha`` (tuple of 2m ints), ``conj(alpha)`` swaps its two
halves; a field ``w_q(z) = sum_{|alpha| = q} W[alpha] z^alpha`` with ``W[conj alpha] = conj W[alpha]`` is real
at real ``z``. Each conjugate pair is represented by the larger of the two tuples (:func:`representatives`):
``alpha`` and ``conj(alpha)`` contribute ``2 Re(W[alpha] z^alpha)``, a self-conjugate one (``a = b``)
``W[alpha] z^alpha`` (real).

**Sampling and projection.** The order-p forcing ``N_p(z) = sum_{q+r=p} G(w_q, w_r) + sum_{a+b+c=p} H(w_a, w_b,
w_c)`` is a real homogeneous polynomial of degree p of ``z``; it is evaluated at ``L`` real sample points
``z_l = r_l e^{i theta_l}``, the SAME points at every order, so the probe directions of
:class:`stepnf.dpim.nonlinear_terms.OrderForcing` are shared across orders (one batched force call per order), and
its coefficients are the least-squares solution of the real design ``A_p`` (L x #monomials of order p: columns
``2 Re z^alpha``, ``-2 Im z^alpha`` per pair, ``z^alpha`` per self-conjugate one), exact for a cubic force.

The points (:func:`select_points`): ``L = OVERSAMPLING`` x the monomials of order N, chosen among
``CANDIDATES`` x L points of a low-discrepancy sequence (:func:`sample_points`: angles on the torus and radii on
the positive part of the unit sphere of R^m; homogeneity leaves m - 1 radial directions, which separate
monomials of the same angular frequencies ``a - b`` but different ``a + b``) by QR with column pivoting of
order N's design (approximate Fekete points: each of the first #monomials pivots the candidate that adds the most
volume to those before it; the remaining 0.25 x are the next columns of LAPACK's pivoted order, not chosen by
volume: a second pivoted pass for them measured worse, condition 19.2 / 37.7 / 71.3 against 17.9 / 32.5 / 61.5
for m = 2, N = 7 / 9 / 11). Every force
evaluation of the manifold is a probe field at one of these points (two per point and direction), so L sets its
cost and memory (the probe values are kept L x n per direction). Condition of ``A_p`` with normalised columns,
the largest over p = 1..N (measured, :attr:`MonomialSampling.condition`; always at p = N):

    ========  =====  =====  =====  =====  =====  =======  =====  =====
    m, N      2, 5   2, 7   2, 9   2, 11  2, 15  3, 5     3, 7   3, 9
    ========  =====  =====  =====  =====  =====  =======  =====  =====
    selected  10.0   17.9   32.5   61.5   203    17.3     104    91
    sequence  13.4   38.0   56.1   77.6   242    57.2     1062   2378
    (2 x)     4.0    10.2   14.9   25.8   95.4   11.5     122    195
    ========  =====  =====  =====  =====  =====  =======  =====  =====

(selected: L = 1.25 x, from 4 x the monomials; sequence: the sequence's first 1.25 x; "2 x": its first 2 x, the
points before 2026-12-07, with 1.6 times as many force evaluations). The projection amplifies the probes'
round-off (2.8e-15 of the largest term for a cubic, :mod:`stepnf.dpim.nonlinear_terms`) by at most the condition:
below 1e-12 at every order here. The condition grows with p because the radial part of the monomials
(``r_1^{n_1} r_2^{n_2}``, ``n_1 + n_2 = p``) is a Bernstein-like basis; the error it amplifies lies in
combinations of monomials of the same frequencies, small on the real torus. For m = 1 it is a Fourier design.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg as sla

from stepnf.dpim.nonlinear_terms import OrderForcing
from stepnf.linalg.block_product import block_product

#: Sample points per monomial of the highest order (module docstring: with :func:`select_points` the design's
#: condition is 18 for m = 2, N = 7 and 203 for N = 15; 1.5 gives 14 and 146, 1.1 gives 26 and 354).
OVERSAMPLING = 1.25
#: Candidate points per monomial of the highest order among which :func:`select_points` chooses (3: condition
#: 146 instead of 91 for m = 3, N = 9; the QR of the candidates' design takes 16 s there, 1 s for m = 2, N = 15).
CANDIDATES = 4

Monomial = tuple[int, ...]


def monomials(m: int, p: int) -> list[Monomial]:
    """Every multi-index of order p in 2m variables, sorted."""
    out = []
    for c in itertools.combinations_with_replacement(range(2 * m), p):
        a = [0] * (2 * m)
        for i in c:
            a[i] += 1
        out.append(tuple(a))
    return sorted(out)


def conj(alpha: Monomial) -> Monomial:
    """The conjugate monomial: the two halves swapped."""
    m = len(alpha) // 2
    return tuple(alpha[m:]) + tuple(alpha[:m])


def representatives(m: int, p: int) -> list[Monomial]:
    """One monomial of each conjugate pair of order p (the larger tuple), self-conjugate ones included."""
    return [a for a in monomials(m, p) if a >= conj(a)]


def frequency(alpha: Monomial) -> tuple[int, ...]:
    """``a - b``: the angular frequencies of ``z^alpha`` (``sigma = i sum_j (a_j - b_j) omega_j``)."""
    m = len(alpha) // 2
    return tuple(alpha[j] - alpha[j + m] for j in range(m))


def powers(Z: np.ndarray, alphas: list[Monomial]) -> np.ndarray:
    """``z_l^alpha`` (L, len(alphas)) for points ``Z`` (L, 2m)."""
    E = np.asarray(alphas, dtype=int)
    if not len(E):
        return np.zeros((len(Z), 0), dtype=complex)
    out = np.ones((len(Z), len(E)), dtype=complex)
    for i in range(Z.shape[1]):
        col = Z[:, i][:, None] ** E[:, i][None, :]
        out *= col
    return out


def values_and_partials(zeta: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """At ``z = (zeta, conj zeta)`` (2m,), the monomials of exponents ``E`` (T, 2m): their values ``z^a`` (T,) and
    partial derivatives ``d z^a / d z_i`` (T, 2m), ``z_i`` and its conjugate taken as independent variables."""
    z = np.concatenate([zeta, np.conj(zeta)])
    pw = z[:, None] ** np.arange(int(E.max(initial=1)) + 1)[None, :]  # (2m, p)
    base = pw[np.arange(len(z))[None, :], E]  # (T, 2m): z_i^{a_i}
    D = np.empty(E.shape, dtype=complex)
    for i in range(len(z)):
        part = base.copy()
        part[:, i] = E[:, i] * pw[i, np.maximum(E[:, i] - 1, 0)]
        D[:, i] = np.prod(part, axis=1)
    return np.prod(base, axis=1), D


def real_design(Z: np.ndarray, reps: list[Monomial]) -> np.ndarray:
    """The real design (L, R) of the representatives: per pair ``2 Re z^alpha, -2 Im z^alpha``, per
    self-conjugate ``Re z^alpha``; a coefficient vector ``(Re W, Im W)`` per pair (``W`` per self-conjugate) maps to
    the field's values."""
    P = powers(Z, reps)
    cols = []
    for k, a in enumerate(reps):
        if a == conj(a):
            cols.append(P[:, k].real)
        else:
            cols += [2.0 * P[:, k].real, -2.0 * P[:, k].imag]
    return np.column_stack(cols) if cols else np.zeros((len(Z), 0))


def to_real(W: dict[Monomial, np.ndarray], reps: list[Monomial]) -> np.ndarray:
    """The real coefficient rows (R, n) of the representatives' fields (the unknowns of :func:`real_design`)."""
    rows = []
    for a in reps:
        w = np.asarray(W[a])
        rows += [w.real] if a == conj(a) else [w.real, w.imag]
    return np.asarray(rows)


def from_real(X: np.ndarray, reps: list[Monomial]) -> dict[Monomial, np.ndarray]:
    """The representatives' complex coefficients from real rows (R, n) (:func:`to_real`'s inverse)."""
    out, k = {}, 0
    for a in reps:
        if a == conj(a):
            out[a] = X[k].astype(complex)
            k += 1
        else:
            out[a] = X[k] + 1j * X[k + 1]
            k += 2
    return out


def sample_points(m: int, L: int) -> np.ndarray:
    """``L`` real points ``(z, conj z)`` (L, 2m): ``z_j = r_j e^{i theta_j}`` from the first L points of the
    Kronecker sequence ``u_l = frac(1/2 + l g)`` in 2m - 1 dimensions (Roberts' R_d: ``g_k = x^-k``, x the root of
    ``x^(2m) = x + 1``; low discrepancy, deterministic): m angles ``2 pi u``, and m - 1 angles ``t = pi u / 2`` of
    the radii on the positive part of the unit sphere, ``r = (cos t_1, sin t_1 cos t_2, ...)``."""
    d = 2 * m - 1
    x = 2.0
    for _ in range(100):  # fixed point of x = (1 + x)^(1 / (d + 1)), converged to round-off
        x = (1.0 + x) ** (1.0 / (d + 1))
    u = (0.5 + np.arange(1, L + 1)[:, None] * x ** -np.arange(1.0, d + 1)) % 1.0
    r = np.ones((L, m))
    t = 0.5 * np.pi * u[:, m:]
    for k in range(m - 1):
        r[:, k] *= np.cos(t[:, k])
        r[:, k + 1:] *= np.sin(t[:, k])[:, None]
    z = r * np.exp(2j * np.pi * u[:, :m])
    return np.concatenate([z, z.conj()], axis=1)


def select_points(m: int, order: int) -> np.ndarray:
    """The manifold's sample points ``(z, conj z)`` (L, 2m), ``L = ceil(OVERSAMPLING x #monomials of order N)``:
    chosen among the first ``CANDIDATES x #monomials`` points of :func:`sample_points` by QR with column pivoting
    of the transposed design of order N (normalised columns), kept in the sequence's order (module docstring).
    Deterministic: the same points for any BLAS thread count (checked with 1 and 2 threads, m = 1..3). Cost
    ~R^3 for R monomials (16 s for m = 3, N = 9, R = 2002; a run of that size makes ~1e5 force evaluations)."""
    R = len(monomials(m, order))
    L = int(np.ceil(OVERSAMPLING * R))
    C = sample_points(m, max(L, CANDIDATES * R))
    A = real_design(C, representatives(m, order))
    _, piv = sla.qr((A / np.linalg.norm(A, axis=0)).T, mode="r", pivoting=True)
    return C[np.sort(piv[:L])]


@dataclass
class MonomialSampling:
    """The sample points of a manifold of ``m`` masters to ``order``, and per order its representatives, real
    design and least-squares projector (module docstring). ``condition[p]``: the 2-norm condition number of
    order p's design with normalised columns."""

    m: int
    order: int
    Z: np.ndarray = field(init=False)
    reps: dict[int, list[Monomial]] = field(init=False, default_factory=dict)
    design: dict[int, np.ndarray] = field(init=False, default_factory=dict)
    projector: dict[int, np.ndarray] = field(init=False, default_factory=dict)
    condition: dict[int, float] = field(init=False, default_factory=dict)

    def __post_init__(self):
        self.Z = select_points(self.m, self.order)
        for p in range(1, self.order + 1):
            reps = representatives(self.m, p)
            A = real_design(self.Z, reps)
            scale = np.linalg.norm(A, axis=0)
            U, s, Vt = np.linalg.svd(A / scale, full_matrices=False)
            self.reps[p], self.design[p] = reps, A
            self.projector[p] = (Vt.T / s) @ U.T / scale[:, None]  # (R, L): the least-squares solution
            self.condition[p] = float(s[0] / s[-1])

    def field_values(self, p: int, W: dict[Monomial, np.ndarray]) -> np.ndarray:
        """``w_p(z_l)`` (L, n), real, from the representatives' coefficients."""
        return self.design[p] @ to_real(W, self.reps[p])

    def project(self, p: int, values: np.ndarray) -> dict[Monomial, np.ndarray]:
        """The coefficients (representatives of order p) of a real homogeneous polynomial of degree p from its
        values (L, n) at the sample points."""
        return from_real(self.projector[p] @ values, self.reps[p])


class SampledForcing:
    """``N[alpha]`` of every order p = 2..N from the black box (module docstring): the fields of the orders below
    at the sample points, their order-p forcing by :meth:`OrderForcing.node_forcing` (one batched force call per
    order, directions shared across orders), projected onto order p's monomials.

    ``forces``, ``K``, ``probe``, ``rotations``: as :class:`~stepnf.dpim.nonlinear_terms.OrderForcing`;
    ``sampling``: :class:`MonomialSampling`.
    """

    def __init__(self, forces, K: Any, probe: float, sampling: MonomialSampling,
                 rotations: np.ndarray | None = None):
        self.sampling = sampling
        L = len(sampling.Z)
        self.forcing = OrderForcing(forces, K, probe, sampling.order, (np.arange(L, dtype=float), {}), rotations)
        self._K = block_product(K)
        self._given: set[int] = set()
        self.stats = self.forcing.stats

    def __call__(self, W: dict[Monomial, np.ndarray], p: int) -> dict[Monomial, np.ndarray]:
        """``{alpha: N[alpha]}`` (complex (n,)) for the representatives of order p, from ``W`` of orders < p."""
        s = self.sampling
        fields = {}
        for q in range(1, p):
            if q not in self._given:
                X = to_real(W, s.reps[q])
                fields[q] = (s.design[q] @ X, s.design[q] @ np.asarray(self._K @ X.T).T)
                self._given.add(q)
        return s.project(p, self.forcing.node_forcing(p, fields))
