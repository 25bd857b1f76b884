"""The full-order linear algebra of the evaluators: ``K^+``, shifted factorisations, deflation."""
from __future__ import annotations

import time
from typing import Callable

import numpy as np
import scipy.sparse as sp

from stepnf.runtime.counters import Counters
from stepnf.linalg.deflation import DeflatedSolver
from stepnf.nf.evaluators import FullOrderContext
from stepnf.linalg.factorization import (Factorization, PseudoInverse, adapter_factorization, apply_columns,
                                         factorize)
from stepnf.linalg.modal_analysis import lambda_scale
from stepnf.pipeline.state import StageView


def adapter_shifted(shift_solver: Callable, n: int, counters: Counters) -> Callable[[float, str], Factorization]:
    """The adapter's own ``K - sigma M`` factorisations, as :class:`Factorization` objects
    (:func:`~stepnf.linalg.factorization.adapter_factorization`: releasing one frees the adapter's factors)."""
    def shifted(sigma: float, label: str) -> Factorization:
        return adapter_factorization(timed_factorisation(counters, lambda: shift_solver(sigma)), n, counters,
                                     label)
    return shifted


def timed_factorisation(counters: Counters, make: Callable[[], Callable]) -> Callable:
    """``make()`` (an adapter's factorisation: it returns the solve), counted and timed in ``counters``."""
    t0 = time.perf_counter()
    counters.factorizations += 1
    solve = make()
    counters.factorization_seconds += time.perf_counter() - t0
    return solve


class DeflatedPinv:
    """``K^+`` through a :class:`DeflatedSolver` (same interface as :class:`PseudoInverse`)."""

    def __init__(self, solver: DeflatedSolver, R: np.ndarray):
        self.solver, self.R = solver, R

    def __call__(self, b: np.ndarray) -> np.ndarray:
        return self.solver.pinv(b)


class EigenPreconditioner:
    """The eigen-solver's factors as the deflated solves' preconditioner; once they are released (the
    evaluators stage frees them before the DNF factorisations that run last, :mod:`stepnf.pipeline.evaluate`),
    a factorisation of ``K - sigma M`` of its own, made on first use: a slender master's DNF solves again
    after that (:mod:`stepnf.pipeline.slender_dnf`). Takes (n,) or (n, k) right-hand sides."""

    def __init__(self, F0: Factorization, state: StageView):
        self.F0, self.state, self.own = F0, state, None

    def __call__(self, b: np.ndarray) -> np.ndarray:
        if self.F0.disabled is None:
            return self.F0.solve(b, count=False)
        if self.own is None:
            st = self.state
            A = sp.csr_matrix(st.K) + 1e-10 * lambda_scale(st.K, st.M) * sp.csr_matrix(st.M)
            self.own = factorize(A, counters=st.counters, backend=st.backend,
                                 label="K - sigma M (the deflated solves' preconditioner, after the eigen-solver's)")
        return self.own.solve(b, count=False)


def deflation_preconditioner(state: StageView, shift_solver: Callable | None) -> Callable | None:
    """A solve with K (or K slightly shifted) that a :class:`DeflatedSolver` can use, or None; it takes
    (n,) or (n, k) right-hand sides (the eigen-solver's factors solve k columns in one call).

    The eigen-solver's factors when stepnf factorised (no extra factorisation); else, for a solver
    with its own shifted solves and a partial spectrum, ONE factorisation by the solver (e.g.
    distributed, under MPI) that then serves every solve below the computed spectrum, bordered
    modal-derivative systems included. None without ``deflation`` or when neither applies.
    """
    basis, scene = state.basis, state.scene
    if basis.factorization is not None and shift_solver is None and scene.deflation:
        return EigenPreconditioner(basis.factorization, state)
    if shift_solver is not None and scene.deflation and basis.n_elastic and not basis.complete:
        raw = timed_factorisation(state.counters, lambda: shift_solver(-1e-10 * lambda_scale(state.K, state.M)))
        return lambda b: apply_columns(raw, b)  # a block in one call only if the solve takes_columns
    return None


def full_order_context(state: StageView) -> FullOrderContext:
    """The evaluators' :class:`FullOrderContext`, built on first use and kept in the run context's ``solvers``.

    Reads ``adapter``, ``scene`` (``deflation``), ``K``, ``M``, ``basis``, ``backend``, ``counters``.
    Built lazily so that a run without full-order methods factorises nothing more. Its ``shifted``
    factorisations are the adapter's when it has shifted solves, else the context's own
    :class:`~stepnf.linalg.shifted.ShiftedFactorizer` (called: an independent factorisation, for callers that
    keep several; its ``refactor``: one instance reused for every shift, MUMPS's analysis kept).
    """
    slot = state.ctx.solvers
    if slot.value is not None:
        return slot.value
    adapter, basis, counters = state.adapter, state.basis, state.counters
    shift_solver = adapter.shifted_solver if adapter.provides_shifted_solves else None
    deflated = None
    precond = deflation_preconditioner(state, shift_solver)
    if precond is not None:
        deflated = DeflatedSolver(state.K, state.M, state.phi, state.omega**2, basis.rigid, precond, counters)
        Kp = DeflatedPinv(deflated, basis.rigid)
    else:
        Kp = PseudoInverse(state.K, state.M, basis.rigid, counters=counters, backend=state.backend,
                           solver_factory=shift_solver)
    shifted = adapter_shifted(shift_solver, state.n, counters) if shift_solver is not None else None
    slot.value = FullOrderContext(state.K, state.M, Kp, counters, state.backend, shifted, deflated,
                                  keep_fields=state.want_fields)
    return slot.value
