"""Which printed numbers the tool itself knows to be wrong (kept for its callers: the rules live in
:mod:`stepnf.flags`, the one catalogue of flag kinds).

The printed table shows such a T (and its Gamma and behaviour) as ``n/a`` with
the reason; the JSON document and the HDF5 file keep the number and its flags,
for whoever wants to study the failure (the paper's point is precisely that
modal NF fails on a 3D model). Known wrong, not merely uncertain:

* **divergence**: T is infinite (an exact internal resonance: a zero denominator);
* **no single-mode manifold**: the master drives a degenerate twin, or a zero-frequency mode
  (``twin_driven``, ``rigid_mode_driven``);
* **modal truncation**: the retained modes carry less than
  :data:`TRUNCATION_UNUSABLE` of ``G(phi_p, phi_p)`` (M^-1 norm). A modal sum
  then misses most of the quadratic coupling; on a 3D model of a shell the
  bending modes carry ~1e-9 of it (the rest is on in-plane and thickness
  modes), so the printed T would be that of another structure. Between this
  and 99% the number is printed with its ``modal_truncation`` flag.
* **STEP accuracy**: T changes by :data:`STEP_UNUSABLE` (100%) or more between
  the two STEP amplitudes, so not even its sign is established.
"""
from __future__ import annotations

from typing import Any

from .flags import STEP_UNUSABLE, TRUNCATION_UNUSABLE, t_unusable

__all__ = ["STEP_UNUSABLE", "TRUNCATION_UNUSABLE", "unusable_reason"]


def unusable_reason(r: Any) -> str | None:
    """Why ``r.T`` is known to be wrong (a short phrase for the table), or ``None`` if it is not
    (:func:`stepnf.flags.t_unusable`)."""
    verdict = t_unusable(r)
    return verdict[1] if verdict else None
