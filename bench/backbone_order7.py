"""Benchmark of issue 12: the DPIM backbone to order 7 of the six shell modes against today's DNF run.

The scene is ``examples/shell_kappa25.toml`` (38k dofs, hex27, FEniCSx) with ``methods = ["dnf"]``:

* ``dnf``: as it is (no ``[analysis.backbone]``);
* ``backbone``: the same plus ``[analysis.backbone] order = 7`` (a grid of 40 amplitudes up to the
  validity limit, W_max/h measured on each);
* ``one_slot``: ``backbone`` with one live shifted factorisation instead of two
  (:data:`stepnf.pipeline.backbone.TWO_SLOTS_UP_TO` set to 0 in that process, as on a model above 400k dofs):
  the other side of the time / memory trade of :mod:`stepnf.pipeline.backbone_slots`;
* with ``--modes K ...``: ``backbone`` again with a first eigen-solve of K modes
  (:func:`stepnf.pipeline.modes.first_batch` replaced in that process): more shifts solved by deflation,
  fewer factorisations (:mod:`stepnf.linalg.deflation`), each row under ``first_batch_runs``.

Each runs in a fresh subprocess (its own peak resident memory, ``ru_maxrss``), one after the other,
without HDF5 or figures. The table gives wall time, peak memory, force evaluations, factorisations
and the ratios (issue's targets: <= 3x the time, <= 1.5x the peak memory), against the DNF run of
the same benchmark and against DNF's first run here (``FIRST_DNF``).

    .venv/bin/python bench/backbone_order7.py [--order 7] [--modes 40 70]

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


def child(kind: str, order: int, modes: int | None = None) -> dict:
    """One run in this process: the scene, its timings, counts and peak memory (``modes``: the first
    eigen-solve's size, None: the pipeline's own)."""
    import resource
    import tomllib

    if modes is not None:
        import stepnf.pipeline.modes

        stepnf.pipeline.modes.first_batch = lambda state: modes
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    src = ROOT / "examples" / "shell_kappa25.toml"
    data = tomllib.loads(src.read_text())
    data["analysis"]["methods"] = ["dnf"]
    if kind in ("backbone", "one_slot"):
        data["analysis"]["backbone"] = {"order": order}
    if kind == "one_slot":
        import stepnf.pipeline.backbone

        stepnf.pipeline.backbone.TWO_SLOTS_UP_TO = 0
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


def run(kind: str, order: int, modes: int | None = None) -> dict:
    env = dict(os.environ)
    extra = [] if modes is None else ["--first-batch", str(modes)]
    p = subprocess.run([sys.executable, __file__, "--child", kind, "--order", str(order)] + extra,
                       capture_output=True, text=True, env=env, cwd=ROOT)
    if p.returncode:
        raise SystemExit(f"{kind} run failed:\n{p.stderr[-4000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--order", type=int, default=7)
    ap.add_argument("--modes", type=int, nargs="*", default=[],
                    help="also run the backbone with a first eigen-solve of this many modes")
    ap.add_argument("--child", choices=("dnf", "backbone", "one_slot"))
    ap.add_argument("--first-batch", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.order, args.first_batch)))
        return
    load = os.getloadavg()
    dnf = run("dnf", args.order)
    bb = run("backbone", args.order)
    one = run("one_slot", args.order)
    more = {k: run("backbone", args.order, k) for k in args.modes}
    keys = [("wall time (s)", "wall_seconds", None), ("peak RSS (MB)", "peak_rss_mb", None),
            ("force evaluations", "counts", "force_evaluations"), ("factorisations", "counts", "factorizations"),
            ("linear solves", "counts", "linear_solves")]
    print(f"{'':22s}{'DNF':>10s}{'+ DPIM o' + str(args.order):>14s}{'ratio':>8s}{'one slot':>12s}{'ratio':>8s}")
    for name, key, sub in keys:
        a, b, c = (r[key] if sub is None else r[key].get(sub) for r in (dnf, bb, one))
        ratio = lambda x: f"{x / a:8.2f}" if a and x is not None else f"{'-':>8s}"  # noqa: E731
        print(f"{name:22s}{a!s:>10s}{b!s:>14s}{ratio(b)}{c!s:>12s}{ratio(c)}")
    for k, r in more.items():
        c = r["counts"]
        print(f"first eigen-solve of {k} modes: {r['wall_seconds']} s ({r['wall_seconds'] / dnf['wall_seconds']:.2f}x), "
              f"{r['peak_rss_mb']} MB ({r['peak_rss_mb'] / dnf['peak_rss_mb']:.2f}x), {c.get('factorizations')} "
              f"factorisations, {c.get('eigensolver_solves')} eigen-solver solves, {c.get('linear_solves')} linear solves")
    doc = {"scene": "examples/shell_kappa25.toml, methods = [dnf]", "order": args.order,
           "load_average_before": [round(x, 2) for x in load], "load_average_after":
           [round(x, 2) for x in os.getloadavg()],
           "ratios": {"time": round(bb["wall_seconds"] / dnf["wall_seconds"], 3),
                      "peak_memory": round(bb["peak_rss_mb"] / dnf["peak_rss_mb"], 3)},
           "ratios_to_first_dnf": {"time": round(bb["wall_seconds"] / FIRST_DNF["wall_seconds"], 3),
                                   "peak_memory": round(bb["peak_rss_mb"] / FIRST_DNF["peak_rss_mb"], 3)},
           "ratios_one_slot": {"time": round(one["wall_seconds"] / dnf["wall_seconds"], 3),
                               "peak_memory": round(one["peak_rss_mb"] / dnf["peak_rss_mb"], 3)},
           "commit": subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                                    cwd=ROOT).stdout.strip(),
           "first_dnf": FIRST_DNF, "targets": {"time": 3.0, "peak_memory": 1.5}, "dnf": dnf, "backbone": bb,
           "one_slot": one,
           "first_batch_runs": {str(k): {key: r[key] for key in ("wall_seconds", "peak_rss_mb", "counts", "timings")}
                                | {"ratios": {"time": round(r["wall_seconds"] / dnf["wall_seconds"], 3),
                                              "peak_memory": round(r["peak_rss_mb"] / dnf["peak_rss_mb"], 3)},
                                   "T_dnf": [m["T_dnf"] for m in r["modes"]]}
                                for k, r in more.items()}}
    OUT.parent.mkdir(parents=True, exist_ok=True)
    # earlier runs' numbers are kept (the load of a shared machine moves them by tens of %)
    old = json.loads(OUT.read_text()) if OUT.exists() else {}
    doc["history"] = old.get("history", []) + ([{k: old[k] for k in ("load_average_before", "ratios")} | {
        "dnf": {k: old["dnf"][k] for k in ("wall_seconds", "peak_rss_mb")},
        "backbone": {k: old["backbone"][k] for k in ("wall_seconds", "peak_rss_mb")}}] if "dnf" in old else [])
    OUT.write_text(json.dumps(doc, indent=1) + "\n")
    first = doc["ratios_to_first_dnf"]
    print(f"time ratio {doc['ratios']['time']:.2f} (target <= 3), peak memory ratio "
          f"{doc['ratios']['peak_memory']:.2f} (target <= 1.5); with one slot {doc['ratios_one_slot']['time']:.2f} "
          f"and {doc['ratios_one_slot']['peak_memory']:.2f}; against DNF's first run here "
          f"({FIRST_DNF['wall_seconds']} s, {FIRST_DNF['peak_rss_mb']} MB, {FIRST_DNF['commit']}): "
          f"{first['time']:.2f} and {first['peak_memory']:.2f}; wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
