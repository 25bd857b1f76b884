"""Backbone branches of a multi-mode manifold: periodic orbits of its reduced dynamics, by continuation.

Reduced dynamics of a :class:`stepnf.dpim.multimode.manifold.ManifoldResult` (docs/design.md, "Manifolds of several
master modes")::

    z_i' = lam_i z_i + sum_alpha f[(i, alpha)] z^alpha,   z = (zeta_1..zeta_m, conj(zeta_1)..conj(zeta_m))

With the resonance vector ``k`` (``ratios``) every kept monomial of equation ``j`` has
``sum_l (a_l - b_l) k_l = k_j``, so ``F`` commutes with the rotation ``z_j -> z_j e^{i k_j phi}`` and
``z_j(t) = zeta_j e^{i k_j Omega t}`` is a periodic orbit (period ``2 pi / Omega`` when the k are coprime) iff::

    G_j(zeta, Omega) = F_j(zeta) - i k_j Omega zeta_j = 0,      j < m       (*)

an equilibrium of the rotating frame ``w_j = z_j e^{-i k_j Omega t}``. Unknowns ``u = (Re zeta, Im zeta,
Omega, eps)`` (2m + 2 reals), equations ``Re G, Im G`` plus the phase condition
``sum_l k_l Im(conj(zeta_prev_l) zeta_l) = 0`` (orthogonal to the rotation, ``zeta_prev`` the last point).
A conservative system's (*) has one redundant equation (its first integral: a branch, not isolated
points, for 2m equations in 2m + 1 unknowns up to the phase); as for periodic orbits of Hamiltonian systems
(Munoz-Almaraz et al., Physica D 181, 2003) the equations are *unfolded* by ``- eps zeta_j`` (a damping-like
term, transverse to the energy's level sets): the Jacobian is then of full rank 2m + 1, and ``eps`` comes
out 0 on the branch (its size measures how far the truncated reduced dynamics is from conserving
anything: kept in :attr:`Branch.eps`). Pseudo-arclength continuation: predictor along the tangent (null
vector of the Jacobian), Newton corrector on the hyperplane orthogonal to it, the step halved when Newton
fails and grown by 1.5 when it converges in <= 3 iterations. A sign change of ``det [J; t^T]`` between two
points marks a branch point (:attr:`Branch.branch_points`).

Stability: the eigenvalues of the real ``2m x 2m`` Jacobian of the rotating-frame field
``(Re G, Im G)`` with respect to ``(Re zeta, Im zeta)`` (eps = 0). The flow is conservative, so
eigenvalues come in pairs ``+-lambda`` and the rotation gives a double zero (a Jordan block of the phase and
the amplitude): a point is stable when every real part is within the round-off of that double zero
(:data:`STABILITY_TOL`, :data:`STABILITY_FLOOR`: the constants say why).

The starts (:func:`starts`): at a small amplitude ``r`` of ``zeta_j``, Newton at fixed ``Re zeta_j = r``
from guesses: the linear mode with the others forced at their lowest order (``zeta_l =
f zeta^alpha / (i (k_l Omega - w_l))``), the closed-form coupled solutions of an exact or near 1:2 pair
(quadratic coupling: ``delta (2 delta + mu) = - f_a f_b r^2``, ``delta = k_j Omega - w_j``,
``mu = 2 w_j - w_l``), at any other exact resonance (1:3, 1:4, ...) the linear mode's guess at Omega detuned by
mode j's own cubic shift and a grid of ``zeta_l`` (magnitudes and phases) and, for a 1:1 pair, ``zeta_l = +-zeta_j,
i zeta_j`` (in-phase, out-of-phase, elliptic). Amplitude measures: :mod:`stepnf.dpim.multimode.measures`;
tracing a master's branches, validity and the table: :mod:`stepnf.dpim.multimode.backbone`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from stepnf.dpim.multimode.monomials import values_and_partials
from stepnf.errors import NumericalError

#: Stable when every eigenvalue's real part is at most ``STABILITY_TOL sqrt(eps w |J|_1) + STABILITY_FLOOR eps w``
#: (w = max(omega)): the double zero of the rotation (a Jordan block of size ~|J|) splits in floating point by
#: ~ sqrt(delta |J|), delta ~ eps w the rounding of the rotating frame's entries (detunings w_j - k_j Omega are
#: differences of numbers of size w). Over every point of tests/dpim/test_branches.py the stable points' largest
#: real part came to at most 1.41 sqrt(eps w |J|_1) and the unstable ones' to 1e5 or more of it. |J| (detuning plus
#: nonlinear terms, ~ A^2) shrinks with the amplitude like the growth rates do: a fixed 1e-6 w (before the review
#: of issue 33) called the 1:1 in-phase branch stable below A ~ 0.002 (growth 7.7e-8 w at A = 5e-4). The floor:
#: the reduced dynamics' coefficients carry round-off (~1e-14 w: the unfolding |eps| of those branches is at most
#: 7e-15 w). Measured growth rates of unstable orbits there: 0.026 to 0.067 w (1:1 in-phase, A ~ 0.3-0.5).
STABILITY_TOL = 16.0
STABILITY_FLOOR = 256.0
#: A starting point is new when its (Omega, zeta) differ from the others' by more than this (relative).
DISTINCT = 1e-6


@dataclass
class Branch:
    """One backbone branch: ``K`` points ``z_j(t) = zeta[:, j] e^{i k_j Omega t}`` of the reduced dynamics.

    ``Omega`` (K,) rad per model time unit (the fundamental; mode j moves at ``k_j Omega``), ``zeta`` (K, m)
    complex (phase: ``zeta[:, mode]`` real >= 0, :func:`normalise_phase`), ``A`` (K, m) amplitudes of
    the masters' modal coordinates (:mod:`stepnf.dpim.multimode.measures`), ``stable`` (K,), ``eps`` (K,) the
    unfolding parameter (module docstring), ``kind`` ``"continues mode s"`` (``s = masters[mode]``, its index
    in the spectrum) or ``"coupled"``, ``masters`` (m,) indices in the spectrum, ``ratios`` (m,) the resonance
    vector ``k``, ``branch_points`` indices i with a branch point between points i and i + 1, ``W_max`` (K,)
    when asked, ``valid_A`` the validity limit (amplitude of master ``mode``) and ``valid_reason``.
    """

    Omega: np.ndarray
    zeta: np.ndarray
    A: np.ndarray
    stable: np.ndarray
    kind: str
    masters: tuple[int, ...]
    ratios: np.ndarray
    mode: int
    eps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    branch_points: list[int] = field(default_factory=list)
    W_max: np.ndarray | None = None
    valid_A: float | None = None
    valid_reason: str = ""

    def frequency(self, j: int | None = None) -> np.ndarray:
        """The angular frequency of master ``j``'s motion, ``k_j Omega`` (K,) (``j`` None: :attr:`mode`)."""
        return self.ratios[self.mode if j is None else j] * self.Omega

    def arrays(self) -> dict[str, np.ndarray]:
        """The branch as arrays (for HDF5): ``Omega``, ``zeta_re``, ``zeta_im``, ``A``, ``stable``, ``eps``,
        ``masters``, ``ratios``, ``mode``, ``branch_points`` and ``W_max`` when measured."""
        out = {"Omega": self.Omega, "zeta_re": self.zeta.real, "zeta_im": self.zeta.imag, "A": self.A,
               "stable": self.stable.astype(np.int8), "eps": self.eps, "masters": np.asarray(self.masters),
               "ratios": np.asarray(self.ratios), "mode": np.asarray(self.mode),
               "branch_points": np.asarray(self.branch_points, dtype=int)}
        if self.W_max is not None:
            out["W_max"] = self.W_max
        return out


class ReducedSystem:
    """The equations (*) of a manifold's reduced dynamics for the resonance vector ``k`` (module docstring).

    ``manifold`` needs ``omega`` (m,), ``f`` {(i, alpha): complex}; ``ratios`` (m,) integers (None: the
    manifold's). A kept coefficient whose monomial is not resonant for ``k`` makes the ansatz wrong:
    NumericalError naming it.
    """

    def __init__(self, manifold: Any, ratios: Any = None):
        self.omega = np.asarray(manifold.omega, dtype=float)
        m = self.m = len(self.omega)
        k = manifold.ratios if ratios is None else ratios
        if k is None:
            raise NumericalError("reduced dynamics: no resonance vector (ratios) for the periodic orbits")
        self.k = np.asarray(k, dtype=int).reshape(m)
        rows = [(i, a, c) for (i, a), c in manifold.f.items() if i < m and c != 0]
        for i, a, c in rows:
            if int(np.dot(np.subtract(a[:m], a[m:]), self.k)) != self.k[i]:
                raise NumericalError(f"reduced dynamics: the kept monomial {a} of equation {i} (coefficient "
                                     f"{c:.3g}) is not resonant for the ratios {self.k.tolist()}")
        self.eq = np.asarray([i for i, _, _ in rows], dtype=int)
        self.E = np.asarray([a for _, a, _ in rows], dtype=int).reshape(len(rows), 2 * m)
        self.c = np.asarray([c for _, _, c in rows], dtype=complex)
        self.pmax = int(self.E.max()) if len(rows) else 1

    def _powers(self, zeta: np.ndarray) -> np.ndarray:
        z = np.concatenate([zeta, np.conj(zeta)])
        return z[:, None] ** np.arange(self.pmax + 1)[None, :]  # (2m, p)

    def field(self, zeta: np.ndarray) -> np.ndarray:
        """``F_j(zeta)`` (m,), j < m: linear and nonlinear parts."""
        pw = self._powers(zeta)
        mono = np.prod(pw[np.arange(2 * self.m)[None, :], self.E], axis=1) if len(self.E) else np.zeros(0)
        out = 1j * self.omega * zeta
        np.add.at(out, self.eq, self.c * mono)
        return out

    def dfield(self, zeta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(dF/dx, dF/dy)`` (m, m) complex, x and y the real and imaginary parts of zeta."""
        m = self.m
        _, D = values_and_partials(zeta, self.E)  # (T, 2m): d z^a / d z_l
        dz = np.zeros((m, 2 * m), dtype=complex)
        for l in range(2 * m):
            np.add.at(dz[:, l], self.eq, self.c * D[:, l])
        dz[np.arange(m), np.arange(m)] += 1j * self.omega
        return dz[:, :m] + dz[:, m:], 1j * (dz[:, :m] - dz[:, m:])

    # ----------------------------------------------------------- equations
    def residual(self, u: np.ndarray) -> np.ndarray:
        """``(Re G, Im G)`` (2m,) at ``u = (x, y, Omega, eps)``."""
        m = self.m
        zeta = u[:m] + 1j * u[m:2 * m]
        G = self.field(zeta) - (1j * self.k * u[2 * m] + u[2 * m + 1]) * zeta
        return np.concatenate([G.real, G.imag])

    def jacobian(self, u: np.ndarray) -> np.ndarray:
        """``d(Re G, Im G) / du`` (2m, 2m + 2)."""
        m = self.m
        zeta = u[:m] + 1j * u[m:2 * m]
        Fx, Fy = self.dfield(zeta)
        shift = 1j * self.k * u[2 * m] + u[2 * m + 1]
        Gx, Gy = Fx - np.diag(shift), Fy - np.diag(1j * shift)
        J = np.column_stack([Gx, Gy, -1j * self.k * zeta, -zeta])
        return np.vstack([J.real, J.imag])

    def phase_row(self, ref: np.ndarray) -> np.ndarray:
        """The phase condition's row (2m + 2,): ``sum_l k_l Im(conj(ref_l) zeta_l) = 0``."""
        return np.concatenate([-self.k * ref.imag, self.k * ref.real, [0.0, 0.0]])

    def stability(self, u: np.ndarray) -> tuple[bool, float]:
        """``(stable, largest real part)`` of the rotating frame's Jacobian (module docstring)."""
        m = self.m
        J = self.jacobian(np.concatenate([u[:2 * m + 1], [0.0]]))[:, :2 * m]
        top = float(np.max(np.linalg.eigvals(J).real))
        eps = float(np.finfo(float).eps)
        w = float(self.omega.max())
        bound = STABILITY_TOL * np.sqrt(eps * w * float(np.abs(J).sum(axis=0).max())) + STABILITY_FLOOR * eps * w
        return top <= bound, top

    def correct(self, u: np.ndarray, extra: Callable[[np.ndarray], tuple[float, np.ndarray]], ref: np.ndarray,
                maxiter: int = 12) -> tuple[np.ndarray, int] | None:
        """Newton on ``[G; phase; extra(u)]`` from ``u`` (``extra(u) -> (value, gradient)``): ``(u, iterations)``
        or None when it does not converge (to 1e-12 of the equations' scale, and a last step of 1e-13 relative in
        u or, once the steps stop shrinking, at the round-off of an ill-conditioned Jacobian, below 1e-9)."""
        m = self.m
        P = self.phase_row(ref)
        scale = float(self.omega.max()) * max(float(np.abs(u[:2 * m]).max()), 1e-300)
        last = np.inf
        for it in range(1, maxiter + 1):
            val, grad = extra(u)
            r = np.concatenate([self.residual(u), [P @ u, val]])
            J = np.vstack([self.jacobian(u), P, grad])
            try:
                du = np.linalg.solve(J, -r)
            except np.linalg.LinAlgError:
                return None
            if not np.all(np.isfinite(du)):
                return None
            u = u + du
            step, size = float(np.abs(du).max()), max(1.0, float(np.abs(u).max()))
            if (step <= 1e-13 * size or (step >= 0.5 * last and step <= 1e-9 * size)) and \
                    np.abs(self.residual(u)).max() <= 1e-12 * scale:
                return u, it
            last = step
        return None

    def tangent(self, u: np.ndarray, ref: np.ndarray, prev: np.ndarray | None) -> np.ndarray:
        """The unit tangent at ``u`` (null vector of ``[J; phase]``), oriented along ``prev`` when given."""
        A = np.vstack([self.jacobian(u), self.phase_row(ref)])
        t = np.linalg.svd(A)[2][-1]
        if prev is not None and t @ prev < 0:
            t = -t
        return t


def continue_branch(system: ReducedSystem, u0: np.ndarray, *, direction: np.ndarray | None = None,
                    stop: Callable[[np.ndarray], bool] | None = None, max_points: int = 400,
                    h0: float | None = None, h_max: float | None = None,
                    units: Callable[[np.ndarray], tuple[Any, np.ndarray]] | None = None
                    ) -> tuple[np.ndarray, list[int]]:
    """Pseudo-arclength continuation from the solution ``u0`` (module docstring): the points (K, 2m + 2) and
    the branch points. ``direction``: the first tangent is oriented along it; ``stop(u)`` ends the branch
    after the first point where it is True; ``h0``, ``h_max`` the first and largest steps (default
    0.1 of the first point's size |zeta| and 0.05 max(omega_max, size)). ``units(u) -> (scaled system, D)``: each
    step is taken in the unknowns ``x = u / D`` of the point it starts from (D > 0; the scaled system's equations
    in x): the steps, the tangent and the corrector's hyperplane in units relative to that point (a Euclidean
    arclength in a model's own units is its largest unknown's alone: :func:`stepnf.dpim.multimode.backbone._scaled`);
    ``h0``, ``h_max``, ``direction`` then in those units. None: in ``u`` itself. The points are returned in u."""
    m = system.m
    S, D = units(u0) if units is not None else (system, None)
    x0 = u0 if D is None else u0 / D
    size = float(np.abs(x0[:2 * m]).max())
    h = 0.1 * size if h0 is None else h0
    h_max = max(h, 0.05 * max(float(S.omega.max()), size)) if h_max is None else h_max
    pts, bps = [u0], []
    t = S.tangent(x0, x0[:m] + 1j * x0[m:2 * m], direction)
    det_prev = None
    while len(pts) < max_points:
        u = pts[-1]
        if D is not None:  # the point's own units; the tangent (a direction in u) carried over
            t_u = t * D
            S, D = units(u)
            t = t_u / D
            t /= np.linalg.norm(t)
        x = u if D is None else u / D
        ref = x[:m] + 1j * x[m:2 * m]
        done = None
        while h >= 1e-10 * max(size, 1e-300):
            pred = x + h * t
            done = S.correct(pred, lambda v, p=pred, d=t: (float(d @ (v - p)), d), ref)
            if done is not None and float(np.dot(done[0] - x, t)) > 0:
                break
            done = None
            h *= 0.5
        if done is None:
            break
        new, its = done
        t_new = S.tangent(new, new[:m] + 1j * new[m:2 * m], t)
        # (its sign does not depend on the units D > 0 when t is the tangent in them: the same in every step)
        det = np.linalg.det(np.vstack([S.jacobian(new), S.phase_row(new[:m] + 1j * new[m:2 * m]), t_new]))
        if det_prev is not None and np.sign(det) != np.sign(det_prev):
            bps.append(len(pts) - 1)
        det_prev = det
        pts.append(new if D is None else new * D)
        t = t_new
        if its <= 3:
            h = min(1.5 * h, h_max)
        if stop is not None and stop(pts[-1]):
            break
    return np.asarray(pts), bps


def _fixed_amplitude(j: int, r: float, n: int) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
    g = np.zeros(n)
    g[j] = 1.0
    return lambda u: (float(u[j] - r), g)


def start_guesses(system: ReducedSystem, j: int, r: float) -> list[tuple[str, np.ndarray]]:
    """``(kind, zeta)`` guesses at ``zeta_j = r`` (module docstring) and their ``Omega``s, as ``u`` vectors."""
    m, k, w = system.m, system.k, system.omega
    Om0 = w[j] / k[j]
    out = []

    def u_of(zeta, Om):
        return np.concatenate([zeta.real, zeta.imag, [Om, 0.0]])

    own = np.array([(system.eq == l) & np.all(np.delete(system.E, [j, j + m], axis=1) == 0, axis=1)
                    for l in range(m)])  # monomials of equation l made of mode j only
    base = np.zeros(m, dtype=complex)
    base[j] = r
    coupled = []
    # mode j's own cubic frequency shift: at an exact k_l Om0 = w_l the guess below needs Omega off Om0
    cubic = (system.eq == j) & np.all(system.E == _unit(2 * m, [j, j, j + m]), axis=1)
    Om_base = Om0
    for l in range(m):
        if l == j or not own[l].any():
            continue
        idx = np.flatnonzero(own[l])
        deg = system.E[idx].sum(axis=1)
        i0 = idx[deg == deg.min()]
        forcing = complex(np.sum(system.c[i0])) * r ** int(deg.min())
        sigma = k[l] * Om0 - w[l]
        back = (system.eq == j) & np.all(system.E == _unit(2 * m, [j + m, l]), axis=1)
        closed = int(deg.min()) == 2 and 2 * k[j] == k[l] and back.any()
        if abs(sigma) <= 1e-8 * w[l] and k[l] != k[j] and not closed:  # exact 1:3, 1:4, ...: shifted, grid
            Om_base = (w[j] + float(np.sum(system.c[cubic]).imag) * r * r) / k[j]
            sigma = k[l] * Om_base - w[l]
            coupled += _grid_guesses(m, j, l, r, Om_base)
        if abs(sigma) > 1e-8 * w[l]:
            base[l] = forcing / (1j * sigma)
        if closed:  # a 1:2 pair: the closed-form coupled solutions
            fa, fb = complex(system.c[back][0]), complex(system.c[i0][0])
            mu = k[l] * Om0 - w[l]  # = 2 w_j - w_l for k = (1, 2)
            disc = np.sqrt(complex(mu * mu - 8 * fa * fb * r * r))
            for sgn in (1, -1):
                delta = (-mu + sgn * disc) / 4
                if abs(delta.imag) > 1e-9 * abs(w[j]):  # no real root: no coupled branch here
                    continue
                zeta = np.zeros(m, dtype=complex)
                zeta[j] = r
                sig = k[l] * (w[j] + delta.real) / k[j] - w[l]
                zeta[l] = fb * r * r / (1j * sig) if sig != 0 else 0
                coupled.append(("coupled", u_of(zeta, (w[j] + delta.real) / k[j])))
    out.append((f"continues mode {j}", u_of(base, Om_base)))
    out += coupled
    for l in range(m):  # 1:1 pairs: in-phase, out-of-phase, elliptic
        if l != j and k[l] == k[j]:
            for ph in (1, -1, 1j):
                zeta = base.copy()
                zeta[l] = ph * r
                out.append(("coupled", u_of(zeta, Om0)))
    return out


def _grid_guesses(m: int, j: int, l: int, r: float, Om: float) -> list[tuple[str, np.ndarray]]:
    """Coupled guesses of an exact resonance with no closed form (1:3, 1:4, ...): ``zeta_l = s e^{i psi}``,
    ``s`` from ``r / 100`` to ``10 r`` (7 values), ``psi`` every ``pi / 4``; :func:`starts` keeps the distinct
    solutions Newton reaches."""
    out = []
    for s in r * np.logspace(-2.0, 1.0, 7):
        for psi in np.arange(8) * np.pi / 4:
            zeta = np.zeros(m, dtype=complex)
            zeta[j], zeta[l] = r, s * np.exp(1j * psi)
            out.append(("coupled", np.concatenate([zeta.real, zeta.imag, [Om, 0.0]])))
    return out


def _unit(n: int, where: list[int]) -> np.ndarray:
    e = np.zeros(n, dtype=int)
    for i in where:
        e[i] += 1
    return e


def starts(system: ReducedSystem, j: int, r: float) -> list[tuple[str, np.ndarray]]:
    """The distinct solutions of (*) at ``Re zeta_j = r`` reached by Newton from :func:`start_guesses`."""
    m = system.m
    found: list[tuple[str, np.ndarray]] = []
    for kind, u in start_guesses(system, j, r):
        ref = np.zeros(m, dtype=complex)
        ref[j] = 1.0
        done = system.correct(u, _fixed_amplitude(j, r, 2 * m + 2), ref, maxiter=40)
        if done is None:
            continue
        v = done[0]
        if abs(v[2 * m + 1]) > 1e-8 * system.omega.max():  # eps must vanish on a periodic orbit
            continue
        if any(np.abs(v - w).max() <= DISTINCT * max(1.0, np.abs(w).max()) for _, w in found):
            continue
        found.append((kind, v))
    return found


def normalise_phase(system: ReducedSystem, zeta: np.ndarray, j: int) -> np.ndarray:
    """``zeta`` rotated (``zeta_l e^{i k_l phi}``) so that ``zeta_j`` is real and >= 0."""
    if zeta[j] == 0:
        return zeta
    phi = -np.angle(zeta[j]) / system.k[j]
    return zeta * np.exp(1j * system.k * phi)
