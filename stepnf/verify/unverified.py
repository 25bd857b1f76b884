"""The masters ``stepnf verify`` does not check, said in its document rather than left out.

A master on a manifold of several modes (``[analysis.backbone] manifolds``, issue 33) is checked on its branches
(:mod:`stepnf.verify.manifold_orbits`); one whose block names a manifold but keeps no branches (no
``coupled_branches``: a run of an older stepnf) has nothing to start the full model's orbits from. Its entry in the
document has no checks and says so (``not_verified``).
"""
from __future__ import annotations

from typing import Any, Callable


def with_unverified(doc: dict, result: Any, say: Callable[[str], None]) -> dict:
    """``doc`` (:func:`stepnf.verify.command.verify_scene`'s) with one entry per master of ``result`` whose
    backbone block has a ``manifold`` and that ``doc`` does not check: ``index``, ``label``, ``omega``,
    ``order``, ``amplitudes_from``, ``checks`` (empty), ``integrator`` and ``stiffness_ratio`` (None) and
    ``not_verified`` (why); each also said through ``say``."""
    checked = {int(m["index"]) for m in doc["modes"]}
    for mode in getattr(result, "modes", []):
        block = getattr(mode, "backbone", None) or {}
        if int(mode.index) in checked or not block.get("manifold"):
            continue
        why = (f"master mode {mode.index} is on the manifold of modes {block['manifold']['modes']}: NOT VERIFIED "
               "(the run kept no branches of it to start the full model's orbits from)")
        say(why)
        label = mode.label
        doc["modes"].append({"index": int(mode.index), "label": list(label) if isinstance(label, tuple) else label,
                             "omega": float(mode.omega), "order": int(block["order"]),
                             "amplitudes_from": "none (not verified)", "checks": [], "not_verified": why,
                             "integrator": None, "stiffness_ratio": None})  # (no orbit: no integrator chosen)
    return doc
