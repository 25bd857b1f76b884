"""Gamma of any structure: the backbone per squared amplitude in thicknesses.

``w_NL / w = 1 + Gamma (W_max / h)^2`` with ``Gamma = T (h / W_max)^2``
(docs/design.md, "Comparing models"): ``T`` is the backbone coefficient of the
M-normalised mode shape ``phi`` (``w_NL = w (1 + T a^2)``), ``W_max`` the
largest transverse displacement of ``phi`` and ``h`` a thickness, both in
model length units, so Gamma is free of the mode's normalisation and of the
unit system.

Where ``h`` and ``W_max`` come from (:func:`gamma_scale`):

* ``[analysis] transverse`` ("ux", "uy", "uz" or a direction vector ``e``):
  ``W_max = max over nodes |u . e|`` of the mode shape, for any mesh (nodes are
  told apart by their dof coordinates; the fixed dofs of a boundary condition
  carry no displacement and are not needed); ``u`` is the node's translation:
  a shell's rotation dofs (``rx ry rz``, radians) never enter W_max, even where
  a mode's largest entry is a rotation;
* otherwise the adapter's own :meth:`~stepnf.plugin.adapter.SolverAdapter.transverse_amplitude`
  (a generated cap: the mid-surface normal displacement);
* ``h``: ``[analysis] thickness``, otherwise the model's shell scales (a cap's h).

Without one of the two, Gamma is ``None`` and :func:`gamma_scale` says why
(the run shows it as a flag): a number the tool cannot define is not printed.

With ``[analysis] transverse``, the share of the mode's kinetic energy the transverse direction carries
(:func:`transverse_share`: ``phi_e^T M phi_e / phi^T M phi``, ``phi_e`` the mode's displacement projected
on ``e`` at every node) says whether Gamma describes the mode: below :data:`GAMMA_SHARE_MIN` (an in-plane
mode of a plate, the sideways bending of a beam), W_max is the peak of a displacement the mode barely has,
and Gamma (kept in the JSON document) gets a ``gamma_not_transverse`` flag and is n/a in the table.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from stepnf.flags import new_flag
from stepnf.plugin.adapter import DIRECTIONS
from stepnf.plugin.dofs import translations_only

#: Below this share of the mode's kinetic energy in the transverse direction (:func:`transverse_share`) Gamma is
#: n/a: the mode moves mostly across it, and W_max measures a secondary component. Half is where the transverse
#: direction stops carrying most of the motion; the cases it tells apart are far from it (measured with
#: transverse = "uz": examples/beam_ccx's bending mode 0.9999, its sideways mode 1.2e-8; issue 31's in-plane
#: mode 0.004), so the figure needs no tuning.
GAMMA_SHARE_MIN = 0.5


def transverse_peak(phi: np.ndarray, X: np.ndarray | None, D: np.ndarray, transverse: str | tuple) -> float | None:
    """``max |u . e|`` over the nodes of the field ``phi`` (dof coordinates ``X``, direction codes ``D``);
    ``None`` when no dof carries that direction."""
    phi, D = np.asarray(phi, dtype=float), np.asarray(D)
    if isinstance(transverse, str):
        sel = D == DIRECTIONS.index(transverse)
        return float(np.max(np.abs(phi[sel]))) if sel.any() else None
    t = np.flatnonzero(D < 3)
    if t.size == 0 or X is None:
        return None
    _, node = np.unique(np.asarray(X, dtype=float)[t], axis=0, return_inverse=True)
    u = np.zeros((int(node.max()) + 1, 3))
    u[node.ravel(), D[t]] = phi[t]
    return float(np.max(np.abs(u @ np.asarray(transverse, dtype=float))))


def transverse_part(phi: np.ndarray, X: np.ndarray | None, D: np.ndarray, transverse: str | tuple) -> np.ndarray | None:
    """``phi`` projected on the transverse direction at every node: ``(u . e) e`` on the translation dofs, 0 on the
    others (n,); ``None`` when no dof carries that direction (or a direction vector without dof coordinates)."""
    phi, D = np.asarray(phi, dtype=float), np.asarray(D)
    if isinstance(transverse, str):
        sel = D == DIRECTIONS.index(transverse)
        return np.where(sel, phi, 0.0) if sel.any() else None
    t = np.flatnonzero(D < 3)
    if t.size == 0 or X is None:
        return None
    e = np.asarray(transverse, dtype=float)
    e = e / np.linalg.norm(e)
    _, node = np.unique(np.asarray(X, dtype=float)[t], axis=0, return_inverse=True)
    node = node.ravel()
    u = np.zeros((int(node.max()) + 1, 3))
    u[node, D[t]] = phi[t]
    out = np.zeros_like(phi)
    out[t] = (u @ e)[node] * e[D[t]]
    return out


def transverse_share(phi: np.ndarray, M: Any, X: np.ndarray | None, D: np.ndarray | None,
                     transverse: str | tuple) -> float | None:
    """The share of the mode's translational kinetic energy carried by the transverse direction:
    ``phi_e^T M phi_e / phi_t^T M phi_t`` with ``phi_e`` = :func:`transverse_part` and ``phi_t`` the mode's
    translations (its rotations, a shell's ``rx ry rz`` in radians, set to zero: a rotary inertia is no
    displacement; for a solid ``phi_t = phi``): 1 for a pure bending mode of a plate whose normal is ``e``,
    0 for an in-plane one; ``None`` without dof directions or a transverse dof."""
    if D is None:
        return None
    pe = transverse_part(phi, X, D, transverse)
    if pe is None:
        return None
    pt = translations_only(phi, D)
    total = float(pt @ (M @ pt))
    return float(pe @ (M @ pe)) / total if total > 0 else None


def share_flag(share: float | None) -> dict | None:
    """The ``gamma_not_transverse`` flag of a mode whose transverse share is below :data:`GAMMA_SHARE_MIN`."""
    if share is None or not share < GAMMA_SHARE_MIN:
        return None
    return new_flag("gamma_not_transverse", value=float(share),
                    message=f"the transverse direction carries {100 * share:.2g}% of the mode's kinetic "
                            f"energy (below {100 * GAMMA_SHARE_MIN:g}%): the mode moves mostly across it, and "
                            "Gamma = T (h / W_max)^2 would scale it by a displacement it barely has")


@dataclass(frozen=True)
class GammaScale:
    """How a run turns T into Gamma: ``thickness`` h (model units), ``amplitude(phi)`` = W_max,
    and ``source``, what defined them (stored with the results)."""

    thickness: float
    amplitude: Callable[[np.ndarray], float | None]
    source: str

    def gamma(self, T: float, w_max: float | None) -> float | None:
        """``T (h / W_max)^2``; ``None`` without a positive W_max."""
        if w_max is None or not w_max > 0:
            return None
        return T * (self.thickness / w_max) ** 2


def gamma_scale(scene: Any, adapter: Any, X: np.ndarray | None, D: np.ndarray | None
                ) -> tuple[GammaScale | None, str | None]:
    """The run's :class:`GammaScale`, or ``None`` and the reason (for a flag)."""
    scales = adapter.shell_scales()
    h = scene.thickness if scene.thickness is not None else (scales.thickness if scales is not None else None)
    if scene.transverse is not None:
        if D is None:
            return None, ("analysis.transverse needs the dof directions of the model; this adapter gives none, "
                          "so Gamma is not computed")
        e = scene.transverse

        def amplitude(phi: np.ndarray) -> float | None:
            return transverse_peak(phi, X, D, e)

        how = f"transverse = {e!r}" if isinstance(e, str) else f"transverse = [{', '.join(f'{c:.6g}' for c in e)}]"
    else:
        amplitude = adapter.transverse_amplitude
        how = "the model's transverse displacement"
    if h is None:
        return None, ("Gamma = T (h / W_max)^2 needs a thickness h: set [analysis] thickness (model length units)"
                      + ("" if scene.transverse is not None else " and transverse (\"uz\" or a direction vector)"))
    return GammaScale(h, amplitude, f"h = {h:g} ({'analysis.thickness' if scene.thickness is not None else 'model'})"
                      f", W_max: {how}"), None


NO_AMPLITUDE = ("Gamma = T (h / W_max)^2 needs the transverse direction of the mode shapes: set [analysis] "
                "transverse (\"uz\" or a direction vector)")
