"""Time integration of the full model ``M x'' + f(x) = 0``: an energy-conserving implicit scheme, and
the frequency and amplitude of the master coordinate measured on its trajectory.

**Scheme (average vector field, a discrete gradient).** With ``x1 - x0 = dt (v0 + v1) / 2`` and::

    M (v1 - v0) = -dt fbar,     fbar = int_0^1 f(x0 + s (x1 - x0)) ds

the energy ``E = v^T M v / 2 + V(x)`` (``f = grad V``) is conserved exactly:
``(v1 + v0)^T M (v1 - v0) / 2 = -(x1 - x0)^T fbar = -(V(x1) - V(x0))``. For a cubic ``f`` the
integrand is a cubic polynomial in ``s`` and Simpson's rule is exact::

    fbar = [f(x0) + 4 f(xm) + f(x1)] / 6 = f(xm) + [f(x0) - 2 f(xm) + f(x1)] / 6,   xm = (x0 + x1) / 2

(the midpoint force plus a correction, from force evaluations only). For an ``f`` that is not an
exact cubic (finite rotations beyond St Venant-Kirchhoff's cubic) Simpson's rule leaves an
``O(dt^4)`` error in the energy, bounded over the run. For a linear ``f`` the scheme is the
trapezoidal rule (Newmark's average acceleration): second order, symmetric (time-reversible),
no numerical damping, frequency error ``-(w dt)^2 / 12 + (w dt)^4 / 80 - ...``; the global error
of a symmetric method expands in even powers of ``dt``, which is what makes Richardson
extrapolation over ``dt, dt/2, dt/4`` effective (:func:`romberg`).

**Newton.** The unknown is ``x1`` (``v1 = 2 (x1 - x0) / dt - v0``); the residual is
``r = (2 / dt^2) M (x1 - x0 - dt v0) + fbar`` with Jacobian
``(2 / dt^2) M + (2 Kt(xm) + Kt(x1)) / 6``. ``jacobian = "modified"`` uses
``J0 = (2 / dt^2) M + K / 2`` factorised once per step size (contraction about
``(w dt)^2 / 4`` times the relative nonlinear stiffness: a few iterations at accurate steps);
``"tangent"`` the adapter's tangent at the predicted midpoint, factorised once per step;
``"differences"`` Newton-Krylov with ``J v`` by directional differences of the forces, preconditioned
by ``J0`` (:mod:`stepnf.verify.krylov`: no tangent needed); ``"auto"`` modified Newton, switching for a
step whose modified iteration does not contract to the tangent when one is given, else to the
*secant stage* (the same iteration with a deep Anderson memory, :data:`DEEP_DEPTH`: a multisecant
quasi-Newton whose low-rank correction of ``J0^-1`` is built from the differences of the residual
along its own iterates), else to ``"differences"``. Once the modified iteration has failed it is not
tried again in the run (a slender structure at a few thicknesses, where ``Kt`` differs from ``K`` by
its membrane stiffening on ~20 directions, fails it at every step); the secant stage is tried at every
step after that, Newton-Krylov (~4 times its cost) only where it fails. ``"modified"`` stops after
the secant stage.
Each iteration sends the two fields ``xm`` and ``x1`` to the black box in one batched call.

**Step control**: a step none of these converges is done again as two half steps (each possibly
halved again, :data:`HALVINGS` times at most); the trajectory is still recorded at the full steps
(``halved_steps`` counts them). A halved step is another discretisation of the fast, unresolved
components (``w_max dt >> 1``), which Richardson extrapolation does not know of: the trajectory can
move by more than its estimate (tests/verify/test_newton_stages.py's stiff string, w_max dt ~ 200:
9% and 25% after 40 steps halved differently), so ``stepnf verify`` notes such steps under its table; more
steps per period avoid them.

**Measurements** (:func:`crossings`, :func:`fit_period`, :func:`extrema`) work on the master
coordinate ``q = phi^T M x`` and its rate ``q' = phi^T M v`` at every step, interpolated by the
cubic Hermite polynomial of ``(q, q')`` within a step (error ``O(dt^4)``, below the scheme's).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.runtime.counters import Counters
from stepnf.errors import NumericalError
from stepnf.linalg.factorization import factorize

ForceBatch = Callable[[np.ndarray], np.ndarray]
JACOBIANS = ("auto", "modified", "tangent", "differences")
#: The secant stage (module docstring): Anderson memory, iterations, and the iterations without halving the
#: increment after which it gives up (Anderson, like GMRES, stalls while it learns the outlying directions).
#: A cantilever, L/h = 100, at W / h = 2, 4, 8: ~20 directions where J0^-1 J is far from 1 (up to 10 at W = 2 h),
#: ~17, 28, 49 iterations a step; depth 5 does not converge, nor depth 40 at 4 h with a patience of 6.
DEEP_DEPTH = 40
DEEP_ITERATIONS = 150
DEEP_PATIENCE = 20
#: How many times a step that does not converge is halved (a step of dt / 2**HALVINGS at the least).
HALVINGS = 3


@dataclass
class Trajectory:
    """What one run of :class:`EnergyConserving` recorded.

    ``t`` (s + 1,) times (model time units); ``q``, ``qd`` (s + 1,) the watched coordinate
    ``w^T x`` and its rate ``w^T v`` at every step; ``states`` ``(t, x, v)`` every ``keep`` steps
    (the first and the last always); ``energy_drift`` the largest ``|E - E0| / E0`` at the kept
    states when a potential was given (else None); ``iterations``, ``force_evaluations``,
    ``factorizations``, ``tangent_steps`` the work done; ``secant_steps`` the steps given to the secant
    stage (:data:`DEEP_DEPTH`); ``krylov_steps`` the steps given to Newton-Krylov
    (:mod:`stepnf.verify.krylov`), ``jacobian_products`` its directional differences (four fields each),
    ``halved_steps`` the steps done again as half steps.
    """

    dt: float
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    states: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    energy_drift: float | None = None
    iterations: int = 0
    force_evaluations: int = 0
    factorizations: int = 0
    tangent_steps: int = 0
    secant_steps: int = 0
    krylov_steps: int = 0
    jacobian_products: int = 0
    halved_steps: int = 0


class EnergyConserving:
    """The average-vector-field scheme for ``M x'' + f(x) = 0`` (module docstring).

    ``M``, ``K`` (n, n) sparse or dense (model units); ``forces(U)`` internal forces (m, n) of
    the fields ``U`` (m, n), one per row; ``tangent(x)`` the tangent stiffness (n, n) or None;
    ``tol`` the Newton tolerance on the displacement increment, relative to the largest
    displacement of the initial state; ``depth`` the Anderson acceleration's memory (0: plain
    modified Newton); ``backend`` the linear solver (:func:`stepnf.linalg.factorization.factorize`);
    ``jacobian`` one of :data:`JACOBIANS` (module docstring).
    """

    def __init__(self, M, K, forces: ForceBatch, *, tangent: Callable | None = None, jacobian: str = "auto",
                 tol: float = 1e-12, maxiter: int = 40, depth: int = 5, backend: str = "auto",
                 counters: Counters | None = None, hint: str = ""):
        if jacobian not in JACOBIANS:
            raise ValueError(f"jacobian must be one of {list(JACOBIANS)}, got {jacobian!r}")
        if jacobian == "tangent" and tangent is None:
            raise ValueError("jacobian = 'tangent' needs a tangent stiffness")
        self.M = sp.csr_matrix(M) if sp.issparse(M) else np.asarray(M, dtype=float)
        self.K = sp.csr_matrix(K) if sp.issparse(K) else np.asarray(K, dtype=float)
        self.forces, self.tangent, self.jacobian = forces, tangent, jacobian
        self.tol, self.maxiter, self.depth, self.backend = float(tol), int(maxiter), int(depth), backend
        self.counters = counters if counters is not None else Counters()
        self.hint = hint  # said after a step that does not converge (stepnf verify: the keys to change)
        self._fac: dict[float, object] = {}
        self._krylov = None  # stepnf.verify.krylov.KrylovNewton, made on first need (its Krylov memory kept)
        self._stage = 0  # the first of _solve's stages tried (1, the secant stage, once modified Newton failed)

    # ------------------------------------------------------------ linear algebra
    def _matrix(self, dt: float, Kref) -> object:
        A = (2.0 / dt ** 2) * self.M + 0.5 * Kref
        return factorize(A, counters=self.counters, backend=self.backend,
                         label=f"2 M / dt^2 + K / 2 (dt = {dt:.6g})")

    def _modified(self, dt: float):
        if dt not in self._fac:
            if len(self._fac) > HALVINGS:  # the run's step and its halves at most
                self._fac.clear()
            self._fac[dt] = self._matrix(dt, self.K)
        return self._fac[dt]

    def _f(self, U: np.ndarray) -> np.ndarray:
        self.counters.force_evaluations += len(U)
        return np.asarray(self.forces(U), dtype=float)

    # ----------------------------------------------------------------- one step
    def _newton(self, x0, v0, f0, x1, dt, J, scale, depth: int | None = None,
                maxiter: int | None = None, patience: int = 6) -> tuple[np.ndarray, np.ndarray, int, bool]:
        """Solve for ``x1`` from the guess with the factorised ``J``; ``(x1, f1, iterations, converged)``.
        ``depth``, ``maxiter``: the Anderson memory and the iterations (default :attr:`depth`, :attr:`maxiter`);
        it gives up when ``patience`` iterations have not halved the smallest increment before them.

        The fixed-point map ``x -> x - J^-1 r(x)`` is Anderson-accelerated (depth :attr:`depth`):
        with ``J`` built on K, the membrane (geometric) stiffness of a shell at amplitudes of the
        thickness changes the bending stiffness by O(1), so the plain iteration contracts by only
        ~0.5; the acceleration restores a few iterations per step.
        """
        Mx = 2.0 / dt ** 2
        depth = self.depth if depth is None else int(depth)
        maxiter = self.maxiter if maxiter is None else int(maxiter)
        hist: list[float] = []
        X, Fh = [], []
        for it in range(1, maxiter + 1):
            F = self._f(np.stack([0.5 * (x0 + x1), x1]))
            fbar = (f0 + 4.0 * F[0] + F[1]) / 6.0
            r = Mx * (self.M @ (x1 - x0 - dt * v0)) + fbar
            if not np.all(np.isfinite(r)):  # forces not finite at this iterate: not converging
                return x1, F[1], it, False
            dx = -J.solve(r)
            size = float(np.abs(dx).max())
            if not np.isfinite(size):
                return x1, F[1], it, False
            if size <= self.tol * scale:
                return x1 + dx, self._f((x1 + dx)[None])[0], it, True
            X.append(x1.copy())
            Fh.append(dx)
            if len(X) > 1 and depth:
                X, Fh = X[-depth - 1:], Fh[-depth - 1:]
                dF = np.column_stack([Fh[i + 1] - Fh[i] for i in range(len(Fh) - 1)])
                dX = np.column_stack([X[i + 1] - X[i] for i in range(len(X) - 1)])
                gamma = np.linalg.lstsq(dF, dx, rcond=None)[0]
                x1 = x1 + dx - (dX + dF) @ gamma
            else:
                x1 = x1 + dx
            hist.append(size)
            if it >= 2 * patience and min(hist[-patience:]) > 0.5 * min(hist[:-patience]):  # no progress
                return x1, F[1], it, False
        return x1, F[1], maxiter, False

    def run(self, x0: np.ndarray, v0: np.ndarray, dt: float, steps: int, *, watch: np.ndarray,
            keep: int = 0, potential: Callable[[np.ndarray], float] | None = None,
            what: str = "time integration") -> Trajectory:
        """Integrate ``steps`` steps of ``dt`` from ``(x0, v0)``; record ``watch^T x``, ``watch^T v``.

        ``keep``: also keep the states every ``keep`` steps (0: first and last only);
        ``potential``: ``V(x)`` for the energy drift at the kept states. A Newton iteration that
        neither converges nor can switch to a tangent, or a state that is not finite or grows
        beyond 1e3 times the initial one, raises :class:`NumericalError` naming ``what`` and the time.
        """
        x = np.asarray(x0, dtype=float).copy()
        v = np.asarray(v0, dtype=float).copy()
        watch = np.asarray(watch, dtype=float)
        ev0, nf0 = self.counters.factorizations, self.counters.force_evaluations
        scale = max(float(np.abs(x).max()), float(np.abs(v).max()) * dt, 1e-300)
        f = self._f(x[None])[0]
        a = None
        t, q, qd = np.zeros(steps + 1), np.zeros(steps + 1), np.zeros(steps + 1)
        q[0], qd[0] = watch @ x, watch @ v
        states = [(0.0, x.copy(), v.copy())]
        E0 = self._energy(x, v, potential)
        drift = 0.0 if E0 is not None else None
        work = dict.fromkeys(("iterations", "tangent_steps", "secant_steps", "krylov_steps", "halved_steps"), 0)
        products0 = self._krylov.products if self._krylov is not None else 0
        past = [x.copy()]
        for k in range(1, steps + 1):
            if len(past) == 4:  # cubic extrapolation of the last four states: O(dt^4)
                guess = 4.0 * past[3] - 6.0 * past[2] + 4.0 * past[1] - past[0]
            else:
                guess = x + dt * v + (0.5 * dt * dt * a if a is not None else 0.0)
            x1, v1, f1 = self._advance(x, v, f, a, guess, dt, scale, work, 0, (what, k * dt, k, dt))
            big = max(float(np.abs(x1).max()), float(np.abs(v1).max()) * dt)
            if not (np.isfinite(big) and big <= 1e3 * scale):
                raise NumericalError(f"{what}: the integration diverged at t = {k * dt:.6g} "
                                     f"(|x| grew to {big:.3g}, 1e3 times the initial state)")
            a = (v1 - v) / dt
            past = (past + [x1])[-4:]
            x, v, f = x1, v1, f1
            t[k], q[k], qd[k] = k * dt, watch @ x, watch @ v
            if (keep and k % keep == 0) or k == steps:
                states.append((k * dt, x.copy(), v.copy()))
                E = self._energy(x, v, potential)
                if E is not None:
                    drift = max(drift, abs(E - E0) / abs(E0))
        products = (self._krylov.products if self._krylov is not None else 0) - products0
        return Trajectory(dt, t, q, qd, states, drift, work["iterations"], self.counters.force_evaluations - nf0,
                          self.counters.factorizations - ev0, work["tangent_steps"], work["secant_steps"],
                          work["krylov_steps"], products, work["halved_steps"])

    def _solve(self, x, v, f, guess, dt, scale, work) -> tuple[np.ndarray, np.ndarray, bool]:
        """``(x1, f1, converged)`` of one step by the Newton iterations :attr:`jacobian` allows, in turn
        (module docstring); once modified Newton has failed, the next steps start at the secant stage."""
        ok, J0 = False, self._modified(dt)
        if self.jacobian in ("auto", "modified") and self._stage == 0:
            x1, f1, it, ok = self._newton(x, v, f, guess, dt, J0, scale)
            work["iterations"] += it
        if not ok and self.tangent is not None and self.jacobian != "differences":
            work["tangent_steps"] += 1
            J = self._matrix(dt, (2.0 * self.tangent(0.5 * (x + guess)) + self.tangent(guess)) / 3.0)
            x1, f1, it, ok = self._newton(x, v, f, guess, dt, J, scale)
            work["iterations"] += it
        if not ok and self.jacobian in ("auto", "modified") and self.tangent is None:
            self._stage = 1  # the secant stage: a deep Anderson memory on the same K
            work["secant_steps"] += 1
            x1, f1, it, ok = self._newton(x, v, f, guess, dt, J0, scale, DEEP_DEPTH, DEEP_ITERATIONS,
                                          DEEP_PATIENCE)
            work["iterations"] += it
        krylov = self.jacobian == "differences" or (self.jacobian == "auto" and self.tangent is None)
        if not ok and krylov:
            from stepnf.verify.krylov import KrylovNewton

            if self._krylov is None:
                self._krylov = KrylovNewton(self.M, self._f, tol=self.tol)
            work["krylov_steps"] += 1
            x1, f1, it, ok = self._krylov.solve(x, v, f, guess, dt, J0, scale)
            work["iterations"] += it
        return x1, f1, ok

    def _advance(self, x, v, f, a, guess, dt, scale, work, depth: int, where: tuple):
        """``(x1, v1, f1)`` one step of ``dt`` on, as two half steps when no Newton converges (module docstring);
        ``where``: ``(what, t, k, dt)`` of the run's step, for the message."""
        x1, f1, ok = self._solve(x, v, f, guess, dt, scale, work)
        if ok:
            return x1, 2.0 * (x1 - x) / dt - v, f1
        if depth >= HALVINGS:
            tried = {"auto": "modified Newton" + (", the model's tangent" if self.tangent is not None else
                                                   ", secant, Newton-Krylov by directional differences of f"),
                     "modified": "modified Newton" + (", the model's tangent" if self.tangent is not None else
                                                       ", secant"),
                     "tangent": "the model's tangent", "differences": "Newton-Krylov by directional differences"}
            what, t, k, step = where
            raise NumericalError(f"{what}: Newton did not converge at t = {t:.6g} (step {k} of dt = {step:.6g}; "
                                 f"tried {tried[self.jacobian]}, and the step halved {HALVINGS} times); "
                                 + (self.hint or "a smaller step or a tangent stiffness may help"))
        work["halved_steps"] += depth == 0
        h = 0.5 * dt
        a0 = np.zeros_like(x) if a is None else a
        xh, vh, fh = self._advance(x, v, f, a, x + h * v + 0.5 * h * h * a0, h, scale, work, depth + 1, where)
        ah = (vh - v) / h
        return self._advance(xh, vh, fh, ah, xh + h * vh + 0.5 * h * h * ah, h, scale, work, depth + 1, where)

    def _energy(self, x, v, potential) -> float | None:
        if potential is None:
            return None
        return 0.5 * float(v @ (self.M @ v)) + float(potential(x))


def cubic_potential(forces: ForceBatch) -> Callable[[np.ndarray], float]:
    """``V(x) = int_0^1 x^T f(s x) ds`` by 3-point Gauss-Legendre (exact for f up to degree 4)."""
    s, w = np.polynomial.legendre.leggauss(3)
    s, w = 0.5 * (s + 1.0), 0.5 * w

    def V(x: np.ndarray) -> float:
        F = np.asarray(forces(np.outer(s, x)), dtype=float)
        return float(w @ (F @ x))
    return V


# ---------------------------------------------------------------- measurements
def _hermite(q0, q1, d0, d1, h):
    """Coefficients (c0..c3) in ``s`` in [0, 1] of the cubic Hermite interpolant of one step."""
    return np.array([q0, h * d0, 3 * (q1 - q0) - h * (2 * d0 + d1), 2 * (q0 - q1) + h * (d0 + d1)])


def crossings(tr: Trajectory, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Times ``(down, up)`` where ``q`` crosses ``level`` downwards and upwards (Hermite-interpolated)."""
    g = tr.q - level
    down, up = [], []
    for i in np.nonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)[0]:
        h = tr.t[i + 1] - tr.t[i]
        c = _hermite(g[i], g[i + 1], tr.qd[i], tr.qd[i + 1], h)
        roots = np.roots(c[::-1])
        roots = [r.real for r in roots if abs(r.imag) < 1e-9 and -1e-12 <= r.real <= 1 + 1e-12]
        s = min(roots, key=lambda r: abs(r - g[i] / (g[i] - g[i + 1]))) if roots else g[i] / (g[i] - g[i + 1])
        (down if g[i] > 0 else up).append(tr.t[i] + s * h)
    return np.asarray(down), np.asarray(up)


def fit_period(down: np.ndarray, up: np.ndarray) -> float:
    """Least-squares period of ``t_k = t0 + k T`` over both families of crossings (two intercepts, one T)."""
    rows, rhs = [], []
    for j, ts in enumerate((down, up)):
        for k, tk in enumerate(ts):
            rows.append([k, 1.0 if j == 0 else 0.0, 1.0 if j == 1 else 0.0])
            rhs.append(tk)
    if len(down) < 2 and len(up) < 2:
        raise NumericalError("time integration: fewer than two crossings of the same kind; integrate longer")
    A = np.asarray(rows)
    keep = [i for i in range(3) if A[:, i].any()]
    sol = np.linalg.lstsq(A[:, keep], np.asarray(rhs), rcond=None)[0]
    return float(sol[0])


def extrema(tr: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Values ``(maxima, minima)`` of the interpolated ``q`` at the sign changes of ``q'``."""
    hi, lo = [], []
    d = tr.qd
    for i in np.nonzero(np.sign(d[:-1]) * np.sign(d[1:]) < 0)[0]:
        h = tr.t[i + 1] - tr.t[i]
        c = _hermite(tr.q[i], tr.q[i + 1], d[i], d[i + 1], h)
        dc = np.array([c[1], 2 * c[2], 3 * c[3]])
        roots = [r.real for r in np.roots(dc[::-1]) if abs(r.imag) < 1e-9 and -1e-9 <= r.real <= 1 + 1e-9]
        vals = [np.polyval(c[::-1], s) for s in roots] or [tr.q[i]]
        (hi if d[i] > 0 else lo).append(max(vals) if d[i] > 0 else min(vals))
    return np.asarray(hi), np.asarray(lo)


def romberg(values: Sequence[float], ratio: float = 2.0) -> tuple[float, float]:
    """Richardson extrapolation of results at steps ``dt, dt/ratio, ...`` with errors in ``dt^2, dt^4, ...``.

    Returns ``(extrapolated, error estimate)``: the estimate is the change made by the last
    extrapolation column (the error of the next-best value); a single value gives ``(value, nan)``.
    """
    T = [list(map(float, values))]
    while len(T[-1]) > 1:
        k = len(T)
        r = ratio ** (2 * k)
        prev = T[-1]
        T.append([(r * prev[i + 1] - prev[i]) / (r - 1) for i in range(len(prev) - 1)])
    if len(T) == 1:
        return T[0][0], float("nan")
    return T[-1][0], abs(T[-1][0] - T[-2][-1])


def steps_per_period(rtol: float, levels: int = 2) -> int:
    """Steps per period of the coarsest level for a frequency error ``rtol`` after ``levels`` levels.

    From the linear scheme's expansion ``-(x^2)/12 + x^4/80 - x^6/448`` (``x = w dt``): after one
    extrapolation (2 levels) the error is ``x^4 / 320``, after two ``~x^6 / 5e4``; a factor 1.5
    covers the nonlinear harmonics. One level: ``x^2 / 12``.
    """
    if levels <= 1:
        x = np.sqrt(12.0 * rtol)
    elif levels == 2:
        x = (320.0 * rtol) ** 0.25
    else:
        x = (5e4 * rtol) ** (1.0 / 6.0)
    return int(np.ceil(1.5 * 2 * np.pi / min(x, 1.0)))


@dataclass
class Measurement:
    """Frequency and amplitude of ``q = w^T x`` from runs at ``dt, dt/2, ...``, Richardson-extrapolated.

    ``omega`` (rad per model time unit) and ``amplitude`` (half the mean peak-to-peak of q) are
    extrapolated (:func:`romberg`); ``omega_error`` (relative) the change the last extrapolation
    made, i.e. the error of the finest un-extrapolated level: a bound (the extrapolated value is
    typically orders of magnitude better: Duffing 2e-9 against 2e-5 at ``rtol = 1e-8``); ``levels``
    one dict per step size; ``finest`` the trajectory of the smallest step.
    """

    omega: float
    omega_error: float
    amplitude: float
    levels: list[dict]
    finest: Trajectory


def measure(integ: EnergyConserving, x0: np.ndarray, v0: np.ndarray, *, watch: np.ndarray, omega: float,
            periods: float = 3.0, rtol: float = 1e-8, levels: int = 2, level: float | None = None,
            keep_per_period: int = 0, potential: Callable | None = None,
            what: str = "time integration", per_period: int | None = None) -> Measurement:
    """Integrate ``periods`` periods (of the guess ``omega``) at ``levels`` step sizes and measure.

    The coarse step gives ``per_period`` steps per period (default :func:`steps_per_period` of ``rtol``,
    ``levels``); each level halves it. The period is the least-squares fit of the crossings of ``level`` (default:
    the middle of the first run's range), both directions; the amplitude the mean of the
    extrema. ``keep_per_period``: states kept per period on the finest level (for manifold distances).
    """
    ns = int(per_period) if per_period else steps_per_period(rtol, levels)
    T = 2 * np.pi / omega
    out, tr = [], None
    for j in range(levels):
        n_per = ns * 2 ** j
        steps = int(np.ceil((periods + 0.05) * n_per))
        keep = max(n_per // keep_per_period, 1) if keep_per_period and j == levels - 1 else 0
        tr = integ.run(x0, v0, T / n_per, steps, watch=watch, keep=keep, potential=potential, what=what)
        if level is None:
            level = 0.5 * (tr.q.max() + tr.q.min())
        down, up = crossings(tr, level)
        hi, lo = extrema(tr)
        if not (len(hi) and len(lo)):
            raise NumericalError(f"{what}: q has no maximum or minimum over {periods:g} periods")
        period = fit_period(down, up)
        out.append({"dt": tr.dt, "steps": steps, "omega": 2 * np.pi / period,
                    "amplitude": 0.5 * (float(hi.mean()) - float(lo.mean())),
                    "newton_iterations": tr.iterations, "force_evaluations": tr.force_evaluations,
                    "tangent_steps": tr.tangent_steps, "secant_steps": tr.secant_steps, "krylov_steps": tr.krylov_steps,
                    "jacobian_products": tr.jacobian_products, "halved_steps": tr.halved_steps,
                    "energy_drift": tr.energy_drift})
    w, err = romberg([d["omega"] for d in out])
    A, _ = romberg([d["amplitude"] for d in out])
    return Measurement(w, err / w if np.isfinite(err) else float("nan"), A, out, tr)
