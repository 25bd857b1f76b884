"""Which printed numbers the tool itself knows to be wrong.

The printed table shows such a T (and its Gamma and behaviour) as ``n/a`` with
the reason; the JSON document and the HDF5 file keep the number and its flags,
for whoever wants to study the failure (the paper's point is precisely that
modal NF fails on a 3D model). Two cases are known wrong, not merely uncertain:

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

from .backbone import MethodResult

#: Below this share of G(phi_p, phi_p) carried by the retained modes, a modal-sum T is not shown.
TRUNCATION_UNUSABLE = 0.5
#: At or above this relative change of T between the two STEP amplitudes, T is not shown.
STEP_UNUSABLE = 1.0


def _captured_fraction(r: MethodResult) -> float | None:
    """The share of G(phi_p, phi_p) on the retained modes, from the result or its flag."""
    if r.extra.get("captured_fraction") is not None:
        return float(r.extra["captured_fraction"])
    values = [float(f["value"]) for f in r.flags
              if f.get("kind") == "modal_truncation" and f.get("value") is not None]
    return min(values) if values else None


def unusable_reason(r: MethodResult) -> str | None:
    """Why ``r.T`` is known to be wrong (a short phrase for the table), or ``None`` if it is not."""
    frac = _captured_fraction(r)
    if frac is not None and float(frac) < TRUNCATION_UNUSABLE:
        n = f"the {r.retained_modes} retained modes" if r.retained_modes else "the retained modes"
        return f"{n} carry {100 * float(frac):.2g}% of G(phi_p, phi_p): the modal sum misses the rest"
    if r.T_error is not None and r.T_error >= STEP_UNUSABLE:
        return (f"T changes by {100 * r.T_error:.3g}% between the two STEP amplitudes: "
                "not even its sign is established")
    return None
