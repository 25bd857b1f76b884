"""DNF of a master whose T's terms cancel (slender structures): a raised STEP, then STEP along the manifold.

The rounding a black-box force carries limits T through the cancellation of its terms
(:mod:`stepnf.nf.roundoff`: the bound ``roundoff``, falling as ``1 / q^2`` with the STEP amplitude
``q``). When it exceeds the STEP tolerance:

1. if the scene leaves the amplitude to stepnf (neither ``[analysis.step] amplitude`` nor
   ``relative_amplitude``), STEP is done once more at ``k q``, ``k = sqrt(roundoff / tolerance)``, at most
   :data:`MAX_FACTOR` and at most the amplitude that moves a dof by :data:`MAX_EXTENT` of the model's size
   (a St Venant-Kirchhoff solid's force is an exact cubic: nothing is lost at a larger amplitude, and the
   new STEP's two amplitudes say so for a force that is not); a ``step_amplitude_raised`` flag;
2. if the bound still exceeds the tolerance, STEP along the quadratic manifold
   (:mod:`stepnf.step.manifold_probe`, at the raised amplitude, with the raised STEP's ``y`` and ``B``),
   which measures the condensed cubic term directly; a ``manifold_probe`` flag. Its error adds to the
   probe's own what the errors of ``y`` and ``B`` cost (:func:`input_errors`: DNF again from the STEP's
   check amplitude, whose ``G`` carries twice the rounding; without one, a solve of the rounding).

Not with ``[analysis.step] method = "tangent"`` (its G and h are not the forces' this module bounds),
and no raise with ``check = false`` (a raised amplitude needs its second amplitude to show a force that is
not an exact cubic).

The result with the smallest ``T_error`` is kept. Measured on cantilever strips against the inextensible
theory (bench/cantilever.py): the first bending mode at L/h = 300 from a wrong sign (STEP at 0.5 h) to
1%, at L/h = 1000 to 2.4%; CalculiX's 7-digit forces: the second mode at L/h = 300 from 15% to 0.1%.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from stepnf.flags import new_flag
from stepnf.nf.coefficient import MethodResult
from stepnf.nf.condensed import dnf_condensed
from stepnf.nf.roundoff import step_rounding
from stepnf.linalg.null_space import abs_product
from stepnf.pipeline.master import MasterData
from stepnf.pipeline.state import StageView
from stepnf.step.manifold_probe import FRACTIONS, manifold_probe
from stepnf.step.procedure import MasterStep, targeted_steps
from stepnf.plugin.dofs import bounded_scale, rotation_mask, translation_mask

#: largest factor by which an automatic STEP amplitude is raised
MAX_FACTOR = 200.0
#: a raised STEP field moves no dof by more than this fraction of the model's size (bounding-box diagonal)
MAX_EXTENT = 0.1
#: DNF from another STEP: ``rerun(st) -> (result, y)`` (fresh solves)
Rerun = Callable[[MasterStep], tuple[MethodResult, np.ndarray]]


def raise_factor(roundoff: float, tolerance: float, q: float, phi: np.ndarray, X: np.ndarray | None,
                 D: np.ndarray | None = None) -> float:
    """The factor of the STEP amplitude that brings ``roundoff`` (relative, falling as ``1 / q^2``) to
    ``tolerance``, within :data:`MAX_FACTOR` and :data:`MAX_EXTENT` (of the translations, dof directions
    ``D``), and keeping the largest rotation (a shell's) within :data:`~stepnf.plugin.dofs.MAX_ROTATION`
    (:func:`~stepnf.plugin.dofs.bounded_scale`);
    1 when nothing is gained (< 2)."""
    if not np.isfinite(roundoff):
        k = MAX_FACTOR
    elif roundoff > tolerance > 0:
        k = min(float(np.sqrt(roundoff / tolerance)), MAX_FACTOR)
    else:
        return 1.0
    size = float(np.linalg.norm(np.ptp(np.asarray(X, dtype=float), axis=0))) if X is not None and len(X) else 0.0
    k = min(k, bounded_scale(q * phi, MAX_EXTENT * size if size > 0 else np.inf, translation_mask(D),
                             rotation_mask(D)))
    return k if k >= 2.0 else 1.0


def may_raise(state: StageView) -> bool:
    """Whether the STEP amplitude may be raised: the scene leaves it to stepnf (no ``amplitude``, no
    ``relative_amplitude``) and keeps the check amplitude."""
    step = state.scene.step
    return step.amplitude is None and step.relative_amplitude is None and state.policy.check


def raised_dnf(state: StageView, d: MasterData, r: MethodResult, rerun: Rerun) -> MethodResult:
    """``r`` (master ``d.p``'s DNF), or DNF at a raised STEP amplitude, or DNF along the quadratic manifold
    (module docstring), whichever has the smallest ``T_error``. The one kept carries
    ``extra["step_amplitude"]`` (modal) and the flags of what was done."""
    roundoff = amplitude_part(r, r.extra.get("roundoff")) if isinstance(r.extra, dict) else None
    st, policy = d.st, state.policy
    if (roundoff is None or st is None or state.model.forces is None or policy.method == "tangent"
            or not roundoff > policy.tolerance):
        return r
    k = raise_factor(float(roundoff), policy.tolerance, st.q, d.phi, state.X, state.dirs) if may_raise(state) else 1.0
    if k <= 1.0:  # an amplitude the scene fixed (or nothing to gain): the manifold at that amplitude
        r.extra["step_amplitude"] = float(st.q)
        return probed_dnf(state, d, r, d.y, st, r, rerun)
    with state.progress.stage("step_raise", f"STEP again for mode {d.p} at {k:.3g} x the amplitude "
                                            f"(rounding leaves T about {min(roundoff, 99.0):.1e} relative)"):
        st2 = targeted_steps(state.model.forces, state.K, d.phi[:, None], np.array([k * st.q]), policy, [d.p],
                             plan=f"raised{d.p}", digits=getattr(state.adapter, "force_digits", None))[0]
    r2, y2 = rerun(st2)
    e1 = r.T_error if r.T_error is not None else np.inf
    e2 = r2.T_error if r2.T_error is not None else np.inf
    best = r2 if e2 < e1 else r
    r.extra["step_amplitude"], r2.extra["step_amplitude"] = float(st.q), float(st2.q)
    flag = new_flag(
        "step_amplitude_raised", value=float(k),
        message=f"rounding left T an error of up to {roundoff:.1e} (relative) at the STEP amplitude {st.q:.3e}: "
                f"STEP again at {st2.q:.3e} ({k:.3g} x) gives {r2.T:+.6e} (error up to {e2:.1e})")
    for res in {id(best): best, id(r2): r2}.values():
        res.flags.append(dict(flag))
    if min(amplitude_part(r, e1), amplitude_part(r2, e2)) <= policy.tolerance:
        return best
    return probed_dnf(state, d, r2, y2, st2, best, rerun)  # y and B of the raised STEP: its Gv has more digits


def amplitude_part(r: MethodResult, err: float | None) -> float | None:
    """``err`` (a relative bound of ``r.T``) without the part of the master's own eigenvalue error
    (``extra["roundoff_dT_lambda"]``, :func:`stepnf.nf.roundoff.eigenvalue_part`): what a larger STEP
    amplitude or the manifold can reduce."""
    if err is None or not np.isfinite(err) or r.T == 0 or not np.isfinite(r.T):
        return err
    return max(float(err) - float(r.extra.get("roundoff_dT_lambda", 0.0)) / abs(r.T), 0.0)


def probed_dnf(state: StageView, d: MasterData, r: MethodResult, y: np.ndarray, st: MasterStep,
               best: MethodResult, rerun: Rerun) -> MethodResult:
    """DNF of master ``d.p`` from STEP along the quadratic manifold (:mod:`stepnf.step.manifold_probe`) at
    the amplitude ``st.q`` (modal), from ``r``'s ``y = K^+ G(phi, phi)`` and ``B`` (DNF from the STEP ``st``);
    returned when its ``T_error`` is smaller than ``best``'s (else ``best``), with a ``manifold_probe`` flag
    either way."""
    s, digits = st.q, getattr(state.adapter, "force_digits", None)
    with state.progress.stage("step_manifold", f"STEP along the quadratic manifold for mode {d.p} "
                                               f"({2 * len(FRACTIONS)} force evaluations)"):
        pr = manifold_probe(state.model.forces, d.phi, y, s, digits, plan=f"manifold{d.p}")
    dh_y, dB = input_errors(state, d, st, r, y, pr.h_s, digits, rerun)
    r2 = dnf_condensed(state.omega[d.p], pr.h_s, pr.dh_s + dh_y, r, dB=dB)
    r2.extra.update(probe_amplitude=pr.s, probe_standard_error=pr.standard_error, probe_dh_s_forces=pr.dh_s,
                    probe_dh_s_y=dh_y)
    e1 = best.T_error if best.T_error is not None else np.inf
    keep = r2 if r2.T_error < e1 else best
    keep.flags.append(new_flag(
        "manifold_probe", value=float(r2.T_error),
        message=f"STEP along the quadratic manifold (u = s phi - s^2 K^+G, s = {s:.3e}): T = {r2.T:+.6e}, error "
                f"{r2.T_error:.1e} (relative), against {best.T:+.6e} ({e1:.1e}) from the STEP at +-q phi; kept: "
                f"the {'manifold' if keep is r2 else 'STEP'}'s T"))
    return keep


def input_errors(state: StageView, d: MasterData, st: MasterStep, r: MethodResult, y: np.ndarray, h_s: float,
                 digits: int | None, rerun: Rerun) -> tuple[float, float]:
    """What the errors of ``y`` and ``B`` (from the STEP ``st``, DNF ``r``: ``y = K^+ G(phi, phi)`` of it) cost
    the probe: ``(dh_s, dB)``,
    absolute. The probe is stationary in ``y`` (``2 e^T K e``, ``e`` the error of ``y``); ``B = 4 y^T M z``
    is not. Measured with a check amplitude: DNF and the probe again from its ``G``, which carries twice
    the rounding (so the differences are about three times the errors sought). Without one: ``e = K^+ r``
    for the rounding ``r`` of ``G`` (:mod:`stepnf.nf.roundoff`: the solver's own and the printed, with
    random signs from a fixed seed), ``dh_s = 5 * 2 e^T K e``, ``dB = 5 * 8 |e|^T |M| |y|``."""
    B = float(r.extra["B"])
    if st.Gv_check is not None:
        chk = MasterStep(p=st.p, q=float(st.q_check), Gv=st.Gv_check, h=float(st.h_check), Hv=st.Hv_check)
        r_chk, y_chk = rerun(chk)
        with state.progress.stage("step_manifold_check", f"STEP along the quadratic manifold for mode {d.p}, "
                                                         "y from the check amplitude"):
            again = manifold_probe(state.model.forces, d.phi, y_chk, st.q, digits,
                                   plan=f"manifold{d.p}c")
        return abs(again.h_s - h_s), abs(float(r_chk.extra["B"]) - B)
    from stepnf.pipeline.context import full_order_context

    K, phi, q = state.K, d.phi, st.q
    own, printed = step_rounding(abs_product(K, np.abs(phi))[:, 0], K, phi, q, st.Gv, None, digits)
    noise = np.random.default_rng(0).choice((-1.0, 1.0), size=len(phi)) * (own + printed) / q ** 2
    e = full_order_context(state).Kpinv(noise)
    return 5.0 * 2.0 * abs(float(noise @ e)), 5.0 * 8.0 * float(np.abs(e) @ abs_product(state.M, np.abs(y))[:, 0])
