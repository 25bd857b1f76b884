"""Stage ``forced``: the frequency-response curves of every master with a backbone, with ``[analysis.forcing]``.

Per master ``p`` whose backbone stage kept a single-mode parametrisation (:class:`~stepnf.dpim.parametrisation.DPIMResult`)
with a validity range, one curve per forcing level (:func:`stepnf.forced.frc.forced_responses`: the averaged
reduced dynamics on the conservative manifold, damped to first order); per master on a manifold of several modes
(``[analysis.backbone] manifolds``), the curves of :func:`stepnf.forced.manifold_frc.manifold_forced_responses` (the
rotating-frame steady states of the manifold's reduced dynamics, damping and forcing at leading order), with every
manifold mode's amplitude:

* ``modal = [k, ...]``: ``F = k M phi_p`` (``phi_p`` mass-normalised, so the master's modal force is ``k``);
* ``load = {set | box, dofs, amplitude}``: ``F`` the nodal forces, ``amplitude`` (force units) on each named dof
  of the selected nodes, over the model's free dofs (a dof the boundary conditions fix carries none).

The load's dofs are found right after the ``model`` stage (:func:`forcing_check_stage`, before any eigen-solve):
a box among the dofs' coordinates, a named set among the node sets of the adapter's mesh (``points`` and
``node_sets``, on the adapter or its ``mesh``), as ``[[model.boundary]]`` selects them
(:func:`stepnf.plugin.boundary.select_nodes`). An unknown set, a box or set with no free dof of the named
directions, or an adapter that exposes no node sets is a :class:`~stepnf.errors.SceneError` naming
``analysis.forcing.load.*`` (exit 2).

A master without a usable backbone (its DPIM failed or was refused: a driven twin; a backbone with no validity
range) gets no curve and a reason (``frc_reason``), never a crash.
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, Iterator

import numpy as np

from stepnf.errors import NumericalError, SceneError
from stepnf.forced.damping import Damping, damping_ratio
from stepnf.forced.frc import forced_responses
from stepnf.forced.manifold_frc import manifold_forced_responses
from stepnf.forced.spec import LoadSpec
from stepnf.plugin.adapter import DIRECTIONS
from stepnf.plugin.boundary import BoundaryCondition, box_tolerance, select_nodes
from stepnf.pipeline.backbone import w_max_measure
from stepnf.pipeline.outputs import Backbones, Evaluations, RunContext, RunModel, RunModes
from stepnf.pipeline.state import StageView

LOAD = "analysis.forcing.load"


@dataclass(frozen=True)
class ForcedOutput:
    """One master's forced responses: its curves (:class:`stepnf.forced.frc.FRC`, one per level) and their HDF5
    arrays (``frc_<p>_<i>_*``), or no curve and the ``reason``."""

    frcs: tuple = ()
    reason: str | None = None
    arrays: dict[str, np.ndarray] = field(default_factory=dict)

    def to_json(self) -> list[dict]:
        """The ``frc`` list of the master's record: one entry per forcing level (issue 34's keys)."""
        return [f.to_json() for f in self.frcs]


def mesh_sets(adapter: Any) -> tuple[np.ndarray, dict] | None:
    """``(points (N, 3), {name: node indices})`` of the adapter's mesh (on the adapter, as the solid adapters
    keep them, or on its ``mesh``); None when it exposes none."""
    for owner in (adapter, getattr(adapter, "mesh", None)):
        sets, points = getattr(owner, "node_sets", None), getattr(owner, "points", None)
        if owner is not None and sets is not None and points is not None:
            return np.asarray(points, dtype=float), sets
    return None


def load_dofs(scene: Any, model: RunModel, load: LoadSpec) -> np.ndarray:
    """Indices (free numbering, sorted) of the dofs the load acts on (module docstring); a SceneError naming the
    key otherwise."""
    f = scene.file
    X, D = model.X, model.dirs
    if X is None or D is None:
        raise SceneError(f, LOAD, f"a load on nodes needs the dofs' coordinates and directions, which the "
                         f"{scene.solver!r} model does not give; use modal = [k, ...] (works with every model)")
    X, D = np.asarray(X, dtype=float), np.asarray(D)
    codes = [DIRECTIONS.index(d) for d in load.dofs]
    if load.box is not None:
        bc = BoundaryCondition(LOAD, tuple(codes), box=load.box)
        nodes = select_nodes(bc, X, {}, f)  # the dofs inside the box (each row of X a dof's node)
        at = np.zeros(len(X), dtype=bool)
        at[nodes] = True
    else:
        found = mesh_sets(model.adapter)
        if found is None:
            raise SceneError(f, f"{LOAD}.set", f"the {scene.solver!r} model exposes no named node sets: a load on a "
                             "set needs a mesh with named sets; select the nodes with box = [[x0, y0, z0], [x1, y1, "
                             "z1]], or use modal = [k, ...] (works with every model)")
        points, sets = found
        nodes = select_nodes(BoundaryCondition(LOAD, tuple(codes), set=load.set), points, sets, f)
        at = near(X, points[nodes], box_tolerance(points))
    dofs = np.flatnonzero(at & np.isin(D, codes))
    if dofs.size == 0:
        where = f"set {load.set!r}" if load.set is not None else "the box"
        raise SceneError(f, f"{LOAD}.dofs", f"no free dof {list(load.dofs)} on the nodes of {where} (the model's "
                         f"dofs there: {sorted({DIRECTIONS[c] for c in D[at]}) or 'none'}; fixed dofs carry no load)")
    return dofs


def near(X: np.ndarray, P: np.ndarray, tol: float) -> np.ndarray:
    """Which rows of ``X`` (n, 3) lie within ``tol`` of a row of ``P`` (k, 3)."""
    from scipy.spatial import cKDTree

    if len(P) == 0:
        return np.zeros(len(X), dtype=bool)
    dist, _ = cKDTree(P).query(X, distance_upper_bound=max(tol, 1e-300))
    return np.isfinite(dist)


def forcing_check_stage(ctx: RunContext, model: RunModel) -> np.ndarray | None:
    """The dofs a ``load`` acts on, found right after the ``model`` stage (a mistake is an exit 2 before any
    solve); None without a load."""
    forcing = ctx.scene.forcing
    if forcing is None or forcing.load is None:
        return None
    return load_dofs(ctx.scene, model, forcing.load)


def damping_check_stage(ctx: RunContext, modes: RunModes) -> None:
    """Refuse an overdamped master (Rayleigh damping with xi >= 1 at its frequency) right after the ``modes``
    stage, before any parametrisation: a :class:`SceneError` naming the key (exit 2)."""
    scene = ctx.scene
    if scene.forcing is None:
        return
    with in_scene(scene):
        for j, q in enumerate(modes.masters):
            damping_ratio(scene.damping, float(modes.omega[q]), j)


@contextmanager
def in_scene(scene: Any) -> Iterator[None]:
    """Re-raise a :class:`SceneError` of :mod:`stepnf.forced` (which knows the key, not the file) naming the
    scene's file."""
    try:
        yield
    except SceneError as exc:
        if exc.file is not None or scene.file is None:
            raise
        raise SceneError(scene.file, exc.key, exc.message) from exc


def levels(ctx: RunContext, model: RunModel, loaded: np.ndarray | None) -> list[tuple]:
    """``(level, value)`` per forcing level: ``({"kappa": k}, k)`` (``F = k M phi_p``, built by
    :func:`stepnf.forced.frc.forced_responses`) or ``({"load": a, "set" | "box": ..., "dofs": [...]}, F)`` (F over
    the free dofs, model force units)."""
    forcing = ctx.scene.forcing
    if forcing.modal is not None:
        return [({"kappa": k}, k) for k in forcing.modal]
    load = forcing.load
    where = {"set": load.set} if load.set is not None else {"box": [list(c) for c in load.box]}
    out = []
    for a in load.amplitude:
        F = np.zeros(model.n)
        F[loaded] = a
        out.append(({"load": a, **where, "dofs": list(load.dofs)}, F))
    return out


def unusable(bb: Any) -> str | None:
    """Why master's backbone output ``bb`` carries no forced response (None: it does)."""
    if bb is None:
        return "no backbone"
    block = bb.block
    if block.get("failed"):
        return "its backbone failed"
    if block.get("manifold") and getattr(bb, "manifold", None) is None:
        return "its manifold of several modes is not kept"
    if bb.result is None and not block.get("manifold"):
        return f"no single-mode parametrisation ({block.get('valid_reason') or 'refused'})"
    if block.get("valid_up_to") == 0:
        return f"its backbone has no validity range ({block.get('valid_reason')})"
    return None


def forced_stage(ctx: RunContext, model: RunModel, modes: RunModes, evals: Evaluations, backbones: Backbones,
                 loaded: np.ndarray | None) -> Backbones:
    """``backbones`` with the forced responses of every master (``Backbones.forced``), when the scene has
    ``[analysis.forcing]``; ``loaded``: :func:`forcing_check_stage`'s dofs. W_max/h is measured as the backbone's
    (:func:`stepnf.pipeline.backbone.w_max_measure`) where that is a linear map on the fields. A curve that
    cannot be computed (:class:`~stepnf.errors.NumericalError`: a response unbounded on the manifold; a
    :class:`~stepnf.errors.SceneError`: a load that does not excite this master) leaves that master without
    curves and says why; the run goes on, the backbones kept."""
    scene = ctx.scene
    if scene.forcing is None:
        return backbones
    wmax = w_max_measure(StageView(ctx, model, modes, None, evals))
    linear = wmax is not None and wmax.linear is not None
    out: dict[int, ForcedOutput] = {}
    with ctx.progress.stage("forced", f"forced responses: {len(levels_of(scene))} level(s) per master"):
        with in_scene(scene):  # the damping's and the forces' refusals name the key; here they get the file too
            damping = Damping(scene.damping, model.M, model.K,
                              [(modes.phi[:, q], float(modes.omega[q])) for q in modes.masters])
            for j, p in enumerate(modes.masters):
                bb = backbones.by_master.get(p)
                why = unusable(bb)
                if why is not None:
                    out[p] = ForcedOutput(reason=why)
                    continue
                if bb.result is None:  # on a manifold of several modes
                    out[p] = manifold_output(ctx, model, bb, damping, loaded, wmax if linear else None, j, p)
                    continue
                backbone = bb.result.backbone()
                try:
                    frcs = forced_responses(bb.result, damping, levels(ctx, model, loaded),
                                            scene.forcing.frequency_range, backbone=backbone,
                                            valid_to=bb.block.get("valid_up_to"), points=scene.forcing.points,
                                            transverse=wmax.linear if linear else None,
                                            h=wmax.h if linear else None, master=j, mode=p)
                except (NumericalError, SceneError) as exc:  # (SceneError: a load that does not excite p)
                    ctx.progress.message(f"forced response of master mode {p} failed: {exc}")
                    out[p] = ForcedOutput(reason=f"not computed: {' '.join(str(exc).split())}")
                    continue
                for c in frcs:  # W_max/h at the peak, as the table prints it
                    c.peak["w_max_h"] = backbone.w_max(c.peak["rho"], wmax.linear, wmax.h) if linear else None
                out[p] = ForcedOutput(tuple(frcs), None, frc_arrays(p, frcs))
    return replace(backbones, forced=out)


def manifold_output(ctx: RunContext, model: RunModel, bb: Any, damping: Damping, loaded: np.ndarray | None,
                    wmax: Any, j: int, p: int) -> ForcedOutput:
    """Master ``p``'s curves on its manifold of several modes (``bb.manifold``), or no curve and the reason."""
    man = bb.manifold
    try:
        frcs = manifold_forced_responses(man, damping, levels(ctx, model, loaded), ctx.scene.forcing.frequency_range,
                                         list(man.masters).index(p), valid_to=bb.block.get("valid_up_to"),
                                         transverse=None if wmax is None else wmax.linear,
                                         h=1.0 if wmax is None else float(wmax.h), master=j)
    except (NumericalError, SceneError) as exc:
        ctx.progress.message(f"forced response of master mode {p} failed: {exc}")
        return ForcedOutput(reason=f"not computed: {' '.join(str(exc).split())}")
    return ForcedOutput(tuple(frcs), None, frc_arrays(p, frcs))


def levels_of(scene: Any) -> tuple:
    forcing = scene.forcing
    return forcing.modal if forcing.modal is not None else forcing.load.amplitude


def frc_arrays(p: int, frcs: list) -> dict[str, np.ndarray]:
    """The HDF5 arrays of master ``p``'s curves: ``frc_<p>_<i>_Omega``, ``_amplitude``, ``_rho`` (single-mode
    curves), ``_stable``, ``_valid``, ``_segment`` (level ``i`` in the scene's order), ``_w_max_over_h`` where
    measured and, on a manifold of several modes, ``_amplitude_<q>`` of every manifold mode q."""
    out = {}
    for i, c in enumerate(frcs):
        key = f"frc_{p}_{i}"
        out[f"{key}_Omega"] = np.asarray(c.Omega, dtype=float)
        out[f"{key}_amplitude"] = np.asarray(c.amplitude, dtype=float)
        if getattr(c, "rho", None) is not None:
            out[f"{key}_rho"] = np.asarray(c.rho, dtype=float)
        for q, A in zip(getattr(c, "masters", ()), np.asarray(getattr(c, "amplitudes", np.zeros((0, 0)))).T):
            out[f"{key}_amplitude_{q}"] = np.asarray(A, dtype=float)
        out[f"{key}_stable"] = np.asarray(c.stable, dtype=bool)
        out[f"{key}_valid"] = np.asarray(c.valid, dtype=bool)  # within the backbone's validity range
        out[f"{key}_segment"] = np.asarray(c.segment, dtype=int)  # the piece in the range (or isola) of each point
        if getattr(c, "w_max_h", None) is not None:
            out[f"{key}_w_max_over_h"] = np.asarray(c.w_max_h, dtype=float)
    return out


def with_forced(records: list, backbones: Backbones) -> list:
    """The master modes' records with their ``frc`` lists (or ``frc_reason``), from :func:`forced_stage`."""
    forced = getattr(backbones, "forced", None) or {}
    for rec in records:
        fo = forced.get(rec.index)
        if fo is not None:
            rec.frc, rec.frc_reason = fo.to_json(), fo.reason
    return records
