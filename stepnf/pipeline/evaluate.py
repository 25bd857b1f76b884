"""Stage ``evaluators``: every method of every master mode, with its diagnostics.

The deflated solves of all masters run first, together (:mod:`stepnf.pipeline.prefetch`).

Memory: the solves that need a new factorisation (DNF's ``K - 4 w_p^2 M`` of a master whose
``2 w_p`` lies above what the computed spectrum solves) run after every other method of every
master. The other full-order solves are preconditioned by the eigen-solver's factorisation; once
they are done, and when no later stage solves with it (no ``[analysis.backbone]``), that
factorisation is freed before the new one is made, so the two never live together (at a million
dofs each holds ~6 GB).
"""
from __future__ import annotations

import numpy as np

from stepnf.nf.diagnostics import overflow_is_numerical, unresolved_flags
from stepnf.nf.gamma import gamma_scale
from stepnf.nf.manifold_checks import rigid_flags, twin_flags
from stepnf.pipeline.context import full_order_context
from stepnf.pipeline.master import MasterData, master_data, mode_record
from stepnf.pipeline.apply_method import factorises, run_method
from stepnf.pipeline.conservative import non_conservative_flags
from stepnf.pipeline.prefetch import prefetch_deflated
from stepnf.io.results import ModeResult
from stepnf.pipeline.outputs import Evaluations, RunContext, RunModel, RunModes, StepTerms
from stepnf.pipeline.state import StageView


def evaluators_stage(ctx: RunContext, model: RunModel, modes: RunModes, terms: StepTerms) -> Evaluations:
    """Evaluate the scene's methods for each master mode, in the scene's order (results too).

    Returns :class:`Evaluations`: the shell scales (or None), how Gamma is scaled (``gscale``) or why it
    is not (``no_gamma``), one :class:`~stepnf.io.results.ModeResult` per master and ``Gv`` (master ->
    G(phi_p, phi_p), empty without a targeted STEP); a full-order method builds the run's linear algebra
    (``ctx.solvers``). A floating-point overflow becomes a :class:`~stepnf.errors.NumericalError` naming
    the master and the method.
    The methods that factorise run last (module docstring); their place in each mode's results is kept.
    Last, every method of a master that has no single-mode manifold (a driven degenerate twin or rigid
    mode: :func:`manifold_flags`) gets its flag, which makes T n/a in the table (:mod:`stepnf.flags`); a model
    with rotation dofs, eight forces per master more: whether its force is a gradient
    (:func:`stepnf.pipeline.conservative.non_conservative_flags`).
    """
    adapter = model.adapter
    scales = adapter.shell_scales()
    gscale, no_gamma = gamma_scale(ctx.scene, adapter, model.X, model.dirs)
    state = StageView(ctx, model, modes, terms, Evaluations([], scales, gscale, no_gamma))
    records_in_order: list[ModeResult] = []
    Gv: dict[int, np.ndarray] = {}
    where = {"stage": "evaluators"}
    deferred: list[tuple[MasterData, str, str]] = []
    with overflow_is_numerical(where, terms.steps), \
            ctx.progress.stage("evaluators", "normal form and modal derivatives"):
        datas = []
        for p in modes.masters:
            where.update(master=int(p), method="(diagnostics)")
            datas.append(master_data(state, p))
        where.pop("master", None)
        where.update(method="(deflated solves of every master)")
        prefetch_deflated(state, datas)
        for d in datas:
            p = d.p
            where.pop("method", None)
            where.update(master=int(p), method="(diagnostics)")
            rec = mode_record(state, d)
            for name, ev in ctx.methods.items():
                where.update(master=int(p), method=name)
                if factorises(state, d, ev):
                    if d.y is None:
                        d.y = full_order_context(state).Kpinv(d.st.Gv)  # K^+ Gv now: SMD reuses it
                    rec.methods[name] = None  # its place in the results, filled below
                    deferred.append((d, name, ev))
                    continue
                rec.methods[name] = run_method(state, d, name, ev)
            records_in_order.append(rec)
            Gv[p] = d.st.Gv if d.st is not None else np.zeros(0)
        if deferred:
            free_eigen_factorisation(state)
        records = {rec.index: rec for rec in records_in_order}
        for d, name, ev in deferred:
            where.update(master=int(d.p), method=name)
            records[d.p].methods[name] = run_method(state, d, name, ev)
        for d in datas:
            where.update(master=int(d.p), method="(single-mode manifold)")
            flags = manifold_flags(state, d)
            for r in records[d.p].methods.values():
                r.flags += [dict(f) for f in flags]
            where.update(method="(potential check)")
            records[d.p].flags += non_conservative_flags(state, d)  # a shell's force that is not a gradient
    return Evaluations(records_in_order, scales, gscale, no_gamma, Gv)


def manifold_flags(state: StageView, d: MasterData) -> list[dict]:
    """Flags of master ``d.p`` that no single-mode reduction exists for (:mod:`stepnf.nf.manifold_checks`): a
    degenerate twin its cubic force drives, a rigid mode its quadratic force drives. Every method of the
    master gets them (T n/a in the table, no validity range for the backbone)."""
    return (twin_flags(d.p, d.st, state.phi, d.twins, state.M, state.tol, state.labels)
            + rigid_flags(d.p, d.st, state.basis.rigid, state.M, state.tol,
                          declared=state.scene.rigid_modes is not None)
            + unresolved_flags(d.p, state.modes.flags))  # its eigenvalue beyond reach (stage modes)


def free_eigen_factorisation(state: StageView) -> None:
    """Free the eigen-solver's factorisation when no later stage solves with it (no backbone).

    It preconditions the deflated solves (:func:`~stepnf.pipeline.context.deflation_preconditioner`);
    a solve after this raises ``RuntimeError`` (never wrong numbers)."""
    fac = state.basis.factorization
    if fac is not None and state.scene.backbone is None:
        fac.release()
