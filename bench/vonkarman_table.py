"""T_p (paper normalisation) and Gamma of six modes of the von Karman shell by NF, MD, SMD.

Usage: .venv/bin/python bench/vonkarman_table.py [kappa ...]   (default 0 10 25)
Prints one row per (kappa, mode) and the time to build the model for each kappa
(the first build also computes the kappa-independent Bessel tables, cached after).
"""
from __future__ import annotations

import sys
import time

import numpy as np

from stepnf.nf.evaluators import md_modal, nf_modal, smd_modal
from stepnf.models import VonKarmanShell

MODES = [(2, 0), (3, 0), (4, 0), (0, 1), (0, 2), (2, 1)]


def rows(model: VonKarmanShell, modes=MODES):
    om, lab = model.omegas(), model.labels()
    wmax = model.mode_maxima()
    S = np.arange(model.n_modes)
    out = []
    for kn in modes:
        p = model.index(*kn)
        g, h = model.quadratic_coefficients(p), model.cubic_coefficient(p)
        res = {m.__name__[:-6]: f(p, om, g, h, S, labels=lab) for m, f in
               ((nf_modal, nf_modal), (md_modal, md_modal), (smd_modal, smd_modal))}
        out.append((kn, om[p], wmax[p], res))
    return out


def main(kappas: list[float]) -> None:
    print(f"{'kappa':>6} {'mode':>7} {'omega':>10} {'max|phi|':>9} {'T_NF':>12} {'Gamma_NF':>12} "
          f"{'T_MD':>12} {'T_SMD':>12}  flags")
    for kappa in kappas:
        t0 = time.perf_counter()
        model = VonKarmanShell(kappa=kappa)
        t_build = time.perf_counter() - t0
        for kn, om, wm, res in rows(model):
            nf = res["nf"]
            flags = "; ".join(f["kind"] + str(f.get("label")) for r in res.values() for f in r.flags)
            print(f"{kappa:6.1f} {str(kn):>7} {om:10.4f} {wm:9.4f} {nf.T:12.5g} {nf.T / wm**2:12.5g} "
                  f"{res['md'].T:12.5g} {res['smd'].T:12.5g}  {flags}")
        print(f"# kappa = {kappa}: model built in {t_build:.3f} s ({model.n_modes} modes)")


if __name__ == "__main__":
    main([float(a) for a in sys.argv[1:]] or [0.0, 10.0, 25.0])
