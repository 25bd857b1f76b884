"""Stage ``backbone``: the DPIM of every master mode to the order of ``[analysis.backbone]``, and its backbone.

Per master mode ``p`` (:meth:`stepnf.dpim.parametrisation.DPIM.parametrise`, full order):

* forces through a :class:`stepnf.step.forces.ForceEvaluator` on the run's counters and checkpoint (batches of
  1024 fields for adapters that prefer batches, else 64; one plan name per order, so an interrupted run
  reuses them), one batched request per order;
* the probe of the polarisation is STEP's amplitude (``[analysis.step] amplitude``, else
  relative_amplitude x the thickness or the model's characteristic length): the size at which STEP
  already found the forces accurate;
* the linear solves of the run's :func:`~stepnf.pipeline.context.full_order_context`: its ``K^+`` (the
  factorisation DNF and SMD used), its deflated solver for every shift below the computed spectrum
  (the resonant shift ``w_p^2`` included, the master and its twins left out, as MD does), its shifted
  factorisations (adapter's or stepnf's) otherwise: kept for all orders of the master up to
  :data:`KEEP_FACTORISATIONS_UP_TO` dofs; above, two live ones (one per parity of the harmonic,
  :mod:`stepnf.pipeline.backbone_slots`) up to :data:`TWO_SLOTS_UP_TO` dofs, one above; freed when the
  master is done;
* the computed spectrum for the internal-resonance flags (naming the mode), with one flag when the
  computed modes stop below ``N w_p`` (resonances with the higher harmonics are not checked there);
* the master's degenerate twins passed: handled when symmetry keeps them uncoupled; a twin the
  master's forces drive (:class:`~stepnf.errors.NoSingleModeManifold`) gives that master a ``twin_driven``
  flag on every method (T n/a in the table) and a block without amplitudes or validity range, and the
  run goes on; a master that drives a twin or a rigid mode (:mod:`stepnf.nf.manifold_checks`, found by the
  evaluators) gets no validity range either (:func:`no_manifold`).

Every rank of a collective (MPI) adapter makes the same calls: the sequence depends only on the
scene and the computed modes.
"""
from __future__ import annotations

import math

import numpy as np

from stepnf.nf.coefficient import json_float
from stepnf.dpim.backbone_report import WMax, backbone_report, transverse_operator
from stepnf.dpim.parametrisation import DPIM, DPIMResult, DPIMTolerances, ModeSpectrum
from stepnf.dpim.nonlinear_terms import planned_evaluations
from stepnf.dpim.solves import Solvers
from stepnf.errors import AdapterError, NoSingleModeManifold, NumericalError, SceneError
from stepnf.flags import (BACKBONE_FAILED_REASON, DIVERGES_REASON, STEP_UNUSABLE, backbone_invalidating, kind_of,
                          new_flag)
from stepnf.nf.gamma import gamma_scale
from stepnf.linalg.shifted import ShiftedFactorizer, Slot
from stepnf.methods import DNF
from stepnf.step.procedure import ForceEvaluator, step_amplitude
from stepnf.plugin.dofs import rotation_mask, translation_mask
from stepnf.pipeline.backbone_slots import ParitySlots
from stepnf.pipeline.context import full_order_context
from stepnf.pipeline.manifolds import (ManifoldPlan, chunked, manifold_text, master_output, parametrise, plan_name,
                                       resolve_manifolds)
from stepnf.pipeline.outputs import BackboneOutput, Backbones, Evaluations, RunContext, RunModel, RunModes, StepTerms
from stepnf.pipeline.state import StageView


#: Models up to this many dofs keep every shifted factorisation of a master for all its orders (a few MB
#: each); larger ones keep at most two (:mod:`stepnf.pipeline.backbone_slots`): on the 38k-dof cap each
#: costs ~220 MB and a high mode needs N - 1 = 6 of them.
KEEP_FACTORISATIONS_UP_TO = 5000
#: Models up to this many dofs keep two live shifted factorisations (one per parity of the harmonic) beside
#: the eigen-solver's; larger ones one. Measured on the hex27 cap: a factorisation holds ~6 KiB per dof and
#: K, M and the vectors ~8 KiB per dof, so three factorisations at 400k dofs take ~10 GB of this 24 GB machine.
TWO_SLOTS_UP_TO = 400_000
#: What ends the DPIM of one master without ending the run (:func:`failed_backbone`): a numerical error (a
#: master that is not an eigenpair, a singular or refused solve, NaN), LAPACK's, or forces the adapter returned
#: unusable (NaN at the probe fields): a rerun would meet them again. Not a solver that failed to run
#: (:class:`~stepnf.errors.SolverRunError`: a crash, a time-out, possibly transient), which still ends the run
#: with its checkpoint kept, so that a rerun resumes; nor an interruption, a memory error or a bug.
BACKBONE_FAILURES = (NumericalError, ArithmeticError, np.linalg.LinAlgError, AdapterError)


def second_slot(state: StageView) -> Slot:
    """The backbone's own slot (odd harmonics): a second refactor instance of stepnf's factoriser, or the
    adapter's factorisations one at a time."""
    ctx = full_order_context(state)
    if getattr(ctx.shifted, "refactor", None) is None:  # the adapter's: one object per factorisation
        return Slot.over(ctx.shifted)
    own = ShiftedFactorizer(state.K, state.M, counters=state.counters, backend=state.backend)
    return Slot.over(own, own.close)


class PlannedForces:
    """``forces(U)`` for :mod:`stepnf.dpim.polarisation`: each call a named checkpoint plan (``backbone_<p>_<k>``)."""

    accepts_out = True  # ``out=`` as :class:`~stepnf.step.forces.ForceEvaluator`: the forces may replace the fields

    def __init__(self, evaluator: ForceEvaluator, p: int):
        self.evaluator, self.p, self.calls = evaluator, p, 0
        # the adapter's forces are checked once (stepnf.step.forces); chunks read back from a checkpoint are
        # not, so with a checkpoint the polarisation checks them again (a damaged chunk is a message)
        self.checked = evaluator.checked and evaluator.checkpoint is None

    def __call__(self, U: np.ndarray, *, out: np.ndarray | None = None) -> np.ndarray:
        self.calls += 1
        return self.evaluator(U, plan=f"backbone_{self.p}_{self.calls}", out=out)


def w_max_measure(state: StageView) -> WMax | None:
    """How W_max / h is measured: ``[analysis] transverse`` as a linear map on the dofs, else the model's
    own transverse amplitude; ``None`` without a thickness or a transverse direction (``state.gscale``)."""
    g = state.gscale
    if g is None:
        return None
    if state.scene.transverse is not None and state.dirs is not None:
        op = transverse_operator(state.X, state.dirs, state.scene.transverse)
        return WMax(g.thickness, linear=op) if op is not None else None
    phi = state.phi[:, state.masters[0]]
    probe = g.amplitude(phi)
    if probe is None or not probe > 0:
        return None
    if g.amplitude == state.adapter.transverse_amplitude and state.adapter.transverse_displacements(
            phi[:, None]) is not None:  # the same peak, all phases at once
        return WMax(g.thickness, linear=state.adapter.transverse_displacements)
    return WMax(g.thickness, peak=g.amplitude)


def spectrum_flag(state: StageView, p: int, order: int) -> dict | None:
    """A flag when the computed modes stop below ``order x w_p`` (resonances above them unchecked); none when
    the eigen-solve computed every mode of the model."""
    top = float(state.omega[-1]) / float(state.omega[p])
    if state.basis.complete or top >= order * (1 + state.tol.resonance):
        return None
    return new_flag("resonance_check_partial", mode=None,
                    message=f"the computed modes reach {top:.3g} x w_p (mode {state.m - 1}): internal resonances "
                            f"with the harmonics {max(2, math.floor(top) + 1)}..{order} of the parametrisation are not "
                            "checked")


def master_dpim(state: StageView, p: int, order: int, forces: ForceEvaluator, probe: float,
                odd_slot: Slot | None = None) -> DPIMResult:
    """The DPIM of master ``p`` with the run's solvers (module docstring); ``odd_slot``: where the odd
    harmonics' factorisations live on a large model (None: in the run's one slot, with the even ones)."""
    ctx = full_order_context(state)
    # the deflated solver does K^+, the resonant solve (master and twins left out: DPIM.resonant_exclude) and
    # every admissible shift, the independent ones of an order in one lockstep run
    # every factorisation of the master kept for its orders (made by the adapter, or by ShiftedSolves), or in
    # the slots on a large model; ShiftedSolves frees them (release()) when the master is done
    large = state.n > KEEP_FACTORISATIONS_UP_TO
    factory = ParitySlots(state.omega[p], (ctx.slot, odd_slot or ctx.slot)) if large else ctx.shifted
    model = DPIM(PlannedForces(forces, p), state.K, state.M,
                 ModeSpectrum(omega=state.omega, rigid=state.basis.rigid, modes=state.phi, twins={p: state.basis.twins(p)}),
                 Solvers(factory=factory, pinv=ctx.Kpinv if ctx.deflated is None else None, deflated=ctx.deflated,
                         backend=state.backend),
                 state.counters, DPIMTolerances(resonance=state.tol.resonance, twin=state.scene.degeneracy_tolerance,
                                                coupling=state.tol.coupling), rotations=rotation_mask(state.dirs))
    res = model.parametrise(state.phi[:, p], float(state.omega[p]), order, probe=probe, master=p,
                            progress=lambda k: state.progress.bar(k - 1, order - 1, f"DPIM mode {p}"))
    flag = spectrum_flag(state, p, order)
    if flag is not None:
        res.flags.append(flag)
    return res


def backbone_check_stage(ctx: RunContext, model: RunModel) -> None:
    """Refuse ``[analysis.backbone] w_over_h`` on a model without a thickness and a transverse displacement,
    right after the ``model`` stage (before any eigen-solve, force evaluation or checkpoint): a
    :class:`SceneError` naming the key (exit 2)."""
    state = StageView(ctx, model)
    spec = state.scene.backbone
    if spec is None or spec.w_over_h is None:
        return
    g, why = gamma_scale(state.scene, state.adapter, state.X, state.dirs)
    if g is not None and state.scene.transverse is None and g.amplitude(np.zeros(state.n)) is None:
        g, why = None, "the model gives no transverse displacement; set [analysis] transverse"
    if g is None:
        raise SceneError(state.scene.file, "analysis.backbone.w_over_h",
                         f"W_max/h needs a thickness and the transverse displacement of the model: {why}; "
                         "or give amplitudes instead")


def backbone_stage(ctx: RunContext, model: RunModel, modes: RunModes, terms: StepTerms,
                   evals: Evaluations) -> Backbones:
    """The DPIM backbone of every master mode, when the scene has ``[analysis.backbone]``.

    Returns :class:`Backbones`: per master its :class:`~stepnf.dpim.parametrisation.DPIMResult`, its ``backbone``
    block (:func:`stepnf.dpim.backbone_report.backbone_report`), the flags its methods get when refused, and
    its arrays (``backbone_<p>_index``, ``_Y``, ``_c``, ``_omega_p``: the coefficients; ``_amplitude``,
    ``_omega``, ``_w_max_over_h``: the reported curve); the results stage puts them into the records. The
    solves are the run's full-order linear algebra (built here if no evaluator did). ``w_over_h`` without
    a thickness and a transverse
    direction is refused by :func:`backbone_check_stage` before any solve.
    """
    spec, scene = ctx.scene.backbone, ctx.scene
    if spec is None:
        return Backbones()
    state = StageView(ctx, model, modes, terms, evals)
    out: dict[int, BackboneOutput] = {}
    wmax = w_max_measure(state)
    if spec.w_over_h is not None and wmax is None:  # (backbone_check_stage refuses the usual cases earlier)
        raise SceneError(scene.file, "analysis.backbone.w_over_h",
                         "W_max/h needs a thickness and the transverse displacement of the model: "
                         + (state.no_gamma or "the master mode has no transverse displacement")
                         + "; or give amplitudes instead")
    length, forces = model.length, model.forces
    probe = step_amplitude(np.ones(1), state.policy, length)  # STEP's target length (peak 1)
    per_mode = sum(planned_evaluations(spec.order))
    records = {rec.index: rec for rec in evals.modes}
    plans = resolve_manifolds(state, spec)  # [analysis.backbone] manifolds: checked before any solve
    member = {q: plan for plan in plans for q in plan.modes}
    made: dict[tuple[int, ...], tuple] = {}
    more = f", {len(plans)} manifold(s) of several modes" if plans else ""  # (their count: in the counts)
    with state.progress.stage("backbone", f"DPIM backbone to order {spec.order}: up to {per_mode} force "
                                          f"evaluations per master mode{more}"):
        odd = second_slot(state) if KEEP_FACTORISATIONS_UP_TO < state.n <= TWO_SLOTS_UP_TO else None
        try:
            for p in state.masters:
                if p in member:  # the backbone of its manifold of several modes (stepnf.pipeline.manifolds)
                    out[p] = manifold_backbone(state, member[p], made, p, forces, probe, wmax, records.get(p))
                    continue
                try:
                    res = master_dpim(state, p, spec.order, forces, probe, odd)
                except NoSingleModeManifold as exc:  # the T table and the block say so; the run goes on
                    refused = refused_backbone(records.get(p), spec, probe, exc)
                    if refused is not None:
                        out[p] = refused
                    continue
                except BACKBONE_FAILURES as exc:  # the T table and the results are kept; the run exits 3
                    state.progress.message(f"backbone of master mode {p} failed: {exc}")
                    out[p] = failed_backbone(spec, probe, exc)
                    continue
                fallback = step_amplitude(state.phi[:, p], state.policy, length, translation_mask(state.dirs),
                                          rotation_mask(state.dirs))  # the master's STEP amplitude
                block = backbone_report(res, spec, wmax, probe=probe, fallback=fallback)
                block = force_accuracy(block, records.get(p), state.policy.tolerance)
                out[p] = kept_backbone(p, res, no_manifold(block, records.get(p)))
        finally:
            if odd is not None:
                odd.close()
    return Backbones(out)


def manifold_backbone(state: StageView, plan: ManifoldPlan, made: dict, p: int, forces: ForceEvaluator, probe: float,
                      wmax: WMax | None, record) -> BackboneOutput:
    """Master ``p``'s backbone on the manifold of ``plan``, parametrised once for all its masters (``made``:
    modes -> (manifold or the failure, the master its arrays are stored with)); a failure as
    :func:`failed_backbone` for every master of that manifold."""
    spec = state.scene.backbone
    if plan.modes not in made:
        try:
            man = parametrise(state, plan, spec, PlannedForces(chunked(forces, state.n), plan_name(plan)), probe)
            state.progress.message(manifold_text(plan, man))
        except BACKBONE_FAILURES as exc:
            man = exc
        made[plan.modes] = (man, p)
    man, stored_with = made[plan.modes]
    try:
        if isinstance(man, BaseException):
            raise man
        fallback = step_amplitude(state.phi[:, p], state.policy, state.model.length, translation_mask(state.dirs),
                                  rotation_mask(state.dirs))
        bo = master_output(state, man, plan, p, spec, wmax, probe, fallback, stored_with)
    except BACKBONE_FAILURES as exc:
        state.progress.message(f"backbone of master mode {p} on the manifold of modes {list(plan.modes)} failed: {exc}")
        return failed_backbone(spec, probe, exc)
    block = no_manifold(force_accuracy(bo.block, record, state.policy.tolerance), record)
    return BackboneOutput(None, block, (), bo.arrays, manifold=man)


def force_accuracy(block: dict, record, tolerance: float) -> dict:
    """``block`` with what STEP's check says of the forces at the probe amplitude (the backbone's probe is
    STEP's amplitude, so its coefficients carry the same force errors).

    The master's methods measured how much T changes between the two STEP amplitudes (``T_error``):
    DNF's T is the backbone's order-3 term, else the steadiest method's is taken. Above the STEP
    tolerance the block gets a ``step_accuracy`` flag; at :data:`stepnf.flags.STEP_UNUSABLE` (100%) or
    more not even T's sign is established (forces at round-off, a model without nonlinearity): no
    amplitude is then called valid (``valid_up_to`` 0, ``valid_reason`` "forces inaccurate").
    """
    methods = getattr(record, "methods", None) or {}
    errors = {name: r.T_error for name, r in methods.items() if r.T_error is not None and np.isfinite(r.T_error)}
    errors.update({name: np.inf for name, r in methods.items() if r.T_error is not None and name not in errors})
    if not errors:
        return block
    name = DNF if DNF in errors else min(errors, key=errors.get)
    err = errors[name]
    if not err > tolerance:
        return block
    flag = new_flag("step_accuracy", mode=None, value=json_float(err),
                    message=f"{name.upper()}'s T changes by {err:.3g} (relative) between the two STEP amplitudes: the "
                            "forces at the probe amplitude carry that error, and so do the backbone's coefficients")
    if err >= STEP_UNUSABLE:
        flag["message"] += ("; the backbone is not established (set [analysis.step] amplitude, or check that "
                            "the model is nonlinear)")
        block.update(valid_up_to=0.0, valid_reason="forces inaccurate")
    block["flags"] = list(block["flags"]) + [flag]
    return block


def no_manifold(block: dict, record) -> dict:
    """``block`` without any validity range (``valid_up_to`` 0, the flag's ``valid_reason``) when a method of
    the master carries a flag that the catalogue (:mod:`stepnf.flags`) says takes it: the master drives a
    degenerate twin or a rigid mode (:mod:`stepnf.nf.manifold_checks`), so the series describes no motion."""
    flags = [f for r in (getattr(record, "methods", None) or {}).values() for f in r.flags]
    flag = backbone_invalidating(flags)
    if flag is None:
        return block
    block.update(valid_up_to=0.0, valid_reason=kind_of(flag).backbone_reason)
    block["flags"] = list(block["flags"]) + [flag]
    return block


def refused_backbone(record, spec, probe: float, exc: NoSingleModeManifold) -> BackboneOutput | None:
    """The DPIM of master ``record.index`` refused (:class:`~stepnf.errors.NoSingleModeManifold`: a degenerate
    twin its forces drive, or a harmonic exactly at a mode): a backbone block with no amplitudes and no
    validity range, its flag of ``exc.kind``; when the catalogue says that kind makes T n/a (a driven twin),
    the flag on every method of the master too (``method_flags``). No parametrisation (nothing to plot or
    verify); None without a record."""
    flag = new_flag(exc.kind, mode=exc.mode, **exc.extra, message=str(exc))
    if record is None:
        return None
    kind = kind_of(flag)
    method_flags = (flag,) if kind is not None and kind.t_na == "always" else ()
    reason = kind.backbone_reason if kind is not None and kind.backbone_reason else DIVERGES_REASON
    block = {"order": spec.order, "amplitude": [], "omega": [], "omega_ratio": [], "w_max_over_h": None,
             "valid_up_to": 0.0, "valid_reason": reason, "grid": False,
             "tolerance": spec.tolerance, "probe": json_float(probe), "flags": [flag], "counts": {}}
    return BackboneOutput(None, block, method_flags)


def failed_backbone(spec, probe: float, exc: BaseException) -> BackboneOutput:
    """The DPIM of a master failed (a numerical error, forces the adapter returned unusable:
    :data:`BACKBONE_FAILURES`): a backbone block with ``failed`` true, ``failed_reason`` the error's message,
    a ``backbone_failed`` flag saying it, no amplitudes and no validity range. The master's T and every other master are kept; the
    command exits 3 (:meth:`stepnf.io.results.RunResult.failed_backbones`)."""
    reason = " ".join(str(exc).split()) or type(exc).__name__  # one line (an adapter's error may quote a log)
    flag = new_flag("backbone_failed", mode=None,
                    message=f"the backbone was not computed: {reason} (T and the rest of the run are not affected)")
    block = {"order": spec.order, "amplitude": [], "omega": [], "omega_ratio": [], "w_max_over_h": None,
             "valid_up_to": 0.0, "valid_reason": BACKBONE_FAILED_REASON, "grid": False,
             "tolerance": spec.tolerance, "probe": json_float(probe), "flags": [flag], "counts": {},
             "failed": True, "failed_reason": reason}
    return BackboneOutput(None, block, ())


def kept_backbone(p: int, res: DPIMResult, block: dict) -> BackboneOutput:
    """Master ``p``'s parametrisation, its backbone block and its HDF5 arrays (``backbone_<p>_*``: the
    coefficients, then the reported curve)."""
    arrays = res.arrays()
    out = {f"backbone_{p}_{key}": arrays[key] for key in ("index", "Y", "c")}
    out[f"backbone_{p}_omega_p"] = arrays["omega"]
    for key in ("amplitude", "omega", "w_max_over_h"):
        if block[key] is not None:
            out[f"backbone_{p}_{key}"] = np.asarray([np.nan if v is None else float(v) for v in block[key]])
    return BackboneOutput(res, block, (), out)
