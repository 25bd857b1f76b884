"""What a run reports of one DPIM parametrisation: the backbone at the asked amplitudes, W_max/h, validity.

The JSON block of a master mode (``modes[i].backbone``)::

    {order, amplitude: [A...], omega: [rad/s...], omega_ratio: [omega / omega_p...],
     w_max_over_h: [...] or null, valid_up_to: A or null, valid_reason, grid, tolerance, probe,
     flags: [...], counts: {"2": {...}, ..., "N": {...}}}

``A`` is the amplitude of the master modal coordinate ``q_p = phi_p^T M x`` over one period
(:mod:`stepnf.dpim.backbone`), model length units (phi_p mass-normalised, as for T). ``valid_up_to``
is the largest A where orders N-2 and N agree to ``tolerance`` in frequency and to its square root in
shape (:meth:`stepnf.dpim.backbone.Backbone.validity_limit`); ``null`` when they agree over the whole
range searched; 0 when the stage found the forces at the probe amplitude inaccurate. ``valid_reason``
says which: "orders differ", "shapes differ", "amplitude folds", "not reached", "forces inaccurate", or
the reason of a flag that takes every validity range (:data:`stepnf.flags.NO_VALIDITY_REASONS`: the
master drives a degenerate twin or a rigid mode; a block whose DPIM refused has no amplitudes at all).
``grid``: the amplitudes are a grid up to the validity limit (no list in the scene). A value the
parametrisation cannot give (A beyond a fold of A(rho)) is ``null``, never NaN.

``W_max / h``: the largest transverse displacement over the mesh and the period, over the thickness,
measured on ``x(theta)`` rebuilt from the parametrisation (:class:`WMax`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import scipy.sparse as sp
from scipy.optimize import brentq, minimize_scalar

from stepnf.flags import new_flag
from stepnf.plugin.adapter import DIRECTIONS
from stepnf.nf.coefficient import json_float
from stepnf.keys.backbone import BackboneSpec
from stepnf.errors import NumericalError

#: Fallback top of the grid when orders N-2 and N never differ by the tolerance: the amplitude at which
#: the cubic estimate w (1 + T A^2) has moved by 10 %.
FALLBACK_SHIFT = 0.1


def transverse_operator(X: np.ndarray | None, D: np.ndarray, transverse: str | Sequence[float]):
    """The linear map fields (n, k) -> transverse displacements (t, k) of ``[analysis] transverse``.

    A name ("uz"): the rows of the dofs of that direction; a direction ``e``: ``u . e`` per node (nodes
    told apart by their dof coordinates ``X``, as :func:`stepnf.nf.gamma.transverse_peak` does). ``None``
    when no dof carries a translation.
    """
    D = np.asarray(D)
    if isinstance(transverse, str):
        sel = np.flatnonzero(D == DIRECTIONS.index(transverse))
        return sel if sel.size else None
    t = np.flatnonzero(D < 3)
    if t.size == 0 or X is None:
        return None
    _, node = np.unique(np.asarray(X, dtype=float)[t], axis=0, return_inverse=True)
    e = np.asarray(transverse, dtype=float)
    T = sp.csr_matrix((e[D[t]], (node.ravel(), t)), shape=(int(node.max()) + 1, len(D)))
    return lambda Y: np.asarray(T @ Y)


@dataclass
class WMax:
    """``W_max / h`` on a parametrisation: ``h`` (model length units) and either ``linear`` (indices or a
    linear map, exact and vectorised) or ``peak(x)`` (the model's largest transverse displacement of one
    field, e.g. :meth:`stepnf.plugin.adapter.SolverAdapter.transverse_amplitude`), then maximised over the
    phase: on ``2 N + 1`` points of [0, pi] (x is even in theta; the spacing is a quarter period of the
    highest harmonic, and the series is dominated by its first harmonic, whose extrema are at 0 and
    pi), refined by bounded Brent between the neighbours of the best point (each call of ``peak`` is a
    pass over the mesh: ~30 per amplitude instead of the 64 N + 1 of the linear route's grid)."""

    h: float
    linear: Any = None
    peak: Callable[[np.ndarray], float | None] | None = None

    def __call__(self, bb: Any, rho: float) -> float:
        if self.linear is not None:
            return float(bb.w_max(rho, self.linear, self.h))
        res, N = bb.res, bb.N
        C = np.zeros((N + 1, len(res.phi)))
        for (p, m), y in res.Y.items():
            C[m] += rho ** p * y
        ms = np.arange(N + 1)
        # einsum, not BLAS: a (N+1)-term combination of fields, where gemv's threads cost ~50x more
        f = lambda t: float(self.peak(np.einsum("m,mn->n", np.cos(ms * t), C)))  # noqa: E731
        grid = np.linspace(0.0, np.pi, 2 * N + 1)
        vals = [f(t) for t in grid]
        j = int(np.argmax(vals))
        lo, hi = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
        r = minimize_scalar(lambda t: -f(t), bounds=(lo, hi), method="bounded", options={"xatol": 1e-8})
        return max(vals[j], -float(r.fun)) / self.h

    def rho_at(self, bb: Any, target: float) -> float:
        """The ``rho`` where ``W_max / h`` reaches ``target`` (NumericalError if it stops growing first)."""
        lin = self(bb, 1e-6) / 1e-6  # W_max / h per unit rho at vanishing amplitude
        if not lin > 0:
            raise NumericalError("the master mode has no transverse displacement: W_max/h is zero")
        hi, prev = target / lin, 0.0
        for _ in range(80):
            with np.errstate(over="ignore", invalid="ignore"):  # rho^p overflows far out: not a number, stop
                w = self(bb, hi)
            if not np.isfinite(w):
                break
            if w >= target:
                return brentq(lambda r: self(bb, r) - target, 0.0, hi, xtol=1e-13 * hi, rtol=1e-13)
            if w <= prev:
                break
            prev, hi = w, hi * 1.25
        why = f"it stops growing at {prev:.6g}" if prev > 0 else "the series overflows on the way"
        raise NumericalError(f"the order-{bb.N} parametrisation never reaches W_max/h = {target:.6g} ({why})")


def backbone_report(res: Any, spec: BackboneSpec, wmax: WMax | None, *, probe: float,
                    fallback: float) -> dict[str, Any]:
    """The JSON block (module docstring) of the parametrisation ``res`` (:class:`stepnf.dpim.parametrisation.DPIMResult`).

    ``fallback``: top amplitude of the grid when the validity limit is not found (e.g. the STEP
    amplitude of the mode); used only when T = 0 too.
    """
    bb = res.backbone()
    w = res.omega
    valid, reason = bb.validity_limit(spec.tolerance)
    flags = list(res.flags)
    if reason == "amplitude folds":
        flags.append(new_flag("backbone_fold", mode=None,
                              message=f"the order-{res.order} amplitude A(rho) stops growing at A = {valid:.6g}: the "
                                      "parametrisation goes no further (validity limit set there)"))
    rhos: list[float | None] = []
    if spec.amplitudes is not None:
        amps = list(spec.amplitudes)
    elif spec.w_over_h is not None:
        amps = []
        for target in spec.w_over_h:
            try:
                rhos.append(wmax.rho_at(bb, target))
                amps.append(bb.amplitude(rhos[-1]))
            except NumericalError as exc:
                rhos.append(None)
                amps.append(None)
                flags.append(new_flag("backbone_unreached", mode=None, message=str(exc)))
    else:
        top = valid if valid else (math.sqrt(FALLBACK_SHIFT / abs(res.T)) if res.T else fallback)
        amps = list(np.linspace(top / spec.points, top, spec.points))
    omega, w_over_h = [], []
    for i, A in enumerate(amps):
        rho = rhos[i] if rhos else None
        if rho is None and A is not None:
            try:
                rho = bb.rho_at(A)
            except NumericalError as exc:
                flags.append(new_flag("backbone_unreached", mode=None, message=str(exc)))
        omega.append(None if rho is None else float(bb.frequency(rho)))
        w_over_h.append(None if rho is None or wmax is None else wmax(bb, rho))
    counts = {str(c["order"]): {k: v for k, v in c.items() if k != "order"} for c in res.counts}
    return {"order": res.order, "amplitude": [json_float(a) for a in amps],
            "omega": [json_float(x) for x in omega],
            "omega_ratio": [None if x is None else json_float(x / w) for x in omega],
            "w_max_over_h": None if wmax is None else [json_float(x) for x in w_over_h],
            "valid_up_to": json_float(valid), "valid_reason": reason,
            "grid": spec.amplitudes is None and spec.w_over_h is None, "tolerance": spec.tolerance,
            "probe": json_float(probe), "flags": flags, "counts": counts}


def beyond_validity(block: dict[str, Any], A: float | None) -> bool:
    """Whether amplitude ``A`` lies beyond the block's validity limit (a limit of None: never)."""
    v = block.get("valid_up_to")
    return A is not None and v is not None and A > float(v) * (1 + 1e-12)
