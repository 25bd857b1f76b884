"""What each stage of a run returns: frozen values, each built once by its stage and read by the later ones.

:func:`~stepnf.pipeline.run.run_adapter` is the sequence::

    model = model_stage(ctx, adapter)                          # RunModel
    backbone_check_stage(ctx, model)                           # refuses a backbone the model cannot give
    loaded = forcing_check_stage(ctx, model)                   # the dofs of [analysis.forcing] load
    modes = modes_stage(ctx, model)                            # RunModes
    damping_check_stage(ctx, modes)                            # refuses an overdamped master
    terms = step_stage(ctx, model, modes)                      # StepTerms
    evals = evaluators_stage(ctx, model, modes, terms)         # Evaluations
    bbs = backbone_stage(ctx, model, modes, terms, evals)      # Backbones
    bbs = forced_stage(ctx, model, modes, evals, bbs, loaded)  # Backbones with the forced responses
    facts = output_mesh_stage(ctx, model)                      # AdapterFacts

and, once the adapter is closed, ``results_stage(ctx, model, modes, terms, evals, bbs, facts)``.

:class:`RunContext` is what every stage is given besides the earlier outputs: the scene, the progress
display, the force checkpoint, the run's counters (added to by every solve) and the full-order linear
algebra, built on first use and shared by the evaluators and the backbone (:class:`SolverSlot`).
A model in modal coordinates (:mod:`stepnf.pipeline.modal_coordinates`) returns the same
:class:`Evaluations` and :class:`Backbones`.

The values are frozen (assigning a field raises ``FrozenInstanceError``); the arrays and records they hold
are not copied: a stage never changes what an earlier one returned, with two exceptions: the per-mode records
(:class:`~stepnf.io.results.ModeResult`) that the ``results`` stage completes with the backbone blocks, and
the eigen-solve's factorisation, which the ``evaluators`` stage releases once it is of no more use (memory).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stepnf.io.results import ModeResult
from stepnf.linalg.modal_analysis import ModalBasis
from stepnf.methods import FULL, MODAL_EVALUATORS
from stepnf.nf.evaluators import FullOrderContext, Tolerances
from stepnf.pipeline.plan import resolve_methods
from stepnf.runtime.counters import Counters
from stepnf.runtime.progress import Progress
from stepnf.scene.parse import Scene
from stepnf.step.checkpoint import Checkpoint
from stepnf.step.procedure import ForceEvaluator, FullStep, MasterStep, StepPolicy


class SolverSlot:
    """The run's :class:`FullOrderContext` (``K^+``, shifted factorisations, deflation), built on first use
    (:func:`stepnf.pipeline.context.full_order_context`): ``value`` is None until then."""

    def __init__(self) -> None:
        self.value: FullOrderContext | None = None


@dataclass(frozen=True)
class RunContext:
    """What every stage of one run is given besides the earlier outputs.

    ``methods``: method name -> evaluator (the scene's, resolved); ``n_ret``: modes in the modal sums;
    ``want_fields``: the run writes field files (:mod:`stepnf.io.fields`); ``started``: ``perf_counter``
    at the start of the run (the ``total`` timing); ``solvers``: the full-order linear algebra.
    """

    scene: Scene
    progress: Progress
    checkpoint: Checkpoint | None = None
    counters: Counters = field(default_factory=Counters)
    methods: dict[str, str] = field(default_factory=dict)
    n_ret: int = 10
    want_fields: bool = False
    writing: bool = False
    started: float = field(default_factory=time.perf_counter)
    solvers: SolverSlot = field(default_factory=SolverSlot)

    @classmethod
    def start(cls, scene: Scene, progress: Progress, checkpoint: Checkpoint | None = None, *,
              fields: bool = False, writing: bool = False, started: float | None = None,
              order: str | None = None) -> "RunContext":
        """The context before any stage: the scene's methods resolved (``qm_order``, else ``order``, else
        full order); ``fields``: the run will write field files; ``writing``: the results file."""
        methods = resolve_methods(scene.methods, scene.qm_order or order or FULL)
        return cls(scene, progress, checkpoint, methods=methods, n_ret=scene.retained_modes or 10,
                   want_fields=fields, writing=writing,
                   started=time.perf_counter() if started is None else started)

    @property
    def tol(self) -> Tolerances:
        return self.scene.tolerances

    @property
    def evaluators(self) -> set[str]:
        """The evaluators the methods map to (``md`` -> ``md_full`` or ``md_modal``, ...)."""
        return set(self.methods.values())

    @property
    def needs_modal(self) -> bool:
        """Whether modal sums are asked for: a modal evaluator, or the full STEP tensors."""
        return bool(self.evaluators & MODAL_EVALUATORS) or self.scene.tensors == "full"


@dataclass(frozen=True)
class RunModel:
    """Stage ``model``: the adapter's matrices and what the model offers.

    ``K``, ``M``: (n, n), real, symmetric, model units; ``backend``: the linear solver; ``policy``: the
    STEP policy (None for a survey of the modes only); ``length``: the STEP length (the scene's thickness,
    else the adapter's characteristic length; None: unknown); ``X`` (n, 3), ``dirs`` (n,): dof geometry
    or None; ``candidates``: rigid-body fields; ``smooth``: the smoothest field's Rayleigh quotient (or
    None); ``forces``: the run's force evaluator (counters, checkpoint, batches).
    """

    adapter: Any
    K: Any
    M: Any
    backend: str
    policy: StepPolicy | None
    length: float | None
    X: np.ndarray | None
    dirs: np.ndarray | None
    candidates: np.ndarray | None
    smooth: float | None
    forces: ForceEvaluator | None

    @property
    def n(self) -> int:
        """Number of (free) dofs of the model."""
        return self.K.shape[0]


@dataclass(frozen=True)
class RunModes:
    """Stage ``modes``: the modal basis (degenerate pairs oriented), the adapter's labels, the master modes
    (indices among the elastic modes, the scene's order) and the run flags of the model."""

    basis: ModalBasis
    labels: list
    masters: list[int]
    flags: tuple[dict, ...] = ()

    @property
    def omega(self) -> np.ndarray:
        """Elastic angular frequencies (rad/s in the model's units), ascending."""
        return self.basis.omega

    @property
    def phi(self) -> np.ndarray:
        """Mass-normalised elastic mode shapes, one per column."""
        return self.basis.phi

    @property
    def m(self) -> int:
        """Number of elastic modes computed."""
        return self.basis.n_elastic


@dataclass(frozen=True)
class StepTerms:
    """Stage ``step``: master -> targeted :class:`MasterStep`; the full plan (:class:`FullStep`, or None)
    over the modes ``full_modes``; the run flags of STEP (no characteristic length, the full plan's)."""

    steps: dict[int, MasterStep] = field(default_factory=dict)
    full: FullStep | None = None
    full_modes: np.ndarray | None = None
    flags: tuple[dict, ...] = ()


@dataclass(frozen=True)
class Evaluations:
    """Stage ``evaluators``: one :class:`ModeResult` per master (the scene's order), the shell ``scales`` (or
    None), ``gscale`` / ``no_gamma`` (how Gamma is scaled, or why not), ``Gv`` (master -> G(phi_p, phi_p),
    an empty array without a targeted STEP)."""

    modes: list[ModeResult]
    scales: Any = None
    gscale: Any = None
    no_gamma: str | None = None
    Gv: dict[int, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class BackboneOutput:
    """One master's backbone: its parametrisation (None when refused), the ``backbone`` block of its
    record, the flags its methods get (a refused parametrisation), its HDF5 arrays (``backbone_<p>_*``); ``manifold``:
    the :class:`~stepnf.dpim.multimode.manifold.ManifoldResult` of a master on a manifold of several modes (its forced
    responses are traced on it), else None."""

    result: Any
    block: dict
    method_flags: tuple[dict, ...] = ()
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    manifold: Any = None


@dataclass(frozen=True)
class Backbones:
    """Stage ``backbone``: master -> :class:`BackboneOutput` (empty without ``[analysis.backbone]``); stage
    ``forced`` adds ``forced``: master -> :class:`stepnf.pipeline.forced.ForcedOutput` (empty without
    ``[analysis.forcing]``)."""

    by_master: dict[int, BackboneOutput] = field(default_factory=dict)
    forced: dict[int, Any] = field(default_factory=dict)

    @property
    def results(self) -> dict[int, Any]:
        """master -> :class:`~stepnf.dpim.parametrisation.DPIMResult`, the masters whose DPIM ran."""
        return {p: b.result for p, b in self.by_master.items() if b.result is not None}


@dataclass(frozen=True)
class AdapterFacts:
    """What the results take from the adapter at the end of its run, while it is open: its output mesh for
    the field files (None: none written), its free-dof map and its description."""

    output_mesh: Any
    free_dofs: Any
    description: dict
