"""Timing benchmark: the von Karman curves (paper Fig. 3) over a kappa grid.

Usage: .venv/bin/python bench/vonkarman_sweep.py [--n-kappa 200] [--kappa-max 100] [--out DIR]

Runs :func:`stepnf.report.curves.compute_curves` for the six modes of Fig. 3 (T_p by NF, MD,
SMD, rho_p, Gamma, flags; one model per kappa), then writes HDF5/CSV and the PNGs
(into DIR, default a temporary folder), prints a table of the wall times and writes
them to ``bench/results/vonkarman_sweep.json``. The issue's target: the whole sweep
(six modes, three methods, 200 kappa values) in under 2 minutes.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from stepnf.report.curves import CurveOptions, compute_curves, format_summary, write_csv, write_hdf5
from stepnf.report.curves import plot_frequencies, plot_nonlinearity

TARGET_SECONDS = 120.0


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-kappa", type=int, default=200)
    ap.add_argument("--kappa-max", type=float, default=100.0)
    ap.add_argument("--out", help="folder for the data and figures (default: a temporary folder)")
    ap.add_argument("--json", default=str(Path(__file__).parent / "results" / "vonkarman_sweep.json"))
    args = ap.parse_args(argv)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="vk_sweep_"))

    t0 = time.perf_counter()
    from stepnf.models import VonKarmanShell

    VonKarmanShell(kappa=0.0)  # the kappa-independent Bessel tables (cached for the sweep)
    t_tables = time.perf_counter() - t0
    opts = CurveOptions(kappa_max=args.kappa_max, n_kappa=args.n_kappa)
    curves = compute_curves(opts)
    t_sweep = curves.seconds
    t1 = time.perf_counter()
    write_hdf5(curves, out / "curves.h5")
    write_csv(curves, out)
    t_write = time.perf_counter() - t1
    t1 = time.perf_counter()
    plot_frequencies(curves, out / "fig2_frequencies.png")
    for q in ("T", "gamma"):
        plot_nonlinearity(curves, out / f"fig3_{q}.png", q)
    t_plot = time.perf_counter() - t1
    total = t_tables + t_sweep + t_write + t_plot

    rows = [("Bessel tables (first model)", t_tables), (f"sweep: {len(curves.modes)} modes x 3 methods x "
            f"{len(curves.kappa)} kappa", t_sweep), ("  per kappa value", t_sweep / len(curves.kappa)),
            ("HDF5 + CSV", t_write), ("figures (3 PNG)", t_plot), ("total", total)]
    w = max(len(r[0]) for r in rows)
    print(f"{'stage'.ljust(w)}  seconds")
    for name, sec in rows:
        print(f"{name.ljust(w)}  {sec:8.3f}")
    ok = total < TARGET_SECONDS
    print(f"target: whole sweep < {TARGET_SECONDS:.0f} s -> {'met' if ok else 'MISSED'}; files in {out}")
    print(format_summary(curves))

    gaps = {f"({k},{n})": {m: int(curves.gaps(m)[i].sum()) for m in ("nf", "md", "smd")}
            for i, (k, n) in enumerate(curves.modes)}
    record = {
        "benchmark": "vonkarman_sweep", "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "n_kappa": len(curves.kappa), "kappa_max": float(curves.kappa[-1]),
        "modes": [list(m) for m in curves.modes], "methods": ["nf", "md", "smd"],
        "seconds": {"tables": t_tables, "sweep": t_sweep, "per_kappa": t_sweep / len(curves.kappa),
                    "write": t_write, "plots": t_plot, "total": total},
        "target_seconds": TARGET_SECONDS, "target_met": ok, "gaps": gaps,
        "model": curves.model, "n_model_modes": int(curves.model.get("n_modes", 0)),
        "machine": {"python": sys.version.split()[0], "platform": platform.platform(), "cpus": os.cpu_count(),
                    "numpy": np.__version__},
    }
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=2, default=str) + "\n")
    print(f"timings -> {path}")
    return record


if __name__ == "__main__":
    main()
