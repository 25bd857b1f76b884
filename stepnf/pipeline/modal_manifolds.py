"""Manifolds of several master modes on a model in modal coordinates (the von Karman shell; issue 33).

The scene's keys are the solver adapters' (``[analysis.backbone] manifolds = [["(2,1)", "(4,1)"]]`` or ``"auto"``,
``resonance``, ``ratios``; :mod:`stepnf.pipeline.manifolds`), and so are the sets' resolution, the "auto" merging,
the branches and the blocks (:func:`~stepnf.pipeline.manifolds.explicit_sets`,
:func:`~stepnf.pipeline.manifolds.auto_sets`, :func:`~stepnf.pipeline.manifolds.manifold_output`). What differs:

* the modal DPIM works over an invariant subspace of the model (:mod:`stepnf.pipeline.modal_forces`: a cos mode of
  ``k_p`` nodal diameters drives the cos modes of ``k = j k_p`` only), so a manifold is parametrised in the
  subspace of the mode of its set that holds every mode of the set (:func:`holder`; unique when it exists: two
  holders have the same k). None holds them when the set has a sin companion, or modes that symmetry does not
  couple (``k`` not all multiples of one of them): a SceneError naming ``analysis.backbone.manifolds[i]``
  (exit 2), before any DPIM;
* ``M = I``, ``K = diag(omega^2)``, the masters are unit vectors of the subspace, the forces the subspace's
  modal forces, probe 1 (modal coordinates: the forces are exact cubics), as the single-mode modal DPIM
  (:func:`stepnf.pipeline.modal_coordinates.modal_dpim`); the result's masters, flags and messages are renumbered
  to the model's modes;
* ``"auto"``: each cos master with the modes :func:`stepnf.dpim.parametrisation.resonance_flags` flags near 1:1 ..
  1:4 of it among the modes of its own subspace (the spectrum the single-mode modal DPIM checks), merged as the
  adapters' when one subspace still holds the union; a sin master keeps its single-mode backbone (its cos twin's);
* ``W_max / h`` from the subspace's transverse field (h = 1), ``A`` the master's modal coordinate.

Blocks and HDF5 arrays as the adapters' (``backbone_<p>_manifold_*`` once, ``backbone_<p>_branch<i>_*``), plus
``modes`` (block) and ``backbone_<p>_modes`` (arrays, with the manifold's): the subspace's modes, over which the
manifold's fields ``W`` are given.
"""
from __future__ import annotations

import re
from dataclasses import replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from stepnf.dpim.backbone_report import WMax
from stepnf.dpim.multimode.manifold import ManifoldResult
from stepnf.dpim.parametrisation import DPIM, DPIMTolerances, ModeSpectrum, resonance_flags
from stepnf.errors import NumericalError, SceneError
from stepnf.pipeline.backbone import BACKBONE_FAILURES, failed_backbone
from stepnf.pipeline.manifolds import (KEY, ManifoldPlan, auto_sets, check_resonant, explicit_sets, manifold_output,
                                       manifold_text, parametrise_plan)
from stepnf.pipeline.modal_forces import ModalSystem, modal_subspace, modal_system
from stepnf.pipeline.outputs import BackboneOutput

#: The probe of the modal DPIM (modal coordinates; as the single-mode modal backbone).
PROBE = 1.0
#: The size that stands for a solver adapter's STEP amplitude in :func:`~stepnf.pipeline.manifolds.manifold_output`
#: (branches started at 1/100 of it, traced to 100 times it at most): the master's amplitude whose linear mode has
#: ``W_max / h`` this (``0.1 / max |phi_p|``; 0.1 without the modes' maxima).
SIZE_W_OVER_H = 0.1


class Subspaces:
    """The invariant subspace (global modes) of each mode of a modal model, found once per mode."""

    def __init__(self, model: Any):
        self.model, self._of = model, {}

    def __call__(self, q: int) -> np.ndarray | None:
        if q not in self._of:
            self._of[q] = modal_subspace(self.model, int(q))
        return self._of[q]

    def is_sin(self, q: int) -> bool:
        """Whether mode ``q`` is outside its own system (a sin companion: its system is its cos twin's)."""
        s = self(q)
        return s is not None and int(q) not in set(s.tolist())

    def holder(self, modes: Any) -> int | None:
        """The mode of ``modes`` whose subspace holds them all (module docstring), or None."""
        for q in modes:
            s = self(q)
            if s is not None and not self.is_sin(q) and set(int(x) for x in modes) <= set(s.tolist()):
                return int(q)
        return None


def modal_plans(scene: Any, model: Any, omega: np.ndarray, labels: list, masters: list[int],
                subspaces: Subspaces) -> list[ManifoldPlan]:
    """The scene's manifolds on the modal model (module docstring; [] without ``manifolds``): every set checked
    before any DPIM."""
    spec = scene.backbone
    if spec is None or spec.manifolds is None:
        return []
    if subspaces(masters[0]) is None:
        raise SceneError(scene.file, "analysis.backbone", f"the {scene.solver!r} model gives only g^s_pp and "
                         "h^p_ppp, not its whole modal force: no DPIM backbone")
    if spec.w_over_h is not None and not callable(getattr(model, "galerkin", None)):
        raise SceneError(scene.file, "analysis.backbone.w_over_h", f"the {scene.solver!r} model gives no "
                         "transverse displacement field; give amplitudes instead")
    tol = scene.tolerances.resonance if spec.resonance is None else float(spec.resonance)
    if spec.manifolds == "auto":
        def flags_of(p: int) -> list[dict] | None:
            if subspaces.is_sin(p):
                return None
            s = subspaces(p)
            w = np.asarray(omega, dtype=float)[s]
            try:
                flags = resonance_flags(sp.diags(w ** 2).tocsr(), sp.identity(len(s), format="csr"),
                                        float(omega[p]), spec.order, w, int(np.flatnonzero(s == p)[0]), None, None,
                                        tol, scene.degeneracy_tolerance)
            except NumericalError:  # an accidental twin in the subspace: the single-mode path says so
                return None
            return [{**f, "mode": int(s[int(f["mode"])])} for f in flags if f.get("mode") is not None]
        return auto_sets(list(masters), np.asarray(omega, dtype=float), flags_of, spec, tol, True,
                         together=lambda modes: subspaces.holder(sorted(modes)) is not None)
    plans = explicit_sets(scene, labels, len(omega), list(masters), spec)
    for plan in plans:
        if subspaces.holder(plan.modes) is None:
            raise SceneError(scene.file, f"{KEY}[{plan.index}]", uncoupled(scene, plan, labels, subspaces))
        check_resonant(scene, plan, omega, tol, int(spec.order), labels)
    return plans


def uncoupled(scene: Any, plan: ManifoldPlan, labels: list, subspaces: Subspaces) -> str:
    """Why no invariant subspace of the model holds the modes of ``plan``."""
    named = ", ".join(f"{q} {labels[q]}" for q in plan.modes)
    sin = [q for q in plan.modes if subspaces.is_sin(q)]
    if sin:
        return (f"mode {sin[0]} {labels[sin[0]]} is a sin companion: the {scene.solver!r} model's manifolds lie in the "
                "invariant subspace of a cos mode (the cos modes of k = j k_p), which holds no sin mode (a sin "
                "master's backbone is its cos twin's; a manifold with a 1:1 twin is not computed): name cos modes")
    return (f"the modes {named} are not coupled by symmetry: none of them drives all the others (a cos mode of k_p "
            f"nodal diameters drives only the cos modes of k = j k_p, j = 0, 1, ...), so no manifold holds them all "
            "on this model: give modes whose k are multiples of one of theirs")


def renumbered(text: str, index: np.ndarray, labels: list) -> str:
    """``text`` (a message of the DPIM in the subspace) with its mode numbers the model's (and their labels)."""
    def one(i: str) -> str:
        g = int(index[int(i)])
        return f"{g} {labels[g]}"

    def tup(mt: re.Match) -> str:
        return "modes [" + ", ".join(one(i) for i in re.findall(r"\d+", mt.group(1))) + "]"
    text = re.sub(r"\bmodes \((\d+(?:, \d+)*),?\)", tup, text)
    return re.sub(r"\bmode (\d+)\b", lambda mt: "mode " + one(mt.group(1)), text)


def modal_manifold(scene: Any, model: Any, plan: ManifoldPlan, holder: int,
                   labels: list) -> tuple[ManifoldResult, ModalSystem]:
    """The manifold of ``plan`` in the subspace of mode ``holder`` (module docstring), numbered as the model."""
    spec, tol = scene.backbone, scene.tolerances
    system = modal_system(model, holder)
    assert system is not None
    local = [int(np.flatnonzero(system.index == q)[0]) for q in plan.modes]
    m = len(system.omega)
    dpim = DPIM(system.forces, sp.diags(system.omega ** 2).tocsr(), sp.identity(m, format="csr"),
                ModeSpectrum(omega=system.omega),
                tolerances=DPIMTolerances(resonance=tol.resonance, twin=scene.degeneracy_tolerance))
    try:
        man = parametrise_plan(dpim, scene.file, plan, local, np.eye(m)[:, local], system.omega[local], spec, PROBE)
    except NumericalError as exc:
        raise NumericalError(renumbered(str(exc), system.index, labels)) from None
    except SceneError as exc:  # ratios that do not match the frequencies
        raise SceneError(exc.file, exc.key, renumbered(exc.message, system.index, labels)) from None
    flags = []
    for f in man.flags:
        f = dict(f, message=renumbered(str(f.get("message", "")), system.index, labels))
        if f.get("mode") is not None:
            f["mode"] = int(system.index[int(f["mode"])])
        flags.append(f)
    return replace(man, masters=tuple(int(q) for q in plan.modes), flags=flags), system


def modal_manifold_backbone(scene: Any, model: Any, plan: ManifoldPlan, holder: int, made: dict, p: int,
                            labels: list, progress: Any) -> BackboneOutput:
    """Master ``p``'s backbone on the manifold of ``plan``, parametrised once for all its masters (``made``: modes
    -> (manifold or its failure, its system, the master its arrays are stored with)); a failure as the adapters'
    (:func:`stepnf.pipeline.backbone.failed_backbone`: the run goes on and exits 3)."""
    spec = scene.backbone
    if plan.modes not in made:
        try:
            man, system = modal_manifold(scene, model, plan, holder, labels)
            progress.message(manifold_text(plan, man))
        except BACKBONE_FAILURES as exc:
            man, system = exc, None
        made[plan.modes] = (man, system, p)
    man, system, stored_with = made[plan.modes]
    try:
        if isinstance(man, BaseException):
            raise man
        wmax = WMax(1.0, linear=system.transverse) if system.transverse is not None else None
        tol = scene.tolerances.resonance if spec.resonance is None else float(spec.resonance)
        peak = model.mode_maxima() if callable(getattr(model, "mode_maxima", None)) else None
        size = SIZE_W_OVER_H / float(peak[p]) if peak is not None and float(peak[p]) > 0 else SIZE_W_OVER_H
        bo = manifold_output(man, plan, p, spec, wmax, PROBE, size, stored_with, tol)
    except BACKBONE_FAILURES as exc:
        progress.message(f"backbone of master mode {p} on the manifold of modes {list(plan.modes)} failed: {exc}")
        return failed_backbone(spec, PROBE, exc)
    bo.block["modes"] = [int(s) for s in system.index]
    if stored_with == p:
        bo.arrays[f"backbone_{p}_modes"] = np.asarray(system.index, dtype=int)
    return bo
