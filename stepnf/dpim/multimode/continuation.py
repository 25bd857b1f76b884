"""Pseudo-arclength continuation of the periodic-orbit equations of a manifold's reduced dynamics.

:class:`stepnf.dpim.multimode.branches.ReducedSystem` (or any system with its ``m``, ``omega``, ``correct``,
``tangent``, ``jacobian``, ``phase_row``: the forced responses' :class:`stepnf.forced.manifold_system.ForcedSystem`)
from a solution ``u0``: predictor along the tangent (null vector of the Jacobian with the phase rows), Newton
corrector on the hyperplane orthogonal to it, the step halved when Newton fails and grown by 1.5 when it converges
in <= 3 iterations. A sign change of ``det [J; phases; t^T]`` between two points marks a branch point
(:attr:`stepnf.dpim.multimode.branches.Branch.branch_points`). A backbone branch that comes back to its start (up to
a time shift: the same orbits) is a closed loop and ends there.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from stepnf.dpim.multimode.branches import ReducedSystem


def continue_branch(system: ReducedSystem, u0: np.ndarray, *, direction: np.ndarray | None = None,
                    stop: Callable[[np.ndarray], bool] | None = None, max_points: int = 400,
                    h0: float | None = None, h_max: float | None = None,
                    units: Callable[[np.ndarray], tuple[Any, np.ndarray]] | None = None, closes: bool = False
                    ) -> tuple[np.ndarray, list[int], bool]:
    """Pseudo-arclength continuation from the solution ``u0`` (module docstring): the points (K, n), the branch
    points and whether the branch closed (with ``closes``: after leaving it by more than 4 steps, it came back within
    a step of ``u0`` or of ``u0`` turned in time, the same orbit, :func:`_from_start`: a loop, ended at ``u0``
    instead of traced again until ``max_points``; a branch that arrives there the other way round would go on
    through the small amplitudes below the start to the linear mode: the same loop). ``direction``: the first
    tangent is oriented along it; ``stop(u)`` ends the branch after the first point where it is True; ``h0``,
    ``h_max`` the first and largest steps (default 0.1 of the first point's size |zeta| and 0.05 max(omega_max,
    size)). ``units(u) -> (scaled system, D)``: each step is taken in the unknowns ``x = u / D`` of the point it
    starts from (D > 0; the scaled system's equations in x): the steps, the tangent and the corrector's hyperplane
    in units relative to that point (a Euclidean arclength in a model's own units is its largest unknown's alone:
    :func:`stepnf.dpim.multimode.backbone._scaled`); ``h0``, ``h_max``, ``direction`` then in those units (``D`` of
    any length >= n: its first n entries). None: in ``u`` itself. The points are returned in u."""
    m, n = system.m, len(u0)

    def scaled(u):
        if units is None:
            return system, None
        S, D = units(u)
        return S, np.asarray(D, dtype=float)[:n]
    S, D = scaled(u0)
    x0 = u0 if D is None else u0 / D
    size = float(np.abs(x0[:2 * m]).max())
    h = 0.1 * size if h0 is None else h0
    h_max = max(h, 0.05 * max(float(S.omega.max()), size)) if h_max is None else h_max
    pts, bps = [u0], []
    t = S.tangent(x0, x0[:m] + 1j * x0[m:2 * m], direction)
    away = 0.0
    det_prev = None
    closed = False
    while len(pts) < max_points:
        u = pts[-1]
        if D is not None:  # the point's own units; the tangent (a direction in u) carried over
            t_u = t * D
            S, D = scaled(u)
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
        if closes:  # back at the start (up to a time shift) after leaving it: a loop, whichever way it arrives
            d = _from_start(S, u0, pts[-1], D)
            away = max(away, d)
            if away > 4 * h and d <= h:
                pts.append(u0.copy())
                closed = True
                break
        if its <= 3:
            h = min(1.5 * h, h_max)
        if stop is not None and stop(pts[-1]):
            break
    return np.asarray(pts), bps, closed


def _from_start(system: ReducedSystem, u0: np.ndarray, u: np.ndarray, D: np.ndarray | None) -> float:
    """The distance (in the units ``D``) of ``u`` from ``u0`` up to a time shift of ``u`` (``zeta_l e^{i k_l phi}``,
    the same orbit; ``phi`` puts ``zeta_j`` of ``u`` at the phase of ``u0``'s, ``j`` the master with the largest
    ``|zeta_j|`` of ``u0``: ``k_j`` choices)."""
    m = system.m
    z0, z = u0[:m] + 1j * u0[m:2 * m], u[:m] + 1j * u[m:2 * m]
    j = int(np.argmax(np.abs(z0)))
    kj = int(system.k[j])
    best = np.inf
    for n in range(max(abs(kj), 1)):
        rot = np.exp(1j * system.k * ((np.angle(z0[j]) - np.angle(z[j])) + 2 * np.pi * n) / kj) if kj else 1.0
        w = z * rot
        back = u0 - np.concatenate([w.real, w.imag, u[2 * m:]])
        best = min(best, float(np.linalg.norm(back if D is None else back / D)))
    return best
