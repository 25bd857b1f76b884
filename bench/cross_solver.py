"""Cross-solver check (issue 4): CalculiX (C3D20) against FEniCSx (hex27) on the same caps.

    .venv/bin/python bench/cross_solver.py

For kappa = 0 and 25 and the modes (2,0), (0,1), (3,0): frequencies, DNF
Gamma of both solvers, their differences and each solver's run time, side by
side; writes ``bench/results/cross_solver.json``.
"""
from __future__ import annotations

import json
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOLVERS = {"fenicsx": "hex27", "calculix": "hex20"}


def main() -> None:
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    base = tomllib.loads((ROOT / "examples" / "plate.toml").read_text())
    base["analysis"].update({"methods": ["dnf"], "master_modes": ["(2,0)", "(0,1)", "(3,0)"]})
    base["output"] = {"hdf5": False}
    out: dict = {}
    for kappa, R in (("0", "inf"), ("25", 1.5)):
        for solver, element in SOLVERS.items():
            data = json.loads(json.dumps(base))
            data["model"].update({"solver": solver, "element": element})
            data["model"]["geometry"]["R"] = R
            t0 = time.perf_counter()
            r = run_scene(parse_scene(data, file=ROOT / "examples" / "plate.toml", base_dir=ROOT / "examples"),
                          write=False)
            out.setdefault(kappa, {})[solver] = {
                "seconds": time.perf_counter() - t0, "n_dofs": r.model["n_dofs"],
                "modes": {f"({m.label[0]},{m.label[1]})": {"omega_bar": m.omega_bar, "gamma": m.methods["dnf"].gamma,
                                                           "T_error": m.methods["dnf"].T_error}
                          for m in r.modes}}
    print(f"{'kappa':>5s} {'mode':6s} {'w_bar fenicsx':>14s} {'w_bar calculix':>15s} {'dw':>8s} "
          f"{'Gamma fenicsx':>14s} {'Gamma calculix':>15s} {'dGamma':>8s}")
    for kappa, s in out.items():
        f, c = s["fenicsx"]["modes"], s["calculix"]["modes"]
        for mode in f:
            dw = abs(c[mode]["omega_bar"] / f[mode]["omega_bar"] - 1)
            dg = abs(c[mode]["gamma"] / f[mode]["gamma"] - 1)
            print(f"{kappa:>5s} {mode:6s} {f[mode]['omega_bar']:14.5f} {c[mode]['omega_bar']:15.5f} {100 * dw:7.3f}% "
                  f"{f[mode]['gamma']:14.5f} {c[mode]['gamma']:15.5f} {100 * dg:7.2f}%")
        print(f"      run time: fenicsx {s['fenicsx']['seconds']:.1f} s ({s['fenicsx']['n_dofs']} dofs), "
              f"calculix {s['calculix']['seconds']:.1f} s ({s['calculix']['n_dofs']} dofs)")
    path = ROOT / "bench" / "results" / "cross_solver.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1))
    print(f"written {path}")


if __name__ == "__main__":
    main()
