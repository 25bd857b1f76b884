"""Where MD and SMD predict the other type of nonlinearity than NF: ranges of kappa, gap counts, a text table."""
from __future__ import annotations

from typing import Any

import numpy as np

from stepnf.methods import MD, NF, SMD
from stepnf.report.curves.data import METHODS, Curves, check_method


def sign_disagreements(curves: Curves, method: str, mode: tuple[int, int]) -> list[tuple[float, float]]:
    """kappa ranges (first, last grid value) where ``method`` and NF differ in sign.

    Only points where neither method has a gap count; a gap ends a range. The true
    boundaries lie within one grid step of the reported ones.
    """
    i = curves.row(mode)
    a, b = curves.T[check_method(method)][i], curves.T[NF][i]
    ok = ~curves.gaps(method)[i] & ~curves.gaps(NF)[i] & np.isfinite(a) & np.isfinite(b)
    bad = ok & (np.sign(a) != np.sign(b))
    out, start = [], None
    for j in range(len(bad)):
        if bad[j] and start is None:
            start = j
        if start is not None and (j == len(bad) - 1 or not bad[j + 1]):
            out.append((float(curves.kappa[start]), float(curves.kappa[j])))
            start = None
    return out


def summary(curves: Curves) -> list[dict[str, Any]]:
    """Per mode: sign-disagreement ranges of MD and SMD with NF, and the gap counts."""
    rows = []
    for i, kn in enumerate(curves.modes):
        row: dict[str, Any] = {"mode": kn}
        for m in (MD, SMD):
            row[f"wrong_sign_{m}"] = sign_disagreements(curves, m, kn)
        for m in METHODS:
            row[f"gaps_{m}"] = int(curves.gaps(m)[i].sum())
        rows.append(row)
    return rows


def format_summary(curves: Curves) -> str:
    """Plain-text table of :func:`summary`."""
    def rng(r: list[tuple[float, float]]) -> str:
        return ", ".join(f"[{a:.4g}, {b:.4g}]" if a != b else f"{{{a:.4g}}}" for a, b in r) or "-"

    lines = [f"kappa in [{curves.kappa[0]:g}, {curves.kappa[-1]:g}] ({len(curves.kappa)} values); "
             "ranges where MD / SMD predict the other sign of T than NF (the wrong type of nonlinearity):",
             f"{'mode':7s} {'gaps NF/MD/SMD':15s} {'MD wrong sign':40s} SMD wrong sign"]
    for row in summary(curves):
        k, n = row["mode"]
        gaps = f"{row['gaps_nf']}/{row['gaps_md']}/{row['gaps_smd']}"
        lines.append(f"({k},{n})   {gaps:15s} {rng(row['wrong_sign_md']):40s} {rng(row['wrong_sign_smd'])}")
    return "\n".join(lines)
