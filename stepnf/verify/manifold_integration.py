"""A branch of a manifold of several modes against the full model's trajectory, by time integration (large models).

As :func:`stepnf.verify.command.by_integration` for single-mode backbones: the energy-conserving scheme
(:mod:`stepnf.verify.integrate`) over ``periods`` periods at two step sizes, Richardson-extrapolated, from the
orbit's start on the manifold (:func:`stepnf.verify.manifold_orbits.start_point`: ``(W(z), V(z))`` at a phase of
the reduced orbit where every velocity vanishes, else where ``q_j`` is largest). The trajectory is not closed by
Newton: it stays near the periodic orbit as far as the manifold's point is near it.

Measured on the coordinate of the master that carries the orbit's fundamental, ``q_l = phi_l^T M x`` with
``k_l = g`` (the gcd of the moving masters' ``k``; master j itself when it does): its crossings of the middle of its
range on the reduced orbit (once up and once down a period when its own harmonic dominates, as on the branches that
continue a mode and the 1:2 coupled ones) give the fundamental ``g Omega``; master j's frequency is ``k_j / g`` of
it. The branch's frequency is taken where master l's amplitude is the trajectory's (half the mean peak-to-peak of
``q_l``); the distance from the manifold at the kept states as :class:`stepnf.verify.manifold_chart.ManifoldChart`.
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Any, Callable

import numpy as np

from stepnf.dpim.multimode.backbone import omega_at
from stepnf.plugin.dofs import peak
from stepnf.verify.integrate import EnergyConserving, measure, steps_per_period
from stepnf.verify.manifold_chart import ManifoldChart

#: What each level of the integration did (as the single-mode checks report it).
LEVEL_KEYS = ("dt", "steps", "newton_iterations", "force_evaluations", "tangent_steps", "secant_steps", "krylov_steps",
              "jacobian_products", "halved_steps")


def watched_master(branch: Any, zeta: np.ndarray, g: int) -> int:
    """The master whose coordinate carries the fundamental: ``branch.mode`` when ``k_j = g``, else the moving
    master with ``k_l = g`` and the largest ``|zeta_l|`` (module docstring)."""
    k = np.asarray(branch.ratios, dtype=int)
    if k[branch.mode] == g:
        return int(branch.mode)
    size = np.abs(zeta)
    cands = [l for l in range(len(k)) if k[l] == g and size[l] > 1e-12 * size.max()]
    return max(cands, key=lambda l: size[l]) if cands else int(branch.mode)


def integrate_orbit(man: Any, chart: ManifoldChart, branch: Any, A: float, start: dict, K, M,
                    forces: Callable[[np.ndarray], np.ndarray], *, tangent: Callable | None = None,
                    jacobian: str = "auto", periods: float = 3.0, rtol: float = 1e-6, per_period: int | None = None,
                    mask: np.ndarray | None = None, samples_per_period: int = 16) -> dict:
    """One check of ``branch`` at amplitude ``A`` by time integration from ``start`` (module docstring): the keys of
    :func:`stepnf.verify.manifold_orbits.check_orbit`'s, ``method`` "integration" and ``error_estimate``."""
    t0 = time.perf_counter()
    j, n, g = branch.mode, K.shape[0], int(start["g"])
    k = np.asarray(branch.ratios, dtype=int)
    zeta0, Om = start["zeta"], float(start["Omega"])
    l = watched_master(branch, zeta0, g)
    psi = np.linspace(0.0, 2 * np.pi / g, 256, endpoint=False)
    ql = [chart.coordinates(zeta0 * np.exp(1j * k * p))[l] for p in psi]
    level = 0.5 * (max(ql) + min(ql))
    hint = (f"more steps per period may help: --steps-per-period {4 * (per_period or steps_per_period(rtol))}"
            + ("" if jacobian in ("auto", "differences") else " or --tangent differences"))
    integ = EnergyConserving(M, K, forces, tangent=tangent, tol=1e-10, jacobian=jacobian, hint=hint)
    x0, v0 = start["x0"], start["v0"]
    m = measure(integ, x0, v0, watch=np.asarray(chart.MPhi[:, l]), omega=g * Om, periods=periods, rtol=rtol,
                level=level, keep_per_period=samples_per_period, what="time integration", per_period=per_period)
    dist, guess, t_prev = 0.0, zeta0, 0.0
    for t, x, v in m.finest.states:  # the reduced orbit's point at the same time guesses the chart's
        d, zeta = chart.distance(x, v, guess * np.exp(1j * k * m.omega / g * (t - t_prev)))
        dist, guess, t_prev = max(dist, d), zeta, t
    w = float(man.omega[j])
    om_check = float(k[j] * m.omega / g)
    om_dpim = float(k[j] * omega_at(man, replace(branch, mode=l), m.amplitude))
    work = {"watched_master": int(man.masters[l]), "watched_amplitude": float(m.amplitude),
            "levels": [{key: d[key] for key in LEVEL_KEYS} for d in m.levels]}
    return {"amplitude": float(A), "orbit_amplitude": float(m.amplitude) if l == j else float(A),
            "omega_dpim": om_dpim, "omega_check": om_check, "omega_dpim_over_omega": om_dpim / w,
            "omega_check_over_omega": om_check / w, "relative_difference": om_dpim / om_check - 1.0,
            "manifold_distance": float(dist), "method": "integration",
            "start": "from rest" if start["brake"] else "from a moving state (no state at rest)",
            "error_estimate": m.omega_error, "seconds": round(time.perf_counter() - t0, 3), "work": work,
            "max_displacement": peak(x0, mask)}
