"""The state the stages of one adapter run share: inputs, then what each stage writes for the next."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..adapter import SolverAdapter
from ..checkpoint import Checkpoint
from ..counters import Counters
from ..evaluators import FullOrderContext, Tolerances
from ..modal import ModalBasis
from ..plan import resolve_methods
from ..progress import Progress
from ..results import ModeResult
from ..scene import Scene
from ..step import FullStep, MasterStep, StepPolicy

#: Evaluators that work on modal coefficients over a retained set of modes.
MODAL_METHODS = {"nf", "md_modal", "smd_modal"}
#: Evaluators that work on the whole mesh (shifted solves, no modal truncation).
FULL_METHODS = {"dnf", "md_full", "smd_full"}


@dataclass
class RunState:
    """Everything one run of a solver adapter has computed so far.

    Set at the start (:meth:`start`): ``scene``, ``adapter``, ``progress``, ``checkpoint``,
    ``counters``, ``methods`` (method name -> evaluator) and ``n_ret`` (modes in the modal sums).
    Written by the ``model`` stage: ``K``, ``M`` (sparse or dense, (n, n), model units), ``backend``,
    ``policy``, ``X``, ``dirs``, ``candidates`` (rigid-body fields), ``smooth``. By ``modes``:
    ``basis``, ``labels``, ``masters``, ``flags`` (run flags), ``arrays`` (``omega``,
    ``master_modes``). By ``step``: ``steps`` (master -> :class:`MasterStep`), ``full``. By
    ``evaluators``: ``modes``, ``scales``, ``gscale``, ``no_gamma``, ``arrays`` (``Gv_<p>``) and,
    on first use, ``context``. By ``output_mesh``: ``output_mesh`` (when ``want_fields``: the run
    writes field files, so the full-order evaluators keep their displacement vectors). By
    ``backbone`` (with ``[analysis.backbone]``): ``backbones`` (master -> :class:`stepnf.dpim.DPIMResult`),
    each :class:`ModeResult`'s ``backbone`` and ``arrays`` (``backbone_<p>_*``).
    """

    scene: Scene
    adapter: SolverAdapter
    progress: Progress
    checkpoint: Checkpoint | None = None
    counters: Counters = field(default_factory=Counters)
    methods: dict[str, str] = field(default_factory=dict)
    n_ret: int = 10
    K: Any = None
    M: Any = None
    backend: str = ""
    policy: StepPolicy | None = None
    X: np.ndarray | None = None
    dirs: np.ndarray | None = None
    candidates: np.ndarray | None = None
    smooth: float | None = None
    basis: ModalBasis | None = None
    labels: list = field(default_factory=list)
    masters: list[int] = field(default_factory=list)
    flags: list[dict] = field(default_factory=list)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    steps: dict[int, MasterStep] = field(default_factory=dict)
    full: FullStep | None = None
    context: FullOrderContext | None = None
    modes: list[ModeResult] = field(default_factory=list)
    scales: Any = None
    gscale: Any = None
    no_gamma: str | None = None
    want_fields: bool = False
    output_mesh: Any = None
    backbones: dict[int, Any] = field(default_factory=dict)

    @classmethod
    def start(cls, scene: Scene, adapter: SolverAdapter, progress: Progress,
              checkpoint: Checkpoint | None = None, *, fields: bool = False) -> "RunState":
        """The state before any stage: the scene's methods resolved (full order unless ``qm_order``);
        ``fields``: the run will write field files (:mod:`stepnf.fields`)."""
        methods = resolve_methods(scene.methods, scene.qm_order or "full")
        return cls(scene, adapter, progress, checkpoint, methods=methods, n_ret=scene.retained_modes or 10,
                   want_fields=fields)

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
        return bool(self.evaluators & MODAL_METHODS) or self.scene.tensors == "full"

    @property
    def n(self) -> int:
        """Number of (free) dofs of the model."""
        return self.K.shape[0]

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
