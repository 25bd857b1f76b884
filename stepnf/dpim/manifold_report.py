"""What a run reports of a master on a manifold of several modes: its ``backbone`` block (issue 33).

The block has every key of the single-mode one (:func:`stepnf.dpim.backbone_report.backbone_report`: ``order``,
``amplitude``, ``omega``, ``omega_ratio``, ``w_max_over_h``, ``valid_up_to``, ``valid_reason``, ``grid``,
``tolerance``, ``probe``, ``flags``, ``counts``), measured on the branch of the manifold's reduced dynamics that
continues the master's linear mode (:func:`stepnf.dpim.multimode.backbone.backbone_branches`): ``A`` the
amplitude of the master's modal coordinate, ``omega`` the master's angular frequency ``k_j Omega`` at A
(:func:`~stepnf.dpim.multimode.backbone.omega_at`, to round-off), validity from orders N-2 and N on the same
branch. And three more::

    manifold: {modes, ratios, resonant_monomials, order, resonance, chosen, why}
    branch: {kind, masters, ratios, Omega: [...], A: [[A of masters[0]...], ...], stable: [...], valid_up_to,
             valid_reason, closed, rotations}    # the continuing branch as traced (its points)
    coupled_branches: [{same keys}, ...]         # the other branches of this master, born at the resonance

``Omega`` is the fundamental (rad per model time unit; master l moves at ``ratios[l] Omega``), ``A`` one
list per master of the manifold (model length units), ``stable`` per point (rotating-frame eigenvalues,
:meth:`stepnf.dpim.multimode.branches.ReducedSystem.stability`). ``resonant_monomials``: the nonlinear
coefficients kept in the reduced dynamics of the masters' equations (one of each conjugate pair). ``closed``: the
branch came back to its first point (a loop, traced once); ``rotations``: how many rotations of exact twin masters
it was traced modulo (1 on a standing wave of exact twins, :class:`stepnf.dpim.multimode.branches.ReducedSystem`).
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from scipy.optimize import brentq

from stepnf.dpim.multimode.backbone import omega_at, point_at
from stepnf.dpim.multimode.measures import orbit_measure
from stepnf.errors import NumericalError
from stepnf.flags import new_flag
from stepnf.keys.backbone import BackboneSpec
from stepnf.nf.coefficient import json_float

#: Without a list of amplitudes the branches are traced to this many times the amplitude where the master's
#: cubic frequency shift reaches 10 % (the single-mode grid's fallback, FALLBACK_SHIFT): far enough for the
#: validity limit of orders N-2 and N to be met on the way in the cases measured (near 1:4: 3.2 against 5.4).
TRACE_BEYOND = 2.0
#: ... but not beyond this many times the master's STEP amplitude (the size at which the forces were found
#: accurate) unless amplitudes are listed: a master without a cubic shift (the upper mode of an exact 1:2) would
#: otherwise be traced from an amplitude of ~1e6.
TRACE_CAP = 100.0


def resonant_monomials(manifold: Any) -> int:
    """The nonlinear coefficients of the masters' own equations (i < m) kept in the reduced dynamics."""
    m = len(manifold.masters)
    return sum(1 for (i, a), c in manifold.f.items() if i < m and sum(a) >= 2 and c != 0)


def trace_top(manifold: Any, j: int, spec: BackboneSpec, fallback: float) -> float:
    """How far (amplitude of master ``j``) to trace its branches: past the largest listed amplitude, else
    :data:`TRACE_BEYOND` times where the cubic shift reaches 10 % (``fallback`` without a cubic term), at most
    :data:`TRACE_CAP` ``fallback``."""
    m = len(manifold.masters)
    cubic = [0] * (2 * m)
    cubic[j], cubic[j + m] = 2, 1
    c = manifold.f.get((j, tuple(cubic)), 0j)
    w = float(manifold.omega[j])
    a10 = 2.0 * math.sqrt(0.1 * w / abs(c.imag)) if c.imag else float(fallback)
    listed = list(spec.amplitudes or ())
    return max([min(TRACE_BEYOND * a10, TRACE_CAP * float(fallback))] + [1.05 * a for a in listed])


def branch_json(b: Any) -> dict[str, Any]:
    """A branch as JSON (module docstring)."""
    return {"kind": b.kind, "masters": [int(q) for q in b.masters], "ratios": [int(k) for k in b.ratios],
            "Omega": [json_float(x) for x in b.Omega], "A": [[json_float(x) for x in col] for col in b.A.T],
            "stable": [bool(s) for s in b.stable], "valid_up_to": json_float(b.valid_A),
            "valid_reason": b.valid_reason, "closed": bool(b.closed),
            "rotations": 0 if b.rotations is None else len(b.rotations)}


def _w_max_at(manifold, branch, measure, A: float, transverse, h: float) -> float:
    m = len(branch.masters)
    u = point_at(manifold, branch, A)
    return float(measure.w_max(u[:m] + 1j * u[m:2 * m], transverse, h))


def _amplitude_at_w(manifold, branch, measure, target: float, transverse, h: float) -> float:
    """The amplitude of the master where W_max / h first reaches ``target`` on ``branch`` (NumericalError
    when it does not)."""
    W, A = branch.W_max, branch.A[:, branch.mode]
    hit = np.flatnonzero(W >= target) if W is not None else np.zeros(0, dtype=int)
    if not len(hit) or hit[0] == 0:
        span = f" (it spans {float(np.min(W)):.6g} to {float(np.max(W)):.6g})" if W is not None else ""
        raise NumericalError(f"the branch '{branch.kind}' never reaches W_max/h = {target:.6g}{span}")
    i = int(hit[0])
    return float(brentq(lambda a: _w_max_at(manifold, branch, measure, a, transverse, h) - target,
                        float(A[i - 1]), float(A[i]), xtol=1e-13 * float(A[i])))


def manifold_report(manifold: Any, j: int, branches: Sequence[Any], spec: BackboneSpec, *, probe: float,
                    resonance: float = 0.05, transverse: Any = None, h: float = 1.0, chosen: str = "explicit",
                    why: str = "") -> dict[str, Any]:
    """The ``backbone`` block (module docstring) of master ``j`` (its position in ``manifold.masters``) from its
    ``branches`` (:func:`~stepnf.dpim.multimode.backbone.backbone_branches`, traced with ``spec.tolerance``);
    ``resonance`` the tolerance the parametrisation used, ``chosen``/``why`` how the manifold was chosen.
    ``transverse``, ``h``: W_max / h (indices or a linear map of fields, :class:`~stepnf.dpim.backbone_report.WMax`'s
    ``linear``; None: not measured)."""
    main = next((b for b in branches if b.kind.startswith("continues mode")), None)
    if main is None:
        return _no_own_branch(manifold, j, branches, spec, probe, resonance, chosen, why)
    k = int(main.ratios[j])
    w = float(manifold.omega[j])
    valid, reason = main.valid_A, main.valid_reason
    flags = list(manifold.flags)
    if reason == "amplitude folds":
        flags.append(new_flag("backbone_fold", mode=None,
                              message=f"the amplitude of mode {manifold.masters[j]} stops growing at A = {valid:.6g} "
                                      "on the branch that continues it (validity limit set there)"))
    measure = orbit_measure(manifold, main.ratios) if transverse is not None else None
    if spec.amplitudes is not None:
        amps: list[float | None] = list(spec.amplitudes)
    elif spec.w_over_h is not None:
        amps = []
        for target in spec.w_over_h:
            try:
                if measure is None:
                    raise NumericalError("W_max/h is not measured on this model's manifolds (no linear transverse map)")
                amps.append(_amplitude_at_w(manifold, main, measure, target, transverse, h))
            except (NumericalError, ValueError) as exc:
                amps.append(None)
                flags.append(new_flag("backbone_unreached", mode=None, message=str(exc)))
    else:
        top = float(valid) if valid else float(main.A[:, j].max())
        amps = list(np.linspace(top / spec.points, top, spec.points))
    omega, w_over_h = [], []
    for A in amps:
        Om = None
        if A is not None:
            try:
                Om = k * omega_at(manifold, main, float(A))
            except NumericalError as exc:
                flags.append(new_flag("backbone_unreached", mode=None, message=str(exc)))
        omega.append(Om)
        w_over_h.append(None if Om is None or measure is None
                        else _w_max_at(manifold, main, measure, float(A), transverse, h))
    return {"order": int(manifold.order), "amplitude": [json_float(a) for a in amps],
            "omega": [json_float(x) for x in omega],
            "omega_ratio": [None if x is None else json_float(x / w) for x in omega],
            "w_max_over_h": None if measure is None else [json_float(x) for x in w_over_h],
            "valid_up_to": json_float(valid), "valid_reason": reason,
            "grid": spec.amplitudes is None and spec.w_over_h is None, "tolerance": spec.tolerance,
            "probe": json_float(probe), "flags": flags, "counts": _counts(manifold),
            "manifold": _manifold_json(manifold, resonance, chosen, why),
            "branch": branch_json(main),
            "coupled_branches": [branch_json(b) for b in branches if b is not main]}


def _counts(manifold: Any) -> dict[str, Any]:
    return {str(c["order"]): {key: v for key, v in c.items() if key != "order"} for c in manifold.counts}


def _manifold_json(manifold: Any, resonance: float, chosen: str, why: str) -> dict[str, Any]:
    ratios = None if manifold.ratios is None else [int(x) for x in manifold.ratios]
    return {"modes": [int(q) for q in manifold.masters], "ratios": ratios,
            "resonant_monomials": resonant_monomials(manifold), "order": int(manifold.order),
            "resonance": json_float(resonance), "chosen": chosen, "why": why}


def _no_own_branch(manifold: Any, j: int, branches: Sequence[Any], spec: BackboneSpec, probe: float,
                   resonance: float, chosen: str, why: str) -> dict[str, Any]:
    """The block of a master no branch of which continues its linear mode (an exact resonance: 1:2 with a
    quadratic coupling): no amplitudes, validity 0, a ``manifold_no_own_branch`` flag; its coupled branches."""
    p = int(manifold.masters[j])
    flag = new_flag("manifold_no_own_branch", mode=None,
                    message=f"no periodic orbit of the reduced dynamics of the manifold {list(manifold.masters)} "
                            f"continues the linear mode {p} (an exact resonance): its {len(branches)} coupled "
                            "branches take its place (coupled_branches); no backbone amplitudes")
    return {"order": int(manifold.order), "amplitude": [], "omega": [], "omega_ratio": [], "w_max_over_h": None,
            "valid_up_to": 0.0, "valid_reason": "no continuing branch", "grid": False, "tolerance": spec.tolerance,
            "probe": json_float(probe), "flags": list(manifold.flags) + [flag], "counts": _counts(manifold),
            "manifold": _manifold_json(manifold, resonance, chosen, why), "branch": None,
            "coupled_branches": [branch_json(b) for b in branches]}
