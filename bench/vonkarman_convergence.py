"""Convergence of T_p (NF, paper normalisation) of the von Karman shell with the numbers kept.

Usage: .venv/bin/python bench/vonkarman_convergence.py [--edge clamped] [kappa ...]   (default 0 10 25)
For each kappa, varies one of n_transverse, n_galerkin, n_airy, k_max at a time
around a reference (much finer than the defaults) and prints T_NF of the six
modes (free edge: the paper's; clamped edge: the first six, (0,1) (1,1) (2,1) (0,2) (3,1) (1,2))
and the largest relative difference to the reference.
"""
from __future__ import annotations

import sys
import time

import numpy as np

from stepnf.nf.evaluators import nf_modal
from stepnf.models import VonKarmanShell
from stepnf.models.vonkarman import DEFAULTS

MODES = {"free": [(2, 0), (3, 0), (4, 0), (0, 1), (0, 2), (2, 1)],
         "clamped": [(0, 1), (1, 1), (2, 1), (0, 2), (3, 1), (1, 2)]}
REFERENCE = {"k_max": 10, "n_transverse": 20, "n_galerkin": 40, "n_airy": 50}


def t_nf(**kw) -> np.ndarray:
    m = VonKarmanShell(**kw)
    om, S = m.omegas(), np.arange(m.n_modes)
    out = []
    for kn in MODES[m.edge]:
        p = m.index(*kn)
        out.append(nf_modal(p, om, m.quadratic_coefficients(p), m.cubic_coefficient(p), S).T)
    return np.array(out)


def main(kappas: list[float], edge: str = "free") -> None:
    variations = [("defaults", {})]
    for n in (4, 6, 8, 10, 14):
        variations.append((f"n_transverse={n}", {"n_transverse": n}))
    for n in (16, 20, 24, 32):
        variations.append((f"n_galerkin={n}", {"n_galerkin": n}))
    for n in (10, 15, 20, 30, 40):
        variations.append((f"n_airy={n}", {"n_airy": n}))
    for n in (8, 9):
        variations.append((f"k_max={n}", {"k_max": n}))
    head = " ".join(f"{str(kn):>11}" for kn in MODES[edge])
    for kappa in kappas:
        t0 = time.perf_counter()
        ref = t_nf(kappa=kappa, edge=edge, **REFERENCE)
        print(f"\n## {edge} edge, kappa = {kappa}   (reference {REFERENCE}, {time.perf_counter() - t0:.1f} s)")
        print(f"{'case':<18} {head}  max rel. diff")
        print(f"{'reference':<18} " + " ".join(f"{t:11.6f}" for t in ref))
        for name, kw in variations:
            cfg = {**DEFAULTS, **kw}
            cfg.pop("n_galerkin") if "n_galerkin" not in kw else None
            if "n_galerkin" not in kw:
                cfg["n_galerkin"] = max(DEFAULTS["n_galerkin"], cfg["n_transverse"] + 12)
            T = t_nf(kappa=kappa, **{**cfg, "edge": edge})
            rel = np.abs(T / ref - 1)
            print(f"{name:<18} " + " ".join(f"{t:11.6f}" for t in T) + f"  {rel.max():.2e}"
                  + f"  (per mode: {' '.join(f'{x:.0e}' for x in rel)})")


if __name__ == "__main__":
    args = sys.argv[1:]
    edge = "free"
    if args[:1] == ["--edge"]:
        edge, args = args[1], args[2:]
    main([float(a) for a in args] or [0.0, 10.0, 25.0], edge)
