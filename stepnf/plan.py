"""The evaluation plan: which evaluator serves each requested method, which modes are the masters."""
from __future__ import annotations

from typing import Any, Sequence

from .errors import SceneError
from .results import label_text
from .scene import Scene, parse_label


def resolve_methods(methods: Sequence[str], qm_order: str) -> dict[str, str]:
    """Map each requested name to its evaluator: ``md``/``smd`` follow ``qm_order``."""
    out = {}
    for m in methods:
        if m in ("md", "smd"):
            out[m] = f"{m}_{qm_order}"
        else:
            out[m] = m
    return out


def _label_matches(label: Any, want: Any) -> bool:
    if label is None:
        return False
    if isinstance(want, tuple) and isinstance(label, (tuple, list)):
        return tuple(int(x) for x in label[:2]) == want
    return str(label) == str(want)


def resolve_masters(scene: Scene, labels: Sequence[Any], n_modes: int, *, complete: bool) -> list[int] | None:
    """Elastic-mode indices of the scene's master modes; None when more modes are needed.

    Raises :class:`SceneError` when a label or index cannot exist.
    """
    out = []
    for i, m in enumerate(scene.master_modes):
        if isinstance(m, int):
            if m >= n_modes:
                if complete:
                    raise SceneError(scene.file, f"analysis.master_modes[{i}]",
                                     f"mode {m} does not exist: the model has {n_modes} elastic modes (0..{n_modes - 1})")
                return None
            out.append(m)
            continue
        want = parse_label(m) or m
        hits = [s for s, lab in enumerate(labels) if _label_matches(lab, want)]
        if not hits:
            if complete:
                found = sorted({label_text(x) for x in labels if x is not None},
                               key=lambda t: (len(t), t))
                more = f" and {len(found) - 30} more" if len(found) > 30 else ""
                raise SceneError(scene.file, f"analysis.master_modes[{i}]",
                                 f"no mode is labelled {m!r} among the {n_modes} modes computed; "
                                 f"labels found: {found[:30]}{more}")
            return None
        out.append(hits[0])
    if len(set(out)) != len(out):
        raise SceneError(scene.file, "analysis.master_modes", f"two entries name the same mode: {out}")
    return out
