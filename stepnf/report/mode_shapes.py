"""Figures: the master mode shapes coloured by transverse displacement (matplotlib, optional)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from stepnf.report.figures import pyplot, save_figure
from stepnf.io.results import RunResult, label_text
from stepnf.flags import gamma_unusable, t_unusable
from stepnf.methods import DNF


def plot_mode_shapes(result: RunResult, path: str | Path) -> Path | None:
    """PNG of every master mode seen from above, coloured by its z displacement.

    Needs the adapter's dof coordinates and directions (FE models); returns
    ``None`` (no figure) for models without them, or whose transverse dofs do not
    span a plane seen from above (fewer than three positions, all on one line).
    Only the ``uz`` translations are drawn and normalised (by their own largest value): a shell's rotation
    dofs (``rx ry rz``, radians), even a mode's largest entry, never scale the figure.
    """
    fig = mode_shapes_figure(result)
    return None if fig is None else save_figure(fig, path, dpi=110)


def mode_shapes_figure(result: RunResult, plt=None):
    """The figure of :func:`plot_mode_shapes` (a matplotlib Figure, drawn with the pyplot module ``plt``;
    default: :func:`stepnf.report.figures.pyplot`), or ``None`` when there is no figure to draw."""
    X = result.arrays.get("dof_coordinates")
    D = result.arrays.get("dof_directions")
    Phi = result.arrays.get("phi_masters")
    if X is None or D is None or Phi is None:
        return None
    plt = plt or pyplot()
    from matplotlib.tri import Triangulation

    sel = np.asarray(D) == 2
    xy = np.asarray(X)[sel][:, :2]
    # one value per in-plane position (through-thickness nodes share x, y): average them
    key = np.round(xy / max(np.ptp(xy), 1e-300), 9)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    counts = np.bincount(inv)
    pts = np.zeros((len(uniq), 2))
    np.add.at(pts, inv, xy)
    pts /= counts[:, None]
    if not _spans_plane(pts):
        return None
    k = len(result.modes)
    ncol = min(3, k)
    nrow = math.ceil(k / ncol)
    try:
        tri = Triangulation(pts[:, 0], pts[:, 1])
    except (RuntimeError, ValueError):  # Qhull refuses a nearly flat set of points: no figure, as without X
        return None
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 4.0 * nrow), squeeze=False)
    for ax, (j, mode) in zip(axes.ravel(), enumerate(result.modes)):
        w = np.zeros(len(uniq))
        np.add.at(w, inv, Phi[sel, j])
        w /= counts
        w /= max(np.max(np.abs(w)), 1e-300)
        ax.tricontourf(tri, w, levels=21, cmap="RdBu_r", vmin=-1, vmax=1)
        ax.tricontour(tri, w, levels=[0.0], colors="k", linewidths=0.8)
        ax.set_aspect("equal")
        ax.set_axis_off()
        dnf = mode.methods.get(DNF)
        shown = dnf is not None and dnf.gamma is not None and not t_unusable(dnf) and not gamma_unusable(dnf)
        g = f"\nGamma_DNF = {dnf.gamma:+.4g}" if shown else ""
        wb = f", w_bar = {mode.omega_bar:.3f}" if mode.omega_bar is not None else ""
        ax.set_title(f"mode {mode.index} {label_text(mode.label)}{wb}{g}", fontsize=10)
    for ax in axes.ravel()[k:]:
        ax.set_visible(False)
    kappa = f" (kappa = {result.kappa:.3g})" if result.kappa is not None else ""
    fig.suptitle(f"master modes, transverse displacement{kappa}")
    fig.tight_layout()
    return fig


def _spans_plane(pts: np.ndarray) -> bool:
    """Whether the points (m, 2) can be triangulated: three or more, not all on one line (relative 1e-9)."""
    if len(pts) < 3:
        return False
    sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    return bool(sv[0] > 0 and sv[1] > 1e-9 * sv[0])
