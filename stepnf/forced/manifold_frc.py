"""Frequency-response curves of a master on a manifold of several modes (issue 34 on the manifolds of issue 33).

The steady states are the zeros of :class:`stepnf.forced.manifold_system.ForcedSystem` (damping and forcing at
leading order in the reduced dynamics) with :class:`stepnf.forced.manifold_projection.Projection`'s terms (the
damping and forcing projected on the manifold, first order in them, every order in A); the derivations are there
and in docs/design.md, "Forced responses on a manifold of several modes". Each forcing level's curve:

* **main curve**: from the linear response at ``Omega = lo w_j`` (Newton at fixed Omega), pseudo-arclength
  continuation (:func:`stepnf.dpim.multimode.continuation.continue_branch`, in the scaled unknowns) until
  ``Omega > hi w_j``; its last point is moved onto ``Omega = hi w_j`` (Newton at fixed Omega);
* **branch points**: a sign change of the bordered Jacobian's determinant ``det [J; t]`` between two points,
  refined by Brent's method along the chord (each trial point corrected onto the curve); from each, the branch born
  there is followed along the null direction of ``J`` other than the tangent (forcing the higher mode of a 1:2 pair:
  the uncoupled response, partner at rest, loses its stability at a pitchfork and the coupled branch of the
  saturation phenomenon, Nayfeh & Mook, is born) until it leaves the range or comes back to another branch point;
* **folds**: where the tangent's Omega component changes sign (Brent's method on it along the chord);
* **peak**: the largest ``A`` of master ``j`` over the curve, refined by a bounded scalar search along the chord
  through the neighbouring points;
* **stable peak**: the largest ``A`` over the stable points, refined the same way, or, when that lands on an
  unstable point, the point where the stability is lost (bisection along the chord); ``peak_stable``, written when
  it differs from the peak (forcing the higher mode of a 1:2 pair the peak is the uncoupled response's unstable top,
  which no experiment reaches);
* **stability**: every eigenvalue of the 2m x 2m real Jacobian with a negative real part.

Amplitudes: ``A`` of each manifold mode's modal coordinate on the orbit (:class:`stepnf.dpim.multimode.measures.
OrbitMeasure`), ``W_max / h`` when the transverse measure is given; ``valid``: master j's ``A`` within the validity
limit of its backbone (``valid_to``). A Newton failure where a point must exist is a NumericalError naming the stage.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from stepnf.dpim.multimode.continuation import continue_branch
from stepnf.dpim.multimode.measures import OrbitMeasure, Transverse, orbit_measure
from stepnf.errors import NumericalError, SceneError
from stepnf.forced.damping import Damping, damping_ratio
from stepnf.forced.manifold_projection import Projection
from stepnf.forced.manifold_system import ForcedSystem

#: Largest continuation step (scaled unknowns: the linear peak's |zeta| and the resonance's half-width xi w).
H_MAX = 0.25
#: Most points per branch.
MAX_POINTS = 4000
#: The farthest the corrector may move a predicted point while tracing (scaled units; the step is halved beyond).
REACH = 0.05
#: A born branch ends at another branch point when it comes this near (scaled units; its steps are at most H_MAX,
#: so a branch through that point has one within H_MAX / 2 of it).
NEAR = 0.6 * H_MAX
#: The first step off a branch point along the born branch (scaled unknowns).
BRANCH_STEP = 0.02


@dataclass
class ManifoldFRC:
    """One forcing level's response of master ``masters[mode]`` on the manifold ``masters`` (module docstring).

    ``Omega`` (K,) forcing frequency, rad per model time unit; ``zeta`` (K, m) rotating-frame amplitudes;
    ``amplitudes`` (K, m) A of every manifold mode; ``amplitude`` (K,) the master's; ``segment`` (K,) 0 on the main
    curve, 1, 2, ... on the branches born at its branch points; ``peak``, ``folds``, ``branch_points`` dicts with
    ``Omega``, ``amplitude`` (and ``amplitudes``, ``valid``); the other fields as :class:`stepnf.forced.frc.FRC`'s.
    """

    level: dict[str, Any]
    masters: tuple[int, ...]
    mode: int
    modal_force: float
    Omega: np.ndarray
    zeta: np.ndarray
    amplitudes: np.ndarray
    stable: np.ndarray
    valid: np.ndarray
    segment: np.ndarray
    peak: dict[str, Any]
    folds: list[dict[str, Any]]
    branch_points: list[dict[str, Any]]
    valid_to: float | None
    xi: float
    omega_d: float
    w_max_h: np.ndarray | None = None
    peak_outside_range: bool = False
    flags: list[str] = field(default_factory=list)
    #: The largest amplitude over the stable points (as ``peak``, with ``segment``; None when no point is stable):
    #: the top an experiment sweeping Omega can reach. Forcing the higher mode of a 1:2 pair, ``peak`` is the
    #: uncoupled response's unstable top and this the pitchfork where it loses its stability.
    peak_stable: dict[str, Any] | None = None

    @property
    def amplitude(self) -> np.ndarray:
        return self.amplitudes[:, self.mode]

    def to_json(self) -> dict[str, Any]:
        """:meth:`stepnf.forced.frc.FRC.to_json`'s keys plus ``manifold`` (the modes), ``amplitudes`` ({mode: [A]}),
        ``branch_points``; ``segment`` when the curve has several pieces; ``peak_stable`` when it is not ``peak``
        (None: no stable point)."""
        out: dict[str, Any] = dict(self.level)
        out.update({"Omega": self.Omega.tolist(), "amplitude": self.amplitude.tolist(),
                    "stable": [bool(s) for s in self.stable], "peak": dict(self.peak),
                    "folds": [dict(f) for f in self.folds], "xi": self.xi, "omega_d": self.omega_d,
                    "valid_to": self.valid_to, "valid": [bool(v) for v in self.valid],
                    "modal_force": self.modal_force, "peak_outside_range": self.peak_outside_range,
                    "manifold": list(self.masters),
                    "amplitudes": {str(q): self.amplitudes[:, i].tolist() for i, q in enumerate(self.masters)},
                    "branch_points": [dict(b) for b in self.branch_points]})
        if self.w_max_h is not None:
            out["w_max_h"] = self.w_max_h.tolist()
        if len(set(self.segment.tolist())) > 1:
            out["segment"] = self.segment.tolist()
        if self.flags:
            out["flags"] = list(self.flags)
        if self.peak_stable != self.peak:
            out["peak_stable"] = None if self.peak_stable is None else dict(self.peak_stable)
        return out


def manifold_damping(manifold: Any, damping: Damping) -> np.ndarray:
    """``xi_l = phi_l^T C phi_l / (2 w_l)`` (m,) of every manifold mode (0 for a partner modal damping ignores)."""
    phi = np.asarray(manifold.phi, dtype=float).reshape(-1, len(manifold.masters))
    CP = np.atleast_2d(damping(phi.T))  # (m, n)
    return np.einsum("in,ni->i", CP, phi) / (2.0 * np.asarray(manifold.omega, dtype=float))


def manifold_forced_responses(manifold: Any, damping: Damping, levels: Sequence[tuple[dict[str, Any], Any]],
                              frequency_range: tuple[float, float], mode: int, *, ratios: Any = None,
                              valid_to: float | None = None, transverse: Transverse | None = None,
                              h: float = 1.0, master: int | None = None) -> list[ManifoldFRC]:
    """The response of master ``manifold.masters[mode]`` per forcing level on the multi-mode ``manifold``
    (a :class:`~stepnf.dpim.multimode.manifold.ManifoldResult`). ``levels``: ``[(level dict, value)]``, value a number
    ``kappa`` (``F = kappa M phi_mode``) or a force vector (n,); ``frequency_range``: ``(lo, hi)`` of ``Omega / w_mode``;
    ``ratios``: the resonance vector (None: the manifold's, or ``e_mode`` without one); ``valid_to``: the backbone's
    validity limit in A; ``transverse``, ``h``: W_max/h; ``master``: the scene's index of the master (its damping
    ratio under modal damping; None: computed from C)."""
    lo, hi = (float(v) for v in frequency_range)
    if not (0.0 < lo < hi and np.isfinite(hi)):
        raise SceneError(None, "analysis.forcing.frequency_range",
                         f"[lo, hi] of Omega/omega with 0 < lo < hi; got {list(frequency_range)}")
    masters = tuple(int(q) for q in manifold.masters)
    if ratios is None:
        ratios = manifold.ratios if manifold.ratios is not None else np.eye(len(masters), dtype=int)[mode]
    k = np.asarray(ratios, dtype=int)
    xi = manifold_damping(manifold, damping)
    w = np.asarray(manifold.omega, dtype=float)
    if master is not None:
        xi[mode] = damping_ratio(damping.spec, float(w[mode]), master)
    measure = orbit_measure(manifold, k)
    phi = np.asarray(manifold.phi, dtype=float).reshape(-1, len(masters))
    projection = Projection(manifold, damping.K, damping, k, mode)  # (its Grams: once for every level)
    out = []
    for level, value in levels:
        g, F = modal_forces(manifold, phi, value, level, k, mode)
        system = ForcedSystem(manifold, k, mode, xi, g, projection.forced(F))
        out.append(_one_level(system, measure, level, float(g[mode]), (lo * w[mode], hi * w[mode]), valid_to,
                              transverse, h, masters))
    return out


def modal_forces(manifold: Any, phi: np.ndarray, value: Any, level: dict, k: np.ndarray,
                 mode: int) -> tuple[np.ndarray, np.ndarray]:
    """``(g, F)``: ``g_l = phi_l^T F`` (m,) with ``F`` (n,) turned so the first resonantly forced mode has ``g > 0``;
    SceneError naming ``analysis.forcing`` when no mode with ``k_l = k_mode`` is forced."""
    key = "analysis.forcing.modal" if np.ndim(value) == 0 else "analysis.forcing.load"
    if np.ndim(value) == 0:
        kap = float(value)
        if not np.isfinite(kap) or kap == 0.0:
            raise SceneError(None, key, f"a forcing level kappa must be a finite nonzero number; got {value}")
        F = kap * np.asarray(manifold.M @ phi[:, mode], dtype=float)
    else:
        F = np.asarray(value, dtype=float)
        if F.shape != (phi.shape[0],) or not np.all(np.isfinite(F)):
            raise SceneError(None, key, f"the force must be {phi.shape[0]} finite values; got shape {F.shape}")
    g = phi.T @ F
    scale = float(np.linalg.norm(F)) * float(np.abs(np.asarray(manifold.M @ phi)).max())
    on = (k == k[mode]) & (np.abs(g) > 1e-12 * scale)
    if not on.any():
        raise SceneError(None, key, f"level {level}: the force excites no mode of the manifold "
                         f"{list(manifold.masters)} resonant with master {manifold.masters[mode]} (phi^T F = "
                         f"{np.round(g, 12).tolist()}): no resonant response at leading order")
    return (g, F) if g[np.flatnonzero(on)[0]] > 0 else (-g, -F)


def _trace(system: ForcedSystem, u0: np.ndarray, direction: np.ndarray, lo: float, hi: float,
           avoid: Sequence[np.ndarray] = ()) -> tuple[np.ndarray, list[int]]:
    """Continue from ``u0`` along ``direction`` until Omega leaves ``[lo, hi]`` or, for a born branch, the branch
    comes back near one of the points ``avoid`` (another branch point)."""
    state = {"n": 0, "away": False}

    def stop(u: np.ndarray) -> bool:
        state["n"] += 1
        Om = system.Omega(u)
        if Om > hi or (state["n"] > 2 and Om < lo):
            return True
        d = min((float(np.abs(u - p).max()) for p in avoid), default=np.inf)
        state["away"] = state["away"] or d > 3 * NEAR
        return bool(state["away"] and d < NEAR)
    system.reach = REACH
    try:
        pts, bps, _ = continue_branch(system, u0, direction=direction, stop=stop, max_points=MAX_POINTS,
                                      h0=0.02 * H_MAX, h_max=H_MAX)  # (its own closing rule: stop)
        return pts, bps
    finally:
        system.reach = np.inf


def _on_chord(system: ForcedSystem, u0: np.ndarray, u1: np.ndarray, s: float, stage: str) -> np.ndarray:
    chord = u1 - u0
    p = u0 + s * chord
    got = system.correct(p, lambda v: (float(chord @ (v - p)), chord), maxiter=30)
    if got is None:
        raise NumericalError(f"forced response on a manifold ({stage}): Newton failed at Omega = "
                             f"{system.Omega(p):.6g}")
    return got[0]


def _ends_in_range(system: ForcedSystem, pts: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The branch's last point moved onto the range's end it crossed (Newton at fixed Omega)."""
    Om = np.array([system.Omega(u) for u in pts])
    if len(pts) < 2 or lo <= Om[-1] <= hi:
        return pts
    end = hi if Om[-1] > hi else lo
    s = (end - Om[-2]) / (Om[-1] - Om[-2])
    got = system.at_frequency(end, pts[-2] + s * (pts[-1] - pts[-2]))
    if got is None:
        raise NumericalError(f"forced response on a manifold (range end): Newton failed at Omega = {end:.6g}")
    return np.vstack([pts[:-1], got])


def _refine_sign(system: ForcedSystem, pts: np.ndarray, i: int, fun, stage: str) -> np.ndarray:
    """The point between ``pts[i]`` and ``pts[i + 1]`` where ``fun(u, t)`` changes sign (Brent along the chord)."""
    u0, u1 = pts[i], pts[i + 1]
    chord = u1 - u0

    def val(s: float) -> float:
        u = _on_chord(system, u0, u1, s, stage)
        return fun(u, system.tangent(u, None, chord))
    f0, f1 = val(0.0), val(1.0)
    if f0 * f1 > 0:
        return _on_chord(system, u0, u1, 0.5, stage)
    return _on_chord(system, u0, u1, brentq(val, 0.0, 1.0, xtol=1e-13, rtol=1e-14), stage)


def _one_level(system: ForcedSystem, measure: OrbitMeasure, level: dict, g: float, rng: tuple[float, float],
               valid_to: float | None, transverse, h: float, masters: tuple[int, ...]) -> ManifoldFRC:
    lo, hi = rng
    j, m = system.j, system.m
    first = system.at_frequency(lo, system.linear(lo))
    if first is None:
        raise NumericalError(f"forced response on a manifold (start): Newton failed at Omega = {lo:.6g}")
    up = np.zeros(2 * m + 2)
    up[2 * m] = 1.0
    pts, bps = _trace(system, first, up, lo - 1e-12 * hi, hi)
    flags = []
    if system.Omega(pts[-1]) <= hi:
        flags.append(f"the curve stops at Omega = {system.Omega(pts[-1]):.6g} before the range's end {hi:.6g}")
    branches = [_ends_in_range(system, pts, lo, hi)]
    main = branches[0]
    bp_pts = [_refine_sign(system, main, i, lambda u, t: system.bordered_det(u, t), "branch point")
              for i in bps if i + 1 < len(main)]
    used: list[int] = []
    for b, ub in enumerate(bp_pts):
        if b in used:
            continue
        v = system.second_direction(ub, system.tangent(ub))
        pred = ub + BRANCH_STEP * v  # off the branch point along the new branch (the tangent there is not unique)
        got = system.correct(pred, lambda x, p=pred: (float(v @ (x - p)), v), maxiter=30)
        if got is None:
            flags.append(f"the branch born at Omega = {system.Omega(ub):.6g} could not be started: not followed")
            continue
        born, _ = _trace(system, got[0], v, lo, hi, avoid=bp_pts)
        born = np.vstack([ub, born])
        if len(born) > 1:
            for c, p in enumerate(bp_pts):  # the branch point this branch came back to: not followed again
                if c != b and float(np.abs(born[-1] - p).max()) < NEAR:
                    used.append(c)
                    born = np.vstack([born, p])
            branches.append(_ends_in_range(system, born, lo, hi))
    U = np.vstack(branches)
    seg = np.concatenate([np.full(len(p), s) for s, p in enumerate(branches)])
    zeta = np.array([system.zeta(u) for u in U])
    A = np.array([measure.amplitudes(z) for z in zeta])
    Om = np.array([system.Omega(u) for u in U])
    stable = np.array([system.stability(u)[0] for u in U])
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(Om))):
        raise NumericalError(f"forced response on a manifold (amplitudes): not finite on the curve of level {level}")
    lim = np.inf if valid_to is None else float(valid_to)

    def record(u: np.ndarray) -> dict[str, Any]:
        z = system.zeta(u)
        a = measure.amplitudes(z)
        return {"Omega": system.Omega(u), "amplitude": float(a[j]), "valid": bool(a[j] <= lim),
                "amplitudes": {str(q): float(x) for q, x in zip(masters, a)}, "stable": system.stability(u)[0],
                "w_max_h": None if transverse is None else float(measure.w_max(z, transverse, h))}
    peak, outside = _peak(system, measure, branches, seg, A[:, j], record)
    top = peak if peak["stable"] else _peak_stable(system, measure, branches, seg, A[:, j], stable, record)
    folds = []
    for s, p in enumerate(branches):
        ends = 1 if s else 0  # a born branch's ends are branch points: no tangent of its own there
        tO = np.array([system.tangent(u, None, p[min(i + 1, len(p) - 1)] - p[max(i - 1, 0)])[2 * m]
                       for i, u in enumerate(p)])[ends:len(p) - ends]
        for i in np.flatnonzero(tO[1:] * tO[:-1] < 0) + ends:
            f = record(_refine_sign(system, p, int(i), lambda u, t: float(t[2 * m]), "fold"))
            folds.append({**f, "segment": s, "in_range": bool(lo <= f["Omega"] <= hi)})
    wmh = None if transverse is None else np.array([measure.w_max(z, transverse, h) for z in zeta])
    return ManifoldFRC(level, masters, j, g, Om, zeta, A, stable, A[:, j] <= lim, seg, peak, folds,
                       [record(u) for u in bp_pts], valid_to, float(system.xi[j]), float(system.wd[j]), wmh,
                       outside, flags, peak_stable=top)


def _peak(system: ForcedSystem, measure: OrbitMeasure, branches: list, seg: np.ndarray, Aj: np.ndarray, record,
          among: np.ndarray | None = None):
    """The refined largest amplitude of master j (over the points ``among`` when given) and whether it lies at the
    range's end: a bounded scalar search over the hyperplanes ``t . (u - u_k) = sigma`` (``t`` the tangent at the
    largest point ``k``) between the neighbours, each trial point corrected onto the curve from the chord on its
    side."""
    i = int(np.argmax(Aj if among is None else np.where(among, Aj, -np.inf)))
    s = int(seg[i])
    p = branches[s]
    k = i - int(np.flatnonzero(seg == s)[0])
    if k in (0, len(p) - 1):
        return record(p[k]), True
    uk = p[k]
    t = system.tangent(uk, None, p[k + 1] - p[k - 1])
    ends = (float(t @ (p[k - 1] - uk)), float(t @ (p[k + 1] - uk)))

    def at(sigma: float) -> np.ndarray:
        un = p[k + 1] if sigma >= 0 else p[k - 1]
        step = float(t @ (un - uk))
        guess = uk + (sigma / step if step else 0.0) * (un - uk)
        got = system.correct(guess, lambda v: (float(t @ (v - uk)) - sigma, t), maxiter=30)
        if got is None:
            raise NumericalError(f"forced response on a manifold (peak): Newton failed at Omega = "
                                 f"{system.Omega(guess):.6g}")
        return got[0]
    r = minimize_scalar(lambda x: -measure.amplitudes(system.zeta(at(x)))[system.j], bounds=(min(ends), max(ends)),
                        method="bounded", options={"xatol": 1e-10 * max(abs(ends[0]), abs(ends[1]))})
    best = at(float(r.x))
    if measure.amplitudes(system.zeta(best))[system.j] < Aj[i]:
        best = uk
    return {**record(best), "segment": s}, False


def _peak_stable(system: ForcedSystem, measure: OrbitMeasure, branches: list, seg: np.ndarray, Aj: np.ndarray,
                 stable: np.ndarray, record) -> dict[str, Any] | None:
    """The largest amplitude of master j over the stable points (None when there is none), refined as
    :func:`_peak`; when the refined point is unstable (the stable part's top is where stability is lost: a branch
    point, a fold), that point by bisection along the chord from the largest stable point to its unstable
    neighbour of larger A, on the stability of each point corrected onto the curve (to 1e-12 of the chord)."""
    if not stable.any():
        return None
    best, _ = _peak(system, measure, branches, seg, Aj, record, among=stable)
    if best["stable"]:
        return best
    i = int(np.argmax(np.where(stable, Aj, -np.inf)))
    s = int(seg[i])
    p, first = branches[s], int(np.flatnonzero(seg == s)[0])
    k = i - first
    nb = [q for q in (k - 1, k + 1) if 0 <= q < len(p) and not stable[first + q]]
    if not nb:  # an unstable refined point between stable samples (no unstable neighbour): the best stable sample
        return {**record(p[k]), "segment": s}
    q = max(nb, key=lambda x: Aj[first + x])
    a, b = 0.0, 1.0  # a: stable side, b: unstable side (fractions of the chord p[k] -> p[q])
    while b - a > 1e-12:
        c = 0.5 * (a + b)
        if system.stability(_on_chord(system, p[k], p[q], c, "stable peak"))[0]:
            a = c
        else:
            b = c
    return {**record(_on_chord(system, p[k], p[q], a, "stable peak")), "segment": s}
