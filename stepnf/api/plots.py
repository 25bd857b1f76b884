"""The figures of a :class:`~stepnf.api.view.RunView` as matplotlib objects (matplotlib is optional).

They draw what ``stepnf run`` writes as ``NAME_backbone.png`` and ``NAME_modes.png``
(:mod:`stepnf.report.backbone_plot`, :mod:`stepnf.report.mode_shapes`), on the caller's pyplot with the
backend it chose (inline in a notebook), and return the axes or figure instead of a file.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from stepnf.io.results import RunResult

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


INSTALL = ("stepnf's figures need matplotlib, which is not installed: install the Debian package python3-matplotlib "
           "(apt install python3-matplotlib) or pip install matplotlib")


def pyplot() -> Any:
    """``matplotlib.pyplot`` with the backend matplotlib chooses (ImportError naming the package if absent)."""
    try:
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ImportError(INSTALL) from exc
    return plt


def plot_backbone(view: Any, result: RunResult, mode: int | None = None, ax: "Axes | None" = None) -> "Axes":
    """The backbone omega/omega_p against the amplitude A of master ``mode`` on ``ax``.

    A run just computed has its parametrisation in memory: orders 3, 5, ..., N are drawn as in
    ``NAME_backbone.png`` (:func:`stepnf.report.backbone_plot.draw_backbone`). A stored run keeps the
    reported points (amplitude, omega / omega_p) and the validity limit: those are drawn. A ValueError
    names the masters that have a backbone when ``mode`` has none.
    """
    have = [m.index for m in view.modes if m.backbone is not None and len(m.backbone.amplitude)]
    if mode is None and not have:
        raise ValueError("this run has no backbone: add an [analysis.backbone] table to the scene")
    index = have[0] if mode is None else mode
    if index not in have:
        raise ValueError(f"mode {index} has no backbone in this run (masters with one: {have})")
    if ax is None:
        _, ax = pyplot().subplots(figsize=(5.5, 4.0))
    from stepnf.report.backbone_plot import decorate_backbone_axes, draw_backbone

    record = next(m for m in result.modes if m.index == index)
    if index in result.backbones:
        draw_backbone(ax, record, result.backbones[index])
        return ax
    bb = view.mode(index).backbone
    ax.plot(bb.amplitude, bb.frequency_ratio, "ko-", ms=3, lw=1.2, label=f"order {bb.order} (stored points)")
    if bb.valid_up_to is not None:
        ax.axvline(bb.valid_up_to, color="tab:red", lw=0.8, ls=":", label="validity limit")
    decorate_backbone_axes(ax, record)
    return ax


def plot_modes(result: RunResult) -> "Figure | None":
    """The master mode shapes (:func:`stepnf.report.mode_shapes.mode_shapes_figure`), None without dof
    coordinates (a modal or polynomial model)."""
    from stepnf.report.mode_shapes import mode_shapes_figure

    return mode_shapes_figure(result, pyplot())
