"""What a stage's helpers read: a read-only view of the run's context and of the earlier stages' outputs.

The stages return frozen values (:mod:`stepnf.pipeline.outputs`); their helpers (one master's data, one
method, the deflated solves, the DPIM of one master) take a :class:`StageView` of those values, whose
properties name what they read (``state.K``, ``state.phi``, ``state.steps``, ...). Nothing is written to it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stepnf.pipeline.outputs import Evaluations, RunContext, RunModel, RunModes, StepTerms


@dataclass(frozen=True)
class StageView:
    """The run's context and the outputs of the stages so far (None: not run yet), read through the names
    the stages' helpers use. Frozen: a helper cannot write to it."""

    ctx: RunContext
    model: RunModel
    modes: RunModes | None = None
    terms: StepTerms | None = None
    evals: Evaluations | None = None

    # the run's context
    scene = property(lambda self: self.ctx.scene)
    progress = property(lambda self: self.ctx.progress)
    checkpoint = property(lambda self: self.ctx.checkpoint)
    counters = property(lambda self: self.ctx.counters)
    methods = property(lambda self: self.ctx.methods)
    n_ret = property(lambda self: self.ctx.n_ret)
    want_fields = property(lambda self: self.ctx.want_fields)
    tol = property(lambda self: self.ctx.tol)
    evaluators = property(lambda self: self.ctx.evaluators)
    needs_modal = property(lambda self: self.ctx.needs_modal)
    # stage ``model``
    adapter = property(lambda self: self.model.adapter)
    K = property(lambda self: self.model.K)
    M = property(lambda self: self.model.M)
    n = property(lambda self: self.model.n)
    backend = property(lambda self: self.model.backend)
    policy = property(lambda self: self.model.policy)
    X = property(lambda self: self.model.X)
    dirs = property(lambda self: self.model.dirs)
    # stage ``modes``
    basis = property(lambda self: self.modes.basis)
    labels = property(lambda self: self.modes.labels)
    masters = property(lambda self: self.modes.masters)
    omega = property(lambda self: self.modes.omega)
    phi = property(lambda self: self.modes.phi)
    m = property(lambda self: self.modes.m)
    # stage ``step``
    steps = property(lambda self: self.terms.steps)
    full = property(lambda self: self.terms.full)
    # stage ``evaluators``
    scales = property(lambda self: self.evals.scales)
    gscale = property(lambda self: self.evals.gscale)
    no_gamma = property(lambda self: self.evals.no_gamma)

    @property
    def context(self) -> Any:
        """The full-order linear algebra, once built (:func:`stepnf.pipeline.context.full_order_context`)."""
        return self.ctx.solvers.value
