"""Backbone branches of a multi-mode manifold: the periodic-orbit equations of its reduced dynamics.

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
anything: kept in :attr:`Branch.eps`). The branches are traced by pseudo-arclength continuation
(:mod:`stepnf.dpim.multimode.continuation`) from starts at a small amplitude
(:mod:`stepnf.dpim.multimode.starts`).

Continuous symmetries (exact twins): when the reduced dynamics commutes with a rotation of masters of equal
frequency and equal ``k`` (a twin pair of an axisymmetric structure: ``(zeta_c, zeta_s) -> (cos t zeta_c - sin t
zeta_s, sin t zeta_c + cos t zeta_s)``, other pairs turning ``q`` times as fast), with generator ``R`` (real,
``m x m``, :mod:`stepnf.dpim.multimode.symmetry`), every standing wave lies on a one-parameter family of turned ones
and carries a second first integral (the angular momentum, gradient ``i R zeta``): (*) loses one more rank. At
such a point (:meth:`ReducedSystem.for_point`: ``R zeta`` independent of the time shift's ``i k zeta``) the
unknowns take one more unfolding ``mu`` (the term ``- mu i R zeta``, 0 on the branch) and the equations one more
phase condition ``Re sum_l conj(R zeta_prev)_l zeta_l = 0`` (orthogonal to the rotation): without them the tracer
walked along the turned standing waves (issue 33: on the von Karman cap's exact twins the branch that continues
the mode "ended" at W_max/h ~ 0.001, differently from run to run). A travelling wave (``R zeta`` parallel to
``i k zeta``: turning it is a time shift) keeps the plain equations.

Stability: the eigenvalues of the real ``2m x 2m`` Jacobian of the rotating-frame field
``(Re G, Im G)`` with respect to ``(Re zeta, Im zeta)`` (eps = 0). The flow is conservative, so
eigenvalues come in pairs ``+-lambda`` and the rotation gives a double zero (a Jordan block of the phase and
the amplitude): a point is stable when every real part is within the round-off of that double zero
(:data:`STABILITY_TOL`, :data:`STABILITY_FLOOR`: the constants say why).

Amplitude measures: :mod:`stepnf.dpim.multimode.measures`;
tracing a master's branches, validity and the table: :mod:`stepnf.dpim.multimode.backbone`.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from stepnf.dpim.multimode import symmetry
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


@dataclass
class Branch:
    """One backbone branch: ``K`` points ``z_j(t) = zeta[:, j] e^{i k_j Omega t}`` of the reduced dynamics.

    ``Omega`` (K,) rad per model time unit (the fundamental; mode j moves at ``k_j Omega``), ``zeta`` (K, m)
    complex (phase: ``zeta[:, mode]`` real >= 0, :func:`normalise_phase`), ``A`` (K, m) amplitudes of
    the masters' modal coordinates (:mod:`stepnf.dpim.multimode.measures`), ``stable`` (K,), ``eps`` (K,) the
    unfolding parameter (module docstring), ``kind`` ``"continues mode s"`` (``s = masters[mode]``, its index
    in the spectrum) or ``"coupled"``, ``masters`` (m,) indices in the spectrum, ``ratios`` (m,) the resonance
    vector ``k``, ``branch_points`` indices i with a branch point between points i and i + 1, ``W_max`` (K,)
    when asked, ``valid_A`` the validity limit (amplitude of master ``mode``) and ``valid_reason``;
    ``rotations`` (s, m, m) the symmetries the branch was traced with (module docstring: s = 0 or 1) and
    ``closed`` True when it came back to its first point (a closed loop, traced once).
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
    rotations: np.ndarray | None = None
    closed: bool = False

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
        if self.rotations is not None and len(self.rotations):
            out["rotations"] = np.asarray(self.rotations)
        return out


class ReducedSystem:
    """The equations (*) of a manifold's reduced dynamics for the resonance vector ``k`` (module docstring).

    ``manifold`` needs ``omega`` (m,), ``f`` {(i, alpha): complex}; ``ratios`` (m,) integers (None: the
    manifold's). A kept coefficient whose monomial is not resonant for ``k`` makes the ansatz wrong:
    NumericalError naming it. ``rotations``: the symmetry generators (s, m, m) the equations carry (module
    docstring, "Continuous symmetries"); None: none (:meth:`rotations` finds them, :meth:`for_point` chooses).
    The unknowns ``u = (Re zeta, Im zeta, Omega, eps, mu_1..mu_s)``.
    """

    def __init__(self, manifold: Any, ratios: Any = None, rotations: Any = None):
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
        self.R = np.zeros((0, m, m)) if rotations is None else np.asarray(rotations, dtype=float).reshape(-1, m, m)

    @property
    def n(self) -> int:
        """The number of unknowns, ``2m + 2 + s`` (s rotations)."""
        return 2 * self.m + 2 + len(self.R)

    # ----------------------------------------------------------- symmetry
    def rotations(self) -> np.ndarray:
        """:func:`stepnf.dpim.multimode.symmetry.rotations` of this system."""
        return symmetry.rotations(self)

    def rotation_misfit(self) -> tuple[np.ndarray, np.ndarray]:
        """:func:`stepnf.dpim.multimode.symmetry.rotation_misfit` of this system."""
        return symmetry.rotation_misfit(self)

    def for_point(self, zeta: np.ndarray, rotations: np.ndarray | None = None) -> "ReducedSystem":
        """This system with the rotations ``zeta`` needs (:func:`stepnf.dpim.multimode.symmetry.needed`: a standing
        wave of exact twins; ``rotations`` the candidates, None: :meth:`rotations`)."""
        out = copy.copy(self)
        out.R = symmetry.needed(self, zeta, self.rotations() if rotations is None else rotations)
        return out

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
        """``(Re G, Im G)`` (2m,) at ``u = (x, y, Omega, eps, mu..)``."""
        m = self.m
        zeta = u[:m] + 1j * u[m:2 * m]
        G = self.field(zeta) - (1j * self.k * u[2 * m] + u[2 * m + 1]) * zeta
        for g, mu in zip(self.R, u[2 * m + 2:]):
            G = G - 1j * mu * (g @ zeta)
        return np.concatenate([G.real, G.imag])

    def jacobian(self, u: np.ndarray) -> np.ndarray:
        """``d(Re G, Im G) / du`` (2m, n), n = 2m + 2 + s."""
        m = self.m
        zeta = u[:m] + 1j * u[m:2 * m]
        Fx, Fy = self.dfield(zeta)
        shift = 1j * self.k * u[2 * m] + u[2 * m + 1]
        Gx, Gy = Fx - np.diag(shift), Fy - np.diag(1j * shift)
        cols = [-1j * self.k * zeta, -zeta]
        for g, mu in zip(self.R, u[2 * m + 2:]):
            Gx, Gy = Gx - 1j * mu * g, Gy + mu * g
            cols.append(-1j * (g @ zeta))
        J = np.column_stack([Gx, Gy, *cols])
        return np.vstack([J.real, J.imag])

    def phase_row(self, ref: np.ndarray, turned: np.ndarray | None = None) -> np.ndarray:
        """The phase conditions' rows (1 + s, n): ``sum_l k_l Im(conj(ref_l) zeta_l) = 0`` (time) and, for each
        rotation R, ``Re sum_l conj(R turned)_l zeta_l = 0`` (``turned``: the rotation's reference, None: ``ref``)."""
        m, s = self.m, len(self.R)
        rows = [np.concatenate([-self.k * ref.imag, self.k * ref.real, np.zeros(2 + s)])]
        for g in self.R:
            v = g @ (ref if turned is None else turned)
            rows.append(np.concatenate([v.real, v.imag, np.zeros(2 + s)]))
        return np.vstack(rows)

    def stability(self, u: np.ndarray) -> tuple[bool, float]:
        """``(stable, largest real part)`` of the rotating frame's Jacobian (module docstring)."""
        m = self.m
        J = self.jacobian(np.concatenate([u[:2 * m + 1], np.zeros(1 + len(self.R))]))[:, :2 * m]
        top = float(np.max(np.linalg.eigvals(J).real))
        eps = float(np.finfo(float).eps)
        w = float(self.omega.max())
        bound = STABILITY_TOL * np.sqrt(eps * w * float(np.abs(J).sum(axis=0).max())) + STABILITY_FLOOR * eps * w
        return top <= bound, top

    def correct(self, u: np.ndarray, extra: Callable[[np.ndarray], tuple[float, np.ndarray]], ref: np.ndarray,
                maxiter: int = 12, turned: np.ndarray | None = None) -> tuple[np.ndarray, int] | None:
        """Newton on ``[G; phases; extra(u)]`` from ``u`` (``extra(u) -> (value, gradient)``; the phases
        :meth:`phase_row` of ``ref``, ``turned``): ``(u, iterations)`` or None when it does not converge (to 1e-12
        of the equations' scale, and a last step of 1e-13 relative in u or, once the steps stop shrinking, at the
        round-off of an ill-conditioned Jacobian, below 1e-9)."""
        m = self.m
        P = self.phase_row(ref, turned)
        scale = float(self.omega.max()) * max(float(np.abs(u[:2 * m]).max()), 1e-300)
        last = np.inf
        for it in range(1, maxiter + 1):
            val, grad = extra(u)
            r = np.concatenate([self.residual(u), P @ u, [val]])
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


def normalise_phase(system: ReducedSystem, zeta: np.ndarray, j: int) -> np.ndarray:
    """``zeta`` rotated (``zeta_l e^{i k_l phi}``) so that ``zeta_j`` is real and >= 0."""
    if zeta[j] == 0:
        return zeta
    phi = -np.angle(zeta[j]) / system.k[j]
    return zeta * np.exp(1j * system.k * phi)
