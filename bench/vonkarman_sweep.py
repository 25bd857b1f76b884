"""Timing benchmark: T_p by NF, MD, SMD of six modes of the von Karman shell for many kappa.

Usage: .venv/bin/python bench/vonkarman_sweep.py [n_kappa] [kappa_max] [out.csv]
(default 200 values in [0, 50], CSV to /tmp/vonkarman_sweep.csv). Prints the
wall time; the issue's target is the whole sweep in under 2 minutes.
"""
from __future__ import annotations

import csv
import sys
import time

import numpy as np

from stepnf.evaluators import md_modal, nf_modal, smd_modal
from stepnf.models import VonKarmanShell

MODES = [(2, 0), (3, 0), (4, 0), (0, 1), (0, 2), (2, 1)]


def main(n: int = 200, kmax: float = 50.0, out: str = "/tmp/vonkarman_sweep.csv") -> None:
    t0 = time.perf_counter()
    rows = []
    for kappa in np.linspace(0.0, kmax, n):
        m = VonKarmanShell(kappa=float(kappa))
        om, S, wmax = m.omegas(), np.arange(m.n_modes), m.mode_maxima()
        for kn in MODES:
            p = m.index(*kn)
            g, h = m.quadratic_coefficients(p), m.cubic_coefficient(p)
            coupled = [s for s in S if s != p and g[s] != 0]
            rho = float(om[coupled].min() / om[p]) if coupled else float("inf")
            res = [f(p, om, g, h, S) for f in (nf_modal, md_modal, smd_modal)]
            rows.append([kappa, f"{kn[0]},{kn[1]}", om[p], wmax[p], rho] + [r.T for r in res])
    dt = time.perf_counter() - t0
    with open(out, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["kappa", "mode", "omega", "max_phi", "rho_coupled", "T_nf", "T_md", "T_smd"])
        w.writerows(rows)
    print(f"{n} kappa values x {len(MODES)} modes x 3 methods: {dt:.1f} s -> {out}")


if __name__ == "__main__":
    a = sys.argv[1:]
    main(int(a[0]) if a else 200, float(a[1]) if len(a) > 1 else 50.0, a[2] if len(a) > 2 else "/tmp/vonkarman_sweep.csv")
