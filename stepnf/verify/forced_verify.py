"""``stepnf verify`` on a scene with ``[analysis.forcing]`` (issue 34, item 4): each forcing level's ROM peak and
folds beside the full model's periodic steady states, after the backbone checks.

For every master whose run computed frequency-response curves (:mod:`stepnf.pipeline.forced`; the masters without
get their ``frc_reason``), each level's force ``F`` as the run built it (:func:`stepnf.pipeline.forced.levels` and
:func:`stepnf.forced.frc.force_vector`) and the damping ``C`` from the same :class:`stepnf.forced.damping.Damping`
(the run's masters ``phi_masters``, ``omega``), the full model ``M x'' + C x' + f(x) = F cos(Omega t)``:

* **shooting** (models up to the backbone checks' shooting size, :data:`stepnf.verify.command.SHOOTING_LIMIT`):
  at the ROM's **peak**, the steady state at the ROM's peak ``Omega`` (fixed; compared: ``A``;
  :meth:`stepnf.verify.forced_orbits.ForcedShooting.orbit`); at each **fold**, the steady state whose amplitude is the
  ROM's fold ``A`` with ``Omega`` unknown (well posed at a fold, where ``Omega`` is extremal in ``A``: its
  ``Omega`` is the full model's fold frequency to second order in the ``A`` difference; compared: ``Omega``;
  :meth:`~stepnf.verify.forced_orbits.ForcedShooting.orbit_at_amplitude`). A peak just below a jump (a fold above it)
  whose ``Omega`` lies beyond the full model's fold has no steady state on its branch there (measured: the 2-dof
  system's ROM peak 2.7e-4 above the full one, 1.6e-4 below its own fold): then ``A`` is fixed instead (the
  orbit's ``Omega`` between the full model's peak and fold; ``fixed = "amplitude"``). Both Newton iterations
  start from the ROM's state ``x(theta = psi, rho)`` at ``t = 0`` (``psi = theta - Omega t`` the averaged phase: ``-pi/2`` at the
  peak, ``sin psi = -2 D / (Omega_d f1)`` on the fold's branch, :class:`stepnf.forced.averaged.Averaged`), the
  velocity scaled to ``Omega``. Models up to :data:`CONTINUATION_LIMIT` dofs also get the full model's own FRC by
  continuation over the scene's range (:func:`stepnf.verify.forced_check.forced_rows`): its refined peak and folds
  beside the ROM's (``method = "continuation"``).
* **time integration** (larger models; :func:`stepnf.verify.forced_check.forced_rows` with ``"integration"``): the
  steady state at the ROM's peak ``Omega`` from the ROM's state, :func:`integration_periods` periods of
  :data:`STEPS` steps, Aitken's extrapolation (``spread``: how settled); folds are listed as not checked (the
  branch between them is unstable, time integration cannot reach it).

Masters on manifolds of several modes: the same rows from the curves rebuilt on the manifold read back
(:mod:`stepnf.verify.manifold_forced`).

Each row (the ``forced`` list of the master's entry in verify's JSON): ``level`` (``{"kappa": k}`` or the load's),
``what`` (``"peak"`` or ``"fold"``), ``fixed`` (``"Omega"`` or ``"amplitude"``, the quantity imposed on the
full model; None for continuation), ``rom`` and ``full`` (``{"Omega", "amplitude", "stable"}``, Omega in rad per
model time unit; ``full`` None with a ``reason`` or an ``error``), ``dA = A_rom / A_full - 1``,
``dOmega = Omega_rom / Omega_full - 1``, ``method``; ``seconds``. A solve that fails is a row with its ``error``
(counted by :func:`forced_failures`: exit 3 as a failed orbit), never a traceback.
"""
from __future__ import annotations

import math
import time
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp

from stepnf.errors import AdapterError, NumericalError
from stepnf.forced.averaged import Averaged
from stepnf.forced.damping import Damping
from stepnf.forced.frc import force_vector
from stepnf.pipeline.forced import forcing_check_stage, levels
from stepnf.verify.clock import OrbitClock
from stepnf.verify.forced_check import forced_rows
from stepnf.verify.forced_orbits import ForcedShooting
from stepnf.verify.manifold_forced import count_solves, manifold_forced_rows

#: Models up to this many dofs also get the full model's own FRC by continuation: 0, none by default (not cheap:
#: 323 s for one level of the 2-dof system of tests/verify/test_forced_verify.py over [0.8, 1.3] w, measured).
CONTINUATION_LIMIT = 0
#: Time integration: steps per forcing period (the scheme's amplitude error 2.5e-4 at the Duffing's peak,
#: docs/forced.md) and the bounds of the number of periods (:func:`integration_periods`).
STEPS = 128
PERIODS = (30, 300)
#: Largest model whose modal damping (a dense ``C``) the time integration takes: beyond, use Rayleigh damping.
DENSE_LIMIT = 2000
#: Newton iterations of the peak's fixed-``Omega`` solve from the ROM's state (4 measured, tests/verify/
#: test_forced_verify.py; twice that: no steady state on that branch, module docstring).
PEAK_NEWTON = 8
#: The errors of one full-model solve that make it a row with an ``error`` (the others still run).
SOLVE_ERRORS = (NumericalError, AdapterError, np.linalg.LinAlgError)


def integration_periods(xi: float) -> int:
    """Periods of the time integration for damping ratio ``xi``: the transient decays as ``exp(-2 pi xi k)``
    after ``k`` periods; ``0.6 / xi`` periods (60 at ``xi = 0.01``: 3.6e-5 from shooting with a spread of 1.5e-6
    on the Duffing, docs/forced.md) within :data:`PERIODS`."""
    return int(min(max(math.ceil(0.6 / xi), PERIODS[0]), PERIODS[1]))


def run_damping(scene: Any, model: Any, result: Any) -> Damping:
    """The damping operator as the run's ``forced`` stage builds it (:func:`stepnf.pipeline.forced.forced_stage`:
    the scene's spec, the model's M and K, the masters ``(phi, omega)`` in the scene's order), from the run's
    arrays ``phi_masters``, ``omega`` and ``master_modes``."""
    arr = result.arrays
    masters = [int(q) for q in np.asarray(arr["master_modes"])]
    phi, omega = np.asarray(arr["phi_masters"]), np.asarray(arr["omega"])
    return Damping(scene.damping, model.M, model.K, [(phi[:, j], float(omega[q])) for j, q in enumerate(masters)])


def damping_matrix(damping: Damping, n: int, *, dense: bool):
    """``C`` as a matrix: dense ``C(I)`` (the operator on the identity's rows, ``C`` symmetric) when ``dense`` or
    the damping is modal (up to :data:`DENSE_LIMIT` dofs); Rayleigh's ``alpha M + beta K`` kept sparse otherwise."""
    if dense or damping.spec.rayleigh is None:
        if n > DENSE_LIMIT:
            raise NumericalError(f"modal damping of a model of {n} dofs: C = sum 2 xi w M phi phi^T M is dense, "
                                 f"beyond the time integration's sparse solves (up to {DENSE_LIMIT} dofs); "
                                 "[analysis.damping] rayleigh = [alpha, beta] is checked at any size")
        return damping(np.eye(n))
    alpha, beta = (float(v) for v in damping.spec.rayleigh)
    return sp.csc_matrix(alpha * damping.M + beta * damping.K)


def rom_state(res: Any, psi: float, rho: float, Omega: float) -> tuple[np.ndarray, np.ndarray]:
    """The ROM's state at ``t = 0`` on the steady state ``theta = Omega t + psi`` of amplitude ``rho``: ``x(psi,
    rho)`` and the parametrisation's velocity rescaled from the backbone's frequency to ``Omega``."""
    om = res.omega + sum(ck * rho ** (2 * k) for k, ck in enumerate(res.c, start=1))
    return res.displacement(psi, rho), res.velocity(psi, rho) * (Omega / om)


def fold_phase(av: Averaged, rho: float, Omega: float) -> float:
    """The averaged phase ``psi`` of the ROM's steady state of amplitude ``rho`` on the branch through ``Omega``
    (``c = -cos psi`` of the sign whose ``Omega`` is nearest)."""
    s, cabs = float(av.sin_psi(rho)), float(av.cos_abs(rho))
    c = min((cabs, -cabs), key=lambda c: abs(float(av.omega_of(rho, c)) - Omega))
    return float(np.arctan2(s, -c))


def rom_stable(curve: dict, point: dict) -> bool | None:
    """The ROM's stability at ``point`` (the curve's sample nearest in ``(Omega, A)``, each scaled by its span)."""
    Om, A, st = (np.asarray(curve.get(k, []), dtype=float) for k in ("Omega", "amplitude", "stable"))
    if not len(Om):
        return None
    span = lambda v: max(float(np.ptp(v)), 1e-300)  # noqa: E731
    i = int(np.argmin(((Om - point["Omega"]) / span(Om)) ** 2 + ((A - point["amplitude"]) / span(A)) ** 2))
    return bool(st[i])


def _row(level: dict, what: str, fixed: str | None, rom: dict, full: Any, method: str, seconds: float) -> dict:
    """A row from the ROM's point and the full model's :class:`~stepnf.verify.forced_orbits.ForcedOrbit`."""
    out = {"level": level, "what": what, "fixed": fixed, "rom": rom, "method": method, "seconds": round(seconds, 3),
           "newton_iterations": int(full.iterations),
           "full": {"Omega": float(full.Omega), "amplitude": float(full.amplitude), "stable": bool(full.stable)}}
    out["dA"] = rom["amplitude"] / full.amplitude - 1
    out["dOmega"] = rom["Omega"] / full.Omega - 1
    return out


def shooting_rows(res: Any, curve: dict, level: dict, F: np.ndarray, av: Averaged, M, C, adapter: Any,
                  tangent: Callable | None, clock: OrbitClock, who: str) -> list[dict]:
    """The peak (fixed ``Omega``) and folds (fixed ``A``) of one level by shooting (module docstring)."""
    rows = []
    points = [("peak", curve["peak"])] + [("fold", f) for f in sorted(curve.get("folds", []), key=lambda f: f["Omega"])]
    for what, p in points:
        rom = {"Omega": float(p["Omega"]), "amplitude": float(p["amplitude"]),
               "stable": None if what == "fold" else rom_stable(curve, p)}  # (a fold: marginal)
        rho, Om = float(p["rho"]), float(p["Omega"])
        fixed = "Omega" if what == "peak" else "amplitude"
        clock.start(f"{who}, {what} at Omega = {Om:.6g} ({fixed} fixed)")
        t0 = time.perf_counter()
        try:
            x0, v0 = rom_state(res, -np.pi / 2 if what == "peak" else fold_phase(av, rho, Om), rho, Om)
            sh = ForcedShooting(M, C, adapter.internal_force, F, tangent=tangent, phi=res.phi)
            y0 = np.concatenate([x0, v0])
            if what == "peak":
                try:
                    orb = sh.orbit(Om, y0, maxiter=PEAK_NEWTON)
                except NumericalError:  # no steady state on the ROM's branch there: A fixed (module docstring)
                    if not any(f["Omega"] > Om for f in curve.get("folds", [])):
                        raise
                    fixed = "amplitude"
                    orb = sh.orbit_at_amplitude(rom["amplitude"], Om, y0)
            else:
                orb = sh.orbit_at_amplitude(rom["amplitude"], Om, y0)
            rows.append(_row(level, what, fixed, rom, orb, "shooting", time.perf_counter() - t0))
        except SOLVE_ERRORS as exc:
            rows.append({"level": level, "what": what, "fixed": fixed, "rom": rom, "full": None, "method": "shooting",
                         "error": f"{who}, {what}: {' '.join(str(exc).split())}"})
        finally:
            clock.stop()
    return rows


def adapted(rows: list[dict], level: dict, curve: dict) -> list[dict]:
    """:func:`stepnf.verify.forced_check.forced_rows`'s rows with the level, what was fixed and the stabilities."""
    out = []
    for r in rows:
        r = {"level": level, "fixed": "Omega" if r["method"] == "integration" and r["what"] == "peak" else None, **r}
        if r.get("rom") is not None:
            r["rom"]["stable"] = rom_stable(curve, r["rom"]) if r["what"] == "peak" else None
        if r.get("full") is not None:
            r["full"].setdefault("stable", None)
        out.append(r)
    return out


def forced_checks(doc: dict, result: Any, model: Any, adapter: Any, say: Callable[[str], None], *, scene: Any,
                  shooting: bool) -> dict:
    """``doc`` (:func:`stepnf.verify.command.verify_scene`'s) with a ``forced`` list (module docstring) in the entry
    of every single-mode master whose run has forced responses (a master on a manifold of several modes: the rows of
    :func:`stepnf.verify.manifold_forced.manifold_forced_rows`), ``forced_reason`` in those the run gave none;
    ``doc`` unchanged without ``[analysis.forcing]``. ``shooting``: the backbone checks' choice (by the model's
    size and tangent)."""
    forcing = getattr(scene, "forcing", None)
    if forcing is None:
        return doc
    entries = {int(m["index"]): m for m in doc["modes"] if "manifold" not in m}
    on_manifolds = {int(m["index"]): m for m in doc["modes"] if "manifold" in m}
    backbones = getattr(result, "backbones", None) or {}
    plan, on_plan = [], []
    for j, rec in enumerate(result.modes):
        entry = entries.get(int(rec.index))
        if int(rec.index) in on_manifolds and rec.frc:  # stepnf.verify.manifold_forced
            on_plan.append((j, rec, on_manifolds[int(rec.index)]))
            continue
        if entry is None or rec.frc is None:
            continue
        if not rec.frc or int(rec.index) not in backbones:
            entry["forced_reason"] = rec.frc_reason or "no forced response"
            continue
        plan.append((j, rec, entry))
    if not plan and not on_plan:
        return doc
    n = model.K.shape[0]
    damping = run_damping(scene, model, result)
    values = levels(SimpleNamespace(scene=scene), model, forcing_check_stage(SimpleNamespace(scene=scene), model))
    model_tangent = adapter.tangent_stiffness if adapter.provides_tangent_stiffness else None
    tangent = (lambda u: model_tangent(u).toarray()) if (model_tangent is not None and shooting) else None
    cont = shooting and n <= CONTINUATION_LIMIT
    clock = OrbitClock(sum(1 + cont + (len(c.get("folds", [])) if shooting else 0) for _, r, _ in plan
                           for c in r.frc) + sum(count_solves(r, shooting) for _, r, _ in on_plan),
                       say)  # solves a level: the peak, the folds, the continuation
    try:
        C = damping_matrix(damping, n, dense=shooting)
    except NumericalError as exc:
        C, why = None, str(exc)
    for j, rec, entry in plan:
        res = backbones[int(rec.index)]
        who = f"master mode {rec.index}, forced"
        rows = entry.setdefault("forced", [])
        for (level, value), curve in zip(values, rec.frc):
            F = force_vector(res, value, level)[0]
            tag = f"{who} {_level_text(level)}"
            if C is None:
                rows.append({"level": level, "what": "peak", "fixed": None, "full": None, "method": "integration",
                             "rom": {k: float(curve["peak"][k]) for k in ("Omega", "amplitude")},
                             "error": f"{tag}: {why}"})
                continue
            if shooting:
                av = Averaged(res, damping, damping.ratio(j), F)
                rows += shooting_rows(res, curve, level, F, av, model.M, C, adapter, tangent, clock, tag)
            if cont or not shooting:
                method = "continuation" if shooting else "integration"
                clock.start(f"{tag}, {method}")
                t0 = time.perf_counter()
                try:
                    got = forced_rows(res, curve, F, model.M, C, model.K, adapter.internal_forces, method=method,
                                      frequency_range=forcing.frequency_range, tangent=tangent, steps=STEPS,
                                      periods=integration_periods(damping.ratio(j)))
                    rows += [{**r, "seconds": round(time.perf_counter() - t0, 3)} for r in adapted(got, level, curve)]
                except SOLVE_ERRORS as exc:
                    rows.append({"level": level, "what": "peak", "fixed": None, "full": None, "method": method,
                                 "rom": {k: float(curve["peak"][k]) for k in ("Omega", "amplitude")},
                                 "error": f"{tag}, {method}: {' '.join(str(exc).split())}"})
                finally:
                    clock.stop()
    for j, rec, entry in on_plan:  # masters on manifolds of several modes (stepnf.verify.manifold_forced)
        who = f"master mode {rec.index}, forced"
        if C is None:
            entry["forced"] = [{"level": level, "what": "peak", "fixed": None, "full": None, "method": "integration",
                                "rom": {k: float(c["peak"][k]) for k in ("Omega", "amplitude")},
                                "error": f"{who} {_level_text(level)}: {why}"}
                               for (level, _), c in zip(values, rec.frc)]
            continue
        entry["forced"] = manifold_forced_rows(result, rec, j, model, damping, values, forcing.frequency_range, C,
                                               adapter.internal_force, adapter.internal_forces, tangent,
                                               shooting=shooting, clock=clock, who=who, steps=STEPS,
                                               periods=integration_periods(damping.ratio(j)))
    clock.finish()
    return doc


def _level_text(level: dict) -> str:
    return f"kappa = {level['kappa']:g}" if "kappa" in level else f"load = {level['load']:g}"


def forced_failures(doc: dict) -> int:
    """How many full-model forced solves of ``doc`` failed (rows with an ``error``)."""
    return sum(1 for m in doc["modes"] for r in m.get("forced", []) if r.get("error"))


def forced_lines(doc: dict) -> list[str]:
    """The text of the forced checks in ``stepnf verify``'s report: one table per master, a row per level's peak
    and fold (frequencies as ratios to the master's ``w``)."""
    lines = []
    for m in doc["modes"]:
        if m.get("forced_reason"):
            lines.append(f"\nmaster mode {m['index']}: no forced response to check ({m['forced_reason']})")
        if not m.get("forced"):
            continue
        w = float(m["omega"])
        lines.append(f"\nmaster mode {m['index']}: forced responses, the ROM's FRC against the full model's steady "
                     "states (* the quantity imposed on the full model)")
        lines.append(f"  {'level':>14s} {'what':>5s} {'ROM W/w':>12s} {'ROM A':>12s} {'full W/w':>12s} "
                     f"{'full A':>12s} {'dOmega':>9s} {'dA':>9s} {'stable':>6s}  method")
        for r in m["forced"]:
            rom, full = r.get("rom"), r.get("full")
            mark = lambda k: "*" if r.get("fixed") == k else " "  # noqa: E731
            left = (f"  {_level_text(r['level']):>14s} {r['what']:>5s} "
                    + (f"{rom['Omega'] / w:12.8f} {rom['amplitude']:12.6g}" if rom else f"{'-':>12s} {'-':>12s}"))
            if full is None:
                lines.append(f"{left}  {r['method']}: {r.get('error') or r.get('reason')}")
                continue
            st = "-" if full.get("stable") is None else ("yes" if full["stable"] else "no")
            extra = f", spread {r['spread']:.1e}" if r.get("spread") is not None else ""
            dA = f"{r['dA']:9.1e}" if "dA" in r else f"{'-':>9s}"
            dO = f"{r['dOmega']:9.1e}" if "dOmega" in r else f"{'-':>9s}"
            lines.append(f"{left} {full['Omega'] / w:11.8f}{mark('Omega')} {full['amplitude']:11.6g}{mark('amplitude')}"
                         f" {dO} {dA} {st:>6s}  {r['method']}{extra}")
            others = [(q, a, (full.get("amplitudes") or {}).get(q)) for q, a in (rom.get("amplitudes") or {}).items()
                      if q != str(m["index"])]  # a manifold's partners (stepnf.verify.manifold_forced)
            if others:
                lines.append(" " * 22 + "; ".join(f"mode {q}: ROM A {a:.6g}, full A "
                                                  + ("-" if b is None else f"{b:.6g}") for q, a, b in others))
    if any(m.get("forced") for m in doc["modes"]):
        lines.append("\nforced: A of q = phi^T M x ((max - min) / 2 over a period); W the forcing's frequency; "
                     "dOmega, dA: ROM / full - 1; stable: the full model's steady state (Floquet; time integration: -)")
    return lines
