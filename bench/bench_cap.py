"""Benchmark: the six-mode kappa = 25 shell scene (DNF, NF, MD, SMD) on caps of growing size.

Each size runs in a fresh subprocess (so its peak memory is its own); the
table gives the stage timings, the counts, the peak resident memory and the
ratio of the total time to the time of the eigen-solve plus the
factorisations (issue 3's target: <= 1.5, and < 30 s / < 3 GB near 40k dofs).

    .venv/bin/python bench/bench_cap.py                 # 10k, 40k, 100k dofs
    .venv/bin/python bench/bench_cap.py --sizes 10k     # one size

Writes ``bench/results/cap_benchmark.json``.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SIZES = {"10k": (10, 4), "40k": (20, 10), "100k": (32, 16)}  # (n_core, n_ring) of the O-grid


def run_one(n_core: int, n_ring: int) -> dict:
    import tomllib

    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    data = tomllib.loads((ROOT / "examples" / "shell_kappa25.toml").read_text())
    data["model"]["geometry"].update({"n_core": n_core, "n_ring": n_ring})
    data["output"] = {"hdf5": False}
    scene = parse_scene(data, file=ROOT / "examples" / "shell_kappa25.toml", base_dir=ROOT / "examples")
    t0 = time.perf_counter()
    res = run_scene(scene, write=False)
    total = time.perf_counter() - t0
    c = res.counts
    eig_fac = res.timings.get("eigen", 0.0) + c["factorization_seconds"]
    return {
        "n_dofs": res.model["n_dofs"], "timings": res.timings, "total": total, "counts": c,
        "eigen_plus_other_factorizations": eig_fac,
        "ratio_total_to_eigen_and_factorizations": total / eig_fac if eig_fac else None,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "gamma_dnf": {str(m.label): m.methods["dnf"].gamma for m in res.modes},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10k,40k,100k", help=f"comma-separated, from {list(SIZES)}")
    ap.add_argument("--one", nargs=2, type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(run_one(*args.one)))
        return
    rows = {}
    for name in args.sizes.split(","):
        nc, nr = SIZES[name]
        out = subprocess.run([sys.executable, __file__, "--one", str(nc), str(nr)], capture_output=True,
                             text=True, check=True)
        rows[name] = json.loads(out.stdout.strip().splitlines()[-1])
        r = rows[name]
        print(f"{name}: {r['n_dofs']} dofs, total {r['total']:.1f} s, peak {r['peak_rss_mb']:.0f} MB", flush=True)
    hdr = ("size", "dofs", "model", "eigen", "step", "evaluators", "total", "factorizations", "fact. s",
           "ratio", "peak MB")
    print("  ".join(f"{h:>10}" for h in hdr))
    for name, r in rows.items():
        t = r["timings"]
        vals = (name, r["n_dofs"], f"{t.get('model', 0) + t.get('matrices', 0):.1f}", f"{t.get('eigen', 0):.1f}",
                f"{t.get('step', 0):.1f}", f"{t.get('evaluators', 0):.1f}", f"{r['total']:.1f}",
                r["counts"]["factorizations"], f"{r['counts']['factorization_seconds']:.1f}",
                f"{r['ratio_total_to_eigen_and_factorizations']:.2f}", f"{r['peak_rss_mb']:.0f}")
        print("  ".join(f"{v!s:>10}" for v in vals))
    dest = ROOT / "bench" / "results"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "cap_benchmark.json").write_text(json.dumps(rows, indent=2))
    print(f"written {dest / 'cap_benchmark.json'}")


if __name__ == "__main__":
    main()
