"""The forced, damped rotating-frame equations of a multi-mode manifold's reduced dynamics (issue 34 on issue 33).

The manifold of masters ``l < m`` with resonance vector ``k`` (:mod:`stepnf.dpim.multimode.branches`) has the
conservative reduced dynamics ``z_l' = i w_l z_l + f_l(z)``. Damping and forcing ``F cos(Omega t)`` are added at
leading order (as SSMTool does): linear damping through the damped eigenvalue ``lam_l = -xi_l w_l + i w_l
sqrt(1 - xi_l^2)``, ``xi_l = phi_l^T C phi_l / (2 w_l)``, and the forcing's modal part ``g_l = phi_l^T F``. For one
mode ``q'' + 2 xi w q' + w^2 q = g cos(Omega t)`` in its damped eigen-coordinates (``q = z + conj z``, ``q' = lam z
+ conj(lam z)``) reads ``z' = lam z + g cos(Omega t) / (lam - conj lam) = lam z - i g cos(Omega t) / (2 w_d)``; of
``cos = (e^{i Omega t} + e^{-i Omega t}) / 2`` only ``e^{i Omega t}`` is resonant. Forcing near master ``j``'s
resonance (``Omega ~ w_j``) the fundamental is ``Omega / k_j``, ``z_l = zeta_l e^{i r_l Omega t}``,
``r_l = k_l / k_j``, and the steady states are the zeros of::

    G_l(zeta, Omega) = F_l(zeta) + (lam_l - i w_l) zeta_l - i r_l Omega zeta_l - [k_l = k_j] i g_l / (4 w_d,l)

(``F_l`` the conservative field, :meth:`stepnf.dpim.multimode.branches.ReducedSystem.field`; only the modes with
``k_l = k_j`` are forced resonantly). No phase condition: the forcing fixes the phase, so ``2m`` real equations in
``(Re zeta, Im zeta, Omega)``. Linear limit: ``|zeta_j| = g / (4 w_d |lam_j - i Omega|)``, largest at ``Omega =
w_d``: ``q = 2 |zeta_j| = g / (2 xi w w_d)``, the exact linear peak ``g / (2 xi sqrt(1 - xi^2) w^2)`` (its
frequency ``w_d`` instead of ``w sqrt(1 - 2 xi^2)``: ``O(xi^2)``). With ``i w`` and ``g / (4 w)`` instead, the peak
would be ``g / (2 xi w^2)``, low by ``xi^2 / 2``.

Beyond leading order: ``projection`` (:class:`stepnf.forced.manifold_projection.Projection`) adds the damping and
forcing projected on the manifold's tangent in the energy inner product and averaged over the orbit's phase, minus
their leading-order part (which is the terms above without the damped-eigenvalue shift): first order in ``(C, F)``,
every order in ``A``. Without it the conservative manifold's nonlinear damping and the forcing's work through the
nonlinear terms of ``V`` are lost: ``O(xi A^2)`` against the linear ``O(xi A)`` for one mode (the single-master
code, :mod:`stepnf.forced.averaged`, keeps them through Gram matrices), ``O(xi A)`` through a quadratic 1:2
coupling (measured: the peak's A 4.75% and 6.7% low against the full model at A = 0.23, 0.30; with it 0.15% and
0.1%). The Jacobian's projected part is by central differences (:data:`stepnf.forced.manifold_projection.STEP`): an
error ~1e-10 of an ``O(xi)`` term, so Newton (exact residual) still converges to the tolerances of :meth:`correct`.

A manifold partner that is not a scene master gets its own ``xi`` from ``C`` (0 under modal damping, which damps
the scene's masters only): then ``lam = i w`` and nothing divides by ``xi``.

The unknowns are scaled for the continuation: ``u = (Re zeta / a, Im zeta / a, Omega / b, 0)`` (``a`` the linear
peak's ``|zeta_j|``, ``b = xi_j w_j`` the resonance's half-width), the last entry a dummy fixed at 0 by the
"phase row", so :func:`stepnf.dpim.multimode.continuation.continue_branch` follows these curves as it follows backbones.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from stepnf.dpim.multimode.branches import ReducedSystem
from stepnf.errors import NumericalError, SceneError
from stepnf.forced.manifold_projection import Projection

#: A steady state is stable when every eigenvalue of the rotating frame's Jacobian has a real part below
#: ``STABLE_TOL w_max`` (an undamped partner, modal damping, has a pair on the axis: round-off ~1e-16 w).
STABLE_TOL = 1e-9


class ForcedSystem:
    """The equations ``G = 0`` of the module docstring, in scaled unknowns, for the master ``j`` (index in the
    manifold), damping ratios ``xi`` (m,) and modal forces ``g`` (m,) (zero where not resonant for ``k``);
    ``projection``: the damping and forcing beyond leading order added to ``G`` (None: leading order only)."""

    def __init__(self, manifold: Any, ratios: Any, j: int, xi: np.ndarray, g: np.ndarray,
                 projection: Projection | None = None):
        self.base = ReducedSystem(manifold, ratios)
        self.projection = projection
        self.m, self.j = self.base.m, int(j)
        w = self.w = self.base.omega
        self.xi = np.asarray(xi, dtype=float)
        self.wd = w * np.sqrt(1.0 - self.xi ** 2)
        self.lam = -self.xi * w + 1j * self.wd
        self.r = self.base.k / float(self.base.k[j])
        resonant = self.base.k == self.base.k[j]
        self.load = np.where(resonant, -1j * np.asarray(g, dtype=float) / (4.0 * self.wd), 0.0)
        if not self.xi[j] > 0:
            raise SceneError(None, "analysis.damping", f"the forced master (mode {j} of the manifold) is undamped "
                             f"(xi = phi^T C phi / (2 w) = {self.xi[j]:.3g}): an unbounded peak")
        self.b = self.xi[j] * w[j]
        self.a = float(np.abs(self.load).max()) / self.b  # the linear peak's |zeta| (load / (xi w))
        if not self.a > 0:
            raise NumericalError("forced response on a manifold: no resonant forcing")
        self.omega = np.array([1.0])  # (continue_branch's default steps; the callers give theirs)
        #: The farthest a corrected point may lie from its guess (scaled units): while tracing, a bound that makes
        #: the continuation halve its step rather than slide along a sharply turning curve past its folds.
        self.reach = np.inf

    # ------------------------------------------------------------ conversions
    def zeta(self, u: np.ndarray) -> np.ndarray:
        m = self.m
        return self.a * (u[:m] + 1j * u[m:2 * m])

    def Omega(self, u: np.ndarray) -> float:
        return float(self.b * u[2 * self.m])

    def point(self, zeta: np.ndarray, Omega: float) -> np.ndarray:
        return np.concatenate([zeta.real / self.a, zeta.imag / self.a, [Omega / self.b, 0.0]])

    # ------------------------------------------------------------ equations
    def residual(self, u: np.ndarray) -> np.ndarray:
        """``(Re G, Im G) / a`` (2m,)."""
        z, Om = self.zeta(u), self.Omega(u)
        G = self.base.field(z) + (self.lam - 1j * self.w - 1j * self.r * Om) * z + self.load
        if self.projection is not None:
            G = G + self.projection.correction(z)
        return np.concatenate([G.real, G.imag]) / self.a

    def jacobian(self, u: np.ndarray) -> np.ndarray:
        """``d(residual)/du`` (2m, 2m + 2), the dummy's column zero."""
        z, Om = self.zeta(u), self.Omega(u)
        Fx, Fy = self.base.dfield(z)
        if self.projection is not None:
            Px, Py = self.projection.derivatives(z, self.a)
            Fx, Fy = Fx + Px, Fy + Py
        d = self.lam - 1j * self.w - 1j * self.r * Om
        J = np.column_stack([Fx + np.diag(d), Fy + np.diag(1j * d), -1j * self.r * z * self.b / self.a,
                             np.zeros(self.m)])
        return np.vstack([J.real, J.imag])

    def phase_row(self, ref: np.ndarray | None = None) -> np.ndarray:
        """The row fixing the dummy unknown (the forcing fixes the phase)."""
        row = np.zeros(2 * self.m + 2)
        row[-1] = 1.0
        return row

    def stability(self, u: np.ndarray) -> tuple[bool, float]:
        """``(stable, largest real part)`` of the eigenvalues of the real 2m x 2m Jacobian in ``(Re zeta, Im zeta)``."""
        top = float(np.max(np.linalg.eigvals(self.jacobian(u)[:, :2 * self.m]).real))
        return top <= STABLE_TOL * float(self.w.max()), top

    def bordered_det(self, u: np.ndarray, t: np.ndarray) -> float:
        return float(np.linalg.det(np.vstack([self.jacobian(u), self.phase_row(), t])))

    def correct(self, u: np.ndarray, extra: Callable[[np.ndarray], tuple[float, np.ndarray]], ref: Any = None,
                maxiter: int = 12) -> tuple[np.ndarray, int] | None:
        """Newton on ``[G; dummy; extra(u)]``: ``(u, iterations)`` or None (no convergence to 1e-12 relative)."""
        P = self.phase_row()
        start = u
        for it in range(1, maxiter + 1):
            val, grad = extra(u)
            r = np.concatenate([self.residual(u), [P @ u, val]])
            try:
                du = np.linalg.solve(np.vstack([self.jacobian(u), P, grad]), -r)
            except np.linalg.LinAlgError:
                return None
            if not np.all(np.isfinite(du)):
                return None
            u = u + du
            if np.abs(du).max() <= 1e-12 * max(1.0, float(np.abs(u).max())) and \
                    np.abs(self.residual(u)).max() <= 1e-10 * float(self.w.max()) * max(1.0, float(np.abs(u).max())):
                return None if np.abs(u - start).max() > self.reach else (u, it)
        return None

    def tangent(self, u: np.ndarray, ref: Any = None, prev: np.ndarray | None = None) -> np.ndarray:
        """The unit tangent (null vector of ``[J; dummy row]``), oriented along ``prev`` when given."""
        t = np.linalg.svd(np.vstack([self.jacobian(u), self.phase_row()]))[2][-1]
        return -t if prev is not None and t @ prev < 0 else t

    def second_direction(self, u: np.ndarray, t: np.ndarray) -> np.ndarray:
        """At a branch point: the null direction of ``J`` other than the tangent ``t`` (unit)."""
        V = np.linalg.svd(np.vstack([self.jacobian(u), self.phase_row()]))[2][-2:]
        v = max((w - (w @ t) * t for w in V), key=lambda x: float(np.linalg.norm(x)))
        return v / np.linalg.norm(v)

    def at_frequency(self, Omega: float, guess: np.ndarray, maxiter: int = 40) -> np.ndarray | None:
        """The steady state at the forcing frequency ``Omega`` by Newton from the scaled ``guess``."""
        n = 2 * self.m + 2
        grad = np.zeros(n)
        grad[2 * self.m] = 1.0
        got = self.correct(guess, lambda v: (float(v[2 * self.m] - Omega / self.b), grad), maxiter=maxiter)
        return None if got is None else got[0]

    def linear(self, Omega: float) -> np.ndarray:
        """The linear response at ``Omega`` (scaled): ``zeta_l = -load_l / (lam_l - i r_l Omega)``."""
        return self.point(-self.load / (self.lam - 1j * self.r * Omega), Omega)
