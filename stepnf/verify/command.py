"""``stepnf verify SCENE``: the DPIM backbones against periodic orbits of the full model.

For each master mode and a few amplitudes ``A`` of the master coordinate ``q = phi^T M x`` (default: three, evenly
up to the backbone's validity limit, capped at W_max/h = 2 with a thickness: :mod:`stepnf.verify.deflection`), the
full model's orbit is computed independently of the parametrisation (a master on a manifold of several modes: per
branch, :mod:`stepnf.verify.manifold_orbits`):

* **shooting** (:class:`stepnf.verify.periodic.Shooting`: Newton on the period and the initial state, DOP853 with
  ``rtol = 1e-12``, or implicit Gauss-Legendre collocation of order 16 for a stiff model, ``w_max / w`` above
  :data:`stepnf.verify.periodic.STIFF_RATIO`) for models up to :data:`SHOOTING_LIMIT` dofs (the variational
  equations are n x n), started from the parametrisation's point at ``theta = 0``;
* **time integration** (:mod:`stepnf.verify.integrate`: the energy-conserving scheme over ``periods`` periods at two
  step sizes, Richardson-extrapolated) from the parametrisation's point ``(x, v)(theta = 0, rho(A))`` for larger
  models.

Both report the orbit's frequency and amplitude, the backbone's at that amplitude, and the orbit's distance from the
manifold: at sampled states, the point ``(rho, theta)`` of the parametrisation with the same ``q = phi^T M x`` and
``q' = phi^T M v`` (Newton), energy norm ``sqrt(dx^T K dx + dv^T M dv) / sqrt(x^T K x + v^T M v)``, the largest.
Then, with ``[analysis.forcing]``, each FRC's peak and folds (:mod:`stepnf.verify.forced_verify`). Progress (stderr,
:class:`stepnf.verify.clock.OrbitClock`): before each orbit the mode, amplitude, ``k of n``, time elapsed and left.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from stepnf.keys.backbone import AMPLITUDE_RANGE
from stepnf.errors import AdapterError, NumericalError, SceneError
from stepnf.plugin.dofs import peak, translation_mask
from stepnf.verify.clock import OrbitClock
from stepnf.verify.deflection import cap_amplitudes
from stepnf.verify.forced_verify import forced_checks, forced_failures, forced_lines
from stepnf.verify.manifold_orbits import manifold_checks, manifold_lines

#: Largest model (dofs) checked by shooting; larger ones by time integration.
SHOOTING_LIMIT = 300
#: The most periods ``--periods`` may ask (3 by default): each period is many implicit steps of the full
#: model at two step sizes, so this bounds a run's length rather than any accuracy.
MAX_PERIODS = 1000
#: ``--steps-per-period``: 8 steps is the coarsest a period's shape survives; 1e5 bounds a run's length.
STEPS_RANGE = (8, 100_000)


class Chart:
    """The point of a DPIM parametrisation with a given master coordinate and rate (module docstring).

    ``res``: a :class:`stepnf.dpim.parametrisation.DPIMResult`; ``K``, ``M`` (n, n) for the energy norm.
    """

    def __init__(self, res: Any, K, M):
        self.res, self.K, self.M = res, K, M
        self.Mphi = np.asarray(M @ res.phi).ravel()
        self.keys = sorted(res.Y)
        self.a = np.array([float(self.Mphi @ res.Y[k]) for k in self.keys])
        self.p = np.array([k[0] for k in self.keys], dtype=float)
        self.m = np.array([k[1] for k in self.keys], dtype=float)

    def frequency(self, rho: float) -> float:
        """``Omega(rho)`` (rad per model time unit)."""
        return self.res.omega + sum(ck * rho ** (2 * k) for k, ck in enumerate(self.res.c, start=1))

    def _q(self, theta: float, rho: float) -> tuple[float, float, np.ndarray]:
        rp = rho ** self.p
        c, s = np.cos(self.m * theta), np.sin(self.m * theta)
        om = self.frequency(rho)
        dom = sum(2 * k * ck * rho ** (2 * k - 1) for k, ck in enumerate(self.res.c, start=1))
        q = float(self.a @ (rp * c))
        sv = float(self.a @ (rp * self.m * s))
        qd = -om * sv
        drp = self.p * rho ** np.maximum(self.p - 1, 0)
        J = np.array([[-float(self.a @ (rp * self.m * s)), float(self.a @ (drp * c))],
                      [-om * float(self.a @ (rp * self.m ** 2 * c)),
                       -dom * sv - om * float(self.a @ (drp * self.m * s))]])
        return q, qd, J

    def locate(self, q: float, qd: float, rho: float | None = None) -> tuple[float, float]:
        """``(theta, rho)`` with ``phi^T M x(theta, rho) = q`` and ``phi^T M v(theta, rho) = qd``.

        Newton from the linear guess, or from ``rho`` when given (far out the map need not be
        one-to-one: an orbit's own ``rho`` keeps Newton on its branch).
        """
        w = self.res.omega
        theta = float(np.arctan2(-qd / w, q))
        rho = float(np.hypot(q, qd / w)) if rho is None else float(rho)
        scale = max(rho, 1e-300)
        for _ in range(50):
            r0, r1, J = self._q(theta, rho)
            res = np.array([r0 - q, (r1 - qd) / w])
            J[1] /= w
            try:
                d = np.linalg.solve(J, -res)
            except np.linalg.LinAlgError:
                break
            theta, rho = theta + d[0], rho + d[1]
            if abs(d[0]) <= 1e-14 and abs(d[1]) <= 1e-14 * scale:
                return theta, rho
        raise NumericalError(f"verify: no point of the parametrisation has q = {q:.6g}, q' = {qd:.6g} "
                             "(the orbit left the parametrisation's range)")

    def distance(self, x: np.ndarray, v: np.ndarray, rho: float | None = None) -> float:
        """Relative energy-norm distance of ``(x, v)`` from the parametrisation at the same ``(q, q')``
        (``rho``: a guess, see :meth:`locate`)."""
        theta, rho = self.locate(float(self.Mphi @ x), float(self.Mphi @ v), rho)
        dx = x - self.res.displacement(theta, rho)
        dv = v - self.res.velocity(theta, rho)
        num = float(dx @ (self.K @ dx)) + float(dv @ (self.M @ dv))
        den = float(x @ (self.K @ x)) + float(v @ (self.M @ v))
        return float(np.sqrt(max(num, 0.0) / den)) if den > 0 else 0.0


@dataclass
class Check:
    """One backbone point against the full model's orbit (frequencies in rad per model time unit)."""

    amplitude: float           # A asked for (of q = phi^T M x)
    omega_dpim: float          # backbone at the orbit's amplitude
    omega_check: float         # the full model's orbit
    orbit_amplitude: float     # A measured on the orbit
    distance: float            # largest relative distance from the manifold along the orbit
    method: str                # "shooting" or "integration"
    error_estimate: float | None = None  # bound on omega_check's error, relative (integration only)
    seconds: float = 0.0
    work: dict | None = None
    max_displacement: float | None = None  # largest |x| at the orbit's start, at rest, translations (W_max; length)

    @property
    def difference(self) -> float:
        """``omega_dpim / omega_check - 1``."""
        return self.omega_dpim / self.omega_check - 1.0


def by_shooting(res: Any, K, M, f1: Callable[[np.ndarray], np.ndarray], A: float, *,
                tangent: Callable | None = None, samples: int = 32, forces: Callable | None = None,
                integrator: str = "auto", w_max: float | None = None, per_period: int | None = None,
                mask: np.ndarray | None = None) -> Check:
    """The brake orbit of amplitude ``A`` by shooting, from the parametrisation's guess.

    ``forces`` the batched internal forces (the implicit integrator sends its stages in one call);
    ``integrator`` as :class:`stepnf.verify.periodic.Shooting` (``"auto"``: implicit for a stiff model); ``w_max``
    the model's highest frequency when known (:func:`stepnf.verify.periodic.highest_frequency`; else computed);
    ``per_period`` the implicit integrator's steps per period (default
    :data:`stepnf.verify.periodic.IMPLICIT_STEPS`); ``mask`` the translation dofs W_max is measured on
    (:func:`stepnf.plugin.dofs.translation_mask`; None: every dof).
    """
    from stepnf.verify.periodic import IMPLICIT_STEPS, Shooting

    t0 = time.perf_counter()
    bb = res.backbone()
    rho = bb.rho_at(A)
    sh = Shooting(M, K, f1, res.phi, res.omega, tangent=tangent, forces=forces, integrator=integrator, w_max=w_max,
                  steps=per_period or IMPLICIT_STEPS)
    orb = sh.at_amplitude(A, guess=(res.displacement(0.0, rho), 2 * np.pi / bb.frequency(rho)))
    states = sh.samples(orb.x0, orb.period, samples)
    chart = Chart(res, K, M)
    n = len(res.phi)
    rho = bb.rho_at(orb.amplitude)
    dist = max(chart.distance(y[:n], y[n:], rho) for y in states)
    return Check(A, float(bb.omega_at(orb.amplitude)[0]), orb.omega, orb.amplitude, dist, "shooting",
                 None, time.perf_counter() - t0, {"newton_iterations": orb.newton_iterations, **sh.work},
                 peak(orb.x0, mask))


def by_integration(res: Any, K, M, forces: Callable[[np.ndarray], np.ndarray], A: float, *,
                   periods: float = 3.0, rtol: float = 1e-7, tangent: Callable | None = None,
                   integrator: Any = None, samples_per_period: int = 16, what: str = "",
                   jacobian: str = "auto", per_period: int | None = None, mask: np.ndarray | None = None) -> Check:
    """Integrate from ``(x, v)(0, rho(A))`` over ``periods`` periods (:func:`stepnf.verify.integrate.measure`).

    ``jacobian``: the implicit steps' Newton (:data:`stepnf.verify.integrate.JACOBIANS`, ``--tangent``);
    ``per_period``: steps per period of the coarse level (``--steps-per-period``; default from ``rtol``);
    ``mask``: the translation dofs W_max is measured on (None: every dof).
    """
    from stepnf.verify.integrate import EnergyConserving, measure

    t0 = time.perf_counter()
    bb = res.backbone()
    rho = bb.rho_at(A)
    chart = Chart(res, K, M)
    # Newton to 1e-10 of the state: over <= 1e3 steps the accumulated error stays <= 1e-7, below rtol, and
    # above the round-off floor of a large FE model's solves (modified Newton stalls near 1e-11 there)
    integ = integrator or EnergyConserving(M, K, forces, tangent=tangent, tol=1e-10, jacobian=jacobian,
                                           hint=newton_hint(jacobian, per_period, rtol))
    x0, v0 = res.displacement(0.0, rho), res.velocity(0.0, rho)
    level = float(chart.Mphi @ res.displacement(np.pi / 2, rho))  # q at theta = pi/2: crossed mid-swing
    m = measure(integ, x0, v0, watch=chart.Mphi, omega=bb.frequency(rho), periods=periods, rtol=rtol,
                level=level, keep_per_period=samples_per_period, what=what or "time integration",
                per_period=per_period)
    dist = max(chart.distance(x, v, rho) for _, x, v in m.finest.states)
    work = {"levels": [{k: d[k] for k in ("dt", "steps", "newton_iterations", "force_evaluations", "tangent_steps",
                                          "secant_steps", "krylov_steps", "jacobian_products", "halved_steps")}
                       for d in m.levels]}
    return Check(A, float(bb.omega_at(m.amplitude)[0]), m.omega, m.amplitude, dist, "integration",
                 m.omega_error, time.perf_counter() - t0, work, peak(x0, mask))


def newton_hint(jacobian: str, per_period: int | None, rtol: float) -> str:
    """What to change when an implicit step does not converge: the keys of ``stepnf verify``."""
    from stepnf.verify.integrate import steps_per_period

    now = per_period or steps_per_period(rtol)
    other = ("" if jacobian in ("auto", "differences") else
             " or --tangent differences (Newton-Krylov by directional differences of the forces)")
    return f"more steps per period may help: --steps-per-period {4 * now} (now {now})" + other


# --------------------------------------------------------------------------- scene
def backbone_spec(scene: Any) -> Any:
    """The scene's ``[analysis.backbone]`` (a :class:`stepnf.keys.backbone.BackboneSpec`), or None."""
    return getattr(scene, "backbone", None)


def default_amplitudes(bb: Any, limit: tuple[float | None, str], fractions: Sequence[float] = (1 / 3, 2 / 3, 1.0),
                       tol: float = 1e-3, shift: float = 0.10) -> tuple[list[float], str]:
    """Amplitudes at ``fractions`` of the backbone's validity limit ``limit`` (``bb.validity_limit(tol)``).

    Without a limit (not reached), of the amplitude where ``omega`` has moved by ``shift``; a limit of 0
    (the backbone has no validity range: forces inaccurate, a flag) gives no amplitude, and says so.
    Returns ``(amplitudes, where the top one comes from)``.
    """
    A_max, why = limit
    if A_max is not None and A_max <= 0:
        return [], f"none: {no_range(why)}"
    if A_max is None:
        w = bb.res.omega
        c1 = abs(bb.res.c[0]) if len(bb.res.c) else 0.0
        rho = 1e-3 * (w / c1) ** 0.5 if c1 > 0 else 1e-3  # Omega - w = c1 rho^2 starts at 1e-6 w
        for _ in range(400):
            if abs(bb.frequency(rho) / w - 1) >= shift:
                break
            rho *= 1.05
        A_max, why = bb.amplitude(rho), f"omega shifted by {shift:.0%}"
    else:
        why = f"validity limit A = {A_max:.6g} ({why}, tol {tol:g})"
    return [A_max * f for f in fractions], why


def no_range(why: str) -> str:
    """The words for a backbone whose validity limit is 0 (``why``: its ``valid_reason``)."""
    return f"the backbone has no validity range ({why}): no amplitude of it is trustworthy"


def scene_amplitudes(spec: Any, limit: float | None) -> tuple[list[float], str]:
    """The scene's ``[analysis.backbone] amplitudes`` up to the validity limit ``limit`` (None: no limit
    found), and where they come from; an empty list without such amplitudes."""
    listed = getattr(spec, "amplitudes", None)
    if not listed:
        return [], ""
    kept = [float(A) for A in listed if limit is None or A <= limit * (1 + 1e-9)]
    left = len(listed) - len(kept)
    return kept, "[analysis.backbone] amplitudes" + (f" ({left} beyond the validity limit left out)" if left else "")


def verify_scene(scene: Any, *, amplitudes: Sequence[float] | None = None, periods: float = 3.0,
                 rtol: float = 1e-6, fractions: Sequence[float] = (1 / 3, 2 / 3, 1.0),
                 progress: Callable[[str], None] | None = None, integrator: str = "auto",
                 tangent: str = "auto", per_period: int | None = None) -> dict:
    """Run the scene's backbone (:func:`stepnf.pipeline.run.run_on_adapter`), then check every master mode.

    Returns the document printed by ``stepnf verify`` (``--json``): ``scene``, ``n_dofs``, ``method``, ``modes``
    (one entry per master: ``index``, ``label``, ``omega``, ``order``, ``amplitudes_from``, ``checks``, one dict per
    amplitude, and ``failed``, one ``{amplitude, error}`` per orbit that could not be computed, when any; by
    shooting, ``integrator``, ``"implicit"`` or ``"explicit"``, chosen for the master whatever its orbits do, and
    ``stiffness_ratio``, ``w_max / w``; a master on a manifold of several modes: per branch,
    :func:`stepnf.verify.manifold_orbits.manifold_checks`). Without ``amplitudes``, each mode is checked at the
    scene's amplitudes within its validity limit (:func:`scene_amplitudes`), else at ``fractions`` of that limit
    (:func:`default_amplitudes`; the top capped at W_max/h = 2 with the scene's thickness,
    :func:`stepnf.verify.deflection.cap_amplitudes`); ``rtol`` the integration's frequency accuracy
    (:func:`stepnf.verify.integrate.measure`). A scene without ``[analysis.backbone]`` or a bad amplitude is a
    :class:`SceneError`; a failed orbit is listed under ``failed`` (:func:`failed_orbits`) and the other checks
    still run. ``integrator``: the shooting's (:class:`stepnf.verify.periodic.Shooting`: ``"auto"`` implicit for a
    stiff model); ``progress`` gets a line before each orbit (:class:`OrbitClock`). ``tangent`` (``--tangent``, one
    of :data:`stepnf.verify.integrate.JACOBIANS`): the time integration's Newton (``"auto"``: modified, then the
    model's tangent, else a secant iteration and Newton-Krylov by directional differences of the forces,
    :mod:`stepnf.verify.integrate`; ``"tangent"`` needs a model that gives one; ``"differences"`` never asks the
    model's); the shooting uses the model's tangent when there is one, else differences, whatever ``tangent``.
    ``per_period`` (``--steps-per-period``): steps per period of the integration's coarse level (default from
    ``rtol``), or of the implicit shooting.
    """
    from stepnf.pipeline.model import is_modal_model, open_model
    from stepnf.pipeline.run import run_on_adapter

    say = progress or (lambda s: None)
    where = getattr(scene, "file", None)
    spec = backbone_spec(scene)
    if spec is None:
        raise SceneError(where, "analysis.backbone", "stepnf verify checks the backbone curves: the scene has no "
                         "[analysis.backbone] table (add one, e.g. order = 7)")
    lo, hi = AMPLITUDE_RANGE
    if amplitudes is not None and not all(np.isfinite(a) and lo <= a <= hi for a in amplitudes):
        raise SceneError(where, None, f"--amplitudes must be numbers in [{lo:g}, {hi:g}] (model length units, as "
                         f"[analysis.backbone] amplitudes), got {list(amplitudes)}")
    if not (np.isfinite(periods) and 1 <= periods <= MAX_PERIODS):
        raise SceneError(where, None, f"--periods must be a number in [1, {MAX_PERIODS}], got {periods}")
    from stepnf.verify.integrate import JACOBIANS

    if tangent not in JACOBIANS:
        raise SceneError(where, None, f"--tangent must be one of {', '.join(JACOBIANS)}, got {tangent!r}")
    if per_period is not None and not (isinstance(per_period, (int, np.integer)) and
                                       STEPS_RANGE[0] <= per_period <= STEPS_RANGE[1]):
        raise SceneError(where, None, f"--steps-per-period must be a whole number in [{STEPS_RANGE[0]}, "
                         f"{STEPS_RANGE[1]}], got {per_period}")
    if is_modal_model(scene):
        raise SceneError(where, "model.solver", f"stepnf verify integrates the full model: solver "
                         f"{scene.solver!r} is a model in modal coordinates, not a solver adapter")
    say("running the scene's backbone")
    adapter = open_model(scene)  # one model for the run and the orbits: its K and M from the run's model stage
    try:
        if tangent == "tangent" and not adapter.provides_tangent_stiffness:
            raise SceneError(where, None, f"--tangent tangent: solver {scene.solver!r} gives no tangent stiffness; "
                             "use --tangent auto or differences (directional differences of its forces)")
        result, model = run_on_adapter(scene, adapter)
        backbones = getattr(result, "backbones", None)
        if backbones is None:
            raise SceneError(where, "analysis.backbone", "this stepnf's run has no backbone stage (RunResult."
                             "backbones is missing): nothing to verify")
        K, M = model.K, model.M
        n = K.shape[0]
        mask = translation_mask(getattr(model, "dirs", None))  # W_max on translations (a shell's rotations: radians)
        jacobian = tangent  # the integration's Newton; the shooting takes the model's tangent when there is one
        tangent = adapter.tangent_stiffness if adapter.provides_tangent_stiffness else None
        shooting = n <= (SHOOTING_LIMIT if tangent is not None else 40)
        if shooting:  # the integrator chosen for each master (stepnf.verify.periodic.Shooting), whatever its orbits do
            from stepnf.verify.periodic import highest_frequency, shooting_method

            w_max = highest_frequency(K, M)
        labels = {m.index: m.label for m in getattr(result, "modes", [])}
        doc = {"scene": str(where), "n_dofs": int(n), "method": "shooting" if shooting else "integration",
               "periods": None if shooting else periods, "modes": []}
        blocks = {m.index: getattr(m, "backbone", None) for m in getattr(result, "modes", [])}
        plan = []  # (who, res, entry, amplitudes): every orbit known before the first, for the estimate
        for p, res in sorted(backbones.items()):
            bb = res.backbone()
            who = f"master mode {p}" + (f" {labels[p]}" if labels.get(p) is not None else "")
            tol = getattr(spec, "tolerance", 1e-3)
            limit, why = _validity_limit(bb, blocks.get(p), tol)
            amps, src = (list(amplitudes), "--amplitudes") if amplitudes else scene_amplitudes(spec, limit)
            if not amps:  # none listed, or every one beyond the limit (then said)
                amps, dsrc = default_amplitudes(bb, (limit, why), fractions, tol)
                amps, dsrc = cap_amplitudes(bb, amps, dsrc, getattr(scene, "thickness", None), mask=mask)
                src = dsrc + (f"; {src}" if src else "")
            if amplitudes:
                if limit is not None and limit <= 0:
                    raise SceneError(where, None, f"--amplitudes: {who}: {no_range(why)}")
                if limit is not None and max(amps) > limit * (1 + 1e-9):
                    raise SceneError(where, None, f"--amplitudes {max(amps):.6g} is beyond the validity limit of "
                                     f"{who}, A = {limit:.6g} ({why}: orders {res.order - 2} and {res.order} "
                                     f"differ by more than {tol:g}); no trustworthy starting orbit there")
            entry = {"index": int(p), "label": _label(labels.get(p)), "omega": float(res.omega),
                     "order": int(res.order), "amplitudes_from": src, "checks": []}
            if shooting:
                ratio = w_max / float(res.omega)
                entry.update(integrator=shooting_method(integrator, ratio), stiffness_ratio=ratio)
            plan.append((who, res, entry, amps))
            doc["modes"].append(entry)
        clock = OrbitClock(sum(len(a) for *_, a in plan), say)
        for who, res, entry, amps in plan:
            for A in amps:
                clock.start(f"{who}, A = {A:.6g}")
                try:
                    if shooting:
                        chk = by_shooting(res, K, M, adapter.internal_force, A, forces=adapter.internal_forces,
                                          tangent=(lambda u: tangent(u).toarray()) if tangent else None,
                                          integrator=integrator, w_max=w_max, per_period=per_period, mask=mask)
                    else:
                        chk = by_integration(res, K, M, adapter.internal_forces, A, periods=periods, rtol=rtol,
                                             tangent=tangent, jacobian=jacobian, per_period=per_period, mask=mask)
                # reported with the checks that worked (exit 3: stepnf.cli.main); an AdapterError: the solver's
                # forces not finite at a state of this orbit (too large an amplitude), the others still run
                except (NumericalError, AdapterError) as exc:
                    entry.setdefault("failed", []).append({"amplitude": float(A), "error": f"{who}: {exc}"})
                    continue
                finally:
                    clock.stop()
                entry["checks"].append(check_dict(chk, res.omega))
        clock.finish()
        doc = manifold_checks(doc, result, model, adapter, say, shooting=shooting, amplitudes=amplitudes,
                              fractions=fractions, integrator=integrator, per_period=per_period, scene=scene,
                              periods=periods, rtol=rtol, jacobian=jacobian)  # masters on manifolds, per branch
        return forced_checks(doc, result, model, adapter, say, scene=scene, shooting=shooting)  # FRCs' peaks, folds
    finally:
        adapter.close()


def _validity_limit(bb: Any, block: dict | None, tol: float) -> tuple[float | None, str]:
    """The backbone's validity limit at ``tol``: the run's (its ``modes[i].backbone`` block, computed at
    the same tolerance) when there, else computed (each call marches the whole range: seconds)."""
    if isinstance(block, dict) and "valid_reason" in block and block.get("tolerance") == tol:
        v = block.get("valid_up_to")
        return (None if v is None else float(v)), str(block["valid_reason"])
    return bb.validity_limit(tol)


def _label(label: Any) -> Any:
    return list(label) if isinstance(label, tuple) else label


def check_dict(c: Check, omega: float) -> dict:
    """The JSON form of one check (frequencies as ratios to the linear ``omega`` and in rad/s; ``max_displacement``
    the largest displacement of the orbit's state at rest, W_max, length units, over the translation dofs)."""
    return {"amplitude": c.amplitude, "orbit_amplitude": c.orbit_amplitude,
            "omega_dpim": c.omega_dpim, "omega_check": c.omega_check,
            "omega_dpim_over_omega": c.omega_dpim / omega, "omega_check_over_omega": c.omega_check / omega,
            "relative_difference": c.difference, "manifold_distance": c.distance, "method": c.method,
            "error_estimate": c.error_estimate, "seconds": round(c.seconds, 3), "work": c.work,
            "max_displacement": c.max_displacement}


def failed_orbits(doc: dict) -> int:
    """How many orbits of the document could not be computed (``modes[i].failed``, failed forced solves)."""
    return sum(len(m.get("failed", [])) for m in doc["modes"]) + forced_failures(doc)


def format_report(doc: dict) -> str:
    """The side-by-side table ``stepnf verify`` prints."""
    # the integrator chosen for each master (``modes[i].integrator``), whatever its orbits' outcome; a
    # document without it (an older stepnf's): the orbits' own record
    works = ([{"method": m["integrator"], "stiffness_ratio": m["stiffness_ratio"]} for m in doc["modes"]]
             if all("integrator" in m for m in doc["modes"]) else
             [c.get("work") or {} for m in doc["modes"] for c in m["checks"]])
    stiff = [w["stiffness_ratio"] for w in works if w.get("method") == "implicit"]
    how = ("shooting (DOP853, rtol 1e-12)" if doc["method"] == "shooting" and not stiff else
           f"shooting (stiff, w_max/w up to {max(stiff):.3g}: implicit Gauss-Legendre of order 16"
           f"{', DOP853 where w_max/w is small' if len(stiff) < len(works) else ''})" if doc["method"] == "shooting"
           else f"time integration over {doc['periods']:g} periods (energy-conserving, Richardson over 2 steps)")
    lines = [f"{doc['scene']}: {doc['n_dofs']} dofs; full-model orbits by {how}"]
    for m in (m for m in doc["modes"] if "manifold" not in m):  # (masters on manifolds: below, per branch)
        lab = "" if m["label"] is None else f" {tuple(m['label']) if isinstance(m['label'], list) else m['label']}"
        lines.append(f"\nmaster mode {m['index']}{lab}: w = {m['omega']:.9g} rad/s, DPIM order {m['order']}, "
                     f"amplitudes from {m['amplitudes_from']}")
        lines.append(f"  {'A':>12s} {'w_DPIM/w':>14s} {'w_check/w':>14s} {'rel. diff':>11s} {'distance':>10s}")
        for c in m["checks"]:
            lines.append(f"  {c['orbit_amplitude']:12.6g} {c['omega_dpim_over_omega']:14.10f} "
                         f"{c['omega_check_over_omega']:14.10f} {c['relative_difference']:11.2e} "
                         f"{c['manifold_distance']:10.2e}")
        for c in m["checks"]:  # a halved step is not the uniform scheme Richardson's estimate assumes
            halved = sum(lv.get("halved_steps", 0) for lv in (c.get("work") or {}).get("levels", []))
            if halved:
                lines.append(f"  {c['orbit_amplitude']:12.6g}  {halved} step(s) halved where no Newton converged: "
                             "more --steps-per-period gives the uniform steps the extrapolation assumes")
        for f in m.get("failed", []):
            lines.append(f"  {f['amplitude']:12.6g}  no orbit: {f['error']}")
        if not m["checks"] and not m.get("failed"):
            lines.append(f"  {m.get('not_verified') or 'no orbit checked (above: why)'}")
    lines += [t for m in doc["modes"] if "manifold" in m for t in manifold_lines(m)]
    lines.append("\nA: amplitude of q = phi^T M x measured on the orbit; w_DPIM at that A; distance: largest "
                 "relative energy-norm distance of the orbit from the parametrisation")
    return "\n".join(lines + forced_lines(doc))
