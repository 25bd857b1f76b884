"""The one path of a force evaluation: batching and caching of the fields a stage sends to an adapter.

A stage (STEP: :mod:`stepnf.pipeline.step`; the DPIM backbone: :mod:`stepnf.pipeline.backbone`, through
:mod:`stepnf.dpim.polarisation`) hands its displacement fields (m, n) to a :class:`ForceEvaluator`, and
from there every field goes the same way::

    ForceEvaluator.__call__            cut into chunks of batch_size(adapter) fields      (batching)
      Checkpoint.load / .store         each chunk stored once computed, reused on a rerun  (caching)
      SolverAdapter.internal_forces    fields checked; forces checked by checked_forces   (checking)
        adapter._internal_forces       the solver call (an external solver: one run per
                                       solver_run_size fields, stepnf.external.adapter)

* **Batching**, here only: :func:`batch_size` is how many fields one call of the adapter gets (its
  declared ``prefers_batches``), and :func:`solver_run_size` how many of them one run of an external
  program gets (its declared ``max_fields_per_run`` and ``parallel_runs``). :func:`stepnf.step.procedure.full_step`
  cuts its plan along :meth:`ForceEvaluator.blocks` (one checkpoint plan per block, for the progress bar).
* **Checking**, once: :func:`stepnf.plugin.adapter.checked_forces` (real, shape (m, n), finite) where the
  forces leave the adapter (an external solver's at the file it wrote, so the failure keeps the work
  folder and quotes the log). An evaluator built by :meth:`ForceEvaluator.for_adapter` is ``checked``:
  it and the polarisation (:func:`stepnf.dpim.polarisation.probe_forces`) do not check its forces again;
  a bare force function (tests, the harness, a modal model's forces) is still checked by them.
* **Caching**: the run's checkpoint (:mod:`stepnf.step.checkpoint`, on disk, per chunk of a named plan).
  An external adapter also keeps the forces of its finished runs in memory
  (:attr:`stepnf.external.adapter.ExternalSolverAdapter.cache_size` fields), so that within one
  process a failure in a later run loses nothing and a retry does not redo the runs done; it is the
  only cache of a direct ``adapter.internal_forces`` call, which has no checkpoint.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from stepnf.errors import NumericalError
from stepnf.runtime.counters import Counters

ForceFunction = Callable[[np.ndarray], np.ndarray]

#: Fields per call of an adapter that prefers batches (an external program: one launch per call).
BATCH_FIELDS = 1024
#: Fields per call of an in-process adapter (a checkpoint chunk every 64 fields).
SINGLE_FIELDS = 64


def batch_size(adapter: Any) -> int:
    """Fields per call of ``adapter.internal_forces`` (and per checkpoint chunk) in a run."""
    return BATCH_FIELDS if adapter.prefers_batches else SINGLE_FIELDS


def solver_run_size(count: int, parallel_runs: int, max_fields_per_run: int | None) -> int:
    """Fields per run of an external program for ``count`` new fields: an even share over ``parallel_runs``
    processes, at most ``max_fields_per_run`` (``None`` or 0: no limit); at least 1."""
    runs = max(1, int(parallel_runs))
    size = max(1, -(-count // runs))  # split the batch evenly over the parallel runs
    if max_fields_per_run:
        size = min(size, int(max_fields_per_run))
    return size


class ForceEvaluator:
    """Sends displacement fields to an adapter (in chunks of ``batch_size``) and counts them.

    With a :class:`stepnf.step.checkpoint.Checkpoint`, every chunk of a named plan
    is stored as soon as it is computed and reused by a rerun that asks for
    the same fields (``reduce`` maps the forces to what is kept, e.g. their
    modal projection). ``checked``: ``forces`` checks what it returns (an adapter's
    ``internal_forces``), so no check is repeated here; otherwise the shape is checked.
    """

    def __init__(self, forces: ForceFunction, n: int, counters: Counters, batch_size: int = 256,
                 checkpoint: Any | None = None, *, checked: bool = False):
        self._forces = forces
        self.n = n
        self.counters = counters
        self.batch_size = max(1, int(batch_size))
        self.checkpoint = checkpoint
        self.checked = checked

    @classmethod
    def for_adapter(cls, adapter: Any, n: int, counters: Counters,
                    checkpoint: Any | None = None) -> "ForceEvaluator":
        """The evaluator of a run: ``adapter.internal_forces`` (checked there) in chunks of :func:`batch_size`."""
        return cls(adapter.internal_forces, n, counters, batch_size=batch_size(adapter), checkpoint=checkpoint,
                   checked=True)

    #: :meth:`__call__` takes ``out=`` (the forces written into a given array, e.g. ``U`` itself).
    accepts_out = True

    def blocks(self, total: int) -> list[tuple[int, int]]:
        """``(start, stop)`` of the blocks a plan of ``total`` fields is cut into: an even number of fields
        each (a pair ``+-v`` stays in one block), one call of the adapter per block."""
        chunk = max(2, self.batch_size + self.batch_size % 2)
        return [(i, min(i + chunk, total)) for i in range(0, total, chunk)]

    def __call__(self, U: np.ndarray, *, plan: str | None = None,
                 reduce: Callable[[np.ndarray], np.ndarray] | None = None,
                 out: np.ndarray | None = None) -> np.ndarray:
        """Forces (m, n) of the fields ``U`` (m, n), or ``reduce`` of them (chunk by chunk, concatenated).

        ``out`` (m, n), without ``reduce``: the forces are written there, chunk by chunk; it may be
        ``U`` itself (each chunk's fields are read, and checkpointed, before its forces replace them),
        so that a large request holds one (m, n) array instead of two.
        """
        U = np.atleast_2d(np.asarray(U, dtype=float))
        if out is not None and (reduce is not None or out.shape != U.shape):
            raise ValueError(f"out= takes the forces of the fields {U.shape} without reduce; got {out.shape}")
        if out is None and reduce is None:
            out = np.empty_like(U)  # filled chunk by chunk: no list of chunks concatenated afterwards
        parts = []
        cp = self.checkpoint if plan is not None else None
        # what one field's stored result must look like: a chunk of another shape (another model size, a
        # reduction to another number of modes) is not these forces and is computed again
        tail = None if cp is None else (self.n,) if reduce is None else reduce(np.zeros((0, self.n))).shape[1:]
        for i, start in enumerate(range(0, len(U), self.batch_size)):
            chunk = U[start:start + self.batch_size]
            res = cp.load(plan, i, chunk, probe=self._evaluate, shape=(len(chunk), *tail)) if cp is not None else None
            if res is None:
                res = self._evaluate(chunk)
                first = res[:1].copy() if cp is not None else None  # the probe of a rerun (stepnf.step.checkpoint)
                if reduce is not None:
                    res = reduce(res)
                if cp is not None:
                    cp.store(plan, i, chunk, res, probe=first)
            if reduce is None:
                out[start:start + len(chunk)] = res
            else:
                parts.append(res)
        if reduce is None:
            return out
        return np.concatenate(parts, axis=0) if parts else reduce(np.zeros((0, self.n)))

    def _evaluate(self, U: np.ndarray) -> np.ndarray:
        """The solver's forces (m, n) of the fields ``U`` (m, n), counted (no checkpoint involved)."""
        if self.checked:
            res = self._forces(U)  # float (m, n), finite: checked by the adapter (stepnf.plugin.adapter)
        else:
            res = np.asarray(self._forces(U), dtype=float)
            if res.shape != U.shape:
                raise NumericalError(f"the solver returned forces of shape {res.shape} for {U.shape} "
                                     "displacement fields")
        self.counters.force_evaluations += len(U)
        self.counters.solver_runs += 1
        return res
