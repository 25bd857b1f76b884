"""Figure ``NAME_backbone.png``: w_NL / w against the amplitude A of q_p, per master mode (matplotlib, optional).

Orders 3, 5, ..., N of the same parametrisation are overlaid (each the truncation of the order-N
one, :meth:`stepnf.dpim.parametrisation.DPIMResult.truncated`); the validity limit (orders N-2 and N differ by the
tolerance) is a vertical line and the order-N curve is dashed beyond it. Where W_max / h was
measured, a second x axis on top gives it (interpolated between the reported points).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from stepnf.errors import NumericalError
from stepnf.report.figures import pyplot, save_figure
from stepnf.io.results import RunResult, label_text

#: Amplitudes per curve, and how far beyond the validity limit the curves are drawn.
SAMPLES = 80
BEYOND = 1.5


def _curve(bb, amps: np.ndarray) -> np.ndarray:
    """``omega(A) / omega_p`` of one backbone, NaN where the parametrisation does not reach A."""
    out = np.full(len(amps), np.nan)
    for i, A in enumerate(amps):
        try:
            out[i] = bb.frequency(bb.rho_at(float(A))) / bb.res.omega
        except NumericalError:
            break  # A(rho) folds: no larger amplitude is reached either
    return out


def _linear(x, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation of ``ys(xs)`` (xs ascending), extended linearly beyond both ends."""
    x = np.asarray(x, dtype=float)
    lo = (ys[1] - ys[0]) / (xs[1] - xs[0])
    hi = (ys[-1] - ys[-2]) / (xs[-1] - xs[-2])
    y = np.interp(x, xs, ys)
    return np.where(x < xs[0], ys[0] + lo * (x - xs[0]), np.where(x > xs[-1], ys[-1] + hi * (x - xs[-1]), y))


def panels(k: int) -> tuple[Any, list]:
    """A figure of ``k`` panels, three to a row (4.6 x 3.8 in each), the unused ones hidden: ``(fig, axes[:k])``."""
    plt = pyplot()
    ncol = min(3, k)
    nrow = math.ceil(k / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.8 * nrow), squeeze=False)
    for ax in axes.ravel()[k:]:
        ax.set_visible(False)
    return fig, list(axes.ravel()[:k])


def plot_backbones(result: RunResult, path: str | Path) -> Path | None:
    """PNG of every master mode's backbone (module docstring); ``None`` when the run computed none."""
    masters = [m for m in result.modes if m.backbone and m.index in result.backbones]
    if not masters:
        return None
    fig, axes = panels(len(masters))
    for ax, mode in zip(axes, masters):
        draw_backbone(ax, mode, result.backbones[mode.index])
    fig.suptitle("DPIM backbones (orders 3 .. N; dashed beyond the validity limit)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def draw_backbone(ax, mode, res) -> None:
    """One panel of the figure on the matplotlib axes ``ax``: master ``mode`` (a
    :class:`~stepnf.io.results.ModeResult` with its backbone block) and its parametrisation ``res``
    (:class:`~stepnf.dpim.parametrisation.DPIMResult`)."""
    block = mode.backbone
    valid = block.get("valid_up_to")
    listed = [float(a) for a in block["amplitude"] if a is not None]
    tops = ([BEYOND * float(valid)] if valid else []) + listed[-1:]
    top = max(tops) if tops else 1.0
    amps = np.linspace(top / SAMPLES, top, SAMPLES)
    for order in range(3, res.order + 1, 2):
        y = _curve(res.truncated(order).backbone(), amps)
        if order < res.order:
            ax.plot(amps, y, lw=0.9, alpha=0.7, label=f"order {order}")
            continue
        inside = amps <= (float(valid) if valid is not None else np.inf)
        ax.plot(amps[inside], y[inside], "k-", lw=1.6, label=f"order {order}")
        if (~inside).any():
            j = max(int(np.argmax(~inside)) - 1, 0)
            ax.plot(amps[j:], y[j:], "k--", lw=1.6, label=f"order {order}, beyond validity")
    if valid is not None:
        ax.axvline(float(valid), color="tab:red", lw=0.8, ls=":", label="validity limit")
    wh = block.get("w_max_over_h")
    pairs = [(float(a), float(w)) for a, w in zip(block["amplitude"], wh or []) if a is not None and w is not None]
    if len(pairs) >= 2:
        a_, w_ = np.asarray(pairs).T
        sec = ax.secondary_xaxis("top", functions=(lambda x, a_=a_, w_=w_: _linear(x, a_, w_),
                                                   lambda w, a_=a_, w_=w_: _linear(w, w_, a_)))
        sec.set_xlabel("W_max / h", fontsize=8)
    decorate_backbone_axes(ax, mode)


def decorate_backbone_axes(ax, mode) -> None:
    """Axis labels, title (master ``mode``'s index and label), grid and legend of one backbone panel."""
    ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3))
    ax.set_xlabel("amplitude A of q_p")
    ax.set_ylabel("w_NL / w")
    ax.set_title(f"mode {mode.index} {label_text(mode.label)}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
