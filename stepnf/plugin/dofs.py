"""Translations and rotations among an adapter's dofs (codes of :data:`stepnf.plugin.adapter.DIRECTIONS`).

A solid's nodes carry translations only (``ux uy uz``, codes 0-2, model length units); a shell's
carry rotations too (``rx ry rz``, codes 3-5, radians). Everything stepnf measures as a displacement
(the STEP amplitude, W_max/h and Gamma, mode labels, mode figures) reads the translations only, so
that a mode whose largest entry is a rotation is never scaled by that rotation (an angle in radians
is no length); rotations are bounded on their own (:data:`MAX_ROTATION`, :func:`bounded_scale`) and
written as their own field (:mod:`stepnf.io.fields`). Without directions (``None``) every dof counts
as a translation, as before rotations existed.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from stepnf.plugin.adapter import DIRECTIONS
from stepnf.runtime.progress import thousands

#: First rotation code of :data:`~stepnf.plugin.adapter.DIRECTIONS` (``rx``); codes below are translations.
FIRST_ROTATION = DIRECTIONS.index("rx")

#: Largest rotation (radians) of a STEP field ``q phi`` of a model with rotational dofs (a shell's ``rx ry rz``).
#: Co-rotational kinematics are trigonometric in the rotation angle: the cubic fit keeps terms up to
#: theta^3, and for one angle the first terms it drops are theta^2 / 12 (``1 - cos``: theta^4/24 against
#: theta^2/2) and theta^2 / 20 (``sin``: theta^5/120 against theta^3/6) of the kept ones: 7.5e-5 and 4.5e-5
#: at 0.03 rad (1.7 degrees), where the series converges fast, while the forces' round-off (eps / theta^2
#: relative, 2.5e-13) stays far below. A whole shell's truncation at that rotation is larger (Kratos's DKT
#: clamped plate at one thickness, largest rotation about pi h / L = 0.03 rad: 6.7e-4 of G, issue 32): the
#: bound keeps STEP in that range, :mod:`stepnf.step.truncation` measures and removes what is left. Every
#: field stepnf sends (STEP, its raised amplitudes, the DPIM's probes, the conservation check) is scaled
#: by :func:`bounded_scale` with it.
MAX_ROTATION = 0.03


def translation_mask(directions: Any, n: int | None = None) -> np.ndarray | None:
    """Bool (n,): the translation dofs; ``None`` without directions (then every dof is one)."""
    if directions is None:
        return None if n is None else np.ones(int(n), dtype=bool)
    D = np.asarray(directions)
    return (D >= 0) & (D < FIRST_ROTATION)


def rotation_mask(directions: Any) -> np.ndarray | None:
    """Bool (n,): the rotation dofs; ``None`` when there are none (a solid, or no directions)."""
    if directions is None:
        return None
    D = np.asarray(directions)
    rot = (D >= FIRST_ROTATION) & (D < len(DIRECTIONS))
    return rot if rot.any() else None


def translations_only(phi: np.ndarray, directions: Any) -> np.ndarray:
    """``phi`` (n,) or (n, k) with its rotation entries set to zero (a copy; ``phi`` itself without rotations)."""
    rot = rotation_mask(directions)
    if rot is None:
        return np.asarray(phi, dtype=float)
    out = np.array(phi, dtype=float)
    out[rot] = 0.0
    return out


def peak(phi: np.ndarray, mask: np.ndarray | None) -> float:
    """``max |phi_i|`` over the dofs of ``mask`` (all dofs for ``None``); 0 for none."""
    v = np.abs(np.asarray(phi, dtype=float) if mask is None else np.asarray(phi, dtype=float)[mask])
    return float(v.max()) if v.size else 0.0


def bounded_scale(phi: np.ndarray, target: float, translations: np.ndarray | None,
                  rotations: np.ndarray | None, max_rotation: float = MAX_ROTATION) -> float:
    """The largest factor ``k`` for which the field ``k phi`` moves no translation dof by more than
    ``target`` (model length units) and turns no rotation dof by more than ``max_rotation`` (radians):
    ``min(target / max|phi_t|, max_rotation / max|phi_r|)`` over the parts that are not zero (``inf`` when
    neither is). ``translations`` (bool (n,)): the dofs the target bounds (``None``: every dof, see
    :func:`peak`); ``rotations`` (bool (n,), or ``None``: no rotation bound)."""
    move = peak(phi, translations)
    turn = peak(phi, rotations) if rotations is not None else 0.0
    k = target / move if move > 0 else np.inf
    return float(min(k, max_rotation / turn) if turn > 0 else k)


def node_vectors(field: np.ndarray, coordinates: Any, directions: Any, *, rotations: bool = False
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The field's translation (or, with ``rotations``, rotation) vector at each node: ``(nodes (N, 3),
    vectors (N, 3))``, nodes told apart by their dof coordinates (sorted), components a node lacks (a fixed
    dof) zero. ``field`` (n,), ``coordinates`` (n, 3), ``directions`` (n,)."""
    X, D = np.asarray(coordinates, dtype=float), np.asarray(directions)
    lo = FIRST_ROTATION if rotations else 0
    sel = np.flatnonzero((D >= lo) & (D < lo + 3))
    if sel.size == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    nodes, inv = np.unique(X[sel], axis=0, return_inverse=True)
    out = np.zeros((len(nodes), 3))
    out[inv.ravel(), D[sel] - lo] = np.asarray(field, dtype=float)[sel]
    return nodes, out


def dof_counts(directions: Any, n: int) -> str:
    """How a summary line counts ``n`` dofs: ``"1 200 dofs"``, or with rotations
    ``"1 200 dofs (600 translations, 600 rotations)"``."""
    text = f"{thousands(n)} dofs"
    rot = rotation_mask(directions)
    if rot is None:
        return text
    r = int(np.count_nonzero(rot))
    return f"{text} ({thousands(n - r)} translations, {thousands(r)} rotations)"


__all__ = ["FIRST_ROTATION", "MAX_ROTATION", "translation_mask", "rotation_mask", "translations_only", "peak",
           "bounded_scale", "node_vectors", "dof_counts"]
