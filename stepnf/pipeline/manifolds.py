"""The backbone stage's masters on manifolds of several modes (``[analysis.backbone] manifolds``, issue 33).

:func:`resolve_manifolds` turns the scene's sets (indices or labels, as ``master_modes``) or ``"auto"`` into
:class:`ManifoldPlan` s of computed modes: with ``"auto"`` each master's set is the master and the modes the
single-mode DPIM flags near 1:1..1:4 of it (:func:`stepnf.dpim.parametrisation.resonance_flags`, the same
flags, the same tolerance), overlapping sets merged when they share a ratio vector (:func:`auto_plans`), and the
plan says which modes and why. Each manifold is
parametrised once (:func:`stepnf.dpim.multimode.manifold.parametrise_manifold`, forces through the run's
evaluator and checkpoint, plans ``backbone_m<modes>_<k>``; its own shifted factorisations, freed when done)
and shared by its masters; each master gets the branches that start at its linear mode
(:func:`stepnf.dpim.multimode.backbone.backbone_branches`) and the block of
:func:`stepnf.dpim.manifold_report.manifold_report`. HDF5 arrays (``arrays/``, as the single-mode
``backbone_<p>_*``): the manifold's coefficients once, ``backbone_<p>_manifold_*`` under its first master
(the others' blocks name it in ``manifold.stored_with``), and every master's branches,
``backbone_<p>_branch<i>_*`` (i = 0 the continuing branch, then the coupled ones).
"""
from __future__ import annotations

import copy
import warnings
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from stepnf.dpim.manifold_report import manifold_report, trace_top
from stepnf.dpim.multimode.backbone import backbone_branches
from stepnf.dpim.multimode.manifold import MAX_RATIO, ManifoldResult, find_ratios, parametrise_manifold
from stepnf.dpim.parametrisation import DPIM, DPIMTolerances, ModeSpectrum, resonance_flags
from stepnf.dpim.solves import Solvers
from stepnf.errors import ModelWarning, NumericalError, SceneError
from stepnf.keys.manifolds import MAX_MODES
from stepnf.pipeline.outputs import BackboneOutput
from stepnf.pipeline.plan import resolve_masters
from stepnf.pipeline.state import StageView
from stepnf.plugin.dofs import rotation_mask

KEY = "analysis.backbone.manifolds"
#: A manifold's forcing is sampled at many more fields than a single mode's (near 1:4, 5 dofs, order 15: 476544
#: against 2336), so its checkpoint chunks hold up to this many bytes of fields (at least the run's chunk): on that
#: system the run's 64-field chunks cost 7447 checkpoint writes, 20 of the stage's 43 s (fsync); on a model of
#: 131k dofs or more a chunk stays the run's.
CHUNK_BYTES = 8 * 2 ** 20
#: Models up to this many dofs keep every shifted factorisation of a manifold to the end of its run (as the
#: single-mode backbone, :data:`stepnf.pipeline.backbone.KEEP_FACTORISATIONS_UP_TO`); larger ones keep the
#: :data:`LIVE_FACTORISATIONS` most recently used: a two-mode manifold of the 38k-dof cap meets ~30 shifts by
#: order 5 (~220 MB each), and keeping them all ran this 24 GB machine out of memory.
KEEP_ALL_FACTORISATIONS_UP_TO = 5000
LIVE_FACTORISATIONS = 2


def chunked(forces: Any, n: int) -> Any:
    """The run's force evaluator with chunks of up to :data:`CHUNK_BYTES` (a copy: the run's keeps its own)."""
    out = copy.copy(forces)
    out.batch_size = max(int(forces.batch_size), CHUNK_BYTES // (8 * max(int(n), 1)))
    return out


@dataclass(frozen=True)
class ManifoldPlan:
    """One manifold: its ``modes`` (indices among the computed elastic modes, ascending), ``ratios`` (None:
    found from the frequencies), ``index`` its position in the scene's list (None: chosen by "auto"),
    ``chosen`` ("explicit" or "auto") and ``why``."""

    modes: tuple[int, ...]
    ratios: tuple[int, ...] | None
    index: int | None
    chosen: str
    why: str


def _resolve_set(scene: Any, labels: list, n: int, i: int, group: tuple) -> list[int]:
    """The modes (of ``n`` with ``labels``) a scene's set names (a SceneError naming ``manifolds[i][j]`` otherwise)."""
    out = []
    for j, entry in enumerate(group):
        try:
            [s] = resolve_masters(_with_masters(scene, [entry]), labels, n, complete=True)
        except SceneError as exc:
            raise SceneError(scene.file, f"{KEY}[{i}][{j}]", exc.message.replace(
                "give a 0-based mode index", "give a 0-based mode index in the manifold")) from None
        out.append(int(s))
    return out


def _with_masters(scene: Any, masters: list) -> Any:
    return replace(scene, master_modes=masters)


def explicit_plans(state: StageView, spec: Any, tol: float) -> list[ManifoldPlan]:
    """The scene's sets resolved among the computed modes (:func:`explicit_sets`), each in resonance
    (:func:`check_resonant`)."""
    plans = explicit_sets(state.scene, state.labels, state.basis.n_elastic, list(state.masters), spec)
    for plan in plans:
        check_resonant(state.scene, plan, state.omega, tol, int(spec.order), state.labels)
    return plans


def check_resonant(scene: Any, plan: ManifoldPlan, omega: Any, tol: float, order: int, labels: list) -> None:
    """SceneError unless the modes of an explicit set without ``ratios`` share a resonance the reduced dynamics can
    hold: integers ``k`` with ``|k_0 w_j / w_0 - k_j| <= tol k_j`` (:func:`~stepnf.dpim.multimode.manifold.find_ratios`)
    and ``max k <= order`` (a resonance of higher ratio has no resonant monomial up to the order). Without one
    the manifold keeps no coupling: its branches would be the single-mode backbones at many times their cost, or
    a mode's own near-resonance with the master's harmonics at a ratio the branches cannot follow."""
    if plan.ratios is not None:  # given: parametrise_manifold checks them against the frequencies
        return
    w = np.asarray(omega, dtype=float)[list(plan.modes)]
    k = find_ratios(w, tol, order)
    if k is not None and int(k.max()) <= order:
        return
    base = plan.modes[0]
    named = ", ".join(f"{q} {labels[q]}" if labels and q < len(labels) and labels[q] is not None else str(q)
                      for q in plan.modes)
    rel = ", ".join(f"{x:.4g}" for x in w / w[0])
    raise SceneError(scene.file, f"{KEY}[{plan.index}]",
                     f"the modes {named} are in no internal resonance within the resonance tolerance {tol:g}: "
                     f"their frequencies are {rel} times mode {base}'s, and no integers k (1 <= k_j <= order "
                     f"{order}) give |k_0 w_j / w_{base} - k_j| <= {tol:g} k_j. A manifold of them keeps no coupling "
                     "(its backbones would be the single-mode ones): name only modes near 1:1 .. 1:"
                     f"{min(order, MAX_RATIO)} of a master (the run's resonance flags list them; manifolds = \"auto\" "
                     "chooses them), or widen [analysis.backbone] resonance")


def explicit_sets(scene: Any, labels: list, n: int, masters: list[int], spec: Any) -> list[ManifoldPlan]:
    """The scene's sets resolved among ``n`` modes of ``labels`` (unknown mode, a mode named twice, a set holding
    none of ``masters``: SceneError)."""
    plans, owner = [], {}
    for i, group in enumerate(spec.manifolds):
        modes = _resolve_set(scene, labels, n, i, group)
        for j, s in enumerate(modes):
            if s in owner:
                raise SceneError(scene.file, f"{KEY}[{i}][{j}]",
                                 f"{group[j]!r} is mode {s}, already in manifold {owner[s]} ({KEY}[{owner[s]}]): a "
                                 "mode belongs to one manifold at most")
            owner[s] = i
        if not set(modes) & set(masters):
            raise SceneError(scene.file, f"{KEY}[{i}]", f"the manifold of modes {modes} holds no master mode "
                             f"(master_modes resolve to {list(masters)}): its backbones would not be reported")
        k = spec.ratios[i] if spec.ratios is not None else None
        order = np.argsort(modes)
        plans.append(ManifoldPlan(tuple(int(modes[o]) for o in order),
                                  None if k is None else tuple(int(k[o]) for o in order), i, "explicit",
                                  f"manifolds[{i}] of the scene"))
    return plans


def auto_plans(state: StageView, spec: Any, tol: float) -> list[ManifoldPlan]:
    """Each master with the modes flagged near 1:h of it (h = 1..:data:`MAX_RATIO`: the resonances whose ratios
    decide the reduced dynamics), the closest first, at most :data:`~stepnf.keys.manifolds.MAX_MODES` modes;
    overlapping sets merged only when the union still has a common ratio vector (integers up to MAX_RATIO) and
    fits MAX_MODES, else the later master keeps the modes no earlier set holds (module docstring). A master with
    no such mode keeps its single-mode backbone (one :class:`~stepnf.errors.ModelWarning` when no master has one:
    "auto" looked and found nothing)."""
    def flags_of(p: int) -> list[dict] | None:
        twin_index = state.basis.twins(p)
        try:
            return resonance_flags(state.K, state.M, float(state.omega[p]), spec.order, state.omega, p,
                                   state.phi[:, twin_index] if twin_index else None, twin_index or None, tol,
                                   state.scene.degeneracy_tolerance)
        except NumericalError:  # an undeclared twin: the single-mode path says so
            return None
    return auto_sets(list(state.masters), np.asarray(state.omega, dtype=float), flags_of, spec, tol,
                     state.basis.complete)


def auto_sets(masters: list[int], omega: np.ndarray, flags_of: Any, spec: Any, tol: float, complete: bool,
              together: Any = None) -> list[ManifoldPlan]:
    """:func:`auto_plans` of ``masters`` from their resonance flags ``flags_of(p)`` (None: no set for p) among the
    modes of angular frequencies ``omega``; ``complete``: whether those are every mode of the model;
    ``together(modes)``: whether one manifold can hold the modes (None: any)."""
    sets: list[tuple[set[int], dict[int, str]]] = []  # (modes, {mode: why it joined})
    for p in masters:
        flags = flags_of(p)
        if flags is None:
            continue
        near = sorted((abs(f["ratio"] - f["harmonic"]) / f["harmonic"], int(f["mode"]), int(f["harmonic"]))
                      for f in flags if str(f.get("kind", "")).startswith("internal_resonance_1_")
                      and int(f["harmonic"]) <= MAX_RATIO)[:MAX_MODES - 1]
        if not near:
            continue
        group = {int(p)} | {m for _, m, _ in near}
        why = {m: f"mode {m} near {h} x w of mode {p} (w_s/w_p = {float(omega[m] / omega[p]):.4f})"
               for _, m, h in near}
        for other in [g for g in sets if g[0] & group]:
            if _mergeable(omega, other[0], group, tol) and (together is None or together(other[0] | group)):
                sets.remove(other)
                group |= other[0]
                why = {**other[1], **why}
            else:  # no common ratio vector (or too many modes): this master keeps what no earlier set holds
                group -= other[0]
        why = {m: w for m, w in why.items() if m in group}
        if int(p) in group and len(group) > 1:
            sets.append((group, why))
    if not sets:
        top = float(np.max(omega)) if len(omega) else 0.0
        short = [] if complete else [int(p) for p in masters
                                     if top < min(int(spec.order), MAX_RATIO) * float(omega[p])]
        seen = (f"; the computed modes reach {top / float(omega[short[0]]):.3g} x w of mode {short[0]} only "
                f"(raise [analysis] max_modes to look further)") if short else ""
        warnings.warn(f"[analysis.backbone] manifolds = \"auto\": no master has a mode near 1:1 .. 1:{MAX_RATIO} of "
                      f"it within the resonance tolerance {tol:g} among the computed modes{seen}; every backbone is "
                      "single-mode", ModelWarning, stacklevel=2)
    return [ManifoldPlan(tuple(sorted(group)), None, None, "auto",
                         "; ".join(why[m] for m in sorted(why)) + f" (resonance tolerance {tol:g})")
            for group, why in sets]


def _mergeable(omega: np.ndarray, a: set[int], b: set[int], tol: float) -> bool:
    """Whether the modes ``a | b`` can share one manifold: at most MAX_MODES, with a common ratio vector of
    integers up to MAX_RATIO within ``tol`` (what the reduced dynamics' branches need)."""
    modes = sorted(a | b)
    if len(modes) > MAX_MODES:
        return False
    k = find_ratios(np.asarray(omega, dtype=float)[modes], tol, MAX_RATIO)
    return k is not None and int(k.max()) <= MAX_RATIO


def resolve_manifolds(state: StageView, spec: Any) -> list[ManifoldPlan]:
    """The manifolds of the scene (module docstring); [] without ``manifolds``."""
    if spec.manifolds is None:
        return []
    tol = state.tol.resonance if spec.resonance is None else float(spec.resonance)
    return auto_plans(state, spec, tol) if spec.manifolds == "auto" else explicit_plans(state, spec, tol)


def plan_name(plan: ManifoldPlan) -> str:
    """The manifold's name in checkpoint plans: ``m<mode>_<mode>...``."""
    return "m" + "_".join(map(str, plan.modes))


def parametrise(state: StageView, plan: ManifoldPlan, spec: Any, forces: Any, probe: float) -> ManifoldResult:
    """The manifold of ``plan`` with the run's counters and tolerances (module docstring); ``forces`` the
    run's evaluator wrapped in named plans (:class:`stepnf.pipeline.backbone.PlannedForces`)."""
    modes = list(plan.modes)
    model = DPIM(forces, state.K, state.M,
                 ModeSpectrum(omega=state.omega, rigid=state.basis.rigid, modes=state.phi),
                 Solvers(backend=state.backend), state.counters,
                 DPIMTolerances(resonance=state.tol.resonance, twin=state.scene.degeneracy_tolerance,
                                coupling=state.tol.coupling), rotations=rotation_mask(state.dirs))
    return parametrise_plan(model, state.scene.file, plan, modes, state.phi[:, modes], state.omega[modes], spec,
                            probe, lambda k: state.progress.bar(k - 1, spec.order - 1, f"DPIM manifold {modes}"),
                            max_live=None if state.n <= KEEP_ALL_FACTORISATIONS_UP_TO else LIVE_FACTORISATIONS)


def parametrise_plan(model: DPIM, file: Any, plan: ManifoldPlan, masters: list[int], phis: np.ndarray,
                     omegas: np.ndarray, spec: Any, probe: float, progress: Any = None,
                     max_live: int | None = None) -> ManifoldResult:
    """:func:`~stepnf.dpim.multimode.manifold.parametrise_manifold` of ``plan`` (``masters``: the modes' indices in
    ``model``'s spectrum), ratios that do not match the frequencies a SceneError on the scene's ``ratios[i]``."""
    try:
        return parametrise_manifold(model, masters, phis, omegas, spec.order, probe=probe, ratios=plan.ratios,
                                    resonance=spec.resonance, max_live=max_live, progress=progress)
    except ValueError as exc:  # ratios that do not match the frequencies
        if plan.index is None or plan.ratios is None:
            raise
        raise SceneError(file, f"analysis.backbone.ratios[{plan.index}]", str(exc)) from None


def master_output(state: StageView, man: ManifoldResult, plan: ManifoldPlan, p: int, spec: Any, wmax: Any,
                  probe: float, fallback: float, stored_with: int) -> BackboneOutput:
    """Master ``p``'s branches on ``man``, its block and its arrays (the manifold's with them when
    ``stored_with`` is ``p``)."""
    tol = state.tol.resonance if spec.resonance is None else float(spec.resonance)
    return manifold_output(man, plan, p, spec, wmax, probe, fallback, stored_with, tol)


def manifold_output(man: ManifoldResult, plan: ManifoldPlan, p: int, spec: Any, wmax: Any, probe: float,
                    fallback: float, stored_with: int, tol: float) -> BackboneOutput:
    """:func:`master_output` with the resonance tolerance ``tol`` the manifold was parametrised with (``man.masters``
    and ``p``: the run's mode indices; ``wmax``: a :class:`~stepnf.dpim.backbone_report.WMax` with ``linear``, or
    None)."""
    store = stored_with == p
    j = list(man.masters).index(p)
    linear = getattr(wmax, "linear", None)
    h = float(wmax.h) if wmax is not None else 1.0
    top = trace_top(man, j, spec, fallback)
    # started at 1/200 of the STEP amplitude at most (a small amplitude, where the linear mode's guess holds)
    branches = backbone_branches(man, j, top, r0=min(top, fallback) / 200.0, tol=spec.tolerance,
                                 transverse=linear, h=h)
    branches.sort(key=lambda b: not b.kind.startswith("continues mode"))
    block = manifold_report(man, j, branches, spec, probe=probe, resonance=tol, transverse=linear, h=h,
                            chosen=plan.chosen, why=plan.why)
    block["manifold"]["stored_with"] = int(stored_with)
    arrays: dict[str, np.ndarray] = {}
    if store:
        arrays.update({f"backbone_{p}_manifold_{k}": v for k, v in man.arrays().items()})
    for i, b in enumerate(branches):
        arrays.update({f"backbone_{p}_branch{i}_{k}": v for k, v in b.arrays().items()})
    for key in ("amplitude", "omega", "w_max_over_h"):
        if block[key] is not None:
            arrays[f"backbone_{p}_{key}"] = np.asarray([np.nan if v is None else float(v) for v in block[key]])
    return BackboneOutput(None, block, (), arrays)


def manifold_text(plan: ManifoldPlan, man: ManifoldResult) -> str:
    """One line for the progress output: which manifold, why, its ratios and kept monomials."""
    k = "none" if man.ratios is None else ":".join(map(str, man.ratios))
    return (f"manifold of modes {list(plan.modes)} ({plan.chosen}: {plan.why}): ratios {k}, order {man.order}")
