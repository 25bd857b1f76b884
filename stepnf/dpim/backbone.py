"""The backbone of a DPIM parametrisation: frequency against the measured amplitude, and its validity.

On the manifold ``x(theta, rho) = sum_p rho^p sum_m Y[p, m] cos(m theta)`` the
motion is ``theta = Omega(rho) t``, so the period is ``2 pi / Omega(rho)``
(:mod:`stepnf.dpim.parametrisation`). The amplitude is measured on that motion, as the issue
defines it: ``A = (max_t q_p - min_t q_p) / 2`` with
``q_p = phi^T M x = sum_p rho^p sum_m a[p, m] cos(m theta)``, found on a
phase grid of ``64 N`` points over [0, pi] (x is even in theta) and refined
by Newton's method on the series' derivative (to round-off). ``W_max`` is the
largest ``|x_i|`` over the transverse dofs and the period, measured the same
way. ``omega(A)`` inverts ``A(rho)`` (Brent; A(rho) = rho + O(rho^2)).

Validity: the largest A below which orders N and N-2 give frequencies that
differ by at most ``tol`` relative (both at the same measured A) and
displacements that differ by at most ``sqrt(tol)`` (the largest M-norm over the
period of the terms of orders N-1 and N, against that of the whole field, at the
same rho). The frequency is stationary with respect to the shape (Rayleigh's
quotient): a shape error ``e`` moves it by ``~e^2``, so ``sqrt(tol)`` asks of the
shape what ``tol`` asks of the frequency. Without the second test a series that
diverges in the modes other than the master (W_max/h growing without bound while
``q_p`` stays moderate) would be called valid.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
from scipy.optimize import brentq

from stepnf.errors import NumericalError

Transverse = Callable[[np.ndarray], np.ndarray] | Sequence[int] | np.ndarray


class Backbone:
    """``omega(A)``, ``A(rho)``, ``W_max(rho)`` of a :class:`stepnf.dpim.parametrisation.DPIMResult` (module docstring)."""

    def __init__(self, res: Any):
        self.res = res
        self.N = res.order
        self.a = np.zeros((self.N + 1, self.N + 1))  # a[p, m] = phi^T M Y[p, m]
        Mphi = res.M @ res.phi
        for (p, m), y in res.Y.items():
            self.a[p, m] = float(Mphi @ y)
        self.theta = np.linspace(0.0, np.pi, 64 * self.N + 1)
        self._cos = np.cos(np.outer(np.arange(self.N + 1), self.theta))  # (m, theta)
        self._transverse_kept: tuple | None = None  # (transverse, keys, parts) of _transverse_parts
        self._sums_kept: tuple | None = None  # (parts, T3, sums) of _transverse_sums
        self._gram: tuple | None = None  # (keys, Y^T M Y) of shape_difference

    # ------------------------------------------------------------ frequency
    def frequency(self, rho: float | np.ndarray) -> np.ndarray | float:
        """``Omega(rho) = omega + sum_k c_k rho^(2k)`` (rad per model time unit)."""
        r2 = np.asarray(rho, dtype=float) ** 2
        out = np.full(r2.shape, self.res.omega)
        for k, ck in enumerate(self.res.c, start=1):
            out = out + ck * r2 ** k
        return float(out) if out.ndim == 0 else out

    # ------------------------------------------------------------ amplitude
    def amplitude(self, rho: float) -> float:
        """``A(rho) = (max q_p - min q_p) / 2`` over one period (module docstring)."""
        cm = ((rho ** np.arange(self.N + 1))[:, None] * self.a).sum(axis=0)  # coefficient of cos(m theta)
        q = cm @ self._cos
        hi = _refine(cm, self.theta, int(np.argmax(q)), maximise=True)
        lo = _refine(cm, self.theta, int(np.argmin(q)), maximise=False)
        return 0.5 * (hi - lo)

    def amplitudes(self, rho: np.ndarray) -> np.ndarray:
        """:meth:`amplitude` at every ``rho`` (n,) (point by point: :func:`_refine` says why)."""
        return np.asarray([self.amplitude(float(r)) for r in np.asarray(rho, dtype=float)]).reshape(-1)

    def rho_at(self, A: float) -> float:
        """The ``rho`` whose measured amplitude is ``A`` (NumericalError when A(rho) never reaches it)."""
        if A <= 0:
            return 0.0
        hi, prev = float(A), 0.0
        for _ in range(200):
            with np.errstate(over="ignore", invalid="ignore"):  # rho^p overflows far out: not a number, stop
                Ahi = self.amplitude(hi)
            if not np.isfinite(Ahi):
                break
            if Ahi >= A:
                return brentq(lambda r: self.amplitude(r) - A, 0.0, hi, xtol=1e-15 * hi, rtol=1e-15)
            if Ahi <= prev:
                break
            prev, hi = Ahi, hi * 1.25
        why = f"its A(rho) stops growing at {prev:.6g}" if prev > 0 else "the series overflows on the way"
        raise NumericalError(f"DPIM backbone: the order-{self.N} parametrisation never reaches the amplitude "
                             f"A = {A:.6g} ({why})")

    def omega_at(self, A: float | Sequence[float]) -> np.ndarray:
        """Backbone frequencies (rad per time unit) at the amplitudes ``A`` of ``q_p``."""
        return np.asarray([self.frequency(self.rho_at(float(x))) for x in np.atleast_1d(A)])

    # -------------------------------------------------------- W_max / h
    def w_max(self, rho: float, transverse: Transverse, h: float = 1.0) -> float:
        """Largest transverse displacement over the period divided by ``h``: :meth:`w_max_many` at one point.

        ``transverse``: indices of the transverse dofs, or a callable mapping
        displacement fields (n, k) to transverse displacements (t, k).
        """
        return float(self.w_max_many(np.array([rho], dtype=float), transverse, h)[0])

    def _transverse_parts(self, keys: list, transverse: Transverse) -> np.ndarray:
        """The transverse parts (t, terms) of the coefficients ``Y[k]``, ``k`` in ``keys``; kept for the
        last ``transverse`` asked (they do not depend on rho)."""
        kept = self._transverse_kept
        if kept is not None and kept[0] is transverse and kept[1] == keys:
            return kept[2]
        Ystack = self.res.stacked(keys).T  # (n, terms): a view of the result's own stack, no copy
        Tc = np.asarray(transverse(Ystack) if callable(transverse) else Ystack[np.asarray(transverse)], dtype=float)
        self._transverse_kept = (transverse, keys, Tc)
        return Tc

    def w_max_at(self, A: float | Sequence[float], transverse: Transverse, h: float = 1.0) -> np.ndarray:
        """``W_max / h`` at the amplitudes ``A`` of ``q_p`` (see :meth:`w_max`)."""
        return np.asarray([self.w_max(self.rho_at(float(x)), transverse, h) for x in np.atleast_1d(A)])

    def w_max_many(self, rho: np.ndarray, transverse: Transverse, h: float = 1.0) -> np.ndarray:
        """``W_max / h`` at every ``rho`` (n,) at once: only the transverse dofs that can hold the peak are expanded
        over the phase grid, then the largest value is refined by Newton (:func:`_refine`). ``sum_m |C_im|`` bounds
        ``max |x_i(theta)|`` and ``|x_i|`` at theta = 0, pi is reached; the dofs whose looser bound ``sum_p |rho|^p
        sum_m |T_ipm|`` reaches the largest of those are found for all points by one product with the ``(t, N + 1)``
        sums, and only they get their ``C_im(rho)`` (on the 38k-dof cap: a few hundred of 13k transverse dofs).
        Memory: about 2e6 values (16 MB) at a time."""
        rho = np.asarray(rho, dtype=float)
        T3, sums = self._transverse_sums(transverse)
        t, G = T3.shape[0], self._cos.shape[1]
        signs = (-1.0) ** np.arange(self.N + 1)
        out = np.zeros(len(rho))  # 0 where rho = 0 (no field)
        live = np.flatnonzero(rho != 0)
        step = max(1, int(2e6 // max(1, 3 * t)))  # points per product
        for k in (live[k0:k0 + step] for k0 in range(0, len(live), step)):
            R = rho[k, None] ** np.arange(self.N + 1)
            X, bound = R @ sums[:, : 2 * t], np.abs(R) @ sums[:, 2 * t:]
            seen = np.abs(X).max(axis=1)
            cand = np.flatnonzero((bound >= seen[:, None] * (1.0 - 1e-9)).any(axis=0))  # (+ round-off)
            C = np.einsum("np,ipm->nim", R, T3[cand])  # (points, candidates, m)
            reached = np.maximum(np.abs(C.sum(axis=2)).max(axis=1), np.abs(C @ signs).max(axis=1))
            pt, row = np.nonzero(np.abs(C).sum(axis=2) >= reached[:, None] * (1.0 - 1e-12))  # w_max's rows
            best, j, val = np.empty(len(pt)), np.empty(len(pt), dtype=int), np.empty(len(pt))
            blk = max(1, int(2e6 // G))
            for b0 in range(0, len(pt), blk):  # each (point, dof) expanded over the grid: its largest |x|
                Wt = C[pt[b0:b0 + blk], row[b0:b0 + blk]] @ self._cos
                jb = np.argmax(np.abs(Wt), axis=1)
                j[b0:b0 + blk], val[b0:b0 + blk] = jb, Wt[np.arange(len(jb)), jb]
                best[b0:b0 + blk] = np.abs(val[b0:b0 + blk])
            top = np.full(len(k), -1.0)
            np.maximum.at(top, pt, best)
            first = np.flatnonzero(best == top[pt])
            first = first[np.unique(pt[first], return_index=True)[1]]  # the first dof holding each point's max
            sign = np.sign(val[first])
            sign[sign == 0] = 1.0
            out[k[pt[first]]] = [_refine(sg * C[p, r], self.theta, int(jj), maximise=True) / h
                                 for sg, p, r, jj in zip(sign, pt[first], row[first], j[first])]
        return out

    def _transverse_sums(self, transverse: Transverse) -> tuple[np.ndarray, np.ndarray]:
        """``(T3, sums)`` of :meth:`w_max_many`: the transverse parts as ``T3[i, p, m]`` and ``(N + 1, 3 t)`` sums
        ``[sum_m T3, sum_m (-1)^m T3, sum_m |T3|]`` (x_i at theta = 0, pi, the bound); kept for the last
        ``transverse``."""
        keys = sorted(self.res.Y)  # the order of the result's stack (DPIMResult.stacked); each (p, m) has one column
        Tc = self._transverse_parts(keys, transverse)
        kept = self._sums_kept
        if kept is not None and kept[0] is Tc:
            return kept[1], kept[2]
        T3 = np.zeros((Tc.shape[0], self.N + 1, self.N + 1))
        for j, (p, m) in enumerate(keys):
            T3[:, p, m] += Tc[:, j]
        sums = np.vstack([T3.sum(axis=2), (T3 * (-1.0) ** np.arange(self.N + 1)).sum(axis=2),
                          np.abs(T3).sum(axis=2)]).T
        self._sums_kept = (Tc, T3, sums)
        return T3, sums

    # ---------------------------------------------------------- validity
    def shape_difference(self, rho: float) -> float:
        """``max_theta |x_N - x_{N-2}|_M / max_theta |x_N|_M`` at ``rho``: the terms of orders N-1 and N
        against the whole field, on the phase grid (``Y^T M Y`` formed once)."""
        if self._gram is None:
            keys = sorted(self.res.Y)
            Ystack = self.res.stacked(keys).T  # (n, terms): a view of the result's own stack, no copy
            self._gram = (keys, Ystack.T @ (self.res.M @ Ystack))
        keys, G = self._gram
        P = np.zeros((len(keys), self.N + 1))
        for j, (p, m) in enumerate(keys):
            P[j, m] = rho ** p
        high = np.asarray([p > self.N - 2 for p, _ in keys])

        def peak(P: np.ndarray) -> float:  # largest |x(theta)|_M^2 over the grid
            S = P.T @ G @ P  # (m, m') Gram of the cosine coefficients
            return float(np.max(np.einsum("mt,mt->t", S @ self._cos, self._cos)))

        whole = peak(P)
        return float(np.sqrt(max(peak(P * high[:, None]), 0.0) / whole)) if whole > 0 else 0.0

    def validity_limit(self, tol: float = 1e-3, lower: "Backbone | None" = None,
                       steps: int = 400, growth: float = 1.05) -> tuple[float | None, str]:
        """``(A_max, reason)``: the largest A with ``|omega_N(A) - omega_{N-2}(A)| <= tol omega`` and the
        shapes of orders N and N-2 within ``sqrt(tol)`` (:meth:`shape_difference`).

        Marches rho up by ``growth`` from a small value and refines the first
        crossing by Brent's method. ``reason`` says what ended the march:
        ``"orders differ"`` (the frequencies), ``"shapes differ"`` (the displacements, module
        docstring), ``"amplitude folds"`` (A(rho) stops growing) or ``"not reached"`` (A_max is then None).
        """
        if lower is None:
            lower = Backbone(self.res.truncated(self.N - 2)) if self.N >= 3 else None
        w = self.res.omega
        c1 = abs(self.res.c[0]) if len(self.res.c) else 0.0
        rho = 1e-4 * (np.sqrt(w / c1) if c1 > 0 else 1.0)

        shape_tol = float(np.sqrt(tol))

        def frequency_excess(r: float) -> float:
            A = self.amplitude(r)
            return abs(self.frequency(r) - lower.frequency(lower.rho_at(A))) / w / tol - 1.0

        def diff(r: float) -> float:  # > 0 where the orders differ (frequency or shape)
            return max(frequency_excess(r), self.shape_difference(r) / shape_tol - 1.0)

        prev_r, prev_A = 0.0, 0.0
        for _ in range(steps):
            with np.errstate(over="ignore", invalid="ignore"):
                A = self.amplitude(rho)
            if not np.isfinite(A) or A <= prev_A:
                return prev_A, "amplitude folds"
            try:
                with np.errstate(over="ignore", invalid="ignore"):
                    d = diff(rho)
            except NumericalError:
                return prev_A, "amplitude folds"
            if not np.isfinite(d):
                return prev_A, "amplitude folds"
            if d > 0:
                if prev_r == 0.0:
                    return 0.0, "orders differ"
                r = brentq(diff, prev_r, rho, xtol=1e-12 * rho)
                shape = self.shape_difference(r) / shape_tol - 1.0 >= frequency_excess(r)
                return self.amplitude(r), "shapes differ" if shape else "orders differ"
            prev_r, prev_A, rho = rho, A, rho * growth
        return None, "not reached"


def _refine(c: np.ndarray, grid: np.ndarray, i: int, *, maximise: bool) -> float:
    """Extremum of the cosine series ``f(t) = sum_m c[m] cos(m t)`` near ``grid[i]``.

    Newton on ``f'`` (exact derivatives, quadratic convergence) from the grid point, kept within one
    grid spacing of it; the grid value is the answer when Newton leaves that interval or does worse
    (a flat or kinked extremum). About ten times cheaper than a bounded Brent search, to round-off.
    One series at a time, also for many points (:meth:`Backbone.amplitudes`, :meth:`Backbone.w_max_many`):
    A(rho) is called one point at a time inside Brent's method (:meth:`Backbone.rho_at`, ~1500 calls per
    :meth:`Backbone.validity_limit`), where a form over arrays costs 2-3 times more per point (numpy's
    per-call overhead on arrays of one row: the backbone stage of examples/beam/beam_fenicsx.toml twice as
    long); over an FRC's points the loop costs ~55 us per point (1200 points: 0.09 s instead of 0.02 s).
    """
    ms = np.arange(len(c))
    mc, m2c = ms * c, ms * ms * c
    h = grid[1] - grid[0]
    t0 = t = float(grid[i])
    for _ in range(30):
        d1, d2 = -float(mc @ np.sin(ms * t)), -float(m2c @ np.cos(ms * t))
        if d2 == 0 or (d2 > 0 if maximise else d2 < 0):  # not curving the right way: keep the grid value
            break
        step = d1 / d2
        t -= step
        if abs(t - t0) > h:
            t = t0
            break
        if abs(step) <= 1e-15 * max(1.0, abs(t)):
            break
    best, g = float(c @ np.cos(ms * t)), float(c @ np.cos(ms * t0))
    return max(best, g) if maximise else min(best, g)
