"""The keys of ``[analysis.backbone]`` that put master modes on manifolds of several modes (issue 33).

::

    [analysis.backbone]
    manifolds = [[0, 4], ["(2,1)", 7]]   # explicit sets of modes (indices or labels, as master_modes), or "auto"
    resonance = 0.05                     # tolerance on the small denominators kept in the reduced dynamics
    ratios = [[1, 4], []]                # optional, per manifold: the resonance vector k ([] : found from omega)

Checked when the scene is read: a set of one mode, a mode twice in a set or in two sets (as written), a
value of the wrong type; whether each mode exists (and what a label names) is decided by the computed
modes, in the backbone stage (:func:`stepnf.pipeline.manifolds.resolve_manifolds`). Every mistake is a
:class:`~stepnf.errors.SceneError` naming the key (exit 2).
"""
from __future__ import annotations

import math

from typing import Any

from stepnf.errors import SceneError
from stepnf.keys.checks import check_number, describe_value

#: At most this many manifolds, each of at most :data:`MAX_MODES` modes: a manifold of m modes has
#: ``C(2m + N, N)`` monomials (order N = 15: 3876 for m = 2, 38760 for m = 3, 245157 for m = 4).
MAX_MANIFOLDS = 50
MAX_MODES = 4
#: The mode indices (0-based elastic modes, as master_modes) and ratios allowed.
MAX_INDEX = 100_000
MAX_RATIO = 25
#: The resonance tolerance: relative distance of a sum of frequencies to a master's (the DPIM's default 0.05).
RESONANCE_RANGE = (1e-9, 0.5)


def _entry(file: Any, key: str, m: Any) -> int | str:
    if isinstance(m, bool) or not isinstance(m, (int, str)):
        raise SceneError(file, key, f"expected a mode index (0-based, as in master_modes) or a label such as "
                         f"\"(2,0)\", got {describe_value(m)}")
    if isinstance(m, int):
        return int(check_number(file, key, m, integer=True, lo=0, hi=MAX_INDEX,
                                why=" (mode indices start at 0, rigid modes excluded)"))
    if not m.strip():
        raise SceneError(file, key, "an empty label: give a mode index or a label such as \"(2,0)\"")
    return m


def check_manifolds(file: Any, key: str, value: Any) -> str | tuple[tuple[int | str, ...], ...]:
    """``"auto"`` or the sets of modes (module docstring), checked as written."""
    if value == "auto":
        return "auto"
    if not isinstance(value, list) or not value or len(value) > MAX_MANIFOLDS:
        raise SceneError(file, key, f"expected \"auto\" or a non-empty list (at most {MAX_MANIFOLDS}) of sets of "
                         f"modes such as [[0, 4]], got {describe_value(value)}")
    out, seen = [], {}
    for i, group in enumerate(value):
        where = f"{key}[{i}]"
        if not isinstance(group, list):
            raise SceneError(file, where, f"expected a list of 2 to {MAX_MODES} modes such as [0, 4], "
                             f"got {describe_value(group)}")
        if not 2 <= len(group) <= MAX_MODES:
            raise SceneError(file, where, f"a manifold holds 2 to {MAX_MODES} modes, got {len(group)} ({group}); "
                             "a master in no manifold gets the single-mode backbone")
        modes = tuple(_entry(file, f"{where}[{j}]", m) for j, m in enumerate(group))
        for j, m in enumerate(modes):
            name = str(m)
            if name in seen:
                other = seen[name]
                raise SceneError(file, f"{where}[{j}]", f"mode {m!r} is already in "
                                 + ("this manifold" if other == i else f"manifold {other} ({key}[{other}])")
                                 + ": a mode belongs to one manifold at most")
            seen[name] = i
        out.append(modes)
    return tuple(out)


def check_resonance(file: Any, key: str, value: Any) -> float:
    """The tolerance on the small denominators (a relative distance of frequencies)."""
    return float(check_number(file, key, value, lo=RESONANCE_RANGE[0], hi=RESONANCE_RANGE[1],
                              why=" (a relative distance of frequencies; the DPIM's default is 0.05)"))


def check_ratios(file: Any, key: str, value: Any) -> tuple[tuple[int, ...] | None, ...]:
    """Per manifold the resonance vector k (positive integers, one per mode), or ``[]``: found from the
    frequencies."""
    if not isinstance(value, list) or not value or len(value) > MAX_MANIFOLDS:
        raise SceneError(file, key, "expected a list with one entry per manifold: the integers k (one per mode, "
                         f"e.g. [1, 4]) or [] to find them, got {describe_value(value)}")
    out: list[tuple[int, ...] | None] = []
    for i, k in enumerate(value):
        if not isinstance(k, list):
            raise SceneError(file, f"{key}[{i}]", f"expected a list of integers such as [1, 4] (or []), "
                             f"got {describe_value(k)}")
        ks = tuple(int(check_number(file, f"{key}[{i}][{j}]", v, integer=True, lo=1, hi=MAX_RATIO,
                                    why=" (a resonance ratio)")) for j, v in enumerate(k))
        g = math.gcd(*ks) if ks else 1
        out.append(tuple(x // g for x in ks) or None)  # 2:8 is 1:4
    return tuple(out)


def check_scene_manifolds(file: Any, where: str, got: dict[str, Any]) -> None:
    """Checks across the keys: ``ratios`` only with explicit manifolds, one entry per manifold, each as long
    as its manifold; ``resonance`` and ``ratios`` only with ``manifolds``."""
    man = got.get("manifolds")
    for name in ("resonance", "ratios"):
        if name in got and man is None:
            raise SceneError(file, f"{where}.{name}", f"{name} applies to manifolds of several modes: set "
                             "manifolds (a list of sets of modes, or \"auto\") or remove it")
    ratios = got.get("ratios")
    if ratios is None:
        return
    if man == "auto":
        raise SceneError(file, f"{where}.ratios", "ratios go with explicit manifolds; with manifolds = \"auto\" "
                         "they are found from the frequencies")
    if len(ratios) != len(man):
        raise SceneError(file, f"{where}.ratios", f"one entry per manifold: {len(man)} manifolds, "
                         f"{len(ratios)} entries")
    for i, (k, modes) in enumerate(zip(ratios, man)):
        if k is not None and len(k) != len(modes):
            raise SceneError(file, f"{where}.ratios[{i}]", f"one integer per mode of manifold {i} "
                             f"({len(modes)} modes), got {list(k)}")
