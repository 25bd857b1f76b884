"""``stepnf verify`` on the forced responses of masters on manifolds of several modes (issue 34, item 4 on issue 33).

The run's curves (:func:`stepnf.forced.manifold_frc.manifold_forced_responses`: the rotating-frame steady states
``z_l(t) = zeta_l e^{i r_l Omega t}``, ``r_l = k_l / k_j``, of the manifold's reduced dynamics under ``F cos(Omega
t)``, :mod:`stepnf.forced.manifold_system`) are checked as a single master's (:mod:`stepnf.verify.forced_verify`):

* **rebuilt**: the manifold from the run's arrays (:func:`stepnf.verify.manifold_chart.manifold_of`), the curves
  recomputed on it (reduced dynamics only: cheap) with the run's damping, levels and range; each level's peak must
  be the run's JSON peak to :data:`MATCH` relative in ``Omega`` and ``A``, else the level is one row with an
  ``error`` (the run's curve cannot be rebuilt: nothing to start from);
* **the points**: each level's **peak** (the full model's steady state at the ROM's peak ``Omega``, compared ``A``
  of the master; ``fixed = "Omega"``; when that Newton iteration fails and a fold of the same segment lies above,
  ``A`` fixed instead, as the single-mode check) and each **fold in range** (``A`` fixed, ``Omega`` unknown:
  :meth:`stepnf.verify.forced_orbits.ForcedShooting.orbit_at_amplitude`; compared ``Omega``). The point's ``zeta``
  is interpolated on the rebuilt curve's samples of its segment (:func:`point_zeta`: only the curve's public
  samples, whatever equations produced them); ``start_offset``: the start's own ``A`` against the point's, minus 1;
* **the start** at ``t = 0``: ``x0 = W(z)``, ``z = (zeta, conj zeta)``, and ``v0 = dW/dz . z'`` with the
  rotating-frame motion ``z_l' = i r_l Omega z_l`` (conjugates ``-i r_l Omega``): the time derivative of the ROM's
  own orbit ``x(t) = W(z(t))``, whose amplitude the curve reports. Not the manifold's velocity ``V(z)``: that is
  the conservative flow's, whose frequency is the backbone's at this amplitude, not the forcing's (off by the
  detuning, ``O(xi)`` at the peak and more on the flanks). Per monomial ``z^a``: ``d z^a / dt = i Omega z^a
  sum_l r_l (a_l - a_{m+l})``, exact, no division by ``z``;
* **the period**: :class:`~stepnf.verify.forced_orbits.ForcedShooting` (and the time integration's amplitudes per
  forcing period, :class:`stepnf.verify.forced_steady.ForcedIntegration`) take steady states of the forcing's
  period ``2 pi / Omega``. The orbit's period is ``2 pi k_j / Omega`` when a mode with a non-integer ``r_l`` moves
  (forcing the higher mode of a 1:2 pair: the partner's subharmonic on the coupled branch): such a point is a row
  with ``full`` None and the reason ``"not verified: subharmonic response ..."`` (a moving mode: ``|zeta_l|`` above
  :data:`AT_REST` of the largest). The uncoupled response there (partner at rest) is checked;
* **shooting** (small models) or **time integration** (larger: the peak only, from the same start, the folds
  listed as not followed, as for a single master).

Rows as :mod:`stepnf.verify.forced_verify`'s, plus ``segment`` and, in ``rom`` and (shooting) ``full``,
``amplitudes`` ``{mode: A}`` of every manifold mode (each partner's from one more accurate run over the converged
orbit: cheap).
"""
from __future__ import annotations

import time
from typing import Any, Callable

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar

from stepnf.dpim.multimode.measures import OrbitMeasure, orbit_measure
from stepnf.dpim.multimode.monomials import powers
from stepnf.errors import AdapterError, NumericalError, SceneError
from stepnf.forced.damping import Damping
from stepnf.forced.manifold_frc import manifold_forced_responses, modal_forces
from stepnf.verify.forced_orbits import ForcedShooting
from stepnf.verify.forced_steady import ForcedIntegration
from stepnf.verify.manifold_chart import manifold_of

#: The rebuilt curve's peak must equal the run's JSON peak to this (relative): the same arrays, the same code.
MATCH = 1e-8
#: A mode whose ``|zeta_l|`` is below this fraction of the largest is at rest (the uncoupled response's partner:
#: exactly 0 on the manifold, ~1e-16 after Newton).
AT_REST = 1e-8
#: Newton iterations of the peak's fixed-``Omega`` solve (as :data:`stepnf.verify.forced_verify.PEAK_NEWTON`).
PEAK_NEWTON = 8
SOLVE_ERRORS = (NumericalError, AdapterError, np.linalg.LinAlgError)


def start_state(man: Any, zeta: np.ndarray, r: np.ndarray, Omega: float) -> tuple[np.ndarray, np.ndarray]:
    """``(x0, v0)`` of the ROM's steady state at ``t = 0`` (module docstring): ``W(z)`` and ``dW/dz . z'``."""
    z = np.concatenate([zeta, np.conj(zeta)])
    keys = list(man.W)
    E = np.asarray(keys, dtype=int).reshape(len(keys), 2 * len(zeta))
    m = len(zeta)
    rate = 1j * Omega * ((E[:, :m] - E[:, m:]) @ np.asarray(r, dtype=float))  # d z^a / dt = rate_a z^a
    P = powers(z[None, :], keys)[0]
    Wm = np.asarray([man.W[a] for a in keys])
    return (P @ Wm).real, ((P * rate) @ Wm).real


def point_zeta(curve: Any, p: dict) -> np.ndarray:
    """``zeta`` (m,) of the curve's refined point ``p`` (a peak or fold): the curve's samples of ``p``'s segment
    interpolated by cubic splines in their chord length (in ``Omega`` and ``zeta`` scaled by their spans), at the
    parameter nearest ``p`` in ``(Omega, A)`` within the two steps around its nearest sample. Only the curve's
    public samples: the curves' equations may change (:mod:`stepnf.forced.manifold_system`) without this."""
    idx = np.flatnonzero(np.asarray(curve.segment) == int(p.get("segment", 0)))
    Om, A = np.asarray(curve.Omega, dtype=float)[idx], np.asarray(curve.amplitude, dtype=float)[idx]
    Z = np.asarray(curve.zeta)[idx]
    span = lambda v: max(float(np.ptp(v)), 1e-300)  # noqa: E731
    Y = np.column_stack([Om / span(Om), Z.real / span(np.abs(Z)), Z.imag / span(np.abs(Z))])
    keep = np.concatenate([[True], np.linalg.norm(np.diff(Y, axis=0), axis=1) > 1e-14])
    Om, A, Z, Y = Om[keep], A[keep], Z[keep], Y[keep]
    k = int(np.argmin(((Om - p["Omega"]) / span(Om)) ** 2 + ((A - p["amplitude"]) / span(A)) ** 2))
    if len(Om) < 2:
        return Z[k]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(Y, axis=0), axis=1))])
    spl = CubicSpline(s, np.column_stack([Om, A, Z.real, Z.imag]))
    dO, dA = 1e-6 * abs(float(p["Omega"])), 1e-6 * max(abs(float(p["amplitude"])), 1e-300)
    miss = lambda t: float(((spl(t)[0] - p["Omega"]) / dO) ** 2 + ((spl(t)[1] - p["amplitude"]) / dA) ** 2)  # noqa
    t = minimize_scalar(miss, bounds=(s[max(k - 1, 0)], s[min(k + 1, len(s) - 1)]), method="bounded",
                        options={"xatol": 1e-12 * s[-1]}).x
    y, m = spl(t), Z.shape[1]
    return y[2:2 + m] + 1j * y[2 + m:]


def subharmonic(zeta: np.ndarray, r: np.ndarray) -> bool:
    """Whether a mode with a non-integer ``r_l`` moves (the orbit's period is then a multiple of the forcing's)."""
    a = np.abs(zeta)
    moving = a > AT_REST * max(float(a.max()), 1e-300)
    return bool(np.any(moving & (np.abs(r - np.round(r)) > 1e-12)))


def _multiple(r: np.ndarray) -> int:
    """The smallest ``p`` with every ``p r_l`` an integer (the orbit's period in forcing periods)."""
    return next(p for p in range(1, 1000) if np.allclose(p * r, np.round(p * r), rtol=0, atol=1e-9))


def rebuild(result: Any, rec: Any, model: Any, damping: Damping, values: list, frequency_range: Any,
            j: int) -> tuple[Any, list, int]:
    """``(manifold, curves, mode)``: master ``rec``'s manifold from the run's arrays and its curves recomputed."""
    block = rec.backbone or {}
    man = manifold_of(result.arrays, int(block["manifold"].get("stored_with", rec.index)), model.M)
    mode = list(man.masters).index(int(rec.index))
    curves = manifold_forced_responses(man, damping, values, frequency_range, mode,
                                       valid_to=block.get("valid_up_to"), master=j)
    return man, curves, mode


def _match(stored: dict, got: dict) -> str | None:
    for key in ("Omega", "amplitude"):
        a, b = float(stored[key]), float(got[key])
        if not abs(a - b) <= MATCH * max(abs(a), 1e-300):
            return (f"the peak's {key} recomputed on the manifold read back, {b:.12g}, is not the run's {a:.12g} "
                    f"(to {MATCH:g} relative)")
    return None


def manifold_forced_rows(result: Any, rec: Any, j: int, model: Any, damping: Damping, values: list,
                         frequency_range: Any, C: Any, forces: Callable, batch_forces: Callable,
                         tangent: Callable | None, *, shooting: bool, clock: Any, who: str,
                         steps: int = 128, periods: int = 60) -> list[dict]:
    """The rows of every level of master ``rec`` (scene index ``j``) on its manifold (module docstring). ``forces``
    one field's internal force (shooting), ``batch_forces`` the batched one (time integration); ``C`` the damping
    matrix; ``clock`` an :class:`~stepnf.verify.clock.OrbitClock` (one tick per full-model solve)."""
    try:
        man, curves, mode = rebuild(result, rec, model, damping, values, frequency_range, j)
    except (NumericalError, SceneError, KeyError) as exc:
        return [{"level": lv, "what": "peak", "fixed": None, "full": None, "method": "rebuild",
                 "rom": {k: float(c["peak"][k]) for k in ("Omega", "amplitude")},
                 "error": f"{who}: the curves could not be rebuilt: {' '.join(str(exc).split())}"}
                for (lv, _), c in zip(values, rec.frc)]
    k = np.asarray(man.ratios if man.ratios is not None else np.eye(len(man.masters))[mode], dtype=int)
    r = k / float(k[mode])
    phi = np.asarray(man.phi, dtype=float).reshape(-1, len(man.masters))
    measure = orbit_measure(man, k)
    rows: list[dict] = []
    for (level, value), stored, curve in zip(values, rec.frc, curves):
        why = _match(stored["peak"], curve.peak)
        if why is not None:
            rows.append({"level": level, "what": "peak", "fixed": None, "full": None, "method": "rebuild",
                         "rom": {k_: float(stored["peak"][k_]) for k_ in ("Omega", "amplitude")},
                         "error": f"{who}: {why}"})
            continue
        F = modal_forces(man, phi, value, level, k, mode)[1]  # turned as the curves turned it
        points = [("peak", curve.peak)] + [("fold", f) for f in sorted(curve.folds, key=lambda f: f["Omega"])
                                           if f.get("in_range", True)]
        for what, p in points:
            rows.append(_one(what, p, level, curve, measure, man, r, phi, mode, F, C, forces, batch_forces,
                             tangent, model, shooting=shooting, clock=clock, who=who, steps=steps, periods=periods))
    return rows


def count_solves(rec: Any, shooting: bool) -> int:
    """The full-model solves :func:`manifold_forced_rows` will make at most (for the clock)."""
    return sum(1 + (sum(1 for f in c.get("folds", []) if f.get("in_range", True)) if shooting else 0)
               for c in rec.frc)


def _one(what: str, p: dict, level: dict, curve: Any, measure: OrbitMeasure, man: Any,
         r: np.ndarray, phi: np.ndarray, mode: int, F: np.ndarray, C: Any, forces: Callable, batch_forces: Callable,
         tangent: Callable | None, model: Any, *, shooting: bool, clock: Any, who: str, steps: int,
         periods: int) -> dict:
    """One point's row (module docstring)."""
    Om = float(p["Omega"])
    masters = [str(q) for q in man.masters]
    rom = {"Omega": Om, "amplitude": float(p["amplitude"]), "stable": bool(p["stable"]) if what == "peak" else None,
           "amplitudes": dict(p.get("amplitudes") or {})}
    method = "shooting" if shooting else "integration"
    fixed = "Omega" if what == "peak" else "amplitude"
    base = {"level": level, "what": what, "segment": int(p.get("segment", 0)), "fixed": fixed, "rom": rom,
            "method": method}
    zeta = point_zeta(curve, p)
    # how far the interpolated start's own A is from the point's (the spline's error; ~1e-6 and below measured)
    base["start_offset"] = float(measure.amplitudes(zeta)[mode]) / rom["amplitude"] - 1
    if subharmonic(zeta, r):
        return {**base, "fixed": None, "full": None,
                "reason": f"not verified: subharmonic response (period 2 pi x {_multiple(r)} / Omega; "
                          "the full model's check takes the forcing's period)"}
    if not shooting and what == "fold":
        return {**base, "fixed": None, "full": None, "reason": "not followed by time integration"}
    tag = f"{who}, {what} at Omega = {Om:.6g}"
    clock.start(f"{tag} ({fixed} fixed)")
    t0 = time.perf_counter()
    try:
        x0, v0 = start_state(man, zeta, r, Om)
        if shooting:
            sh = ForcedShooting(model.M, C, forces, F, tangent=tangent, phi=phi[:, mode])
            y0 = np.concatenate([x0, v0])
            if what == "peak":
                try:
                    orb = sh.orbit(Om, y0, maxiter=PEAK_NEWTON)
                except NumericalError:  # no steady state on the ROM's branch there: A fixed (module docstring)
                    if not any(f["Omega"] > Om and f.get("segment", 0) == base["segment"] for f in curve.folds):
                        raise
                    fixed = "amplitude"
                    orb = sh.orbit_at_amplitude(rom["amplitude"], Om, y0)
            else:
                orb = sh.orbit_at_amplitude(rom["amplitude"], Om, y0)
            amps = {}
            for i, q in enumerate(masters):  # every manifold mode's A on the converged orbit: one accurate run each
                other = sh if i == mode else ForcedShooting(model.M, C, forces, F, phi=phi[:, i])
                amps[q] = float(other.amplitude(other.run(orb.y0, orb.Omega, dense=True))[0])
            full = {"Omega": float(orb.Omega), "amplitude": float(orb.amplitude), "stable": bool(orb.stable),
                    "amplitudes": amps}
            extra = {"newton_iterations": int(orb.iterations)}
        else:
            Mphi = np.asarray(model.M @ phi[:, mode]).ravel()
            run = ForcedIntegration(model.M, C, model.K, batch_forces, F).run(x0, v0, Om, Mphi, periods=periods,
                                                                              steps=steps)
            full = {"Omega": Om, "amplitude": float(run.amplitude), "stable": None}
            extra = {"spread": float(run.spread / run.amplitude)}
        return {**base, "fixed": fixed, "full": full, "dA": rom["amplitude"] / full["amplitude"] - 1,
                "dOmega": Om / full["Omega"] - 1, "seconds": round(time.perf_counter() - t0, 3), **extra}
    except SOLVE_ERRORS as exc:
        return {**base, "full": None, "error": f"{tag}: {' '.join(str(exc).split())}"}
    finally:
        clock.stop()
