"""Benchmark of issue 33: a two-mode (1:2) manifold of the kappa = 25 cap against the single-mode backbones.

The scene is ``examples/shell_kappa25.toml`` (38k dofs, hex27, FEniCSx) with ``methods = ["dnf"]`` and
``master_modes = ["(2,1)"]``:

* ``manifold``: ``[analysis.backbone] order = N, manifolds = [["(2,1)", "(4,1)"]]``: (2,1) on the manifold of
  its 1:2 partner (4,1) at 1.93 w (``"auto"`` takes every mode flagged near 1:2 .. 1:4 of (2,1) on this dense
  spectrum: four modes, 3432 monomials at order 7, ~3e5 force evaluations: not this benchmark);
* ``single``: the single-mode backbones of the same modes (``master_modes`` = the manifold's modes) to the
  same order.

Each runs in a fresh subprocess (its own peak resident memory, ``ru_maxrss``), one after the other, without
HDF5 or figures. The table gives wall time, the backbone stage's time, peak memory, force evaluations and
factorisations (issue 33's target: the manifold at most 2x the single-mode backbones of its modes), beside
SSMTool's published figures for its non-intrusive 1:2 shell (1320 dofs, MATLAB): 4 min 48 s at order 5 and
43 min at order 7 (issue 33).

    .venv/bin/python bench/manifold_order7.py [--orders 5 7]

Writes ``bench/results/manifold_order7.json`` (the orders asked; the file's runs of other orders are kept, each run
with its date and load averages). Not a test: the numbers depend on the machine and its load.
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
OUT = ROOT / "bench" / "results" / "manifold_order7.json"
#: SSMTool's published times for its 1:2 shell (issue 33), seconds.
SSMTOOL = {"dofs": 1320, "order_5_seconds": 288.0, "order_7_seconds": 2580.0}


def child(kind: str, order: int, masters: list) -> dict:
    """One run in this process: the scene, its timings, counts and peak memory."""
    import resource
    import tomllib

    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    src = ROOT / "examples" / "shell_kappa25.toml"
    data = tomllib.loads(src.read_text())
    data["analysis"]["methods"] = ["dnf"]
    data["analysis"]["master_modes"] = masters
    data["analysis"]["backbone"] = {"order": order} | (
        {"manifolds": [["(2,1)", "(4,1)"]]} if kind == "manifold" else {})
    data["output"] = {"hdf5": False, "plot": False}
    scene = parse_scene(data, file=src, base_dir=src.parent)
    t0 = time.perf_counter()
    res = run_scene(scene, write=False)
    wall = time.perf_counter() - t0
    doc = res.to_dict()
    modes = []
    for m in doc["modes"]:
        bb = m.get("backbone") or {}
        modes.append({"index": m.get("index"), "label": m["label"], "omega": m["omega"],
                      "manifold": (bb.get("manifold") or {}).get("modes"),
                      "valid_up_to": bb.get("valid_up_to"), "T": bb.get("T")})
    return {"kind": kind, "order": order, "masters": masters, "wall_seconds": round(wall, 2),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            "n_dofs": doc.get("model", {}).get("n_dofs"), "counts": res.counts, "timings": res.timings,
            "modes": modes}


def run(kind: str, order: int, masters: list) -> dict:
    p = subprocess.run([sys.executable, __file__, "--child", kind, "--order", str(order), "--masters",
                        json.dumps(masters)], capture_output=True, text=True, env=dict(os.environ), cwd=ROOT)
    if p.returncode:
        raise SystemExit(f"{kind} run (order {order}) failed:\n{p.stderr[-4000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orders", type=int, nargs="+", default=[5, 7])
    ap.add_argument("--child", choices=("manifold", "single"))
    ap.add_argument("--order", type=int, default=7)
    ap.add_argument("--masters", default='["(2,1)"]')
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.order, json.loads(args.masters))))
        return
    runs = []
    for order in args.orders:
        load = os.getloadavg()
        man = run("manifold", order, ["(2,1)"])
        modes = next((m["manifold"] for m in man["modes"] if m["manifold"]), None)
        if not modes:
            raise SystemExit(f"order {order}: no manifold chosen for (2,1): {man['modes']}")
        single = run("single", order, [int(i) for i in modes])
        runs.append({"order": order, "modes": modes, "manifold": man, "single": single,
                     "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                     "load_average_before": [round(x, 2) for x in load],
                     "load_average_after": [round(x, 2) for x in os.getloadavg()]})
    print(f"{'':24s}{'order':>6s}{'single (both)':>15s}{'manifold':>12s}{'ratio':>8s}")
    for r in runs:
        s, m = r["single"], r["manifold"]
        rows = [("wall time (s)", s["wall_seconds"], m["wall_seconds"]),
                ("backbone stage (s)", s["timings"].get("backbone"), m["timings"].get("backbone")),
                ("peak RSS (MB)", s["peak_rss_mb"], m["peak_rss_mb"]),
                ("force evaluations", s["counts"].get("force_evaluations"), m["counts"].get("force_evaluations")),
                ("factorisations", s["counts"].get("factorizations"), m["counts"].get("factorizations"))]
        for name, a, b in rows:
            ratio = f"{b / a:8.2f}" if a and b is not None else f"{'-':>8s}"
            a_s = f"{a:.2f}" if isinstance(a, float) else str(a)
            b_s = f"{b:.2f}" if isinstance(b, float) else str(b)
            print(f"{name:24s}{r['order']:>6d}{a_s:>15s}{b_s:>12s}{ratio}")
        key = f"order_{r['order']}_seconds"
        if key in SSMTOOL:
            print(f"{'SSMTool 1320 dofs (s)':24s}{r['order']:>6d}{'':>15s}{SSMTOOL[key]:>12.0f}"
                  f"{SSMTOOL[key] / m['wall_seconds']:8.2f}  (its time / stepnf's manifold on 38k dofs)")
        r["ratios"] = {"wall": round(m["wall_seconds"] / s["wall_seconds"], 3),
                       "backbone_stage": round(m["timings"]["backbone"] / s["timings"]["backbone"], 3),
                       "peak_memory": round(m["peak_rss_mb"] / s["peak_rss_mb"], 3)}
    done = {r["order"] for r in runs}  # the orders not asked keep their earlier runs
    kept = [r for r in (json.loads(OUT.read_text())["runs"] if OUT.exists() else []) if r["order"] not in done]
    doc = {"scene": "examples/shell_kappa25.toml, methods = [dnf], master (2,1), manifolds = [[(2,1), (4,1)]]",
           "target": "manifold <= 2x the single-mode backbones of its modes (time and peak memory)",
           "ssmtool": SSMTOOL, "runs": sorted(kept + runs, key=lambda r: r["order"])}
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
