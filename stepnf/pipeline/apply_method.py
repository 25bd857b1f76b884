"""One method (NF, DNF, MD, SMD; modal or full order) applied to one master mode."""
from __future__ import annotations

import numpy as np

from stepnf.nf.coefficient import MethodResult
from stepnf.nf.diagnostics import captured_share, floor_scale, merge_flags, one_two_flags, t_error, truncation_flags
from stepnf.flags import new_flag
from stepnf.nf.evaluators import (Rounding, Tolerances, dnf, dnf_uses_factorisation, md_full, resonance_flags,
                                   retained_set, smd_full)
from stepnf.methods import DNF, MD, MD_FULL, MODAL_EVALUATORS, SMD_FULL, method
from stepnf.nf.linearised import Spectrum
from stepnf.nf.roundoff import roundoff_message, with_modal_eigen_part
from stepnf.pipeline.context import full_order_context
from stepnf.pipeline.master import MasterData
from stepnf.pipeline.state import StageView
from stepnf.pipeline.slender_dnf import raised_dnf
from stepnf.step.procedure import MasterStep


def modal_method(name: str, p: int, omega: np.ndarray, g: np.ndarray, h: float, S: np.ndarray, tol: Tolerances,
                 labels: list, floor: np.ndarray | float | None = None) -> MethodResult:
    """The modal evaluator ``name`` ("nf", "md_modal" or "smd_modal": :data:`~stepnf.methods.MODAL_EVALUATORS`)
    of master ``p`` over modes ``S``."""
    if name not in MODAL_EVALUATORS:
        raise KeyError(name)
    return method(name).function()(p, omega, g, h, S, tol=tol, labels=labels, floor=floor)


def run_modal(state: StageView, d: MasterData, ev: str) -> MethodResult:
    """A modal evaluator over the retained set, with T again at the check amplitude, the master's own
    eigenvalue error through T (:func:`~stepnf.nf.roundoff.with_modal_eigen_part`) and truncation flags."""
    S = retained_set(d.p, state.n_ret, state.m)
    r = modal_method(ev, d.p, state.omega, d.g_mod, d.h_mod, S, state.tol, state.labels, d.floor)
    if d.g_chk is not None:
        r2 = modal_method(ev, d.p, state.omega, d.g_chk, d.h_chk, S, state.tol, state.labels, d.floor)
        r.T_error = t_error(r.T, r2.T)
    r = with_modal_eigen_part(r, lambda om: modal_method(ev, d.p, om, d.g_mod, d.h_mod, S, state.tol, state.labels,
                                                         d.floor).T, state.omega, d.p, state.K, d.phi)
    frac = captured_share(d.p, d.st, state.full, d.g_all, S, state.M)
    if frac is not None:
        r.flags += truncation_flags(r, frac, len(S))
    return r


def run_dnf(state: StageView, d: MasterData) -> MethodResult:
    """Direct normal form on the whole mesh, flagged for 1:2 resonances; keeps ``y = K^+ Gv`` in ``d.y``
    (given there already: not solved again)."""
    p, st, omega = d.p, d.st, state.omega
    dG, dh = check_differences(st)
    r, d.y = dnf(p, d.phi, omega[p], st.Gv, st.h, full_order_context(state), dGv=dG, dh=dh, y=d.y, z=d.z,
                 rounding=rounding_of(state, st))

    def rerun(st2: MasterStep) -> tuple[MethodResult, np.ndarray]:  # DNF from another amplitude: fresh solves
        dG2, dh2 = check_differences(st2)
        return dnf(p, d.phi, omega[p], st2.Gv, st2.h, full_order_context(state), dGv=dG2, dh=dh2,
                   rounding=rounding_of(state, st2))

    r = raised_dnf(state, d, r, rerun)
    r.flags = merge_flags(r.flags, one_two_flags(p, omega[p], st, state.basis, full_order_context(state),
                                                 floor_scale(st, state.M, state.tol), state.tol, state.adapter,
                                                 state.counters))
    return r


def factorises(state: StageView, d: MasterData, ev: str) -> bool:
    """True when evaluator ``ev`` of master ``d.p`` needs a new factorisation: DNF with ``4 w_p^2``
    outside what the computed spectrum can solve (:func:`~stepnf.nf.evaluators.dnf_uses_factorisation`)."""
    return method(ev).shift_above_master and dnf_uses_factorisation(state.omega[d.p], full_order_context(state))


def computed_spectrum(state: StageView) -> Spectrum:
    """The computed modes ``[R, Phi]``, their ``w^2`` (rigid: 0) and ``M [R, Phi]``, for the linearised
    ``T_error``: the deflated solver's own arrays when it runs (no new product), else computed here."""
    defl = full_order_context(state).deflated
    if defl is not None:
        return Spectrum(defl.Psi, defl.lam, defl.MPsi)
    R = state.basis.rigid
    modes = np.column_stack([R, state.phi]) if R.shape[1] else state.phi
    return Spectrum(modes, np.concatenate([np.zeros(R.shape[1]), state.omega**2]), state.M @ modes)


def check_differences(st) -> tuple[np.ndarray | None, float]:
    """``(Gv - Gv_check, h - h_check)`` of a targeted STEP, ``(None, 0)`` without a check amplitude."""
    if st.Gv_check is None:
        return None, 0.0
    return st.Gv - st.Gv_check, st.h - st.h_check


def run_smd_full(state: StageView, d: MasterData) -> MethodResult:
    """Static modal derivatives at full order (reusing DNF's K^+ solve when DNF ran first).

    ``T_error`` is the first-order change of T between the STEP amplitudes (no solve at the check amplitude).
    """
    p, st, omega = d.p, d.st, state.omega
    dG, dh = check_differences(st)
    return smd_full(p, d.phi, omega[p], st.Gv, st.h, full_order_context(state), y=d.y, dGv=dG, dh=dh,
                    spectrum=computed_spectrum(state) if dG is not None else None, rounding=rounding_of(state, st))


def rounding_of(state: StageView, st: MasterStep) -> Rounding | None:
    """What the full-order evaluators need to bound T's rounding (:mod:`stepnf.nf.roundoff`) for STEP ``st``;
    None for STEP from tangent stiffnesses (``[analysis.step] method = "tangent"``: the bound models forces)."""
    if state.policy.method == "tangent":
        return None
    return Rounding(st.q, st.Hv, getattr(state.adapter, "force_digits", None), st.rounding_excess)


def run_md_full(state: StageView, d: MasterData) -> MethodResult:
    """Modal derivatives at full order (bordered solves), the master's twins excluded, resonances flagged.

    ``T_error`` is the first-order change of T between the STEP amplitudes (no solve at the check amplitude).
    """
    p, st, omega, twins = d.p, d.st, state.omega, d.twins
    tw = state.phi[:, twins] if twins else None
    nr = state.basis.rigid.shape[1]
    dG, dh = check_differences(st)
    r = md_full(p, d.phi, omega[p], st.Gv, st.h, full_order_context(state), tw, g=d.g_all, tol=state.tol,
                floor=d.floor, exclude=[nr + p] + [nr + t for t in twins], twin_index=twins, labels=state.labels,
                dGv=dG, dh=dh, spectrum=computed_spectrum(state) if dG is not None else None, theta=d.theta,
                rounding=rounding_of(state, st))
    r.flags += resonance_flags(MD, p, omega, d.g_all, [s for s in range(state.m) if s not in twins], 1.0,
                               state.tol, state.labels, d.floor)
    return r


#: How the pipeline runs each full-order evaluator (:data:`~stepnf.methods.FULL_EVALUATORS`).
FULL_RUNS = {DNF: run_dnf, SMD_FULL: run_smd_full, MD_FULL: run_md_full}


def run_method(state: StageView, d: MasterData, name: str, ev: str) -> MethodResult:
    """Method ``name`` (evaluator ``ev``) of master ``d.p``, named, with its STEP-accuracy flag and Gamma."""
    r = run_modal(state, d, ev) if ev in MODAL_EVALUATORS else FULL_RUNS[ev](state, d)
    r.method = name
    if ev in MODAL_EVALUATORS:
        r.retained_modes = len(retained_set(d.p, state.n_ret, state.m))
    tolerance = state.policy.tolerance
    extra = r.extra if isinstance(r.extra, dict) else {}
    change = extra.get("T_change", r.T_error)  # DNF keeps the change apart from its rounding bound
    if change is not None and change > tolerance:
        r.flags.append(new_flag("step_accuracy", value=float(change),
                                message=f"T changes by {change:.2e} (relative) between the two "
                                        f"STEP amplitudes; tolerance {tolerance:.1e}"))
    roundoff = extra.get("roundoff")
    if roundoff is not None and roundoff > tolerance:
        r.flags.append(new_flag("t_roundoff", value=float(roundoff),
                                message=roundoff_message(d.p, r.T, extra, tolerance)))
    if state.gscale is not None:
        r.gamma = state.gscale.gamma(r.T, d.w_max)
    return r
