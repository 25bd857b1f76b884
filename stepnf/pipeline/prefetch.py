"""The deflated solves of every master mode at once, before the methods run.

The full-order methods solve, per master ``p``, with the computed modes and the eigen-solver's
factorisation (:class:`~stepnf.linalg.deflation.DeflatedSolver`):

* ``y = K^+ Gv`` (DNF, SMD),
* DNF's ``(K - 4 w_p^2 M) z = b`` when ``2 w_p`` lies inside what the computed spectrum solves,
* MD's ``(K - w_p^2 M) theta = -2 Gv``, the master and its twins left out (unless a twin couples:
  then MD diverges and solves nothing).

Each is a preconditioned CG whose every iteration is one solve with the factorisation. Run one
master after the other, each solve reads the factors once per column; here the right-hand sides
of all masters go through :meth:`~stepnf.linalg.deflation.DeflatedSolver.solve_many` in lockstep, in
blocks of at most :data:`BLOCK` columns, so each iteration reads the factors once per block
(MUMPS, one thread, 112k dofs: 0.14 s for 6 columns against 0.08 s for one). The methods then
find ``y``, ``z``, ``theta`` in their :class:`~stepnf.pipeline.master.MasterData` and do not solve
again; the results equal one-by-one solves to round-off.

Nothing is fetched when the run has no deflated solver (no full-order method, ``deflation =
false``, a complete basis); a block whose solve fails (a shift that is an eigenvalue, CG that does
not converge) is left to the methods, which then meet the same failure one master at a time and
report it as they always have (a flag, or an error naming the master and the method).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stepnf.errors import NumericalError
from stepnf.methods import DNF, MD_FULL, method
from stepnf.nf.evaluators import dnf_shifted_rhs, dnf_uses_factorisation, md_twin_flag
from stepnf.pipeline.context import full_order_context
from stepnf.pipeline.master import MasterData
from stepnf.pipeline.state import StageView

#: Largest number of right-hand sides in one lockstep run (memory: about 7 vectors of n per column).
BLOCK = 12


@dataclass
class Request:
    """One deflated solve: ``(K - sigma M) x = rhs``, ``exclude`` as in ``DeflatedSolver.solve``;
    its solution goes to ``data.<field>``."""

    data: MasterData
    field: str
    rhs: np.ndarray
    sigma: float
    exclude: tuple[int, ...]


def deflated_requests(state: StageView, datas: list[MasterData]) -> list[Request]:
    """The deflated solves the scene's full-order methods will ask for, master by master."""
    evs = state.evaluators
    if not any(method(e).factorises for e in evs):
        return []
    ctx = full_order_context(state)
    if ctx.deflated is None:
        return []
    nr = state.basis.rigid.shape[1]
    out: list[Request] = []
    for d in datas:
        if d.st is None:
            continue
        p, Gv, w = d.p, d.st.Gv, float(state.omega[d.p])
        if any(method(e).pinv for e in evs):
            out.append(Request(d, "y", Gv, 0.0, tuple(range(nr))))
        if DNF in evs and not dnf_uses_factorisation(w, ctx):
            out.append(Request(d, "z", dnf_shifted_rhs(Gv, ctx), 4 * w**2, ()))
        if MD_FULL in evs and not _md_diverges(state, d):
            out.append(Request(d, "theta", -2.0 * Gv, w**2, (nr + p, *(nr + t for t in d.twins))))
    return out


def _md_diverges(state: StageView, d: MasterData) -> bool:
    """Whether MD of ``d.p`` stops at a coupling twin (:func:`~stepnf.nf.evaluators.md_twin_flag`)."""
    D = np.column_stack([d.phi, state.phi[:, d.twins]]) if d.twins else d.phi[:, None]
    return md_twin_flag(d.p, d.phi, d.st.Gv, D, d.g_all, state.tol, d.floor, d.twins, state.labels) is not None


def prefetch_deflated(state: StageView, datas: list[MasterData]) -> None:
    """Solve every master's deflated systems in lockstep blocks and store them in ``datas``."""
    requests = deflated_requests(state, datas)
    if not requests:
        return
    solver = full_order_context(state).deflated
    n_blocks = -(-len(requests) // BLOCK)
    for chunk in np.array_split(np.arange(len(requests)), n_blocks):
        block = [requests[i] for i in chunk]
        try:
            X = solver.solve_many(np.column_stack([r.rhs for r in block]), [r.sigma for r in block],
                                  [r.exclude for r in block])
        except NumericalError:
            continue  # the methods solve these one by one and report the failure where it belongs
        for j, r in enumerate(block):
            setattr(r.data, r.field, X[:, j])
