"""Amplitude measures of a periodic orbit of a manifold's reduced dynamics, as the single-mode backbone's.

On the orbit ``z_j(t) = zeta_j e^{i k_j Omega t}`` (:mod:`stepnf.dpim.multimode.branches`) the displacement
``x(t) = W(z(t)) = sum_alpha W[alpha] zeta^alpha e^{i n_alpha theta}``, ``theta = Omega t``,
``n_alpha = sum_l (a_l - b_l) k_l``: a Fourier series in ``theta`` with integer harmonics
``|n| <= N max(k)``. Master j's modal coordinate ``q_j = phi_j^T M x`` is the series of the scalars
``phi_j^T M W[alpha]`` (formed once), and its amplitude, as :mod:`stepnf.dpim.backbone` defines it, is
``A_j = (max_theta q_j - min_theta q_j) / 2``: found on a grid of ``64 N max(k)`` points over one period and
refined by Newton's method on the series' derivative (to round-off). ``W_max`` is the largest ``|x_i|``
over the transverse dofs and the period, found the same way.

Cost: what a measure needs of the fields is formed once, on first use, and kept (no copy of ``W``): the scalars
``phi_j^T M W[alpha]`` (m per monomial), the transverse rows of ``W``, and the Gram matrix
``G = W^H M W`` (terms x terms) that makes :meth:`OrbitMeasure.shape_difference` independent of n. A manifold's
measure is built once per resonance vector (:func:`orbit_measure`, kept on the manifold): the branches' tracing,
validity and report ask for it hundreds of times (each :func:`stepnf.dpim.multimode.backbone.point_at`), and on
the 38k-dof cap each rebuild copied ``W`` (200 MB at order 7) and each shape test multiplied it out again.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from stepnf.errors import NumericalError

Transverse = Callable[[np.ndarray], np.ndarray] | Sequence[int] | np.ndarray


class OrbitMeasure:
    """``A_j`` and ``W_max`` of the orbits of ``manifold`` (``W``, ``phi`` (n, m), ``M``, ``order``) for the
    resonance vector ``ratios`` (module docstring)."""

    def __init__(self, manifold: Any, ratios: Any):
        k = np.asarray(ratios, dtype=int)
        m = len(k)
        self.keys = [a for a in manifold.W if sum(a) >= 1]
        self.E = np.asarray(self.keys, dtype=int).reshape(len(self.keys), 2 * m)
        self.n_of = (self.E[:, :m] - self.E[:, m:]) @ k  # harmonic of each monomial
        self.nmax = int(np.abs(self.n_of).max())
        self.pmax = int(self.E.max())
        self.W = manifold.W
        n = len(np.asarray(manifold.W[self.keys[0]]))
        Mphi = np.asarray(manifold.M @ np.asarray(manifold.phi).reshape(n, m))  # (n, m)
        self.P = np.column_stack([Mphi.T @ np.asarray(manifold.W[a]) for a in self.keys])  # (m, terms)
        self.theta = np.linspace(0.0, 2 * np.pi, 64 * int(manifold.order) * max(int(np.abs(k).max()), 1),
                                 endpoint=False)
        ns = np.arange(self.nmax + 1)
        self._cos, self._sin = np.cos(np.outer(ns, self.theta)), np.sin(np.outer(ns, self.theta))
        self._transverse: tuple | None = None
        self.M, self.order_of = manifold.M, self.E.sum(axis=1)
        self._E: np.ndarray | None = None  # e^{i n theta} (2 nmax + 1, grid) of shape_difference
        self._G: np.ndarray | None = None  # W^H M W (terms, terms) of shape_difference

    def _stack(self) -> np.ndarray:
        """The monomials' fields as columns (n, terms), complex: a temporary copy."""
        return np.column_stack([np.asarray(self.W[a], dtype=complex) for a in self.keys])

    def _gram(self) -> np.ndarray:
        """``G = W^H M W`` (terms, terms), formed once (module docstring), in column blocks of 64 fields."""
        if self._G is None:
            T = len(self.keys)
            Ws = self._stack()
            G = np.empty((T, T), dtype=complex)
            for c in range(0, T, 64):  # W^H (M W_c) = ((M W_c)^H W)^H: no conjugate copy of W
                MW = np.asarray(self.M @ Ws[:, c:c + 64])
                G[:, c:c + 64] = (MW.conj().T @ Ws).conj().T
            self._G = G
        return self._G
    def shape_difference(self, zeta: np.ndarray, cut: int) -> float:
        """``max_theta |x_high|_M / max_theta |x|_M`` on the orbit of ``zeta``: the terms of orders above ``cut``
        against the whole field (:meth:`stepnf.dpim.backbone.Backbone.shape_difference`, there at the same rho)."""
        if self._E is None:
            self._E = np.exp(1j * np.outer(np.arange(-self.nmax, self.nmax + 1), self.theta))
        mono = self._monomials(zeta)
        whole = self._peak(mono)
        return float(np.sqrt(max(self._peak(mono * (self.order_of > cut)), 0.0) / whole)) if whole > 0 else 0.0

    def _peak(self, coef: np.ndarray) -> float:
        """Largest ``|x(theta)|_M^2`` over the grid, ``x = sum_t coef_t W_t e^{i n_t theta}``: the harmonics'
        fields ``C_h = sum_{n_t = h} coef_t W_t``, their Gram ``S = C^H M C = B^H G B`` (``B`` (terms, harmonics)
        the coefficients by harmonic, ``G`` :meth:`_gram`), then ``sum_hk conj(e_h) S_hk e_k``."""
        T, H = len(coef), 2 * self.nmax + 1
        B = np.zeros((T, H), dtype=complex)
        B[np.arange(T), self.n_of + self.nmax] = coef
        S = B.conj().T @ (self._gram() @ B)  # (H, H)
        return float(np.max(np.einsum("ht,ht->t", self._E.conj(), S @ self._E).real))

    def _monomials(self, zeta: np.ndarray) -> np.ndarray:
        z = np.concatenate([zeta, np.conj(zeta)])
        pw = z[:, None] ** np.arange(self.pmax + 1)[None, :]
        return np.prod(pw[np.arange(len(z))[None, :], self.E], axis=1)  # (terms,)

    def _series(self, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(a, b)`` (rows, nmax + 1) with ``q = sum_n a_n cos(n theta) + b_n sin(n theta)`` from the
        complex coefficients ``coef`` (rows, terms) of the monomials' ``e^{i n theta}``."""
        C = np.zeros((coef.shape[0], 2 * self.nmax + 1), dtype=complex)
        for n in np.unique(self.n_of):
            C[:, n + self.nmax] = coef[:, self.n_of == n].sum(axis=1)
        return self._fourier(C)

    def _fourier(self, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(a, b)`` (rows, nmax + 1), the cos and sin coefficients of the series whose ``e^{i n theta}``
        coefficients are ``C`` (rows, 2 nmax + 1), ``n = -nmax..nmax``."""
        pos, neg = C[:, self.nmax:], C[:, self.nmax::-1]  # c_n and c_-n, n >= 0
        a = (pos + neg).real
        a[:, 0] = C[:, self.nmax].real
        b = (-(pos - neg).imag)
        b[:, 0] = 0.0
        return a, b

    def amplitudes(self, zeta: np.ndarray) -> np.ndarray:
        """``A_j`` (m,) of every master on the orbit of ``zeta`` (module docstring)."""
        a, b = self._series(self.P * self._monomials(zeta)[None, :])
        q = a @ self._cos + b @ self._sin
        out = []
        for j in range(len(a)):
            hi = _refine(a[j], b[j], self.theta, int(np.argmax(q[j])), maximise=True)
            lo = _refine(a[j], b[j], self.theta, int(np.argmin(q[j])), maximise=False)
            out.append(0.5 * (hi - lo))
        return np.asarray(out)

    def w_max(self, zeta: np.ndarray, transverse: Transverse, h: float = 1.0) -> float:
        """Largest ``|x_i|`` over the transverse dofs and the period, divided by ``h``: ``transverse`` the
        indices of those dofs or a callable mapping real fields (n, k) to transverse displacements (t, k), linear
        (the manifold's complex coefficients go through it as their real and imaginary parts).

        Each dof's harmonics ``C_h = sum_{n_alpha = h} T_alpha zeta^alpha`` by one product per harmonic (the
        transverse rows kept sorted by harmonic); the grid is then searched only on the dofs that can hold its
        maximum: ``sum_n |a_n| + |b_n|`` bounds ``|x_i(theta)|``, and a dof whose bound is below the largest value on
        every 16th grid point (a subset of the grid; less 1e-12 relative for the bound's rounding) cannot reach the
        grid's maximum. The same maximum as evaluating every dof on the grid (to round-off: the rows kept go
        through the same products), at a fraction of the cost (the dofs near the largest displacement; 48 of 133 on
        random fields, few on a mode shape): this measure is called at every point of every branch (348 times on the
        38k-dof cap's order-7 manifold: 19 s of its run before; the run 224 -> 202 s). A non-finite field (a
        diverged branch point) is a :class:`~stepnf.errors.NumericalError`, not a NaN."""
        if self._transverse is None or self._transverse[0] is not transverse:
            if callable(transverse):  # a real linear map (an adapter's takes real fields: casting a complex field
                # to float would drop its imaginary part), applied to both parts
                Ws = self._stack()
                T = np.asarray(transverse(Ws.real)) + 1j * np.asarray(transverse(Ws.imag))
            else:
                rows = np.asarray(transverse)
                T = np.column_stack([np.asarray(self.W[a])[rows] for a in self.keys])
            order = np.argsort(self.n_of, kind="stable")
            cuts = np.searchsorted(self.n_of[order], np.arange(-self.nmax, self.nmax + 2))
            self._transverse = (transverse, np.ascontiguousarray(np.asarray(T)[:, order]), order, cuts)
        _, Ts, order, cuts = self._transverse
        mono = self._monomials(zeta)[order]
        C = np.zeros((Ts.shape[0], 2 * self.nmax + 1), dtype=complex)
        for i in range(2 * self.nmax + 1):
            if cuts[i + 1] > cuts[i]:
                C[:, i] = Ts[:, cuts[i]:cuts[i + 1]] @ mono[cuts[i]:cuts[i + 1]]
        a, b = self._fourier(C)
        coarse = np.abs(a @ self._cos[:, ::16] + b @ self._sin[:, ::16]).max()
        if not np.isfinite(coarse):
            raise NumericalError(f"W_max: the displacement on the orbit of zeta = {zeta} is not finite")
        keep = np.flatnonzero(np.abs(a).sum(axis=1) + np.abs(b).sum(axis=1) >= coarse * (1.0 - 1e-12))
        x = a[keep] @ self._cos + b[keep] @ self._sin
        i, t = np.unravel_index(int(np.argmax(np.abs(x))), x.shape)
        sign = 1.0 if x[i, t] >= 0 else -1.0
        return _refine(sign * a[keep[i]], sign * b[keep[i]], self.theta, int(t), maximise=True) / h


def _refine(a: np.ndarray, b: np.ndarray, grid: np.ndarray, i: int, *, maximise: bool) -> float:
    """Extremum of ``f(t) = sum_n a_n cos(n t) + b_n sin(n t)`` near ``grid[i]``: Newton on ``f'`` kept
    within one grid spacing (as :func:`stepnf.dpim.backbone._refine`, with sines)."""
    ns = np.arange(len(a))
    h = grid[1] - grid[0]
    t0 = t = float(grid[i])

    def f(s: float) -> float:
        return float(a @ np.cos(ns * s) + b @ np.sin(ns * s))
    for _ in range(30):
        c, s_ = np.cos(ns * t), np.sin(ns * t)
        d1 = float(np.sum(ns * (b * c - a * s_)))
        d2 = -float(np.sum(ns * ns * (a * c + b * s_)))
        if d2 == 0 or (d2 > 0 if maximise else d2 < 0):
            break
        step = d1 / d2
        t -= step
        if abs(t - t0) > h:
            t = t0
            break
        if abs(step) <= 1e-15 * max(1.0, abs(t)):
            break
    best, g = f(t), f(t0)
    return max(best, g) if maximise else min(best, g)


def orbit_measure(manifold: Any, ratios: Any) -> OrbitMeasure:
    """The :class:`OrbitMeasure` of ``manifold`` for ``ratios``, built once and kept on the manifold (module
    docstring, "Cost"; a manifold that takes no attribute gets a new one each call)."""
    key = tuple(int(x) for x in np.asarray(ratios, dtype=int).ravel())
    cache = getattr(manifold, "_orbit_measures", None)
    if cache is None:
        cache = {}
        try:
            manifold._orbit_measures = cache
        except AttributeError:
            return OrbitMeasure(manifold, ratios)
    if key not in cache:
        cache[key] = OrbitMeasure(manifold, ratios)
    return cache[key]
