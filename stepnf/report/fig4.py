"""Paper Fig. 4: FE points of a sweep (DNF Gamma) on the von Karman Gamma(kappa) curves.

``stepnf fig4 STORE [STORE ...] --out DIR`` reads sweep stores (``stepnf
sweep``), draws for each master mode the von Karman NF curve of Gamma against
kappa (:mod:`stepnf.report.curves`) with the FE points of every store (3D solid,
DKT shells, shallow-shell FE, CalculiX...), and writes the table of points (CSV
and JSON): case, kappa, thickness, mode, Gamma of the FE model, Gamma of the von
Karman model at the same kappa, their difference, and the flags. As the paper
draws it, a store whose cases span several thicknesses h (the paper's Table 2:
1, 3 and 5 mm) gives one series per thickness: one marker per store, one colour
per thickness (grey: near an internal resonance), one legend for the figure.
The summary gives, per mode, the largest difference away from internal resonances (points that either model
flags within the resonance tolerance are listed but left out of it).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from stepnf.io.atomic import csv_text, write_text
from stepnf.report.curves import CurveOptions, compute_curves
from stepnf.errors import InputFileError, SceneError, StoreError
from stepnf.methods import DNF, NF
from stepnf.nf.evaluators import nf_modal
from stepnf.report.figures import pyplot, save_figure
from stepnf.sweep.dask_sweep import read_store

RESONANCE_KINDS = ("internal_resonance_1_2", "internal_resonance_1_1")


@dataclass
class Point:
    store: str
    case: str
    kappa: float
    mode: tuple[int, int]
    gamma_fe: float
    gamma_vk: float | None = None
    flags_fe: list[str] = field(default_factory=list)
    flags_vk: list[str] = field(default_factory=list)
    h: float | None = None  # the case's thickness (model.geometry.h, model length unit), None if not stored

    @property
    def resonant(self) -> bool:
        return any(k in RESONANCE_KINDS for k in self.flags_fe + self.flags_vk)

    @property
    def difference(self) -> float | None:
        return None if self.gamma_vk is None else self.gamma_fe - self.gamma_vk


def fe_points(store: str | Path, name: str | None = None, method: str = DNF) -> list[Point]:
    """Every (case, master mode) of a sweep store with its kappa and Gamma by ``method``."""
    if not Path(store).is_file():
        raise SceneError(store, None, "no such sweep store: give the .h5 file that `stepnf sweep` wrote")
    try:  # a store named on the command line is the user's input: unusable, it is bad input (exit 2)
        recs = read_store(store)
    except StoreError as exc:
        raise InputFileError.of(store, exc) from exc
    if not recs:
        raise InputFileError(store, "no stored case (run `stepnf sweep` first)")
    out = []
    for cid, rec in sorted(recs.items()):
        if rec.get("status") != "done":
            continue
        doc = rec["result"]
        kappa = doc.get("kappa")
        if kappa is None:
            continue
        h = thickness(doc)
        for m in doc["modes"]:
            r = m["methods"].get(method)
            lab = m.get("label")
            if r is None or r.get("gamma") is None or not isinstance(lab, list):
                continue
            g = r["gamma"]
            g = float("inf") * (1 if g == "inf" else -1) if isinstance(g, str) else float(g)
            out.append(Point(name or Path(store).stem, cid, float(kappa), (int(lab[0]), int(lab[1])), g,
                             flags_fe=[f["kind"] for f in r.get("flags", [])], h=h))
    return out


def thickness(doc: dict[str, Any]) -> float | None:
    """The stored case's shell thickness (its model's ``geometry.h``, model length unit), or ``None``."""
    model = doc.get("model")
    geo = model.get("geometry") if isinstance(model, dict) else None
    h = geo.get("h") if isinstance(geo, dict) else None
    return float(h) if isinstance(h, (int, float)) and not isinstance(h, bool) and np.isfinite(h) else None


def vonkarman_at(points: Sequence[Point], nu: float = 0.3, tol=None) -> None:
    """Fill ``gamma_vk`` (NF with every mode of the model) at each point's own kappa."""
    from stepnf.nf.evaluators import Tolerances
    from stepnf.models import VonKarmanShell

    tol = tol or Tolerances()
    for kappa in sorted({p.kappa for p in points}):
        vk = VonKarmanShell(kappa=kappa, nu=nu)
        om, wmax = vk.omegas(), vk.mode_maxima()
        for pt in (p for p in points if p.kappa == kappa):
            try:
                i = vk.index(*pt.mode)
            except (KeyError, ValueError, IndexError):
                continue
            r = nf_modal(i, om, vk.quadratic_coefficients(i), vk.cubic_coefficient(i), np.arange(len(om)),
                         tol=tol, labels=vk.labels())
            pt.gamma_vk = r.T / wmax[i] ** 2
            pt.flags_vk = [f["kind"] for f in r.flags]


def summary(points: Sequence[Point]) -> dict[str, dict[str, Any]]:
    """Per store and mode: the largest |Gamma_FE - Gamma_vK| away from internal resonances."""
    out: dict[str, dict[str, Any]] = {}
    for p in points:
        if p.gamma_vk is None or not np.isfinite(p.gamma_fe):
            continue
        key = f"{p.store} ({p.mode[0]},{p.mode[1]})"
        s = out.setdefault(key, {"points": 0, "resonant": 0, "max_abs_difference": 0.0, "at_kappa": None,
                                 "max_rel_difference": 0.0})
        s["points"] += 1
        if p.resonant:
            s["resonant"] += 1
            continue
        d = abs(p.difference)
        if d > s["max_abs_difference"]:
            s["max_abs_difference"], s["at_kappa"] = d, p.kappa
        if abs(p.gamma_vk) > 0.02:  # relative differences of a Gamma near zero mean nothing
            s["max_rel_difference"] = max(s["max_rel_difference"], d / abs(p.gamma_vk))
    return out


def figure4(stores: Sequence[str | Path], out_dir: str | Path, *, names: Sequence[str] | None = None,
            n_kappa: int = 300, nu: float = 0.3) -> dict[str, Any]:
    """Draw Fig. 4 and write the table of points; returns the summary and the file paths."""
    plt = pyplot()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = list(names) if names else [Path(s).stem for s in stores]
    points: list[Point] = []
    for s, n in zip(stores, names):
        points += fe_points(s, n)
    vonkarman_at(points, nu)
    modes = sorted({p.mode for p in points}, key=lambda m: (m[1], m[0]))
    kpos = [p.kappa for p in points if p.kappa > 0]
    # Table 2 spans kappa from 1 to 6000: a logarithmic axis (a plate point, kappa = 0, sits at its left end)
    lo = min(kpos) / 1.5 if kpos else 0.1
    hi = max(kpos) * 1.5 if kpos else 100.0
    grid = np.geomspace(lo, hi, n_kappa)
    curves = compute_curves(CurveOptions(kappas=tuple(grid), modes=tuple(modes), nu=nu))
    ncol = 3
    nrow = int(np.ceil(len(modes) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(5 * ncol, 3.8 * nrow), squeeze=False)
    markers = ["o", "s", "^", "D", "v"]
    thick = sorted({p.h for p in points if p.h is not None})
    store_h = {n: sorted({p.h for p in points if p.store == n and p.h is not None}) for n in names}
    legend: dict[str, Any] = {}
    for ax, mode in zip(axes.ravel(), modes):
        i = curves.row(mode)
        legend["von Karman, NF"], = ax.plot(curves.kappa, curves.plotted(NF, "gamma")[i], "m-", lw=1.5)
        for j, n in enumerate(names):
            pts = [p for p in points if p.store == n and p.mode == mode and np.isfinite(p.gamma_fe)]
            pts = [Point(**{**p.__dict__, "kappa": max(p.kappa, lo)}) for p in pts]
            for label, colour, ok in series(n, j, pts, store_h[n], thick):
                legend[label], = ax.plot([p.kappa for p in ok], [p.gamma_fe for p in ok], markers[j % 5], mfc="none",
                                         color=colour)
            rs = [p for p in pts if p.resonant]
            if rs:
                legend[f"{n}, near resonance"], = ax.plot([p.kappa for p in rs], [p.gamma_fe for p in rs],
                                                          markers[j % 5], color="0.6")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_title(f"mode ({mode[0]},{mode[1]})")
        ax.set_xscale("log")
        ax.set_xlabel("kappa")
        ax.set_ylabel("Gamma")
        lo, hi = np.nanpercentile(np.r_[curves.plotted(NF, "gamma")[i], [p.gamma_fe for p in points
                                                                             if p.mode == mode]], [2, 98])
        pad = 0.2 * (hi - lo + 1e-3)
        ax.set_ylim(lo - pad, hi + pad)
    for ax in axes.ravel()[len(modes):]:
        ax.set_visible(False)
    fig.suptitle("Type of nonlinearity: von Karman model (lines) and FE models with DNF (points)")
    extra = 0.22 * np.ceil(len(legend) / 4) + 0.2  # inches below the panels for the one legend
    fig.set_size_inches(5 * ncol, 3.8 * nrow + extra)
    fig.legend(list(legend.values()), list(legend), loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0.0, extra / (3.8 * nrow + extra), 1.0, 1.0))
    png = save_figure(fig, out_dir / "fig4.png", dpi=110)
    rows = [{"store": p.store, "case": p.case, "kappa": p.kappa, "h": p.h, "mode": f"({p.mode[0]},{p.mode[1]})",
             "gamma_fe": p.gamma_fe, "gamma_vk": p.gamma_vk, "difference": p.difference,
             "resonant": p.resonant, "flags_fe": ";".join(p.flags_fe), "flags_vk": ";".join(p.flags_vk)}
            for p in points]
    table = out_dir / "fig4_points.csv"
    names = list(rows[0]) if rows else ["store"]
    write_text(table, csv_text([names] + [[r[k] for k in names] for r in rows]), what="table of points")
    summ = summary(points)
    write_text(out_dir / "fig4_summary.json", json.dumps({"summary": summ, "points": rows}, indent=1, default=str),
               what="summary")
    return {"summary": summ, "figure": str(png), "table": str(table), "points": len(points), "series": list(legend)}


def series(name: str, j: int, pts: Sequence[Point], hs: Sequence[float],
           thick: Sequence[float]) -> list[tuple[str, str, list[Point]]]:
    """The drawn series of store ``name`` (its ``j``-th, of thicknesses ``hs``; ``thick``: every store's) in one
    panel: ``(legend label, colour, points)`` of its points away from resonances, one per thickness (its colour
    the same in every store) when the store spans several, else one."""
    ok = [p for p in pts if not p.resonant]
    if len(hs) < 2:
        return [(f"{name}, DNF", f"C{(len(thick) + j) % 10}", ok)]
    return [(f"{name}, h = {h:g}", f"C{thick.index(h) % 10}", [p for p in ok if p.h == h]) for h in hs]


def format_summary(summ: dict[str, dict[str, Any]]) -> str:
    lines = [f"{'store and mode':32s} {'points':>6s} {'resonant':>8s} {'max |dGamma|':>12s} {'at kappa':>9s} "
             f"{'max rel':>8s}"]
    for key, s in summ.items():
        at = "-" if s["at_kappa"] is None else f"{s['at_kappa']:.4g}"
        lines.append(f"{key:32s} {s['points']:6d} {s['resonant']:8d} {s['max_abs_difference']:12.4f} {at:>9s} "
                     f"{100 * s['max_rel_difference']:7.2f}%")
    return "\n".join(lines)
