"""Figure ``NAME_branches.png``: the backbone branches of every master on a manifold of several modes (issue 33).

One panel per such master, in the (Omega, A) plane: its frequency ``k_p Omega`` (over its linear ``w_p``)
against the amplitude ``A`` of its modal coordinate, the branch that continues its linear mode in black and
each coupled branch in colour, solid where the orbit is stable and dashed where it is not (rotating-frame
eigenvalues, :mod:`stepnf.dpim.multimode.branches`); the validity limit of the continuing branch (orders N-2
and N) a dotted vertical line. Drawn from the ``backbone`` blocks alone (:mod:`stepnf.dpim.manifold_report`:
``branch`` and ``coupled_branches``), so a stored run draws it too. The style is the backbone figure's
(:mod:`stepnf.report.backbone_plot`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from stepnf.io.results import RunResult, label_text
from stepnf.report.backbone_plot import BEYOND, panels
from stepnf.report.figures import save_figure

#: Opacity of a branch beyond its own validity limit.
FADED = 0.35


def _runs(stable: np.ndarray) -> list[tuple[int, int, int]]:
    """``(start, stop, value)`` of the maximal runs of equal values (stability, or a code), each overlapping the
    next by one point (the curve stays connected)."""
    out, start = [], 0
    for i in range(1, len(stable) + 1):
        if i == len(stable) or stable[i] != stable[start]:
            out.append((start, min(i + 1, len(stable)), int(stable[start])))
            start = i
    return out


def draw_branch(ax, c: dict[str, Any], p: int, w: float, color: str, label: str, top: float) -> None:
    """One branch (a JSON branch of the block) of master ``p``: ``k_p Omega / w`` against ``A_p``, dashed where
    unstable, faded beyond the branch's own validity limit (``valid_up_to``: orders N-2 and N); the points beyond
    ``A_p = top`` left out (a branch is traced past its validity)."""
    j = c["masters"].index(p)
    k = float(c["ratios"][j])
    A = np.asarray([np.nan if a is None else a for a in c["A"][j]], dtype=float)
    y = k * np.asarray([np.nan if o is None else o for o in c["Omega"]], dtype=float) / w
    stable = np.asarray(c["stable"], dtype=bool)
    inside = ~(A > top)
    A, y, stable = A[inside], y[inside], stable[inside]
    valid = c.get("valid_up_to")
    within = ~(A > float(valid)) if valid is not None else np.ones(len(A), dtype=bool)
    shown = set()
    for a, b, code in _runs(2 * stable + within):  # (stable, within its validity) as one code per point
        ok, trusted = bool(code // 2), bool(code % 2)
        name = f"{label}{'' if ok else ', unstable'}{'' if trusted else ', beyond validity'}"
        ax.plot(A[a:b], y[a:b], color=color, ls="-" if ok else "--", lw=1.6 if color == "k" else 1.1,
                alpha=1.0 if trusted else FADED, label=None if name in shown else name)
        shown.add(name)


def draw_branches(ax, mode: Any) -> None:
    """One panel: master ``mode`` (a :class:`~stepnf.io.results.ModeResult` whose backbone block has a
    manifold) and its branches."""
    block = mode.backbone
    w = float(mode.omega)
    valid = block.get("valid_up_to")
    main = block["branch"]  # None: no branch continues the linear mode (exact resonance)
    shown = [main] if main else block.get("coupled_branches", [])
    A_all = [a for c in shown for a in c["A"][c["masters"].index(mode.index)] if a is not None]
    top = BEYOND * float(valid) if valid else max(A_all, default=1.0)
    if main:
        draw_branch(ax, main, mode.index, w, "k", main["kind"], top)
    for i, c in enumerate(block.get("coupled_branches", [])):
        draw_branch(ax, c, mode.index, w, f"C{i % 10}", f"coupled {i + 1}", top)
    if valid:
        ax.axvline(float(valid), color="tab:red", lw=0.8, ls=":", label="validity limit")
    ax.set_xlim(0.0, top)
    ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3))
    ax.set_xlabel(f"amplitude A of q_{mode.index}")
    ax.set_ylabel(f"k Omega / w_{mode.index}")
    ax.set_title(f"mode {mode.index} {label_text(mode.label)} on the manifold of modes "
                 f"{block['manifold']['modes']}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def plot_branches(result: RunResult, path: str | Path) -> Path | None:
    """PNG of every master on a manifold (module docstring); ``None`` when no master is on one."""
    masters = [m for m in result.modes if m.backbone and m.backbone.get("manifold")]
    if not masters:
        return None
    fig, axes = panels(len(masters))
    for ax, mode in zip(axes, masters):
        draw_branches(ax, mode)
    fig.suptitle("backbone branches (dashed: unstable; faded: beyond validity)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
