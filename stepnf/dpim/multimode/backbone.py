"""The backbone branches of one master on a multi-mode manifold: trace, measure, validity, table.

:func:`backbone_branches` finds the starts of master ``mode``'s branches at a small amplitude
(:func:`stepnf.dpim.multimode.starts.starts`: the branch that continues the linear mode and the coupled ones
born at the resonance), continues each (:func:`stepnf.dpim.multimode.continuation.continue_branch`) until master
``mode``'s amplitude ``A`` reaches ``A_stop``, and measures every point
(:class:`stepnf.dpim.multimode.measures.OrbitMeasure`) and its stability. :func:`omega_at` refines the
frequency at a given amplitude on a branch (Brent's method along the chord between two points, each
trial point corrected onto the branch: to round-off). Validity (:func:`validity`), as
:mod:`stepnf.dpim.backbone`'s: the same branch of the manifold truncated at order N - 2, traced from the
same start, and the largest ``A`` below which ``|k_j Omega_N(A) - k_j Omega_{N-2}(A)| <= tol omega_j``
(``Omega_{N-2}`` at the same A by cubic interpolation of its points), and where the terms of orders N - 1 and N
stay within ``sqrt(tol)`` of the whole field (M-norm, largest over the period, at the same point: the single-mode
shape test, :meth:`stepnf.dpim.backbone.Backbone.validity_limit`).

Units: the continuation and the chords of :func:`omega_at` work in scaled unknowns (:func:`_scaled`: ``zeta`` over
its size, ``Omega`` over the master's linear fundamental), so that a branch is traced the same in any units. In a
model's own (metres and rad/s: zeta ~ 1e-4, Omega ~ 7.6e3 on the kappa = 25 cap) a Euclidean arclength in
``(zeta, Omega)`` is Omega's alone: the steps were steps in Omega, which cannot pass a fold of Omega (the backbone
bending back), and the corrector jumped past it to another part of the branch or turned back (issue 33, order 5
of the cap's (2,1) with (4,1)).
"""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import brentq

from stepnf.dpim.multimode.branches import Branch, ReducedSystem, normalise_phase
from stepnf.dpim.multimode.continuation import continue_branch
from stepnf.dpim.multimode.measures import OrbitMeasure, Transverse, orbit_measure
from stepnf.dpim.multimode.starts import starts
from stepnf.errors import NumericalError


def _u(b: Branch, i: int) -> np.ndarray:
    """Point i of ``b`` as the unknowns of its equations (the rotations' unfoldings at 0: their value on it)."""
    z = b.zeta[i]
    s = 0 if b.rotations is None else len(b.rotations)
    return np.concatenate([z.real, z.imag, [b.Omega[i], b.eps[i]], np.zeros(s)])


def _system(manifold: Any, branch: Branch, ratios: Any = None) -> ReducedSystem:
    """The equations ``branch`` was traced with, for ``manifold`` (the rotations it carried)."""
    return ReducedSystem(manifold, branch.ratios if ratios is None else ratios, rotations=branch.rotations)


def _scaled(system: ReducedSystem, a: float, b: float) -> tuple[ReducedSystem, np.ndarray]:
    """The same equations in the unknowns ``x = u / D``, ``D = (a, .., a, b, b)`` (``zeta / a``, ``Omega / b``,
    ``eps / b``, the rotations' unfoldings ``mu / b``): the reduced dynamics of ``zeta / a`` in the time ``b t``
    (coefficients ``c a^(|alpha| - 1) / b``, frequencies ``omega / b``), so the scaled system's residual is
    ``G / (a b)`` and its stability the same.
    The continuation's arclength, its tangent and the chord's hyperplane (:func:`point_at`) are Euclidean in ``u``:
    in a model's units (zeta ~ 1e-4 m, Omega ~ 7.6e3 rad/s on the kappa = 25 cap) Omega alone would set them,
    the steps would be steps in Omega, and a fold of Omega (the backbone bending back) would be jumped over
    (module docstring, "Units"). ``(system, D)``."""
    deg = system.E.sum(axis=1)
    f = {(int(i), tuple(int(t) for t in e)): complex(c) * a ** (int(d) - 1) / b
         for i, e, c, d in zip(system.eq, system.E, system.c, deg)}
    ns = SimpleNamespace(omega=system.omega / b, f=f, ratios=system.k)
    m = system.m
    return (ReducedSystem(ns, system.k, rotations=system.R),
            np.concatenate([np.full(2 * m, a), np.full(2 + len(system.R), b)]))


def _units(system: ReducedSystem, mode: int, zeta_size: float) -> tuple[ReducedSystem, np.ndarray]:
    """:func:`_scaled` with ``a = zeta_size`` and ``b = omega_mode / k_mode`` (the master's linear fundamental)."""
    b = float(system.omega[mode]) / float(system.k[mode])
    return _scaled(system, max(float(zeta_size), np.finfo(float).tiny), b)


def trace(system: ReducedSystem, measure: OrbitMeasure, u0: np.ndarray, kind: str, mode: int, masters,
          A_stop: float, *, max_points: int = 400, transverse: Transverse | None = None,
          h: float = 1.0) -> Branch:
    """The branch through the solution ``u0`` of ``system`` (``Re zeta_mode`` growing first) up to ``A_mode >=
    A_stop`` or back to ``u0`` (a loop: :attr:`Branch.closed`), measured (module docstring)."""
    m = system.m
    wmax = float(system.omega.max())

    def stop(u: np.ndarray) -> bool:
        A = measure.amplitudes(u[:m] + 1j * u[m:2 * m])
        return bool(A[mode] >= A_stop or A.max() >= 10 * A_stop or not 0 < u[2 * m] < 3 * wmax)
    direction = np.zeros(len(u0))
    direction[mode] = 1.0
    # each step in units of its point (_scaled): zeta / |zeta|, Omega / the linear fundamental; steps <= ~10%
    pts, bps, closed = continue_branch(system, u0, direction=direction, stop=stop, max_points=max_points,
                                       units=lambda u: _units(system, mode, float(np.abs(u[:2 * m]).max())),
                                       closes=True)
    if len(pts) > 1 and not pts[-1, 2 * m] > 0:  # the point that stopped the trace at Omega <= 0: no orbit
        pts, bps = pts[:-1], [i for i in bps if i < len(pts) - 2]
    zeta = np.asarray([normalise_phase(system, u[:m] + 1j * u[m:2 * m], mode) for u in pts])
    A = np.asarray([measure.amplitudes(z) for z in zeta])
    stable = np.asarray([system.stability(u)[0] for u in pts])
    b = Branch(pts[:, 2 * m].copy(), zeta, A, stable, kind, tuple(masters), system.k.copy(), mode,
               eps=pts[:, 2 * m + 1].copy(), branch_points=bps, rotations=system.R.copy(), closed=closed)
    if transverse is not None:
        b.W_max = np.asarray([measure.w_max(z, transverse, h) for z in zeta])
    return b


def backbone_branches(manifold: Any, mode: int, A_stop: float, *, ratios: Any = None, r0: float | None = None,
                      tol: float | None = 1e-3, transverse: Transverse | None = None, h: float = 1.0,
                      max_points: int = 400) -> list[Branch]:
    """Master ``mode``'s branches (index into ``manifold.masters``) up to its amplitude ``A_stop`` (module
    docstring). ``ratios``: the resonance vector (None: the manifold's; when it has none, ``k = e_mode``: the other
    masters' kept monomials are those of every frequency, ``a - b = e_l``, and they stay at rest); ``r0``: the starting
    ``|zeta_mode|`` (None: ``A_stop / 200``, ``A ~ 2 |zeta|``); ``tol``: the validity tolerance (None: no
    validity); ``transverse``, ``h``: W_max as :meth:`stepnf.dpim.backbone.Backbone.w_max`."""
    if ratios is None and manifold.ratios is None:  # no resonance between the masters: mode j alone moves
        ratios = np.eye(len(manifold.masters), dtype=int)[mode]
    system = ReducedSystem(manifold, ratios)
    measure = orbit_measure(manifold, system.k)
    r = A_stop / 200.0 if r0 is None else float(r0)
    found = starts(system, mode, r)
    if not found:
        raise NumericalError(f"backbone branches: no periodic orbit of the reduced dynamics of masters "
                             f"{list(manifold.masters)} starts at |zeta_{mode}| = {r:.3g}")
    out = []
    for kind, u0, sub in found:
        if kind.startswith("continues mode"):  # named by its index in the spectrum, not its position
            kind = f"continues mode {manifold.masters[mode]}"
        b = trace(sub, measure, u0, kind, mode, manifold.masters, A_stop, max_points=max_points,
                  transverse=transverse, h=h)
        if tol is not None:
            b.valid_A, b.valid_reason = validity(manifold, b, tol, ratios=system.k, max_points=max_points)
        out.append(b)
    return out


def omega_at(manifold: Any, branch: Branch, A: float, *, ratios: Any = None) -> float:
    """The fundamental ``Omega`` of ``branch`` where master ``branch.mode``'s amplitude is ``A`` (the first
    crossing; NumericalError when the branch does not reach it), to round-off (module docstring)."""
    return float(point_at(manifold, branch, A, ratios=ratios)[2 * len(branch.masters)])


def point_at(manifold: Any, branch: Branch, A: float, *, ratios: Any = None) -> np.ndarray:
    """The point ``u = (Re zeta, Im zeta, Omega, eps, mu..)`` (mu: :class:`ReducedSystem`) of ``branch`` where
    master ``branch.mode``'s amplitude is ``A`` (as :func:`omega_at`); its stability:
    ``ReducedSystem(manifold).stability(u)``."""
    system = _system(manifold, branch, ratios)
    measure = orbit_measure(manifold, system.k)
    j, m = branch.mode, system.m
    Aj = branch.A[:, j]
    hit = np.flatnonzero((Aj[:-1] - A) * (Aj[1:] - A) <= 0)
    if not len(hit):
        raise NumericalError(f"backbone branch ({branch.kind}): the amplitude A = {A:.6g} of master {j} is not "
                             f"on it (A from {Aj.min():.6g} to {Aj.max():.6g})")
    i = int(hit[0])
    u0, u1 = _u(branch, i), _u(branch, i + 1)
    # the chord and its hyperplanes in units of the two points' size (_scaled: not Omega's alone)
    scaled, D = _units(system, j, max(float(np.abs(u0[:2 * m]).max()), float(np.abs(u1[:2 * m]).max())))
    x0 = u0 / D
    chord = u1 / D - x0

    def on_branch(s: float) -> np.ndarray:
        p = x0 + s * chord
        done = scaled.correct(p, lambda v: (float(chord @ (v - p)), chord), p[:m] + 1j * p[m:2 * m])
        if done is None:
            raise NumericalError(f"backbone branch ({branch.kind}): Newton failed between points {i} and {i + 1} "
                                 f"(A = {Aj[i]:.6g} and {Aj[i + 1]:.6g}, Omega = {u0[2 * m]:.6g} and "
                                 f"{u1[2 * m]:.6g}): no point of the branch near their chord at s = {s:.3g}")
        return done[0] * D

    def g(s: float) -> float:
        u = on_branch(s)
        return float(measure.amplitudes(u[:m] + 1j * u[m:2 * m])[j] - A)
    if A == Aj[i]:
        return u0
    if A == Aj[i + 1]:
        return u1
    return on_branch(brentq(g, 0.0, 1.0, xtol=1e-15, rtol=4 * np.finfo(float).eps))


def validity(manifold: Any, branch: Branch, tol: float, *, ratios: Any = None,
             max_points: int = 400) -> tuple[float | None, str]:
    """``(A_max, reason)`` for ``branch`` of ``manifold`` at order N against order N - 2 (module docstring):
    ``"orders differ"``, ``"shapes differ"``, ``"stability differs"`` (orders N - 2 and N call the orbit stable and
    unstable on both sides of it), ``"amplitude folds"`` (A of the master stops growing first), ``"not reached"``
    (A_max None) or ``"no lower order"`` (N < 5: A_max None)."""
    N = int(manifold.order)
    if N < 5:
        return None, "no lower order"
    lower = manifold.truncated(N - 2)
    system = _system(lower, branch, ratios)
    measure = orbit_measure(lower, system.k)
    j, m = branch.mode, system.m
    u0 = _u(branch, 0)
    g = np.zeros(len(u0))
    g[j] = 1.0
    done = system.correct(u0, lambda v: (float(v[j] - u0[j]), g), u0[:m] + 1j * u0[m:2 * m], maxiter=40)
    if done is None:
        return 0.0, "orders differ"
    A_top = float(branch.A[:, j].max())
    low = trace(system, measure, done[0], branch.kind, j, branch.masters, A_top, max_points=max_points)
    AL = low.A[:, j]
    grow = int(np.argmax(np.diff(AL) <= 0)) + 1 if np.any(np.diff(AL) <= 0) else len(AL)
    if grow < 4:
        return 0.0, "orders differ"
    spline = CubicSpline(AL[:grow], low.Omega[:grow])
    w = float(np.asarray(manifold.omega)[j])
    k = float(branch.ratios[j])
    shapes, shape_tol = orbit_measure(manifold, system.k), float(np.sqrt(tol))
    prev_A = 0.0
    prev_d = -1.0
    A = branch.A[:, j]

    def excesses(u: np.ndarray, Om_low: float) -> tuple[float, float]:  # > 0: the frequencies, the shapes differ
        return (abs(k * (u[2 * m] - Om_low)) / (tol * w) - 1.0,
                shapes.shape_difference(u[:m] + 1j * u[m:2 * m], N - 2) / shape_tol - 1.0)
    for i in range(len(A)):
        if i and A[i] <= A[i - 1]:
            return float(prev_A), "amplitude folds"
        if A[i] > AL[grow - 1]:  # order N - 2 folds or ends (its trace stopped) below: nothing to compare with
            return float(prev_A), "orders differ"
        il = min(int(np.searchsorted(AL[:grow], A[i])), grow - 1)  # order N - 2's points around A[i]
        if all(bool(branch.stable[i]) != bool(low.stable[t]) for t in {max(il - 1, 0), il}):
            return float(prev_A), "stability differs"  # (exact 1:2's upper branch: stable at N = 7 beyond A = 2.2)
        df, ds = excesses(_u(branch, i), float(spline(A[i])))
        d = max(df, ds)
        if d > 0:
            if i == 0:
                return 0.0, "orders differ" if df >= ds else "shapes differ"

            def excess(a: float) -> float:  # both frequencies refined on their branches, the shapes at a
                return max(excesses(point_at(manifold, branch, a), omega_at(lower, low, a)))
            try:
                a = float(brentq(excess, prev_A, float(A[i]), xtol=1e-12 * float(A[i])))
                df, ds = excesses(point_at(manifold, branch, a), omega_at(lower, low, a))
            except (ValueError, NumericalError):  # no sign change once refined: the interpolated crossing
                a = float(prev_A + (A[i] - prev_A) * (-prev_d) / (d - prev_d))
            return a, "orders differ" if df >= ds else "shapes differ"
        prev_A, prev_d = float(A[i]), d
    return None, "not reached"


def tabulate(branch: Branch, rows: int = 12) -> str:
    """A compact table of ``branch``: about ``rows`` points evenly spread, ``k_j Omega``, every ``A_j``,
    ``|zeta_j|``, stability (and W_max), with a header naming its kind, masters, ratios and validity."""
    head = (f"branch '{branch.kind}' of master {branch.masters[branch.mode]} on the manifold "
            f"{list(branch.masters)}, ratios {branch.ratios.tolist()}: {len(branch.Omega)} points, valid to A = "
            + ("-" if branch.valid_A is None else f"{branch.valid_A:.4g}")
            + (f" ({branch.valid_reason})" if branch.valid_reason else "")
            + ("; a closed loop (back to its first point)" if branch.closed else "")
            + ("; traced modulo the rotation of exact twins" if branch.rotations is not None and len(branch.rotations)
               else ""))
    cols = ["Omega"] + [f"A_{q}" for q in branch.masters] + [f"|zeta_{q}|" for q in branch.masters]
    cols += (["W_max"] if branch.W_max is not None else []) + ["stable"]
    lines = [head, "  ".join(f"{c:>11s}" for c in cols)]
    K = len(branch.Omega)
    for i in sorted(set(np.linspace(0, K - 1, min(rows, K)).round().astype(int))):
        vals = [branch.Omega[i], *branch.A[i], *np.abs(branch.zeta[i])]
        vals += [branch.W_max[i]] if branch.W_max is not None else []
        lines.append("  ".join(f"{v:11.6g}" for v in vals) + f"  {'yes' if branch.stable[i] else 'no':>11s}")
    return "\n".join(lines)
