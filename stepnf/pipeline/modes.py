"""Stage ``modes``: the eigen-solve, the mode labels, the master modes and the model's run flags."""
from __future__ import annotations

import math
import warnings
from dataclasses import replace
from typing import Callable

from stepnf.linalg.deflation import ADMISSIBLE_MARGIN
from stepnf.nf.diagnostics import conditioning_flags, soft_mode_flags
from stepnf.errors import ModelWarning
from stepnf.dpim.multimode.manifold import MAX_RATIO
from stepnf.flags import new_flag
from stepnf.linalg.modal_analysis import ModalBasis, lambda_scale, modal_analysis, orient_degenerate, probe_vector
from stepnf.methods import DNF
from stepnf.pipeline.plan import check_elastic_modes, check_mechanism, resolve_masters
from stepnf.pipeline.outputs import RunContext, RunModel, RunModes
from stepnf.pipeline.state import StageView
from stepnf.plugin.dofs import translations_only


class ModeLabels:
    """The adapter's labels of a basis, asked once per basis size (the last one only is kept)."""

    def __init__(self, adapter):
        self.adapter = adapter
        self.cache: dict[int, list] = {}

    def of(self, basis: ModalBasis) -> list:
        key = basis.n_elastic
        if key not in self.cache:
            self.cache.clear()
            self.cache[key] = list(self.adapter.mode_labels(basis.phi))
        return self.cache[key]


def modes_needed(state: StageView) -> int:
    """Elastic modes to compute at least: two above the highest integer master (or mode of an explicit
    ``[analysis.backbone] manifolds``), ``n_ret`` for modal sums."""
    int_masters = [m for m in state.scene.master_modes if isinstance(m, int)]
    spec = getattr(state.scene, "backbone", None)
    if spec is not None and isinstance(spec.manifolds, tuple):
        int_masters += [m for group in spec.manifolds for m in group if isinstance(m, int)]
    need = max(int_masters, default=0) + 2
    return max(need, state.n_ret) if state.needs_modal else need


def first_batch(state: StageView) -> int | None:
    """Modes of the first eigen-solve when masters are labels: two per master (each may be one of a
    degenerate pair) and four more (the modes just above the highest one), at least
    :func:`modes_needed`; None (the eigen-solve's own default) when every master is an index. On the
    paper's cap (six labelled masters, the highest the 14th mode) that is one run of 16 modes where a
    first run of 6 had to be extended. On a large model, more: :func:`dnf_span_batch`."""
    masters = state.scene.master_modes
    labelled = any(isinstance(m, str) for m in masters)
    batch = max(modes_needed(state), modes_to_highest_master(masters) + 4) if labelled else None
    span = dnf_span_batch(state)
    return batch if span is None else max(batch or modes_needed(state) + 4, span)


#: Models from this many dofs compute the modes that DNF's shifted solves need (:func:`dnf_span_batch`).
#: Measured on the hex27 cap, six labelled masters, one thread, the same day (a first run of 31-32 modes
#: against 20 with ``retained_modes = 20``, 16 for DNF alone): all four methods 61-65 -> 46-47 s at 250k
#: dofs and 310-316 -> 215-252 s at 1M, DNF alone 45-55 -> 42-44 s at 250k and 266-292 -> 206 s at 1M;
#: but DNF alone 1.5 s slower at 44k and 112k (a factorisation costs there 20 to 25 shifted solves, not
#: 30 to 40), so smaller models factorise.
DNF_SPAN_FROM = 200_000


def dnf_span_batch(state: StageView) -> int | None:
    """On a model of at least :data:`DNF_SPAN_FROM` dofs running full-order DNF with deflation (stepnf's
    eigen-solver, or an adapter's with its own shifted solves, e.g. SLEPc and MUMPS under MPI): a first
    eigen-solve that reaches ``2 w_p`` of every master with the deflation's margin, so that DNF's
    ``K - 4 w_p^2 M`` is solved by deflation instead of a new factorisation (one of 30-45 s at 1M dofs,
    against about one shifted solve, ~1.2 s, per mode more; 2 MPI ranks at 250k dofs: DNF alone 55.0 ->
    45.3 s and 3632 -> 3083 MB per rank, all four methods 55.9 -> 50.6 s).

    The modes below a frequency grow about linearly with it for a plate or a shell, so the run asks
    for ``2 sqrt(margin)`` times the modes up to the highest master (:func:`modes_to_highest_master`)
    and four more (a twin, the modes
    just above). None otherwise. A guess that falls short only costs the factorisations it would
    have saved."""
    scene = state.scene
    adapter = state.adapter
    if state.n < DNF_SPAN_FROM or DNF not in state.evaluators or not scene.deflation:
        return None
    if adapter.provides_eigenmodes and not adapter.provides_shifted_solves:  # nothing to deflate with
        return None
    return math.ceil(2 * math.sqrt(ADMISSIBLE_MARGIN) * modes_to_highest_master(scene.master_modes)) + 4


def modes_to_highest_master(masters: list) -> int:
    """The elastic modes up to the highest master: its index + 1; for labels, whose indices the
    eigen-solve has yet to find, a guess of two per master (each may be one of a degenerate pair)."""
    if any(isinstance(m, str) for m in masters):
        return 2 * len(masters)
    return max(masters, default=0) + 1


def enough_modes(state: StageView, labels: ModeLabels) -> Callable[[ModalBasis], bool]:
    """Whether a partial basis holds every master mode and the modes just above the highest one."""
    scene, tol = state.scene, state.tol

    spec = getattr(scene, "backbone", None)
    named = [m for group in spec.manifolds for m in group] if spec is not None and isinstance(spec.manifolds, tuple) \
        else []
    wanted = replace(scene, master_modes=list(scene.master_modes) + [m for m in dict.fromkeys(named)
                                                                       if isinstance(m, str) and m not in scene.master_modes])
    reach = manifold_reach(scene)

    def enough(b: ModalBasis) -> bool:
        labs = labels.of(b) if any(isinstance(x, str) for x in wanted.master_modes) else [None] * b.n_elastic
        ms = resolve_masters(wanted, labs, b.n_elastic, complete=False)
        if ms is None:
            return False
        # the 1:1 checks need the modes just above the highest master (1:2 is checked locally)
        return b.complete or b.omega[-1] >= (1 + tol.resonance) * reach * max(b.omega[i] for i in ms)
    return enough


def manifold_reach(scene) -> float:
    """How far above the highest master the spectrum must reach: 1 (the modes just above it), or with
    ``[analysis.backbone] manifolds = "auto"`` ``min(N, MAX_RATIO)``, since "auto" builds each manifold from the
    modes the resonance flags find near ``h w_p``, h = 1..min(N, 4), among the COMPUTED modes (a 38k-dof cap whose
    first solve stops at 1.22 w_p of (2,1) would otherwise find no 1:2 partner and say there is none)."""
    spec = getattr(scene, "backbone", None)
    if spec is None or spec.manifolds != "auto":
        return 1.0
    return float(min(int(spec.order), MAX_RATIO))


def modes_stage(ctx: RunContext, model: RunModel) -> RunModes:
    """Compute the modes the scene needs, label them and pick the master modes.

    Returns :class:`RunModes`: the basis (degenerate pairs oriented by a probe field that depends on
    positions only, so every solver picks the same twins), the labels, the masters and the model's run
    flags (conditioning, soft modes counted as rigid, too few modes for the modal sums). A scene asking
    for modes the model does not have is a :class:`~stepnf.errors.SceneError`.
    """
    scene, adapter, K, M = ctx.scene, model.adapter, model.K, model.M
    state = StageView(ctx, model)
    labels = ModeLabels(adapter)
    eig = adapter.eigenmodes if adapter.provides_eigenmodes else None
    with ctx.progress.stage("eigen", "modal analysis"):
        basis = modal_analysis(K, M, modes_needed(state), counters=ctx.counters,
                               rigid_tolerance=scene.rigid_tolerance, rigid_modes=scene.rigid_modes,
                               degeneracy_tolerance=scene.degeneracy_tolerance, max_modes=scene.max_modes,
                               backend=model.backend, eigensolver=eig, enough=enough_modes(state, labels),
                               rigid_candidates=model.candidates, progress=ctx.progress.message,
                               first_batch=first_batch(state))
    check_elastic_modes(scene, basis)
    check_mechanism(scene, adapter, basis)
    # the same twins whatever the solver: a probe on the translations (a shell's rotations are no displacements,
    # so its pairs turn as a solid model's of the same structure do)
    orient_degenerate(basis, M, translations_only(probe_vector(model.X, model.dirs, model.n), model.dirs))
    labels.cache.clear()
    names = labels.of(basis)
    masters = resolve_masters(scene, names, basis.n_elastic, complete=True)
    assert masters is not None
    flags = conditioning_flags(basis, K, model.smooth, masters)  # each mode's own bound; masters beyond: n/a
    if scene.rigid_modes is None:  # a count the user gave is theirs to keep
        for fl in soft_mode_flags(basis.rigid_eigenvalues, lambda_scale(K, M), scene.rigid_tolerance,
                                  rigid=basis.rigid, K=K):
            # stacklevel 3: reported where stepnf.pipeline.run starts the run (_compute), as before the split
            warnings.warn(fl["message"], ModelWarning, stacklevel=3)
            flags.append(fl)
    if ctx.needs_modal and basis.n_elastic < ctx.n_ret:
        flags.append(new_flag("fewer_modes", message=f"only {basis.n_elastic} elastic modes available, "
                                    f"{ctx.n_ret} asked for in the modal sums"))
    return RunModes(basis, names, masters, tuple(flags))
