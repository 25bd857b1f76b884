"""Periodic orbits of the full model by shooting: the independent reference for DPIM backbones.

Model ``M x'' + f(x) = 0`` (conservative, ``f`` a gradient, no velocity
terms), hence reversible (``t -> -t``). A nonlinear-normal-mode orbit is a
*brake orbit*: it starts at rest, ``x(0) = x0, v(0) = 0``, and is at rest
again at half its period, after which it retraces itself. So the shooting
unknowns are ``(x0, T)`` (n + 1) and the equations::

    v(T/2; x0) = 0                       (n)
    phi^T M x0 = q0                      (1, the amplitude condition)

solved by Newton. The Jacobian is ``[[dv/dx0, v'(T/2)/2], [phi^T M, 0]]``
with ``dv/dx0`` from the variational equations
``d/dt [X; V] = [V; -M^-1 Df(x) X]``, ``X(0) = I, V(0) = 0``, ``Df`` from
``tangent(x)`` or central differences of f along the columns of X (the
Jacobian only steers Newton: the converged orbit's accuracy is that of the
residual integration, ``solve_ivp`` DOP853 with ``rtol = 1e-12``).

**Stiff models.** DOP853's step is bounded by its stability, ``~3.3 / w_max``, whatever the accuracy:
a model whose highest frequency ``w_max`` is 1000 times the master's ``w`` needs thousands of steps
per period (minutes). Above :data:`STIFF_RATIO` (``integrator = "auto"``) the orbit is integrated
by Gauss-Legendre collocation instead (:class:`stepnf.verify.collocation.GaussLegendre`: implicit, order 16,
A-stable and symmetric, :data:`IMPLICIT_STEPS` equal steps per period whatever ``w_max``), and
Newton's Jacobian is the exact derivative of that discrete map (its own sensitivities, at the first
iterate of each orbit; kept as a chord while the residual falls by 4 an iteration and the period
moves by less than ``0.1 / w_max``, renewed otherwise), so the
shooting converges on the integrator's orbit; the residual is the same integration.

The amplitude is measured as for the backbone: ``A = (max q - min q) / 2``,
``q = phi^T M x(t)`` over one period (over [0, T/2] by reversibility), on a
dense grid of the integrator's dense output refined by Brent's method. An
outer secant iteration on ``q0`` hits a requested ``A``; a continuation in
``q0`` from small amplitudes (linear guess ``x0 = q0 phi``, ``T = 2 pi / w``)
keeps Newton on the branch of the master mode.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.integrate import solve_ivp
from scipy.optimize import minimize_scalar

from stepnf.errors import NumericalError

Force = Callable[[np.ndarray], np.ndarray]
INTEGRATORS = ("auto", "explicit", "implicit")
#: ``w_max / w`` above which ``integrator = "auto"`` integrates implicitly. DOP853's step is bounded by
#: ``3.3 / w_max``: at ``w_max / w = 10.5`` it already asks for 1.6 times the force evaluations of a
#: system at 3.6 and takes 5-15 times as long as the implicit scheme (bench/verify_stiff.py); below 5
#: the non-stiff models keep DOP853 and the numbers they had.
STIFF_RATIO = 5.0
#: Stages of the implicit Gauss-Legendre integration (order 16).
IMPLICIT_STAGES = 8
#: Equal steps per period of the implicit integration: ``w h = 2 pi / 32 = 0.2``, where the order-16
#: scheme's error constant ``(s!)^4 / ((2s)! (2s + 1)!) = 3.5e-10`` gives a phase error per period
#: ``~3.5e-10 (w h)^16 2 pi`` of 1e-20 (1e-13 for a 3rd harmonic, ``(3 w h)^16 = 3e-4``): at the
#: level of DOP853's ``rtol = 1e-12`` (tests/verify/test_periodic.py checks 1e-10 on Duffing).
IMPLICIT_STEPS = 32
#: A converged implicit orbit is integrated again at twice the steps: ``|v(T/2)| / (w |x0|)`` above this
#: doubles the steps (up to :data:`MAX_IMPLICIT_STEPS` a period) and Newton resumes (DOP853 at
#: ``rtol = 1e-12`` leaves 1e-16..1e-13).
IMPLICIT_RESIDUAL = 1e-11
MAX_IMPLICIT_STEPS = 1024


def highest_frequency(K, M) -> float:
    """The largest ``w = sqrt(lambda)`` of ``K phi = lambda M phi`` (rad per model time unit)."""
    n = K.shape[0]
    if n <= 500:
        Kd = K.toarray() if sp.issparse(K) else np.asarray(K, dtype=float)
        Md = M.toarray() if sp.issparse(M) else np.asarray(M, dtype=float)
        lam = sla.eigh(Kd, Md, eigvals_only=True, subset_by_index=[n - 1, n - 1])
    else:
        lam = spla.eigsh(sp.csc_matrix(K), k=1, M=sp.csc_matrix(M), which="LA", return_eigenvectors=False)
    return float(np.sqrt(max(float(lam[-1]), 0.0)))


def mass_solver(M) -> Callable[[np.ndarray], np.ndarray]:
    """``b -> M^-1 b`` (M dense or sparse, factorised once) for the shootings' right-hand sides; a force that is
    not finite (a Newton iterate far from the orbit, whose trajectory diverges) is a NumericalError there, not a
    NaN the integrator would chase with ever smaller steps (or LAPACK's ValueError)."""
    if sp.issparse(M):
        solve = spla.splu(sp.csc_matrix(M)).solve
    else:
        cho = sla.cho_factor(np.asarray(M, dtype=float))
        solve = lambda b: sla.cho_solve(cho, b, check_finite=False)  # noqa: E731 - checked below

    def apply(b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=float)
        if not np.isfinite(b).all():
            raise NumericalError("shooting: the trajectory diverged (a force that is not finite): the Newton "
                                 "iterate left the neighbourhood of the orbit")
        return solve(b)
    return apply


def shooting_method(integrator: str, stiffness_ratio: float) -> str:
    """What :class:`Shooting` integrates with: ``"implicit"`` or ``"explicit"`` for ``integrator`` (one of
    :data:`INTEGRATORS`) at ``stiffness_ratio = w_max / w`` (``"auto"``: implicit above :data:`STIFF_RATIO`)."""
    stiff = stiffness_ratio > STIFF_RATIO
    return "implicit" if integrator == "implicit" or (integrator == "auto" and stiff) else "explicit"


@dataclass
class PeriodicOrbit:
    """A converged brake orbit: ``x0`` (n,), period ``T``, ``omega = 2 pi / T``, amplitude ``A`` of q_p."""

    x0: np.ndarray
    period: float
    omega: float
    amplitude: float
    q0: float
    residual: float
    newton_iterations: int


class Shooting:
    """Shooting for the brake orbits of ``M x'' + f(x) = 0`` near master mode ``phi`` (module docstring).

    ``M``, ``K`` (n, n) dense or sparse; ``f(x)`` the internal force of one
    field (n,); ``tangent(x)`` (optional) ``Df(x)`` (n, n); ``phi``
    M-normalised; ``omega`` its angular frequency; ``forces(U)`` (optional) the forces (m, n) of a
    batch of fields (m, n) in one call (the implicit integrator sends its stages together);
    ``integrator`` ``"explicit"`` (DOP853), ``"implicit"`` (Gauss-Legendre) or ``"auto"`` (implicit
    when ``w_max / omega`` > :data:`STIFF_RATIO`: :attr:`method`, :attr:`stiffness_ratio`); ``w_max`` the
    model's highest frequency when the caller knows it (else :func:`highest_frequency` of K, M).
    :attr:`force_evaluations` counts the fields sent to ``f``/``forces`` (central differences included).
    """

    def __init__(self, M, K, f: Force, phi: np.ndarray, omega: float, *, tangent: Callable | None = None,
                 rtol: float = 1e-12, jac_rtol: float = 1e-9, forces: Callable | None = None,
                 integrator: str = "auto", steps: int = IMPLICIT_STEPS, w_max: float | None = None):
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {list(INTEGRATORS)}, got {integrator!r}")
        self.n = len(phi)
        self.M = M
        self.K = K
        self.force_evaluations = 0
        self._f1 = f
        self._batch = forces
        self.tangent = tangent
        self.phi = np.asarray(phi, dtype=float)
        self.Mphi = np.asarray(M @ self.phi).ravel()
        self.omega = float(omega)
        self.rtol, self.jac_rtol = rtol, jac_rtol
        self.Minv = mass_solver(M)
        self.stiffness_ratio = (highest_frequency(K, M) if w_max is None else float(w_max)) / self.omega
        self.method = shooting_method(integrator, self.stiffness_ratio)
        self.steps = 2 * max(int(np.ceil(steps / 2)), 1)  # even: T / 2 is a node
        self._gl = None
        self._J: np.ndarray | None = None  # the implicit shooting's last Jacobian (a chord) and its period
        self._J_T = 0.0
        if self.method == "implicit":
            from stepnf.verify.collocation import GaussLegendre

            self._gl = GaussLegendre(M, K, self.forces, tangent=tangent, stages=IMPLICIT_STAGES)

    # ------------------------------------------------------------ forces
    def f(self, x: np.ndarray) -> np.ndarray:
        """The internal force of one field (counted)."""
        self.force_evaluations += 1
        return self._f1(x)

    def forces(self, U: np.ndarray) -> np.ndarray:
        """The internal forces of a batch of fields (m, n), in one call when a batch function was given."""
        self.force_evaluations += len(U)
        if self._batch is not None:
            return np.asarray(self._batch(U), dtype=float)
        return np.stack([np.asarray(self._f1(u), dtype=float) for u in U])

    @property
    def work(self) -> dict:
        """What the shooting did: ``method``, ``stiffness_ratio``, ``force_evaluations`` and, implicit,
        the integrator's steps, Newton iterations, batched calls, tangents, factorisations."""
        out = {"method": self.method, "stiffness_ratio": float(self.stiffness_ratio),
               "force_evaluations": int(self.force_evaluations)}
        if self._gl is not None:
            out.update({k: v for k, v in self._gl.work.as_dict().items() if k != "force_evaluations"})
        return out

    # ------------------------------------------------------------ dynamics
    def _rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        n = self.n
        return np.concatenate([y[n:], -self.Minv(self.f(y[:n]))])

    def _df(self, x: np.ndarray, X: np.ndarray) -> np.ndarray:
        if self.tangent is not None:
            return np.asarray(self.tangent(x) @ X)
        h = 1e-4 * max(np.abs(x).max(), 1e-8)
        cols = [(self.f(x + h * X[:, j]) - self.f(x - h * X[:, j])) / (2 * h) for j in range(X.shape[1])]
        return np.column_stack(cols)

    def _rhs_var(self, t: float, y: np.ndarray) -> np.ndarray:
        n = self.n
        x, v = y[:n], y[n:2 * n]
        X = y[2 * n:2 * n + n * n].reshape(n, n)
        V = y[2 * n + n * n:].reshape(n, n)
        dV = -self.Minv(self._df(x, X))
        return np.concatenate([v, -self.Minv(self.f(x)), V.ravel(), dV.ravel()])

    def _scale(self, x0: np.ndarray) -> float:
        return max(np.abs(x0).max(), 1e-300)

    def integrate(self, x0: np.ndarray, t_end: float, *, dense: bool = False):
        """``solve_ivp`` (DOP853, ``rtol``) from rest at ``x0`` to ``t_end`` (the explicit integrator)."""
        s = self._scale(x0)
        y0 = np.concatenate([x0, np.zeros(self.n)])
        atol = np.concatenate([np.full(self.n, 1e-14 * s), np.full(self.n, 1e-14 * s * self.omega)])
        sol = solve_ivp(self._rhs, (0.0, t_end), y0, method="DOP853", rtol=self.rtol, atol=atol,
                        dense_output=dense)
        if not sol.success:
            raise NumericalError(f"shooting: the time integration failed ({sol.message})")
        return sol

    def _implicit(self, x0: np.ndarray, T: float, periods: float = 0.5, *, sensitivity: bool = False,
                  keep: bool = False, steps: int | None = None):
        """Gauss-Legendre from rest at ``x0`` over ``periods`` periods ``T`` (:attr:`steps` per period)."""
        steps = steps or max(int(round(self.steps * periods)), 1)
        return self._gl.run(x0, np.zeros(self.n), periods * T, steps, sensitivity=sensitivity, keep=keep,
                            what="shooting")

    def end_state(self, x0: np.ndarray, t_end: float, T: float | None = None) -> np.ndarray:
        """The state ``(x, v)`` (2n,) at ``t_end`` from rest at ``x0`` (``T``: the orbit's period, which
        sets the implicit step; default ``t_end`` is half of it)."""
        if self.method == "explicit":
            return self.integrate(x0, t_end).y[:, -1]
        T = 2 * t_end if T is None else T
        r = self._implicit(x0, T, t_end / T)
        return np.concatenate([r.x, r.v])

    def samples(self, x0: np.ndarray, T: float, count: int) -> np.ndarray:
        """States ``(x, v)`` (count + 1, 2n) at ``count + 1`` evenly spaced times over one period ``T``."""
        if self.method == "explicit":
            return self.integrate(x0, T, dense=True).sol(np.linspace(0.0, T, count + 1)).T
        per = int(np.ceil(self.steps / count))
        return self._implicit(x0, T, 1.0, keep=True, steps=per * count).nodes[::per]

    # ------------------------------------------------------------- Newton
    def orbit(self, q0: float, x0: np.ndarray, T: float, *, tol: float = 1e-11,
              maxiter: int = 25) -> PeriodicOrbit:
        """Newton on ``(x0, T)`` at ``phi^T M x0 = q0`` from the guess ``(x0, T)``."""
        n = self.n
        x0 = np.asarray(x0, dtype=float).copy()
        x0 += self.phi * (q0 - float(self.Mphi @ x0))
        last, self._J = np.inf, None  # a fresh Jacobian for each orbit, kept as a chord within it
        for it in range(1, maxiter + 1):
            s = self._scale(x0)
            if self.method == "implicit":  # the discrete map's own derivatives (chord: kept while it contracts)
                # the chord holds while the fastest mode's phase over T/2 moves little: w_max |T - T_J| / 2 <= 0.05
                fresh = self._J is None or self.stiffness_ratio * self.omega * abs(T - self._J_T) > 0.1
                run = self._implicit(x0, T, sensitivity=fresh)
                r = np.concatenate([run.v, [float(self.Mphi @ x0) - q0]])
                size = float(np.abs(run.v).max())
                if not fresh and size > 0.25 * last:  # the kept Jacobian does not contract: a new one
                    run, fresh = self._implicit(x0, T, sensitivity=True), True
                if fresh:
                    self._J = np.zeros((n + 1, n + 1))
                    self._J[:n, :n] = run.S[n:, :n]  # dv(T/2)/dx0
                    self._J[:n, n] = 0.5 * run.S[n:, n]  # dv(T/2)/dT: the run's end is T / 2
                    self._J[n, :n] = self.Mphi
                    self._J_T = T
                last = size
                # a chord converges linearly (by <= 4 an iteration): its last step must be 100 times smaller
                x0, T, small = self._newton_step(self._J, r, x0, T, q0, tol if fresh else 0.01 * tol, s)
                if small:
                    return self._converged(x0, T, q0, it)
                continue
            y0 = np.concatenate([x0, np.zeros(n), np.eye(n).ravel(), np.zeros(n * n)])
            sol = solve_ivp(self._rhs_var, (0.0, T / 2), y0, method="DOP853", rtol=self.jac_rtol,
                            atol=1e-12 * max(s, 1.0))
            if not sol.success:
                raise NumericalError(f"shooting: the variational integration failed ({sol.message})")
            yT = sol.y[:, -1]
            V = yT[2 * n + n * n:].reshape(n, n)
            # the residual from the accurate integration
            ye = self.integrate(x0, T / 2).y[:, -1]
            r = np.concatenate([ye[n:], [float(self.Mphi @ x0) - q0]])
            acc = -self.Minv(self.f(ye[:n]))
            J = np.zeros((n + 1, n + 1))
            J[:n, :n] = V
            J[:n, n] = 0.5 * acc
            J[n, :n] = self.Mphi
            x0, T, small = self._newton_step(J, r, x0, T, q0, tol, s)
            if small:
                return self._converged(x0, T, q0, it)
        raise NumericalError(f"shooting: Newton did not converge in {maxiter} iterations at q0 = {q0:.6g}")

    def _newton_step(self, J, r, x0, T, q0, tol, s) -> tuple[np.ndarray, float, bool]:
        n = self.n
        try:
            step = np.linalg.solve(J, -r)
        except np.linalg.LinAlgError as exc:
            raise NumericalError(f"shooting: singular Newton matrix at q0 = {q0:.6g} ({exc})") from exc
        if not np.all(np.isfinite(step)):
            raise NumericalError(f"shooting: Newton step not finite at q0 = {q0:.6g}")
        x0 = x0 + step[:n]
        T = T + step[n]
        return x0, T, bool(np.abs(step[:n]).max() <= tol * s and abs(step[n]) <= tol * T)

    def _converged(self, x0, T, q0, it) -> PeriodicOrbit:
        if self.method == "explicit":
            res = float(np.abs(self.end_state(x0, T / 2)[self.n:]).max() / (self.omega * self._scale(x0)))
            return PeriodicOrbit(x0, T, 2 * np.pi / T, self.amplitude(x0, T), q0, res, it)
        # the implicit scheme has no error control of its own: the orbit found at `steps` a period must
        # be one at twice as many (its residual there is the discretisation's error), else refine
        fine = self._implicit(x0, T, steps=self.steps)
        res = float(np.abs(fine.v).max() / (self.omega * self._scale(x0)))
        if res > IMPLICIT_RESIDUAL:
            if self.steps >= MAX_IMPLICIT_STEPS:
                raise NumericalError(f"shooting: the implicit integration does not resolve the orbit at q0 = "
                                     f"{q0:.6g} ({self.steps} steps a period leave a residual {res:.3g})")
            self.steps *= 2
            return self.orbit(q0, x0, T)
        A, _ = self._implicit_amplitude(x0, T)
        return PeriodicOrbit(x0, T, 2 * np.pi / T, A, q0, res, it)

    def amplitude(self, x0: np.ndarray, T: float) -> float:
        """``(max q - min q) / 2`` over the orbit (reversibility: [0, T/2] suffices)."""
        if self.method == "implicit":
            return self._implicit_amplitude(x0, T)[0]
        sol = self.integrate(x0, T / 2, dense=True)
        t = np.linspace(0.0, T / 2, 2001)
        q = self.Mphi @ sol.sol(t)[: self.n]
        return refined_half_range(t, q, lambda s: float(self.Mphi @ sol.sol(min(max(s, 0.0), T / 2))[: self.n]),
                                  1e-14 * T)

    def _implicit_amplitude(self, x0: np.ndarray, T: float) -> tuple[float, np.ndarray]:
        """As :meth:`amplitude` (and the state at ``T / 2``), from the nodes of the implicit integration:
        an extremum at a node where ``q'`` vanishes (the brake orbit's ends) is that node's value; one
        between nodes is found by Brent's method on one implicit step from the node before it (the
        scheme's accuracy)."""
        run = self._implicit(x0, T, keep=True)
        nodes, h, n = run.nodes, run.h, self.n
        q, qd = nodes[:, :n] @ self.Mphi, nodes[:, n:] @ self.Mphi

        def qf(t: float) -> float:
            k = min(int(t // h), len(q) - 2)
            return float(self.Mphi @ self._gl.state_at(nodes[k], t - k * h)[:n])

        def at_node(i: int) -> bool:  # a brake orbit's end: q' = 0 there
            return i in (0, len(q) - 1) and abs(qd[i]) <= 1e-9 * self.omega * max(abs(q[i]), 1e-300)
        return refined_half_range(h * np.arange(len(q)), q, qf, 1e-14 * T, exact=at_node), nodes[-1]

    def at_amplitude(self, A: float, *, steps: int = 6, guess: tuple[np.ndarray, float] | None = None,
                     tol: float = 1e-12, maxiter: int = 30) -> PeriodicOrbit:
        """The orbit whose amplitude of ``q_p`` is ``A``: continuation in ``q0``, then secant on ``q0``.

        Without ``guess``, ``steps`` continuation steps from ``q0 = A / steps``
        (linear guess); with ``guess = (x0, T)`` Newton starts from it.
        """
        if guess is None:
            x0, T = self.phi * (A / steps), 2 * np.pi / self.omega
            orb = self.orbit(A / steps, x0, T)
            for k in range(2, steps + 1):
                q = A * k / steps
                orb = self.orbit(q, orb.x0 * (q / orb.q0), orb.period)
        else:
            x0, T = guess
            orb = self.orbit(float(self.Mphi @ x0), x0, T)
        prev = None
        for _ in range(maxiter):
            if abs(orb.amplitude - A) <= tol * A:
                return orb
            slope = 1.0 if prev is None else (orb.amplitude - prev.amplitude) / (orb.q0 - prev.q0)
            q = orb.q0 + (A - orb.amplitude) / slope
            prev, orb = orb, self.orbit(q, orb.x0 * (q / orb.q0), orb.period)
        raise NumericalError(f"shooting: amplitude {A:.6g} not reached (last {orb.amplitude:.12g})")


def refined_half_range(t: np.ndarray, q: np.ndarray, qf: Callable[[float], float], xatol: float, *,
                       exact: Callable[[int], bool] = lambda i: False) -> float:
    """``(max q - min q) / 2`` of a signal sampled as ``q`` at the times ``t`` (:func:`refined_extrema`)."""
    (qmax, _), (qmin, _) = refined_extrema(t, q, qf, xatol, exact=exact)
    return 0.5 * (qmax - qmin)


def refined_extrema(t: np.ndarray, q: np.ndarray, qf: Callable[[float], float], xatol: float, *,
                    exact: Callable[[int], bool] = lambda i: False,
                    periodic: bool = False) -> tuple[tuple[float, float], tuple[float, float]]:
    """``((q_max, t_max), (q_min, t_min))`` of a signal sampled as ``q`` at the evenly spaced times ``t``:
    each extremum refined by Brent's bounded search on ``qf(t)`` within one spacing of its sample (clipped to
    ``t``'s ends unless ``periodic``; ``qf`` then takes any time), to ``xatol``; the sample's value kept
    when it is better (the time is Brent's). ``exact(i)``: sample ``i`` is the extremum itself (not refined)."""
    out = []
    dt = t[1] - t[0]
    for i, sgn in ((int(np.argmax(q)), -1.0), (int(np.argmin(q)), 1.0)):
        if exact(i):
            out.append((float(q[i]), float(t[i])))
            continue
        lo, hi = (t[i] - dt, t[i] + dt) if periodic else (t[max(i - 1, 0)], t[min(i + 1, len(t) - 1)])
        r = minimize_scalar(lambda s: sgn * qf(s), bounds=(lo, hi), method="bounded", options={"xatol": xatol})
        val = sgn * r.fun
        out.append((max(val, q[i]) if sgn < 0 else min(val, q[i]), float(r.x)))
    return out[0], out[1]
