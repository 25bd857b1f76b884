"""Frequency-response curves (FRCs) of one master from its DPIM manifold, damping and forcing levels.

For each forcing level the steady states of :class:`stepnf.forced.averaged.Averaged` form a level set
parametrised by the manifold amplitude ``rho`` on ``(0, rho_peak]``: ``rho_peak`` the first root of
``2 D = Omega_d f1`` (Brent's method, to round-off), where the two branches
``Omega = Omega_d(rho) -/+ (1/2)(df1/dI) |cos psi|`` meet. The curve is walked with one parameter
``u`` in ``(-1, 1)``, ``rho = rho_peak (1 - u^2)`` and ``-cos psi = sign(u) |cos psi|``, which is smooth
through the peak (``|cos psi| ~ |u|`` there): from the low-frequency end, up to the peak, down the other
branch. Where ``2 D <= Omega_d f1`` again on ``[rho_2, rho_3]`` beyond the peak the level set is a closed
curve of its own (an isola), walked with ``rho = (rho_2 + rho_3)/2 + (rho_3 - rho_2)/2 cos(tau)``.

Only the parts with ``Omega / omega`` in ``frequency_range`` are kept (each part a segment, its ends
found by Brent's method on the range's ends; ``peak_outside_range`` says when the peak is not in it).
Folds (saddle-node points) are the zeros of ``dOmega/drho`` on a branch (Brent's method); the stability
of each point is that of the averaged dynamics (stable iff trace < 0 and det > 0 of its Jacobian).
Amplitudes are the backbone's measures (:class:`stepnf.dpim.backbone.Backbone`): ``A`` of the master's
modal coordinate ``q = phi^T M x`` and ``W_max / h``, ``A`` with the first-order shift of the averaging's
change of variables (:meth:`stepnf.forced.averaged.Averaged.amplitude_shift`: it makes the flanks second
order; zero at the peak); a point whose ``A`` exceeds the backbone's validity limit is marked
``valid: False`` (the peak too). A curve's points are measured all at once (the ``*_many`` methods, which the
one-point forms used for the peak and the folds wrap).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.optimize import brentq

from stepnf.dpim.backbone import Backbone, Transverse
from stepnf.errors import NumericalError, SceneError
from stepnf.forced.averaged import Averaged, manifold_grams
from stepnf.forced.damping import Damping, damping_ratio

#: Dense samples of the curve parameter, before clipping and resampling by arc length.
DENSE = 3000


@dataclass
class FRC:
    """One forcing level's frequency response (module docstring).

    ``level``: ``{"kappa": k}`` or ``{"load": amplitude, ...}``; ``modal_force``: ``phi^T F`` (f1's slope
    at ``rho -> 0``); ``Omega`` (rad per model time unit), ``rho``, ``amplitude`` (A of ``q``),
    ``w_max_h`` (or None), ``stable``, ``valid`` (A within the validity limit), ``segment`` (index of the
    in-range piece each point is on): arrays ordered along the curve. ``peak``: ``{"amplitude", "Omega",
    "rho", "valid"}``; ``folds``: ``[{"Omega", "amplitude", "rho", "valid", "in_range"}]``; ``isolas``: the
    number of isolas found (their points are segments of their own); ``valid_to``: the backbone's
    validity limit in A (None: not reached); ``flags``: what was found and not followed (a level set that
    comes back beyond the peak and does not close).
    """

    level: dict[str, Any]
    modal_force: float
    Omega: np.ndarray
    rho: np.ndarray
    amplitude: np.ndarray
    w_max_h: np.ndarray | None
    stable: np.ndarray
    valid: np.ndarray
    segment: np.ndarray
    peak: dict[str, Any]
    folds: list[dict[str, Any]]
    valid_to: float | None
    xi: float
    omega_d: float
    peak_outside_range: bool = False
    isolas: int = 0
    segment_isola: list[bool] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """Issue 34's JSON: the level's key, ``Omega``, ``amplitude``, ``stable``, ``peak``, ``folds``, plus
        ``xi``, ``omega_d``, ``valid_to``, ``valid``, ``w_max_h`` when known, ``segment`` when more than one."""
        out: dict[str, Any] = dict(self.level)
        out.update({"Omega": self.Omega.tolist(), "amplitude": self.amplitude.tolist(),
                    "stable": [bool(s) for s in self.stable], "peak": dict(self.peak),
                    "folds": [dict(f) for f in self.folds], "xi": self.xi, "omega_d": self.omega_d,
                    "valid_to": self.valid_to, "valid": [bool(v) for v in self.valid],
                    "modal_force": self.modal_force, "peak_outside_range": self.peak_outside_range})
        if self.w_max_h is not None:
            out["w_max_h"] = self.w_max_h.tolist()
        if len(self.segment_isola) > 1:
            out["segment"] = self.segment.tolist()
            out["segment_isola"] = list(self.segment_isola)
        if self.isolas:
            out["isolas"] = self.isolas
        if self.flags:
            out["flags"] = list(self.flags)
        return out


def forced_responses(res: Any, damping: Damping, levels: Sequence[tuple[dict[str, Any], Any]],
                     frequency_range: tuple[float, float], *, backbone: Backbone | None = None,
                     valid_to: float | None = None, transverse: Transverse | None = None, h: float | None = None,
                     points: int = 400, master: int = 0, mode: int | None = None,
                     validity_tol: float = 1e-3) -> list[FRC]:
    """The FRC of the master of ``res`` (a :class:`~stepnf.dpim.parametrisation.DPIMResult`) per level.

    ``levels``: ``[(level dict, value)]``, value a number ``kappa`` (``F = kappa M phi``) or a force
    vector ``F`` (n,); ``frequency_range``: ``(lo, hi)`` of ``Omega / omega``; ``backbone``: the master's
    backbone (built when None); ``valid_to``: its validity limit in A (when None, computed by
    :meth:`~stepnf.dpim.backbone.Backbone.validity_limit` with ``validity_tol``); ``transverse``, ``h``:
    W_max/h as the backbone measures it; ``points``: samples per FRC; ``master``: the master's position in
    the scene's list (its damping ratio); ``mode``: its number in messages.
    """
    who = f"forced response of mode {master if mode is None else mode}"
    lo, hi = (float(v) for v in frequency_range)
    if not (0.0 < lo < hi and np.isfinite(hi)):
        raise SceneError(None, "analysis.forcing.frequency_range",
                         f"[lo, hi] of Omega/omega with 0 < lo < hi; got {list(frequency_range)}")
    if int(points) < 10:
        raise SceneError(None, "analysis.forcing.points", f"at least 10 samples per FRC; got {points}")
    bb = backbone if backbone is not None else Backbone(res)
    if valid_to is None:
        valid_to, _ = bb.validity_limit(validity_tol)
    xi = damping_ratio(damping.spec, res.omega, master)
    out = []
    grams = manifold_grams(res, damping)  # the same for every level
    for level, value in levels:
        F, proj = force_vector(res, value, level, Mphi=grams[2])
        av = Averaged(res, damping, xi, F, grams)
        out.append(_one_level(av, bb, level, proj, (lo, hi), valid_to, transverse, h, int(points), who))
    return out


def force_vector(res: Any, value: Any, level: dict[str, Any], *,
                 Mphi: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """``(F, phi^T F)``: the force amplitude (n,) of one level, turned to excite the master with
    ``phi^T F > 0`` (a sign of F is a phase of pi: the same response), and its modal force as given.
    SceneError when it is zero, not finite or does not excite the master. ``Mphi``: ``M phi`` when known."""
    Mphi = np.asarray(res.M @ res.phi, dtype=float) if Mphi is None else np.asarray(Mphi, dtype=float)
    key = "analysis.forcing.modal" if np.ndim(value) == 0 else "analysis.forcing.load"
    if np.ndim(value) == 0:
        k = float(value)
        if not np.isfinite(k) or k == 0.0:
            raise SceneError(None, key, f"a forcing level kappa must be a finite nonzero number; got {value}")
        F = k * Mphi
    else:
        F = np.asarray(value, dtype=float)
        if F.shape != res.phi.shape or not np.all(np.isfinite(F)):
            raise SceneError(None, key, f"the force must be {res.phi.shape[0]} finite values; got shape {F.shape}")
    proj = float(res.phi @ F)
    scale = float(np.linalg.norm(F) * np.linalg.norm(Mphi))
    if scale == 0.0 or abs(proj) <= 1e-12 * scale:
        raise SceneError(None, key, f"level {level}: the force does not excite the master mode "
                                    f"(phi^T F = {proj:.3g}): no resonant response at leading order")
    return (F if proj > 0 else -F), proj


def _peak_roots(av: Averaged, who: str, rho_cap: float | None):
    """``(rho_peak, isolas, reopens)``: the first root of ``Omega_d f1 - 2 D``, the isolas' ``(rho_2, rho_3)``
    up to the scan's end (1.5 ``rho_cap``), and the ``rho`` beyond which steady states exist again up to
    that end (an unbounded branch of the series; None without one), the scan's end and the isolas left out
    (the action decreases on them): ``(rho, end, dropped)``."""
    rho_lin = float(av.df1(0.0)) / (2.0 * av.xi * av.omega * av.omega_d)  # the linear peak
    top = 1e3 * rho_lin if rho_cap is None else max(1.5 * rho_cap, 2.0 * rho_lin)
    r = np.geomspace(1e-6 * rho_lin, top, 2000)
    with np.errstate(over="ignore", invalid="ignore"):
        g, dI = av.reach(r), av.dI(r)
    ok = np.isfinite(g) & np.isfinite(dI)
    stop = int(np.argmin(ok)) if not ok.all() else len(r)
    r, g, dI = r[:stop], g[:stop], dI[:stop]
    if len(r) < 2:  # the series overflows from the scan's first point (a forcing level far too large)
        raise NumericalError(f"{who}: the manifold's series overflows at rho = {1e-6 * rho_lin:.3g}, a millionth of "
                             f"the linear peak rho = {rho_lin:.3g}: the forcing level is far beyond the backbone")
    change = np.nonzero(np.sign(g[1:]) != np.sign(g[:-1]))[0]
    if not len(change):
        raise NumericalError(f"{who}: the response grows without bound up to rho = {r[-1]:.3g} (2 D never "
                             f"reaches Omega_d f1: the damping does not bound this forcing on the manifold)")
    roots = [brentq(av.reach, r[i], r[i + 1], xtol=4e-16 * r[i + 1], rtol=1e-15, maxiter=200) for i in change]
    rho_peak = roots[0]
    bad = np.nonzero((dI <= 0) & (r <= rho_peak))[0]
    if len(bad):
        raise NumericalError(f"{who}: the action of the manifold stops growing at rho = {r[bad[0]]:.4g} before "
                             f"the peak (rho = {rho_peak:.4g}): the parametrisation is used beyond its validity")
    pairs = list(zip(roots[1::2], roots[2::2]))
    isolas = [(a, b) for a, b in pairs if np.all(dI[(r >= a) & (r <= b)] > 0)]
    dropped = [(a, b) for a, b in pairs if (a, b) not in isolas]  # the action decreases there: no angle variable
    reopens = roots[-1] if len(roots) % 2 == 0 else None  # the level set comes back and stays to the scan's end
    return rho_peak, isolas, (reopens, float(r[-1]), dropped)


def _pieces(rho_peak: float, isolas: list[tuple[float, float]]):
    """The curves to walk: ``(rho(t), c_sign(t), t_dense, isola)``."""
    r = np.geomspace(1e-10, 1.0, DENSE // 2)
    u = np.unique(np.concatenate([np.linspace(-1, 1, DENSE)[1:-1], -np.sqrt(1 - r[:-1]),
                                  np.sqrt(1 - r[:-1]), [0.0]]))
    u = u[np.abs(u) < 1.0]
    yield (lambda t: rho_peak * (1.0 - t * t)), np.sign, u, False
    tau = np.linspace(0.0, 2 * np.pi, DENSE)
    for a, b in isolas:
        yield (lambda t, a=a, b=b: 0.5 * (a + b) + 0.5 * (b - a) * np.cos(t)), (lambda t: np.sign(np.sin(t))), tau, True


def _runs(omega_of, t: np.ndarray, W: np.ndarray, lo: float, hi: float) -> list[tuple[float, float]]:
    """The parameter intervals where ``lo <= Omega <= hi``, their ends refined by Brent's method."""
    inside = (W >= lo) & (W <= hi)
    out = []
    i = 0
    while i < len(t):
        if not inside[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(t) and inside[j + 1]:
            j += 1

        def end(k_out: int, k_in: int) -> float:
            bound = lo if W[k_out] < lo else hi
            return brentq(lambda s: omega_of(s) - bound, min(t[k_out], t[k_in]), max(t[k_out], t[k_in]),
                          xtol=1e-15, rtol=1e-15)
        out.append((end(i - 1, i) if i > 0 else t[i], end(j + 1, j) if j + 1 < len(t) else t[j]))
        i = j + 1
    return out


def _folds(av: Averaged, rho_peak: float) -> list[tuple[float, float]]:
    """``(rho, c_sign)`` of every zero of ``dOmega/drho`` on either branch of the main curve."""
    r = rho_peak * (1.0 - np.geomspace(1e-9, 1.0, DENSE)[::-1][1:])[::-1]  # (0, rho_peak), dense at both ends
    r = np.unique(np.concatenate([r, np.linspace(0, rho_peak, DENSE)[1:-1]]))
    out = []
    for sign in (-1.0, 1.0):
        d = av.domega(r, sign)
        for i in np.nonzero(np.sign(d[1:]) * np.sign(d[:-1]) < 0)[0]:
            out.append((brentq(lambda x: float(av.domega(x, sign)), r[i], r[i + 1], xtol=1e-15 * rho_peak,
                               rtol=1e-15), sign))
    return out


def _one_level(av: Averaged, bb: Backbone, level: dict[str, Any], modal_force: float, rng: tuple[float, float],
               valid_to: float | None, transverse, h, points: int, who: str) -> FRC:
    w = av.omega
    lo, hi = rng[0] * w, rng[1] * w
    rho_cap = None
    if valid_to is not None:
        try:
            rho_cap = bb.rho_at(valid_to)
        except NumericalError:
            rho_cap = None
    rho_peak, isolas, (reopens, end, dropped) = _peak_roots(av, who, rho_cap)
    flags = [] if reopens is None else [
        f"steady states again from rho = {reopens:.6g} (A = {bb.amplitude(reopens):.6g}) to the end of the scan "
        f"(rho = {end:.3g}): not followed"]
    flags += [f"an isola between rho = {a:.6g} and {b:.6g} where the manifold's action decreases: not followed"
              for a, b in dropped]
    folds = _folds(av, rho_peak)
    special = {0.0: rho_peak} | {s * np.sqrt(max(1.0 - x / rho_peak, 0.0)): x for x, s in folds}  # u -> rho
    samples: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (rho, c, segment) per piece
    pieces = []
    for rho_of, csign, t, isola in _pieces(rho_peak, isolas):
        def omega_of(s, rho_of=rho_of, csign=csign):
            x = rho_of(s)
            return av.omega_of(x, csign(s) * av.cos_abs(x))
        W = omega_of(t)
        outside = np.nonzero((W < lo) | (W > hi))[0]
        if isola and len(outside):  # a closed curve: start where it is out of the range (one piece per pass)
            t = t + t[outside[0]]
            W = omega_of(t)
        for a, b in _runs(omega_of, t, W, lo, hi):
            keep = (t > a) & (t < b)
            tt = np.concatenate([[a], t[keep], [b]])
            pieces.append((tt, omega_of(tt), rho_of, csign, isola, special if not isola else {}))
    total = sum(_length(tt, WW, rho_of(tt), w, rho_peak) for tt, WW, rho_of, *_ in pieces) or 1.0
    for seg, (tt, WW, rho_of, csign, isola, spec) in enumerate(pieces):
        s = np.concatenate([[0.0], np.cumsum(_steps(WW, rho_of(tt), w, rho_peak))])
        n = max(3, int(round(points * s[-1] / total)))
        ts = np.interp(np.linspace(0.0, s[-1], n), s, tt)
        ts = np.unique(np.concatenate([ts, [x for x in spec if tt[0] < x < tt[-1]]]))
        r = np.asarray(rho_of(ts), dtype=float)
        for x, rx in spec.items():  # the peak's and the folds' rho exactly
            r[ts == x] = rx
        samples.append((r, np.asarray(csign(ts) * av.cos_abs(r), dtype=float), np.full(len(ts), seg)))
    rho = np.concatenate([x[0] for x in samples]) if samples else np.zeros(0)
    c = np.concatenate([x[1] for x in samples]) if samples else np.zeros(0)
    A = measured_many(av, bb, rho, c)
    valid = np.ones(len(rho), bool) if valid_to is None else A <= valid_to
    A_peak = bb.amplitude(rho_peak)
    W_peak = float(av.Od(rho_peak))
    fold_list = []
    for x, s in folds:
        cf = s * float(av.cos_abs(x))
        Wf, Af = float(av.omega_of(x, cf)), measured(av, bb, x, cf)
        fold_list.append({"Omega": Wf, "amplitude": Af, "rho": x, "valid": bool(valid_to is None or Af <= valid_to),
                          "in_range": bool(lo <= Wf <= hi)})
    fold_list.sort(key=lambda f: f["Omega"])
    return FRC(level=dict(level), modal_force=modal_force, Omega=av.omega_of(rho, c), rho=rho, amplitude=A,
               w_max_h=None if transverse is None else bb.w_max_many(rho, transverse, h or 1.0),
               stable=av.stable(rho, c), valid=valid,
               segment=np.concatenate([x[2] for x in samples]).astype(int) if samples else np.zeros(0, dtype=int),
               peak={"amplitude": A_peak, "Omega": W_peak, "rho": rho_peak,
                     "valid": bool(valid_to is None or A_peak <= valid_to)},
               folds=fold_list, valid_to=valid_to, xi=av.xi, omega_d=av.omega_d,
               peak_outside_range=not lo <= W_peak <= hi, isolas=len(isolas),
               segment_isola=[p[4] for p in pieces], flags=flags)


def measured(av: Averaged, bb: Backbone, rho: float, c: float) -> float:
    """:func:`measured_many` at one steady state ``(rho, c = -cos psi)``."""
    return float(measured_many(av, bb, np.array([rho], dtype=float), np.array([c], dtype=float))[0])


def measured_many(av: Averaged, bb: Backbone, rho: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The amplitude ``A`` of ``q`` on the steady states ``(rho, c = -cos psi)`` (n,): the backbone's ``A0(rho)`` with
    the averaging's first-order shift ``dA`` (:meth:`~stepnf.forced.averaged.Averaged.amplitude_shift`) as
    ``A0 / (1 - dA / A0)``: the same to first order, and exact for an undamped linear oscillator at every Omega
    (the forced amplitude ``k / |w^2 - Omega^2| = rho 2 w / (w + Omega)`` where ``dA / A0 = -(Omega - w) / (2 w)``),
    so that it stays positive far from the resonance, where ``A0 + dA`` would not. With damping a linear
    oscillator's curve is within ``0.35 xi^2`` (relative) of the exact one, its top ``0.125 xi^2`` above the exact
    peak (1.25e-5 at xi = 0.01, 0.5% at xi = 0.2), which ``peak`` reports (``A0(rho_peak)``, no shift)."""
    if len(rho) == 0:
        return np.zeros(0)
    A0 = bb.amplitudes(rho)
    return A0 / (1.0 - av.amplitude_shift_many(rho, c, *av.extremes_many(rho)) / A0)


def _steps(W: np.ndarray, rho: np.ndarray, w: float, rho_peak: float) -> np.ndarray:
    """Lengths of the chords of the curve in (Omega / (0.1 omega), rho / rho_peak)."""
    return np.hypot(np.diff(W) / (0.1 * w), np.diff(rho) / rho_peak)


def _length(t, W, rho, w, rho_peak) -> float:
    return float(np.sum(_steps(W, rho, w, rho_peak)))
