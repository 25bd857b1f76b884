"""Benchmark of issue 12: the DPIM backbone to order 7 of the six shell modes against today's DNF run.

The scene is ``examples/shell_kappa25.toml`` (38k dofs, hex27, FEniCSx) with ``methods = ["dnf"]``:

* ``dnf``: as it is (no ``[analysis.backbone]``);
* ``backbone``: the same plus ``[analysis.backbone] order = 7`` (a grid of 40 amplitudes up to the
  validity limit, W_max/h measured on each).

Each runs in a fresh subprocess (its own peak resident memory, ``ru_maxrss``), one after the other,
without HDF5 or figures. The table gives wall time, peak memory, force evaluations, factorisations
and the ratios (issue's targets: <= 3x the time, <= 1.5x the peak memory), against the DNF run of
the same benchmark and against DNF's first run here (``FIRST_DNF``).

    .venv/bin/python bench/backbone_order7.py [--order 7]

Writes ``bench/results/backbone_order7.json`` (the numbers and each mode's backbone block, read by
``bench/backbone_kappa25.py``). Not a test: the numbers depend on the machine and its load.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "backbone_order7.json"
#: DNF's run when this benchmark was first written (commit 254c116, 2026-12-01, the issue's "today"):
#: the targets read against it too, since DNF itself has become faster and leaner since.
FIRST_DNF = {"wall_seconds": 14.17, "peak_rss_mb": 913.5, "commit": "254c116"}


def child(kind: str, order: int) -> dict:
    """One run in this process: the scene, its timings, counts and peak memory."""
    import resource
    import tomllib

    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    src = ROOT / "examples" / "shell_kappa25.toml"
    data = tomllib.loads(src.read_text())
    data["analysis"]["methods"] = ["dnf"]
    if kind == "backbone":
        data["analysis"]["backbone"] = {"order": order}
    data["output"] = {"hdf5": False, "plot": False}
    scene = parse_scene(data, file=src, base_dir=src.parent)
    t0 = time.perf_counter()
    res = run_scene(scene, write=False)
    wall = time.perf_counter() - t0
    doc = res.to_dict()
    out = {"kind": kind, "wall_seconds": round(wall, 2),
           "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
           "n_dofs": doc.get("model", {}).get("n_dofs"), "counts": res.counts, "timings": res.timings,
           "modes": [{"label": m["label"], "omega": m["omega"], "T_dnf": m["methods"]["dnf"]["T"],
                      "w_max": m.get("w_max"), "backbone": m.get("backbone")} for m in doc["modes"]]}
    return out


def run(kind: str, order: int) -> dict:
    env = dict(os.environ)
    p = subprocess.run([sys.executable, __file__, "--child", kind, "--order", str(order)], capture_output=True,
                       text=True, env=env, cwd=ROOT)
    if p.returncode:
        raise SystemExit(f"{kind} run failed:\n{p.stderr[-4000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--order", type=int, default=7)
    ap.add_argument("--child", choices=("dnf", "backbone"))
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.order)))
        return
    load = os.getloadavg()
    dnf = run("dnf", args.order)
    bb = run("backbone", args.order)
    c_d, c_b = dnf["counts"], bb["counts"]
    rows = [("wall time (s)", dnf["wall_seconds"], bb["wall_seconds"]),
            ("peak RSS (MB)", dnf["peak_rss_mb"], bb["peak_rss_mb"]),
            ("force evaluations", c_d.get("force_evaluations"), c_b.get("force_evaluations")),
            ("factorisations", c_d.get("factorizations"), c_b.get("factorizations")),
            ("linear solves", c_d.get("linear_solves"), c_b.get("linear_solves"))]
    print(f"{'':22s}{'DNF':>12s}{'DNF + DPIM o' + str(args.order):>18s}{'ratio':>9s}")
    for name, a, b in rows:
        ratio = f"{b / a:9.2f}" if a and b is not None else f"{'-':>9s}"
        print(f"{name:22s}{a!s:>12s}{b!s:>18s}{ratio}")
    doc = {"scene": "examples/shell_kappa25.toml, methods = [dnf]", "order": args.order,
           "load_average_before": [round(x, 2) for x in load], "load_average_after":
           [round(x, 2) for x in os.getloadavg()],
           "ratios": {"time": round(bb["wall_seconds"] / dnf["wall_seconds"], 3),
                      "peak_memory": round(bb["peak_rss_mb"] / dnf["peak_rss_mb"], 3)},
           "ratios_to_first_dnf": {"time": round(bb["wall_seconds"] / FIRST_DNF["wall_seconds"], 3),
                                   "peak_memory": round(bb["peak_rss_mb"] / FIRST_DNF["peak_rss_mb"], 3)},
           "first_dnf": FIRST_DNF, "targets": {"time": 3.0, "peak_memory": 1.5}, "dnf": dnf, "backbone": bb}
    OUT.parent.mkdir(parents=True, exist_ok=True)
    # earlier runs' numbers are kept (the load of a shared machine moves them by tens of %)
    old = json.loads(OUT.read_text()) if OUT.exists() else {}
    doc["history"] = old.get("history", []) + ([{k: old[k] for k in ("load_average_before", "ratios")} | {
        "dnf": {k: old["dnf"][k] for k in ("wall_seconds", "peak_rss_mb")},
        "backbone": {k: old["backbone"][k] for k in ("wall_seconds", "peak_rss_mb")}}] if "dnf" in old else [])
    OUT.write_text(json.dumps(doc, indent=1) + "\n")
    first = doc["ratios_to_first_dnf"]
    print(f"time ratio {doc['ratios']['time']:.2f} (target <= 3), peak memory ratio "
          f"{doc['ratios']['peak_memory']:.2f} (target <= 1.5); against DNF's first run here "
          f"({FIRST_DNF['wall_seconds']} s, {FIRST_DNF['peak_rss_mb']} MB, {FIRST_DNF['commit']}): "
          f"{first['time']:.2f} and {first['peak_memory']:.2f}; wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
