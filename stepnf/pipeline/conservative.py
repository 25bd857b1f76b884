"""Is the internal force the gradient of an energy? A cheap check on a master's STEP coefficients.

Normal forms assume a potential: ``f(x) = K x + G(x, x) + H(x, x, x)`` with ``G`` (and ``H``) fully
symmetric, ``a.G(b, c) = b.G(a, c)``. STEP gives, per master ``p``, only ``G(phi_p, phi_p)``: its modal
projections ``g_s = phi_s.G(phi_p, phi_p)``; the methods that use them (NF, DNF, MD, SMD, modal and full
order) take the coefficient of ``q_p q_s`` in the master's own equation, ``2 phi_p.G(phi_p, phi_s)``, to
be ``2 g_s``: that is the symmetry. The DPIM does not take it (it sends its fields to the force and
projects what comes back), and the backbone itself does not need a potential: ``M x'' + f(x) = 0`` with a
force of the state alone is reversible (``t -> -t``), so its symmetric periodic orbits still form a
one-parameter family (the backbone) with no energy gained or lost over a period (the work
``int f(x).v dt`` of a symmetric orbit is an odd integrand over a full period).

The check: the field the quadratic terms of the master drive, ``y = K^+ G(phi_p, phi_p)`` (the static
condensation: DNF's and SMD's first solve, reused; without those methods, its restriction to the computed
elastic modes, ``sum_s g_s phi_s / w_s^2``: a flat plate's membrane modes, which carry its ``y``, lie far
above them, so run DNF for a figure that means something there), and the two numbers a potential makes
equal::

    a_sym = y.G(phi_p, phi_p)                          (from STEP: no force evaluation)
    a_dyn = phi_p.G(phi_p, y)                          (8 forces: G(a, b) by polarisation)

``G(a, b) = [f(a + b) + f(-a - b) - f(a - b) - f(b - a)] / 8`` (the cubic terms cancel, the quartic
leave ``O(q^2)`` relative, as in STEP), ``a = q phi_p`` at the master's STEP amplitude ``q`` (which
bounds its rotations, :data:`stepnf.plugin.dofs.MAX_ROTATION`) and ``b`` the field ``y`` scaled to
the same largest translation (rotations bounded likewise), and again at half of both: ``a_dyn`` is the
Richardson extrapolation of the two (eight forces, one batch; a DKT plate at 0.1 and 0.05 h: 4.3e-5 and
1.1e-5 before it, O(q^2)). The figure is ``|a_dyn - a_sym| / |a_sym|``;
beyond :data:`NON_CONSERVATIVE` a ``non_conservative`` flag on the master carries it (``value``). Run only
for models with rotation dofs (a shell: co-rotational elements whose projected internal force need not
be a gradient, issue 32), so a solid model's run, force count and results are unchanged. Kratos's DKT
shells (whose force fails the harness's check on random fields, 2.6e-3) measured, with ``y = K^+ Gv``:
free plate (2,0) 4e-6 and (0,1) 1e-6, kappa = 25 cap 4e-5 and 6e-5 at 0.1 h, a quarter of that at 0.05 h
(the polarisation's O(q^2), no asymmetry): no flag there.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from stepnf.flags import new_flag
from stepnf.plugin.dofs import MAX_ROTATION, bounded_scale, peak, rotation_mask, translation_mask

#: Largest relative asymmetry ``|a_dyn - a_sym| / |a_sym|`` taken as a potential's: above the
#: polarisation's own truncation (``O(q^2)``, the size of STEP's error estimate, 1e-4 by default) and
#: below what it changes in a normal form's T (the quadratic part of T moves by about as much).
NON_CONSERVATIVE = 1e-2


def modal_condensation(Gv: np.ndarray, Phi: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``sum_s g_s phi_s / w_s^2`` over the computed elastic modes (``g_s = phi_s.Gv``): ``K^+ Gv`` on them."""
    return Phi @ ((Phi.T @ Gv) / omega ** 2)


def asymmetry_of(forces: Callable[[np.ndarray], np.ndarray], phi_p: np.ndarray, Gv: np.ndarray, y: np.ndarray,
                 q: float, dirs: Any = None) -> tuple[float, float, float]:
    """``(a_sym, a_dyn, relative)`` of the module docstring: ``Gv = G(phi_p, phi_p)`` (n,), ``y`` (n,) the field
    condensed from it, ``q`` the master's STEP amplitude, ``dirs`` the dof directions (rotations bounded by
    MAX_ROTATION, sizes measured on translations)."""
    a_sym = float(y @ Gv)
    mask, rot = translation_mask(dirs), rotation_mask(dirs)
    target = q * peak(phi_p, mask)
    # y's translations scaled to phi_p's STEP size, its rotations within the bound; finite for a y without
    # translations (a zero y: a_sym = 0)
    k = min(bounded_scale(y, target, mask, rot), target / 1e-300)
    c = 1.0 if rot is None else min(1.0, MAX_ROTATION / max(peak(np.abs(q * phi_p) + np.abs(k * y), rot), 1e-300))
    q, k = c * q, c * k  # a + b rotates by at most MAX_ROTATION too
    a, b = q * phi_p, k * y
    F = forces(np.stack([s * v for s in (1.0, 0.5) for v in (a + b, -a - b, a - b, b - a)]))
    G1, G2 = ((F[i] + F[i + 1] - F[i + 2] - F[i + 3]) / 8.0 for i in (0, 4))
    d1, d2 = float(phi_p @ G1) / (q * k), float(phi_p @ G2) / (0.25 * q * k)
    a_dyn = (4.0 * d2 - d1) / 3.0  # Richardson: the quartic terms' O(q^2) removed
    rel = abs(a_dyn - a_sym) / abs(a_sym) if a_sym != 0 else 0.0
    return a_sym, a_dyn, rel


def non_conservative_flags(state: Any, d: Any) -> list[dict]:
    """The master ``d.p``'s ``non_conservative`` flag (a list of none or one): only for a model with rotation
    dofs and a targeted STEP (``d.st``); ``state`` a :class:`~stepnf.pipeline.state.StageView`."""
    if d.st is None or rotation_mask(state.dirs) is None or state.model.forces is None:
        return []
    y = d.y if d.y is not None else modal_condensation(d.st.Gv, state.phi, state.omega)
    a_sym, a_dyn, rel = asymmetry_of(state.model.forces, d.phi, d.st.Gv, y, d.st.q, state.dirs)
    if not rel > NON_CONSERVATIVE:
        return []
    return [new_flag("non_conservative", value=rel,
                     message=f"master mode {d.p}: the internal force is not the gradient of an energy: "
                             f"phi_p.G(phi_p, y) = {a_dyn:.4g} and y.G(phi_p, phi_p) = {a_sym:.4g} differ by "
                             f"{rel:.2%} (y: the static condensation of G(phi_p, phi_p)); nf, dnf, md and smd "
                             "take them equal (their T's quadratic part carries an error of about that), the "
                             "DPIM backbone does not (a force of the state alone keeps the backbone)")]


__all__ = ["NON_CONSERVATIVE", "asymmetry_of", "modal_condensation", "non_conservative_flags"]
