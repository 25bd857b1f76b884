"""``stepnf verify`` on masters of manifolds of several modes (issue 33): the full model's orbits, branch by branch.

A master on a manifold (``[analysis.backbone] manifolds``) has branches, periodic orbits of the manifold's reduced
dynamics ``z_l(t) = zeta_l e^{i k_l Omega t}`` (:mod:`stepnf.dpim.multimode.branches`): the one that continues its
linear mode and the coupled ones born at the resonance. Each is checked like a single-mode backbone
(:mod:`stepnf.verify.command`), at the amplitudes ``A`` of the master's modal coordinate ``q_j = phi_j^T M x``:
the scene's or ``--amplitudes`` within the branch's validity limit, else ``fractions`` of that limit (of the end
of the traced branch when the limit is not reached), the top capped at ``W_max/h = 2`` with a thickness
(:data:`stepnf.verify.deflection.DEFAULT_DEFLECTION`; ``W_max`` here over the reduced orbit's whole period).

The orbit's start: the branch's point at ``A`` (:func:`stepnf.dpim.multimode.backbone.point_at`), moved along the
reduced orbit to a phase ``psi = Omega t`` where every ``zeta_l e^{i k_l psi}`` is real (then ``V(z) = 0``: the
parametrisation's velocities are imaginary, the system reversible), found on a grid and refined by Brent's method,
of the two such phases a period holds the one where ``q_j`` is the larger (``q_j > 0``, as single-mode checks);
from there ``x0 = W(z)`` starts the brake-orbit shooting of :class:`stepnf.verify.periodic.Shooting` (the
same as the single-mode checks: explicit, or implicit for a stiff model). Where no such phase exists (the
rotated ``zeta`` keeps an imaginary part above :data:`BRAKE` of its size: the elliptic orbits of a 1:1 pair), the
start is the phase where ``q_j`` is largest and the shooting's unknowns are the whole state and the period
(:class:`stepnf.verify.free_shooting.FreeShooting`). The period guess is ``2 pi / (g Omega)``, ``g`` the gcd of
the ``k_l`` of the masters that move (the upper mode's own branch of a 1:2 pair moves at ``2 Omega`` alone).

Compared: master j's frequency ``k_j Omega`` of the branch at the orbit's measured amplitude
(:func:`~stepnf.dpim.multimode.backbone.omega_at`) against the orbit's ``k_j 2 pi / (g T)``, and the largest
distance of the orbit's states (:data:`SAMPLES` a period) from the manifold
(:class:`stepnf.verify.manifold_chart.ManifoldChart`: same masters' coordinates and rates, energy norm, relative).
The manifold and its branches are read back from the run's arrays (:mod:`stepnf.verify.manifold_chart`).
Models beyond shooting's size: time integration from the same start (:mod:`stepnf.verify.manifold_integration`).
"""
from __future__ import annotations

import math
import time
from typing import Any, Callable, Sequence

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from stepnf.dpim.multimode.backbone import omega_at, point_at
from stepnf.errors import AdapterError, NumericalError
from stepnf.plugin.dofs import peak, translation_mask
from stepnf.verify.clock import OrbitClock
from stepnf.verify.deflection import DEFAULT_DEFLECTION
from stepnf.verify.free_shooting import FreeShooting
from stepnf.verify.manifold_chart import ManifoldChart, branches_of, manifold_of
from stepnf.verify.manifold_integration import integrate_orbit
from stepnf.verify.periodic import IMPLICIT_STEPS, Shooting, highest_frequency, shooting_method
from stepnf.verify.unverified import with_unverified

#: States per period at which the orbit's distance from the manifold is measured.
SAMPLES = 32
#: A rotated branch point whose ``zeta`` keeps ``max |Im zeta_l| > BRAKE max |zeta_l|`` has no state at rest: the
#: shooting on the whole state. The branches' points are real to ~1e-15 where they are (the phase condition's
#: Newton tolerance, 1e-13, bounds it): 1e-8 leaves every such branch a brake orbit.
BRAKE = 1e-8


def phase_grid(order: int, k: np.ndarray, g: int) -> np.ndarray:
    """Phases ``psi`` over one period ``[0, 2 pi / g)``: 64 N max(k) points, as the branches' measures."""
    return np.linspace(0.0, 2 * np.pi / g, 64 * int(order) * max(int(np.abs(k).max()), 1), endpoint=False)


def start_point(man: Any, chart: ManifoldChart, branch: Any, u: np.ndarray) -> dict:
    """The orbit's start on the reduced orbit through the branch point ``u`` (module docstring): ``zeta`` (m,),
    ``x0``, ``v0`` (n,), ``brake`` (bool), ``period`` (the guess) and ``g``."""
    m, j = len(branch.masters), branch.mode
    zeta, Om = u[:m] + 1j * u[m:2 * m], float(u[2 * m])
    k = np.asarray(branch.ratios, dtype=int)
    size = float(np.abs(zeta).max())
    moving = np.abs(zeta) > 1e-12 * size
    g = math.gcd(*[int(t) for t in k[moving]]) or 1
    grid = phase_grid(man.order, k, g)
    rot = lambda psi: zeta * np.exp(1j * k * psi)  # noqa: E731
    imag = lambda psi: float(np.sum(rot(psi).imag ** 2))  # noqa: E731
    step = grid[1] - grid[0]
    i = int(np.argmin([imag(p) for p in grid]))
    psi = float(minimize_scalar(imag, bounds=(grid[i] - step, grid[i] + step), method="bounded",
                                options={"xatol": 1e-15}).x)
    brake = np.sqrt(imag(psi)) <= BRAKE * size
    if brake:  # at rest twice a period, at psi and psi + pi / g (k_l / g integers): where q_j is the larger, as the
        # single-mode checks start at q > 0 (not the grid's pick: a secant step the wrong way, a platform's rounding)
        zs = [rot(p).real.astype(complex) for p in (psi, psi + np.pi / g)]  # real: V(z) = 0 exactly there
        z = max(zs, key=lambda c: float(chart.coordinates(c)[j]))
    else:  # no state at rest: start where q_j is largest (q_j' = 0, the free shooting's phase condition)
        qj = lambda p: -float(chart.coordinates(rot(p))[j])  # noqa: E731
        i = int(np.argmin([qj(p) for p in grid]))
        psi = float(minimize_scalar(qj, bounds=(grid[i] - step, grid[i] + step), method="bounded",
                                    options={"xatol": 1e-15}).x)
        z = rot(psi)
    full = np.concatenate([z, np.conj(z)])
    return {"zeta": z, "x0": man.displacement(full), "v0": man.velocity(full), "brake": bool(brake),
            "period": 2 * np.pi / (g * Om), "g": g, "Omega": Om}


def orbit_peak(man: Any, branch: Any, A: float, mask: np.ndarray | None) -> float:
    """``W_max``: the largest ``|x_i|`` (dofs of ``mask``) over the reduced orbit of ``branch`` at amplitude A."""
    m = len(branch.masters)
    u = point_at(man, branch, A)
    zeta, k = u[:m] + 1j * u[m:2 * m], np.asarray(branch.ratios)
    Z = zeta[None, :] * np.exp(1j * np.outer(np.linspace(0, 2 * np.pi, 64, endpoint=False), k))
    X = man.displacement(np.concatenate([Z, np.conj(Z)], axis=1))
    return max(peak(x, mask) for x in X)


def branch_amplitudes(man: Any, branch: Any, block: dict, listed: Sequence[float] | None, listed_from: str,
                      fractions: Sequence[float], h: float | None, mask: np.ndarray | None) -> tuple[list[float], str]:
    """The amplitudes of ``branch`` checked and where they come from (module docstring)."""
    master_limit, own = block.get("valid_up_to"), block.get("branch") or {}
    mine = own.get("valid_up_to") == master_limit and own.get("valid_reason") == block.get("valid_reason")
    # 0 for the whole master (forces inaccurate, a twin), not its continuing branch's own limit: no branch is checked
    if master_limit is not None and master_limit <= 0 and not mine \
            and block.get("valid_reason") != "no continuing branch":
        return [], f"none: the master's backbone has no validity range ({block['valid_reason']})"
    limit, why = branch.valid_A, branch.valid_reason
    if limit is not None and limit <= 0:
        return [], f"none: the branch has no validity range ({why}): no amplitude of it is trustworthy"
    top_traced = float(np.max(branch.A[:, branch.mode]))
    if listed:
        cap = top_traced if limit is None else min(limit, top_traced)
        kept = [float(a) for a in listed if a <= cap * (1 + 1e-9)]
        left = len(listed) - len(kept)
        src = listed_from + (f" ({left} beyond the branch's validity limit or traced end left out)" if left else "")
        if kept or listed_from == "--amplitudes":
            return kept, src if kept else f"none: {src}"
    top = top_traced if limit is None else float(limit)
    src = (f"validity limit A = {top:.6g} ({why}, tol {block.get('tolerance', 1e-3):g})" if limit is not None
           else f"the end of the traced branch, A = {top:.6g} (validity limit not reached)")
    amps = [top * f for f in fractions]
    if h is None or not h > 0:
        return amps, src
    far = orbit_peak(man, branch, top, mask) / h
    if far <= DEFAULT_DEFLECTION:
        return amps, src
    lo = float(branch.A[0, branch.mode])  # the traced start (W_max/h grows like A from 0 there)
    A = lo if orbit_peak(man, branch, lo, mask) / h >= DEFAULT_DEFLECTION else brentq(
        lambda a: orbit_peak(man, branch, a, mask) / h - DEFAULT_DEFLECTION, lo, top, xtol=1e-10 * top)
    return ([a * A / top for a in amps],
            f"W_max/h = {DEFAULT_DEFLECTION:g} at A = {A:.6g} (h = {h:g}; the default top, {src}, deflects "
            f"{far:.3g} h)")


def check_orbit(man: Any, chart: ManifoldChart, branch: Any, A: float, K, M, adapter: Any, *, tangent: Callable | None,
                integrator: str, w_max: float, per_period: int | None, mask: np.ndarray | None) -> dict:
    """The full model's orbit of ``branch`` at amplitude ``A`` against the branch (module docstring): one check, the
    keys of the single-mode checks' (:func:`stepnf.verify.command.check_dict`; ``max_displacement`` here the largest
    over the orbit's sampled states) and ``start``."""
    t0 = time.perf_counter()
    j, n = branch.mode, K.shape[0]
    k = np.asarray(branch.ratios, dtype=int)
    st = start_point(man, chart, branch, point_at(man, branch, A))
    phi, w = np.asarray(man.phi)[:, j], float(man.omega[j])
    if st["brake"]:
        sh = Shooting(M, K, adapter.internal_force, phi, w, tangent=tangent, forces=adapter.internal_forces,
                      integrator=integrator, w_max=w_max, steps=per_period or IMPLICIT_STEPS)
        orb = sh.at_amplitude(A, guess=(st["x0"], st["period"]))
        states = sh.samples(orb.x0, orb.period, SAMPLES)
        work = {"newton_iterations": orb.newton_iterations, **sh.work}
    else:
        fs = FreeShooting(M, K, adapter.internal_force, phi, w, tangent=tangent)
        orb = fs.at_amplitude(A, (st["x0"], st["v0"], st["period"]))
        states = fs.samples(orb, SAMPLES)
        work = {"newton_iterations": orb.newton_iterations, **fs.work}
    g = st["g"]
    Omega = 2 * np.pi / (g * orb.period)
    guess, dist = st["zeta"], 0.0
    turn = np.exp(1j * k * Omega * orb.period / SAMPLES)
    for y in states:  # the reduced orbit's point one sample later guesses the next
        d, zeta = chart.distance(y[:n], y[n:], guess)
        dist, guess = max(dist, d), zeta * turn
    om_dpim, om_check = float(k[j] * omega_at(man, branch, orb.amplitude)), float(k[j] * Omega)
    return {"amplitude": float(A), "orbit_amplitude": float(orb.amplitude), "omega_dpim": om_dpim,
            "omega_check": om_check, "omega_dpim_over_omega": om_dpim / w, "omega_check_over_omega": om_check / w,
            "relative_difference": om_dpim / om_check - 1.0, "manifold_distance": float(dist), "method": "shooting",
            "start": "brake orbit" if st["brake"] else "state and period (no state at rest)",
            "error_estimate": None, "seconds": round(time.perf_counter() - t0, 3), "work": work,
            "max_displacement": max(peak(y[:n], mask) for y in states)}


def manifold_checks(doc: dict, result: Any, model: Any, adapter: Any, say: Callable[[str], None], *,
                    shooting: bool, amplitudes: Sequence[float] | None = None,
                    fractions: Sequence[float] = (1 / 3, 2 / 3, 1.0), integrator: str = "auto",
                    per_period: int | None = None, scene: Any = None, periods: float = 3.0, rtol: float = 1e-6,
                    jacobian: str = "auto") -> dict:
    """``doc`` (:func:`stepnf.verify.command.verify_scene`'s) with one entry per master on a manifold of several
    modes (module docstring), then :func:`stepnf.verify.unverified.with_unverified` for any left. ``shooting``: by
    shooting (:func:`check_orbit`), else by time integration (:func:`stepnf.verify.manifold_integration.integrate_orbit`
    with ``periods``, ``rtol``, ``jacobian``); the other keys as :func:`stepnf.verify.command.verify_scene`'s.

    Each entry: ``index``, ``label``, ``omega``, ``order``, ``manifold`` (``modes``, ``ratios``), ``amplitudes_from``
    ("per branch"), ``branches`` (one per branch: ``branch``, ``kind``, ``valid_up_to``, ``valid_reason``,
    ``amplitudes_from``), ``checks`` (every branch's, each with ``branch`` and ``kind`` and the single-mode check's
    keys, ``start``: "brake orbit" or the whole state), ``failed`` (``amplitude``, ``branch``, ``error``) when any,
    ``integrator``, ``stiffness_ratio``; ``not_verified`` (why) when no orbit was computed."""
    K, M = model.K, model.M
    mask = translation_mask(getattr(model, "dirs", None))
    spec = getattr(scene, "backbone", None)
    listed, listed_from = ((list(amplitudes), "--amplitudes") if amplitudes else
                           (list(getattr(spec, "amplitudes", None) or []), "[analysis.backbone] amplitudes"))
    model_tangent = adapter.tangent_stiffness if adapter.provides_tangent_stiffness else None
    tangent = (lambda x: model_tangent(x).toarray()) if model_tangent is not None else None  # (shooting: dense)
    w_max = highest_frequency(K, M) if shooting else None
    checked = {int(m["index"]) for m in doc["modes"]}
    plan = []
    for mode in getattr(result, "modes", []):
        block = getattr(mode, "backbone", None) or {}
        if int(mode.index) in checked or not block.get("manifold") or "coupled_branches" not in block:
            continue
        try:
            man = manifold_of(result.arrays, int(block["manifold"].get("stored_with", mode.index)), M)
            branches = branches_of(result.arrays, int(mode.index), block)
        except NumericalError:  # the run kept no coefficients or branches: with_unverified says so
            continue
        w = float(mode.omega)
        entry = {"index": int(mode.index), "label": list(mode.label) if isinstance(mode.label, tuple) else mode.label,
                 "omega": w, "order": int(block["order"]),
                 "manifold": {"modes": list(block["manifold"]["modes"]), "ratios": block["manifold"].get("ratios")},
                 "amplitudes_from": "per branch", "branches": [], "checks": [],
                 "integrator": shooting_method(integrator, w_max / w) if shooting else None,
                 "stiffness_ratio": w_max / w if shooting else None}
        who = f"master mode {mode.index}"
        chart = ManifoldChart(man, K, M)
        for i, b in enumerate(branches):
            try:
                amps, src = branch_amplitudes(man, b, block, listed, listed_from, fractions,
                                              getattr(scene, "thickness", None), mask)
            except NumericalError as exc:  # the branch's points do not reach an amplitude asked for
                amps, src = [], f"none: {exc}"
            entry["branches"].append({"branch": i, "kind": b.kind, "valid_up_to": b.valid_A,
                                      "valid_reason": b.valid_reason, "amplitudes_from": src})
            plan.append((f"{who}, branch {i} ({b.kind})", man, chart, b, i, entry, amps))
        doc["modes"].append(entry)
    clock = OrbitClock(sum(len(p[-1]) for p in plan), say) if plan else None
    for who, man, chart, b, i, entry, amps in plan:
        for A in amps:
            clock.start(f"{who}, A = {A:.6g}")
            try:
                if shooting:
                    chk = check_orbit(man, chart, b, A, K, M, adapter, tangent=tangent, integrator=integrator,
                                      w_max=w_max, per_period=per_period, mask=mask)
                else:
                    chk = integrate_orbit(man, chart, b, A, start_point(man, chart, b, point_at(man, b, A)), K, M,
                                          adapter.internal_forces, tangent=model_tangent, jacobian=jacobian,
                                          periods=periods, rtol=rtol, per_period=per_period, mask=mask)
            except (NumericalError, AdapterError) as exc:  # listed; the others still run (exit 3)
                entry.setdefault("failed", []).append({"amplitude": float(A), "branch": i, "error": f"{who}: {exc}"})
                continue
            finally:
                clock.stop()
            entry["checks"].append({"branch": i, "kind": b.kind, **chk})
    for entry in {id(p[5]): p[5] for p in plan}.values():
        if not entry["checks"] and "not_verified" not in entry:
            why = "; ".join(f"branch {d['branch']} ({d['kind']}): {d['amplitudes_from']}" for d in entry["branches"]
                            if not any(c["branch"] == d["branch"] for c in entry["checks"]))
            entry["not_verified"] = (f"master mode {entry['index']} is on the manifold of modes "
                                     f"{entry['manifold']['modes']}: NOT VERIFIED, no orbit computed "
                                     f"({why or 'no branch'}"
                                     + ("; orbits failed, below" if entry.get("failed") else "") + ")")
            say(entry["not_verified"])
    if clock is not None:
        clock.finish()
    return with_unverified(doc, result, say)


def manifold_lines(m: dict) -> list[str]:
    """The text of one master on a manifold in ``stepnf verify``'s report: a table per branch."""
    lab = "" if m["label"] is None else f" {tuple(m['label']) if isinstance(m['label'], list) else m['label']}"
    k = m["manifold"].get("ratios")
    lines = [f"\nmaster mode {m['index']}{lab}: w = {m['omega']:.9g} rad/s, on the manifold of modes "
             f"{m['manifold']['modes']}" + (f" (ratios {':'.join(map(str, k))})" if k else "")
             + f", DPIM order {m['order']}"]
    for d in m.get("branches", []):
        valid = "-" if d["valid_up_to"] is None else f"{d['valid_up_to']:.6g}"
        lines.append(f"  branch {d['branch']} '{d['kind']}' (valid to A = {valid}, {d['valid_reason']}): amplitudes "
                     f"from {d['amplitudes_from']}")
        rows = [c for c in m["checks"] if c["branch"] == d["branch"]]
        if rows:
            lines.append(f"  {'A':>12s} {'w_DPIM/w':>14s} {'w_check/w':>14s} {'rel. diff':>11s} {'distance':>10s}"
                         "  start")
        for c in rows:
            lines.append(f"  {c['orbit_amplitude']:12.6g} {c['omega_dpim_over_omega']:14.10f} "
                         f"{c['omega_check_over_omega']:14.10f} {c['relative_difference']:11.2e} "
                         f"{c['manifold_distance']:10.2e}  {c['start']}")
        for f in m.get("failed", []):
            if f["branch"] == d["branch"]:
                lines.append(f"  {f['amplitude']:12.6g}  no orbit: {f['error']}")
    if m.get("not_verified"):
        lines.append(f"  {m['not_verified']}")
    return lines
