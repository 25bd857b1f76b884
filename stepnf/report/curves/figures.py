"""The curves' figures: Fig. 2 (frequencies versus kappa) and Fig. 3 (T_p or Gamma by NF, MD, SMD).

Drawn and saved through :mod:`stepnf.report.figures` (matplotlib's Agg backend, atomic PNG writes).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from stepnf.report.figures import pyplot, save_figure
from stepnf.methods import MD, NF, SMD
from stepnf.report.curves.data import METHODS, Curves, check_quantity

_COLORS = {NF: "#d000d0", MD: "#d62728", SMD: "#e0b000"}   # magenta, red, yellow (paper)
_NAMES = {NF: "NF", MD: "QM MD", SMD: "QM SMD"}


def plot_frequencies(curves: Curves, path: str | Path) -> Path:
    """Fig. 2: ``omega_kn`` versus kappa, one line per (k, n) label, labelled at the right end."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 6.0))
    cmap = plt.get_cmap("tab10")
    ends = curves.frequencies[:, -1]
    ypos = ends.copy()  # label heights at the right end, pushed apart so they do not overlap
    gap = 0.022 * (float(np.nanmax(curves.frequencies)) - float(np.nanmin(curves.frequencies)))
    order = np.argsort(ends)
    for a, b in zip(order[:-1], order[1:]):
        ypos[b] = max(ypos[b], ypos[a] + gap)
    for i, (k, n) in enumerate(curves.freq_labels):
        y = curves.frequencies[i]
        ls = "-" if n == 0 else ("--" if k == 0 else "-.")
        ax.plot(curves.kappa, y, ls, color=cmap(k % 10), lw=1.3)
        ax.annotate(f"({k},{n})", (curves.kappa[-1], ypos[i]), xytext=(3, 0), textcoords="offset points",
                    fontsize=7, va="center", color=cmap(k % 10), annotation_clip=False)
    ax.set_xlabel(r"$\kappa = a^4/(R^2h^2)$")
    ax.set_ylabel(r"$\omega_{kn}$ (nondimensional)")
    ax.set_title(r"Natural frequencies of the free-edge shallow spherical shell"
                 "\n(solid: (k,0); dashed: (0,n); dash-dot: mixed)", fontsize=10)
    ax.set_xlim(curves.kappa[0], curves.kappa[-1] * 1.08 if curves.kappa[-1] > 0 else 1)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path, dpi=130)


def _limits(curves: Curves, i: int, quantity: str) -> tuple[float, float]:
    """y-range: every drawn NF value, and the central 96 % of MD's and SMD's, the latter capped
    at 5 max|NF| (farther out a divergence leaves the axes instead of flattening the reference)."""
    ref = curves.plotted(NF, quantity)[i]
    ref = ref[np.isfinite(ref)]
    vals = [ref, np.zeros(1)]
    cap = 5.0 * float(np.abs(ref).max()) if ref.size else math.inf
    for m in (MD, SMD):
        v = curves.plotted(m, quantity)[i]
        v = v[np.isfinite(v)]
        if v.size:
            vals.append(np.clip(np.percentile(v, [2, 98]), -cap, cap))
    allv = np.concatenate(vals)
    lo, hi = float(allv.min()), float(allv.max())
    pad = 0.08 * (hi - lo if hi > lo else 1.0)
    return lo - pad, hi + pad


def plot_nonlinearity(curves: Curves, path: str | Path, quantity: str = "T") -> Path:
    """Fig. 3 to a PNG file (see :func:`draw_nonlinearity`)."""
    return save_figure(draw_nonlinearity(curves, quantity), path, dpi=120)


def draw_nonlinearity(curves: Curves, quantity: str = "T") -> Any:
    """Fig. 3: T_p (or Gamma) by NF, MD, SMD versus kappa, one panel per mode, rho_p on a second axis.

    Returns the matplotlib figure; in each panel ``ax.lines[1:4]`` are the NF, MD, SMD
    curves (:meth:`Curves.plotted`). Gaps (flagged points) break the lines; each is marked
    by a tick at the bottom of the panel in the method's colour (rows: NF, MD, SMD). The
    rho = 3 and rho = 4 lines bound the slow/fast criterion of the paper.
    """
    q = check_quantity(quantity)
    plt = pyplot()
    n = len(curves.modes)
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.0 * ncol, 3.9 * nrow), squeeze=False)
    ylab = r"$T_p$" if q == "T" else r"$\Gamma_p = T_p/\max|\phi_p|^2$"
    rho_top = max(4.6, float(np.nanmax(curves.rho)) * 1.08 if np.isfinite(curves.rho).any() else 4.6)
    handles = []
    for i, kn in enumerate(curves.modes):
        ax = axes.ravel()[i]
        ax.axhline(0.0, color="0.6", lw=0.7)
        for m in METHODS:
            (line,) = ax.plot(curves.kappa, curves.plotted(m, q)[i], color=_COLORS[m], lw=1.6, label=_NAMES[m])
            if i == 0:
                handles.append(line)
        for r, m in enumerate(METHODS):
            gx = curves.kappa[curves.gaps(m)[i]]
            if gx.size:
                ax.plot(gx, np.full(gx.size, 0.03 + 0.035 * r), "|", color=_COLORS[m], ms=7, mew=1.2,
                        transform=ax.get_xaxis_transform(), clip_on=False)
        ax.set_ylim(*_limits(curves, i, q))
        ax.set_xlim(curves.kappa[0], curves.kappa[-1])
        ax.set_xlabel(r"$\kappa$")
        ax.set_ylabel(ylab)
        ax.set_title(f"mode ({kn[0]},{kn[1]})")
        ax.grid(alpha=0.25)
        ax2 = ax.twinx()
        (lr,) = ax2.plot(curves.kappa, curves.rho[i], "k--", lw=1.0, label=r"$\rho_p$")
        for level in (3.0, 4.0):
            ax2.axhline(level, color="0.35", lw=0.8, ls=":")
        ax2.set_ylim(0.0, rho_top)
        ax2.set_ylabel(r"$\rho_p$")
        if i == 0:
            handles.append(lr)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    (tick,) = axes[0, 0].plot([], [], "|", color="0.3", ms=7, label="flagged (gap)")
    handles.append(tick)
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    fig.suptitle("Type of nonlinearity versus kappa ("
                 + ("T_p, modes normalised by int phi^2 dS = 1" if q == "T" else "Gamma = T_p / max|phi_p|^2")
                 + "); dotted: rho = 3 and 4", fontsize=11)
    fig.tight_layout(rect=(0, 0.05, 1, 0.96))
    return fig
