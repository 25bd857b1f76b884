"""Direct parametrisation of the invariant manifold of several master modes, complex normal form, full order.

Model ``M x'' + K x + G(x, x) + H(x, x, x) = 0`` (the forces of a black box); m masters (shapes ``phi_j``,
M-normalised, frequencies ``omega_j``); normal coordinates ``z`` in C^{2m} (``z_{j+m} = conj z_j`` on real
motions, ``lam_j = i omega_j``, ``lam_{j+m} = -i omega_j``); the contract is ``docs/design.md``, "Manifolds of
several master modes"::

    x = W(z) = sum_alpha W[alpha] z^alpha,   v = V(z),   z_i' = lam_i z_i + sum_{|alpha| >= 2} f[(i, alpha)] z^alpha

Order p, monomial alpha, ``sigma = sum_i alpha_i lam_i = i d``, ``d = sum_j (a_j - b_j) omega_j``::

    V[alpha] = sigma W[alpha] + sum_i Phi_i f[(i, alpha)] + P[alpha]
    (K - d^2 M) W[alpha] + M sum_i (sigma + lam_i) Phi_i f[(i, alpha)] = -N[alpha] - M (Q[alpha] + sigma P[alpha])

``P``, ``Q`` the order-p coefficients of ``grad W . f`` and ``grad V . f`` over the nonlinear orders below p
(:func:`transport`), ``N[alpha]`` that of ``G(W, W) + H(W, W, W)`` from the black box
(:class:`stepnf.dpim.multimode.monomials.SampledForcing`). Equation i is resonant for alpha when ``|sigma - lam_i| <=
resonance |lam_i|`` (exact ones always; with ``ratios`` k given instead: when ``sum_l (a_l - b_l) k_l = +-k_j``,
the sign of lam_i): its ``f[(i, alpha)] = phi_j^T rhs / (sigma + lam_i)`` (``phi_j^T M W[alpha] = 0``, so the
left side has no ``phi_j`` part) and W comes from the system bordered with those masters
(:class:`stepnf.dpim.multimode.solves.ManifoldSolves`); the other f are 0. Only one monomial of each conjugate pair
is solved: ``W[conj alpha] = conj W[alpha]``, ``f[(i +- m, conj alpha)] = conj f[(i, alpha)]``.

One real factorisation per distinct shift ``d^2`` (shared by every order and monomial), complex right-hand sides as
two real columns. With one master this is today's single-mode DPIM (:mod:`stepnf.dpim.parametrisation`) in
complex form (tests/dpim/test_manifold.py: equal to round-off).
"""
from __future__ import annotations

import math
import time
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.dpim.multimode.solves import ManifoldSolves, shift_key
from stepnf.dpim.multimode.monomials import (Monomial, MonomialSampling, SampledForcing, conj, frequency, monomials,
                                   powers)
from stepnf.dpim.parametrisation import DENSE_SPECTRUM_LIMIT, DPIM, EIGENPAIR_FLOOR, check_mode, dense_spectrum
from stepnf.errors import NumericalError
from stepnf.flags import new_flag
from stepnf.runtime.counters import Counters

#: The largest integer of a resonance vector found from the frequencies (1:1, 1:2, 1:3, 1:4 and their combinations,
#: issue 33): such a resonance decides by its ratios which monomials are resonant; a higher-order one (2:7) is left
#: to the tolerance on each small denominator.
MAX_RATIO = 4
#: ``|sigma - lam_i| <= EXACT_RESONANCE |lam_i|``: an exact resonance (kept in the reduced dynamics whatever the
#: tolerance or ratios say: the shift is singular there), the relative round-off of a sum of frequencies.
EXACT_RESONANCE = 1e-9

Coefficient = tuple[int, Monomial]


@dataclass
class ManifoldResult:
    """The parametrisation of the manifold of ``masters`` to odd ``order`` (module docstring).

    ``omega`` (m,) rad per model time unit, ``phi`` (n, m); ``W``, ``V``: every alpha with 1 <= |alpha| <= order
    (both conjugates), complex (n,); ``f``: the nonlinear reduced coefficients of all 2m equations, ``(i, alpha)
    -> complex`` (the resonant ones only: the others are 0); ``ratios`` (m,) ints: the resonance vector k
    (``omega_j ~ k_j omega_0 / k_0``) the resonant monomials follow, None without a resonance between masters;
    ``counts`` one dict per order p = 2..N; ``flags`` small denominators met.
    """

    masters: tuple[int, ...]
    omega: np.ndarray
    phi: np.ndarray
    M: Any
    order: int
    W: dict[Monomial, np.ndarray]
    V: dict[Monomial, np.ndarray]
    f: dict[Coefficient, complex]
    ratios: np.ndarray | None = None
    flags: list[dict[str, Any]] = field(default_factory=list)
    counts: list[dict[str, Any]] = field(default_factory=list)

    @property
    def m(self) -> int:
        return len(self.masters)

    @property
    def lam(self) -> np.ndarray:
        """``(i omega, -i omega)`` (2m,)."""
        return np.concatenate([1j * self.omega, -1j * self.omega])

    def _field(self, X: dict[Monomial, np.ndarray], z: np.ndarray) -> np.ndarray:
        Z = np.atleast_2d(np.asarray(z, dtype=complex))
        keys = list(X)
        out = (powers(Z, keys) @ np.asarray([X[k] for k in keys])).real
        return out[0] if np.ndim(z) == 1 else out

    def displacement(self, z: np.ndarray) -> np.ndarray:
        """``x = W(z)``: real (n,) for ``z`` (2m,), (k, n) for (k, 2m); model length units."""
        return self._field(self.W, z)

    def velocity(self, z: np.ndarray) -> np.ndarray:
        """``v = V(z)``: real (n,) or (k, n), model length per time unit."""
        return self._field(self.V, z)

    def vector_field(self, z: np.ndarray) -> np.ndarray:
        """``z'`` of the reduced dynamics, linear and nonlinear: complex (2m,) or (k, 2m)."""
        Z = np.atleast_2d(np.asarray(z, dtype=complex))
        keys = list(self.f)
        out = Z * self.lam[None, :]
        if keys:
            Pz = powers(Z, [a for _, a in keys])
            for k, (i, _) in enumerate(keys):
                out[:, i] += self.f[keys[k]] * Pz[:, k]
        return out[0] if np.ndim(z) == 1 else out

    def truncated(self, order: int) -> "ManifoldResult":
        """The same parametrisation truncated at odd ``order`` (monomials of order <= ``order``)."""
        if order % 2 == 0 or order < 1 or order > self.order:
            raise ValueError(f"truncation order must be odd, between 1 and {self.order}; got {order}")
        keep = lambda a: sum(a) <= order  # noqa: E731
        return ManifoldResult(self.masters, self.omega, self.phi, self.M, order,
                              {a: w for a, w in self.W.items() if keep(a)},
                              {a: v for a, v in self.V.items() if keep(a)},
                              {k: c for k, c in self.f.items() if keep(k[1])}, self.ratios, self.flags,
                              self.counts[: max(order - 1, 0)])

    def arrays(self) -> dict[str, np.ndarray]:
        """The coefficients as real arrays (for HDF5): ``index`` (k, 2m) of alpha, ``W_re``, ``W_im``, ``V_re``,
        ``V_im`` (k, n); ``f_index`` (l, 1 + 2m) of (i, alpha), ``f_re``, ``f_im`` (l,); ``masters``, ``omega``,
        ``phi``, ``ratios`` (zeros without), ``order``."""
        keys = sorted(self.W)
        fk = sorted(self.f)
        W = np.asarray([self.W[k] for k in keys])
        V = np.asarray([self.V[k] for k in keys])
        fv = np.asarray([self.f[k] for k in fk], dtype=complex)
        return {"index": np.asarray(keys, dtype=int), "W_re": W.real, "W_im": W.imag, "V_re": V.real,
                "V_im": V.imag, "f_index": np.asarray([(i,) + a for i, a in fk], dtype=int).reshape(len(fk), -1),
                "f_re": fv.real, "f_im": fv.imag, "masters": np.asarray(self.masters, dtype=int),
                "omega": self.omega, "phi": self.phi, "order": np.asarray(self.order),
                "ratios": np.zeros(self.m, dtype=int) if self.ratios is None else np.asarray(self.ratios)}


def find_ratios(omega: np.ndarray, tol: float, order: int) -> np.ndarray | None:
    """The smallest integers k (m,) with ``|omega_j k_0 / omega_0 - k_j| <= tol k_j`` for every master, k_0 <= order;
    None when there are none."""
    r = np.asarray(omega, dtype=float) / float(omega[0])
    for k0 in range(1, int(order) + 1):
        k = np.rint(r * k0).astype(int)
        if np.all(k >= 1) and np.all(np.abs(r * k0 - k) <= tol * k):
            return k // math.gcd(*k.tolist()) if len(k) > 1 else np.ones(1, dtype=int)
    return None


def resonant_equations(c: tuple[int, ...], omega: np.ndarray, tol: float, ratios: np.ndarray | None) -> list[int]:
    """The equations i (0..2m-1) for which the monomials of frequencies ``c`` are resonant (module docstring)."""
    m = len(omega)
    d = float(np.dot(c, omega))
    kc = None if ratios is None else int(np.dot(c, ratios))
    out = []
    for i in range(2 * m):
        j, sign = i % m, (1 if i < m else -1)
        gap = abs(d - sign * omega[j])
        if gap <= EXACT_RESONANCE * omega[j]:
            out.append(i)
        elif ratios is None and gap <= tol * omega[j]:
            out.append(i)
        elif ratios is not None and kc == sign * int(ratios[j]):
            out.append(i)
    return out


def transport(f: dict[Coefficient, complex], X: dict[Monomial, np.ndarray], p: int,
              wanted: set[Monomial]) -> dict[Monomial, np.ndarray]:
    """``[grad X_{2..p-1} . f_{2..p-1}]_alpha`` for alpha in ``wanted`` (order p): ``sum gamma_i f[(i, beta)]
    X[gamma]`` over ``gamma - e_i + beta = alpha``, ``|gamma| = p + 1 - |beta| >= 2``."""
    out: dict[Monomial, np.ndarray] = {}
    by_order: dict[int, list[Monomial]] = defaultdict(list)
    for a in X:
        by_order[sum(a)].append(a)
    for (i, beta), fc in f.items():
        q = p + 1 - sum(beta)
        if q < 2:
            continue
        for gamma in by_order.get(q, ()):
            if gamma[i] == 0:
                continue
            alpha = tuple(g + b - (k == i) for k, (g, b) in enumerate(zip(gamma, beta)))
            if alpha in wanted:
                term = (gamma[i] * fc) * X[gamma]
                out[alpha] = out[alpha] + term if alpha in out else term
    return out


def spectrum_of(dpim: DPIM) -> np.ndarray | None:
    """The computed modes' frequencies, or all of them (dense) for n <= DENSE_SPECTRUM_LIMIT, else None."""
    if dpim.spectrum.omega is not None:
        return np.asarray(dpim.spectrum.omega, dtype=float)
    return None if dpim.K.shape[0] > DENSE_SPECTRUM_LIMIT else dense_spectrum(dpim.K, dpim.M)


def parametrise_manifold(dpim: DPIM, masters: Sequence[int] | None, phis: np.ndarray, omegas: np.ndarray,
                         order: int, *, probe: float, ratios: Sequence[int] | None = None,
                         resonance: float | None = None, max_live: int | None = None,
                         progress: Callable[[int], None] | None = None) -> ManifoldResult:
    """The manifold of the masters ``phis`` (n, m), M-normalised, of angular frequencies ``omegas`` (m,), to odd
    ``order`` (module docstring).

    ``masters``: their indices in the spectrum (messages, flags; None: the computed modes nearest ``omegas``);
    ``probe``: the polarisation probe (model length units, :mod:`stepnf.dpim.polarisation`); ``ratios``: the
    resonance vector k (m,) that decides the resonant monomials (None: a resonance of integers up to
    :data:`MAX_RATIO` the frequencies show within ``resonance`` decides the same way; without one the tolerance
    decides each small denominator, and k is found afterwards from the kept monomials if they fit one);
    ``resonance``: that tolerance (None: ``dpim.tolerances.resonance``); ``max_live``: at most this many shifted
    factorisations alive at once (:class:`~stepnf.dpim.multimode.solves.ManifoldSolves`; None: all kept);
    ``progress(p)`` after each order.
    """
    order = int(order)
    if order < 3 or order % 2 == 0:
        raise ValueError(f"DPIM order must be odd and >= 3, got {order}")
    K, M = dpim.K, dpim.M
    n = K.shape[0]
    Phi = np.asarray(phis, dtype=float).reshape(n, -1)
    omega = np.asarray(omegas, dtype=float).reshape(-1)
    m = Phi.shape[1]
    if len(omega) != m:
        raise ValueError(f"{m} master shapes but {len(omega)} frequencies")
    spectrum = spectrum_of(dpim)
    if masters is None:
        masters = [int(np.argmin(np.abs(spectrum - w))) for w in omega] if spectrum is not None else range(m)
    masters = tuple(int(i) for i in masters)
    for j in range(m):
        check_mode(K, M, Phi[:, j], omega[j], masters[j])
    gram = Phi.T @ (M @ Phi)
    if not np.allclose(gram, np.eye(m), rtol=0.0, atol=EIGENPAIR_FLOOR):
        raise NumericalError(f"DPIM manifold of modes {masters}: the masters are not M-orthonormal "
                             f"(|Phi^T M Phi - I| = {np.abs(gram - np.eye(m)).max():.2e})")
    tol = dpim.tolerances.resonance if resonance is None else float(resonance)
    k_given = None
    if ratios is not None:
        k_given = np.asarray(ratios, dtype=int).reshape(m)
        r = omega / omega[0] * k_given[0]
        if np.any(k_given < 1) or np.any(np.abs(r - k_given) > tol * k_given):
            raise ValueError(f"DPIM manifold of modes {masters}: ratios {k_given.tolist()} do not match the "
                             f"frequencies {omega.tolist()} within the resonance tolerance {tol:g}")
    elif m > 1:  # a low-order resonance the frequencies show decides by ratios too, every monomial it makes resonant
        k_low = find_ratios(omega, tol, MAX_RATIO)  # kept (masters 3% apart: z0^2 conj(z1), 6% off, is 1:1's)
        k_given = k_low if k_low is not None and int(k_low.max()) <= MAX_RATIO else None
    counters = dpim.counters if dpim.counters is not None else Counters()
    sampling = MonomialSampling(m, order)
    forcing = SampledForcing(dpim.forces, K, probe, sampling, dpim.rotations)
    solves = ManifoldSolves(K, M, Phi, masters, omega, dpim.solves, counters, R=dpim.spectrum.rigid,
                            spectrum=spectrum, rigid_window=(tol * float(omega.min())) ** 2, max_live=max_live)
    try:
        W, V, f, flags, counts = recursion(forcing, solves, counters, M, Phi, omega, masters, order, tol, k_given,
                                           spectrum, progress)
    finally:
        solves.release()
    k = np.ones(1, dtype=int) if m == 1 and k_given is None else k_given
    nontrivial = [(i, a) for i, a in f if frequency(a) != tuple(int(t == i % m) * (1 if i < m else -1)
                                                                 for t in range(m))]
    if k is None and nontrivial:
        k = find_ratios(omega, tol, order)
        if k is not None and any(resonant_equations(frequency(a), omega, tol, k).count(i) == 0
                                 for i, a in nontrivial):
            k = None  # a resonant monomial the ratios do not explain: the caller must give them
    return ManifoldResult(masters, omega, Phi, M, order, W, V, f, k, flags, counts)


def recursion(forcing: SampledForcing, solves: ManifoldSolves, counters: Counters, M, Phi: np.ndarray,
              omega: np.ndarray, masters: tuple[int, ...], order: int, tol: float, ratios: np.ndarray | None,
              spectrum: np.ndarray | None, progress: Callable[[int], None] | None):
    """Orders 2..``order`` of the homological equations (module docstring): ``(W, V, f, flags, counts)``."""
    n, m = Phi.shape
    lam = np.concatenate([1j * omega, -1j * omega])
    Mop = sp.csr_matrix(M) if sp.issparse(M) else np.asarray(M)
    MPhi = np.asarray(Mop @ Phi)
    W: dict[Monomial, np.ndarray] = {}
    V: dict[Monomial, np.ndarray] = {}
    for i in range(2 * m):
        e = tuple(int(k == i) for k in range(2 * m))
        W[e] = Phi[:, i % m].astype(complex)
        V[e] = lam[i] * Phi[:, i % m]
    f: dict[Coefficient, complex] = {}
    near: dict[int, tuple[float, dict[str, Any]]] = {}  # mode -> (relative gap, flag): its closest shift only
    seen: set[float] = set()
    counts: list[dict[str, Any]] = []
    for p in range(2, order + 1):
        t0 = time.perf_counter()
        before = (forcing.stats.force_evaluations, forcing.stats.calls, counters.linear_solves,
                  counters.factorizations)
        reps = forcing.sampling.reps[p]
        N = forcing(W, p)
        wanted = set(reps)
        P, Q = transport(f, W, p, wanted), transport(f, V, p, wanted)
        groups: dict[tuple[float, tuple[int, ...]], list] = defaultdict(list)
        inertia = [a for a in reps if a in P or a in Q]  # M (Q + sigma P) of every monomial: one block product
        MX = dict(zip(inertia, np.asarray(Mop @ np.column_stack(
            [Q.get(a, 0.0) + 1j * float(np.dot(frequency(a), omega)) * P.get(a, 0.0) for a in inertia])).T)) \
            if inertia else {}
        for a in reps:
            c = frequency(a)
            d = float(np.dot(c, omega))
            sigma = 1j * d
            Pa = P.get(a, np.zeros(n, dtype=complex))
            rhs = -N[a] - MX[a] if a in MX else -N[a]
            fa = {}
            for i in resonant_equations(c, omega, tol, ratios):
                mu = Phi[:, i % m] @ rhs
                fa[i] = complex(mu / (sigma + lam[i]))
                rhs = rhs - MPhi[:, i % m] * mu
            bordered = tuple(sorted({i % m for i in fa}))
            groups[(d * d, bordered)].append((a, rhs, sigma, Pa, fa))
            key = shift_key(d * d)
            if key not in seen:
                seen.add(key)
                for gap, flag in near_resonances(d, c, omega, masters, spectrum, tol):
                    if flag["mode"] not in near or gap < near[flag["mode"]][0]:
                        near[flag["mode"]] = (gap, flag)
        for (s, bordered), items in groups.items():
            X = solves.solve(s, bordered, np.column_stack([it[1] for it in items]), str(items[0][0]))
            for (a, _, sigma, Pa, fa), x in zip(items, X.T):
                v = sigma * x + Pa + sum(fc * Phi[:, i % m] for i, fc in fa.items())
                ca = conj(a)
                if ca == a:  # self-conjugate: real
                    W[a], V[a] = x.real.astype(complex), v.real.astype(complex)
                    continue
                W[a], V[a], W[ca], V[ca] = x, v, x.conj(), v.conj()
                for i, fc in fa.items():
                    f[(i, a)] = fc
                    f[((i + m) % (2 * m), ca)] = fc.conjugate()
        counts.append({"order": p, "monomials": len(monomials(m, p)),
                       "force_evaluations": forcing.stats.force_evaluations - before[0],
                       "force_calls": forcing.stats.calls - before[1],
                       "linear_solves": counters.linear_solves - before[2],
                       "factorizations": counters.factorizations - before[3],
                       "condition": round(forcing.sampling.condition[p], 2),
                       "seconds": round(time.perf_counter() - t0, 4)})
        if progress is not None:
            progress(p)
    return W, V, f, [near[s][1] for s in sorted(near)], counts


def near_resonances(d: float, c: tuple[int, ...], omega: np.ndarray, masters: tuple[int, ...],
                    spectrum: np.ndarray | None, tol: float) -> list[tuple[float, dict[str, Any]]]:
    """``(relative gap, flag)`` of the modes outside the manifold within ``tol`` (relative) of the frequency ``|d|``
    of monomials of frequencies ``c``: a small denominator of the parametrisation (an exact one is refused by the
    solve); the recursion keeps each mode's closest."""
    if spectrum is None:
        return []
    out = []
    for s, ws in enumerate(spectrum):
        if s in masters or ws <= 0 or abs(abs(d) - ws) > tol * ws:
            continue
        message = (f"DPIM manifold of modes {masters}: mode {s} (w_s/w = {ws / omega[0]:.4f} of mode {masters[0]}) "
                   f"is near the frequency {abs(d):.6g} of the monomials of frequencies {list(c)}: K - s M is "
                   "nearly singular there, a small denominator")
        out.append((abs(abs(d) - ws) / ws, new_flag("manifold_small_denominator", mode=int(s), frequencies=list(c),
                                                     ratio=float(ws / omega[0]), message=message)))
    return out
