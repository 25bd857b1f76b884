"""The top of ``stepnf verify``'s default amplitudes in thicknesses: ``W_max / h <= DEFAULT_DEFLECTION``.

The default amplitudes run up to the backbone's validity limit (orders N-2 and N within the backbone's
tolerance, :meth:`stepnf.dpim.backbone.Backbone.validity_limit`). A slender structure's first modes are
nearly linear in frequency, so its series agree far out: the cantilever strips of issue 31 reached the
limit at W_max/h = 26 to 79 (tip rotations of tenths of a radian at L/h = 30 to 100), where the full
model's implicit steps have no converging Newton and every default orbit failed. The paper's plates and
the kappa = 25 cap end their validity ranges below two thicknesses (W_max/h 0.26 to 1.84 at orders 7 and 9,
bench/results/backbone_order7.json, backbone_kappa25_3d_order9.json), so the bound below leaves them as
they were, and the issue's "done" asks a cantilever verified up to W_max/h = 2: the default top amplitude
is the smaller of the validity limit and the amplitude where the orbit's state at rest deflects
``DEFAULT_DEFLECTION`` thicknesses.

``W_max`` here is what ``stepnf verify`` reports per orbit (``max_displacement``): the largest ``|x_i|``
of the parametrisation's point at ``theta = 0`` (the state at rest the orbit starts from) over the
translation dofs (a shell's rotations, in radians, are no displacement: :mod:`stepnf.plugin.dofs`); ``h`` the
scene's ``[analysis] thickness``. Without a thickness there is no cap (the validity limit alone, as before).
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from scipy.optimize import brentq

from stepnf.plugin.dofs import peak

#: Largest W_max/h of the default amplitudes (module docstring).
DEFAULT_DEFLECTION = 2.0


def deflection(bb: Any, A: float, h: float, mask: np.ndarray | None = None) -> float:
    """``W_max / h`` of the backbone ``bb``'s state at rest of amplitude ``A`` (module docstring); ``mask``
    the translation dofs (:func:`stepnf.plugin.dofs.translation_mask`; None: every dof)."""
    return peak(bb.res.displacement(0.0, bb.rho_at(A)), mask) / h


def cap_amplitudes(bb: Any, amplitudes: Sequence[float], source: str, h: float | None,
                   bound: float = DEFAULT_DEFLECTION, mask: np.ndarray | None = None) -> tuple[list[float], str]:
    """``amplitudes`` (increasing, from :func:`stepnf.verify.command.default_amplitudes`) scaled down so
    that the top one deflects ``bound`` thicknesses when it deflects more, and where the top now comes
    from; unchanged without ``h`` or amplitudes, or when the top deflects ``bound`` or less. ``mask``: the
    translation dofs W_max is measured on (None: every dof)."""
    amps = [float(A) for A in amplitudes]
    if not amps or h is None or not h > 0:
        return amps, source
    top = max(amps)
    with np.errstate(over="ignore", invalid="ignore"):
        far = deflection(bb, top, h, mask)
    if np.isfinite(far) and far <= bound:
        return amps, source
    lo = top * 1e-6  # W_max/h grows like A from 0 (the linear mode): below the bound there but for an absurd h
    A = lo if deflection(bb, lo, h, mask) >= bound else brentq(lambda a: deflection(bb, a, h, mask) - bound, lo,
                                                               top, xtol=1e-10 * top, rtol=1e-10)
    return ([a * A / top for a in amps],
            f"W_max/h = {bound:g} at A = {A:.6g} (h = {h:g}, [analysis] thickness; the default top, "
            f"{source}, deflects {f'{far:.3g} h' if np.isfinite(far) else 'beyond the series range'})")
