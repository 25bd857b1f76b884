"""Figure ``NAME_frc.png``: the forced responses of every master, one panel per master (matplotlib, optional).

Each forcing level's curve (``[analysis.forcing]``) is the amplitude A of the master's modal coordinate against
``Omega / omega_p``: solid where stable, dashed where unstable, faint beyond the backbone's validity (a
truncated series' number, not a response to trust), each piece in the frequency range and each isola apart;
its folds (saddle-node points, where the response jumps) marked by circles and its peak by a cross (none when
the peak lies outside the range); the backbone ``omega_NL(A) / omega_p`` (order N, from the
parametrisation, or the reported points of a stored run) is drawn in grey over the same amplitudes, and the
backbone's validity limit as a dotted horizontal line.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from stepnf.io.results import RunResult, label_text
from stepnf.report.backbone_plot import panels
from stepnf.report.figures import save_figure

#: Amplitudes of the backbone's curve.
SAMPLES = 120


def _runs(stable: np.ndarray) -> list[tuple[int, int, Any]]:
    """``(start, stop, value)`` of the maximal runs of equal values (stop inclusive: each run shares its end
    point with the next one, so the drawn curve has no gap)."""
    out, start = [], 0
    for i in range(1, len(stable) + 1):
        if i == len(stable) or stable[i] != stable[start]:
            out.append((start, min(i, len(stable) - 1), stable[start].item()))
            start = i
    return out


def backbone_curve(mode: Any, res: Any, top: float) -> tuple[np.ndarray, np.ndarray]:
    """``(Omega / omega_p, A)`` of master ``mode``'s backbone up to amplitude ``top``: from the parametrisation
    ``res`` when the run holds it, else the block's reported points."""
    if res is not None:
        bb = res.backbone()
        amps, ratio = np.linspace(top / SAMPLES, top, SAMPLES), []
        for A in amps:
            try:
                ratio.append(bb.frequency(bb.rho_at(float(A))) / res.omega)
            except (ArithmeticError, ValueError, RuntimeError):
                break  # (NumericalError: A(rho) folds, no larger amplitude is reached either)
        return np.asarray(ratio), amps[:len(ratio)]
    block = mode.backbone or {}
    pairs = [(float(r), float(a)) for a, r in zip(block.get("amplitude", []), block.get("omega_ratio", []))
             if a is not None and r is not None and float(a) <= top]
    return (np.asarray(pairs).T if pairs else (np.zeros(0), np.zeros(0)))


def draw_frc(ax, mode: Any, res: Any) -> None:
    """One panel: master ``mode`` (its ``frc`` list and backbone block) and its parametrisation ``res`` (or None)."""
    w = float(mode.omega)
    top = 0.0
    for k, c in enumerate(mode.frc):
        x = np.asarray(c["Omega"], dtype=float) / w
        y = np.asarray(c["amplitude"], dtype=float)
        stable = np.asarray(c["stable"], dtype=bool)
        valid = np.asarray(c.get("valid") or np.ones(len(x), bool), dtype=bool)
        segment = np.asarray(c.get("segment") or np.zeros(len(x), int), dtype=int)
        color = f"C{k % 10}"
        name = f"kappa = {float(c['kappa']):.3g}" if "kappa" in c else f"load = {float(c['load']):.3g}"
        for seg in np.unique(segment):  # the pieces in the range and the isolas: never joined by a line
            at = np.flatnonzero(segment == seg)
            code = 2 * stable[at].astype(int) + valid[at].astype(int)
            for i, j, kind in _runs(code):
                ax.plot(x[at[i:j + 1]], y[at[i:j + 1]], "-" if kind >= 2 else "--", color=color, lw=1.4,
                        alpha=1.0 if kind % 2 else 0.35, label=name if seg == segment[0] and i == 0 else None)
        for f in c.get("folds") or []:
            ax.plot(float(f["Omega"]) / w, float(f["amplitude"]), "o", mfc="none", color=color, ms=6)
        pk = c.get("peak") or {}
        if pk.get("amplitude") is not None and not c.get("peak_outside_range"):
            ax.plot(float(pk["Omega"]) / w, float(pk["amplitude"]), "x", color=color, ms=7)
        top = max(top, float(np.nanmax(y)) if y.size else 0.0)
    bx, by = backbone_curve(mode, res, 1.1 * top if top > 0 else 1.0)
    if len(bx):
        ax.plot(bx, by, color="0.4", lw=1.0, label="backbone")
    valid = (mode.backbone or {}).get("valid_up_to")
    if valid:
        ax.axhline(float(valid), color="tab:red", lw=0.8, ls=":", label="validity limit")
    ax.set_xlabel("Omega / omega_p")
    ax.set_ylabel("amplitude A of q_p")
    ax.set_title(f"mode {mode.index} {label_text(mode.label)}", fontsize=10)
    ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 3))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def plot_frcs(result: RunResult, path: str | Path) -> Path | None:
    """PNG of every master's forced responses (module docstring); ``None`` when the run computed none."""
    masters = [m for m in result.modes if getattr(m, "frc", None)]
    if not masters:
        return None
    fig, axes = panels(len(masters))
    for ax, mode in zip(axes, masters):
        draw_frc(ax, mode, result.backbones.get(mode.index))
    fig.suptitle("FRCs: dashed unstable, faint beyond validity, o folds, x peak", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
