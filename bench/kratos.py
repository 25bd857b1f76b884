"""Benchmark: the kratos adapter's costs (issue 32, item 6), against FEniCSx, and whole runs.

    OMP_NUM_THREADS=1 .venv/bin/python bench/kratos.py                       # 12k and 100k dofs
    .venv/bin/python bench/kratos.py --sizes 12k --no-runs                   # the force path only

Every measurement runs in a fresh subprocess with one OpenMP/BLAS thread; each row carries the machine's
load average (``os.getloadavg``, 1 minute) when it ended: the machine is shared, and wall times grow with
the load where CPU times do not (the worker's CPU seconds are its own ``time.process_time``).

* ``worker`` (per size: the DKT mid-surface of the kappa = 25 cap, ``examples/shell_kappa25_dkt.toml``
  with the O-grid ``n_core x n_ring``): start-up (process start and Kratos's import, to the first
  reply), ``build`` (``.mdpa`` written and read, dofs numbered, the sparsity graph) and ``matrices`` (K
  and the consistent M assembled, renumbered, transferred), each the parent's wall time and the worker's
  own share; then one batch of ``--fields`` random fields (one call, as a STEP plan's or a DPIM order's
  fields are sent): per field the worker's phases of the reset recipe (``reset``: the scheme's step
  initialised; ``set``: DISPLACEMENT, ROTATION and node positions of all nodes; ``frames``: the
  non-linear iteration finalised; ``rhs``: the right-hand side zeroed and assembled; ``copy``: -RHS
  renumbered), wall and CPU, and ``transfer`` (the parent's wall time of the call minus the worker's
  phases: pickling both ways and the pipes); microseconds per field per dof.
* ``fenicsx`` (per size: the 3D hex27 cap of ``examples/shell_kappa25.toml`` on an O-grid of similar
  dofs): the internal forces of the same number of fields in one call, in-process, wall and CPU per
  field per dof.
* ``run`` (per size): ``stepnf run`` of the DKT scene (the CLI's ``main`` in a child process, output
  written to a temporary folder): wall time, the run's stage times, peak RSS of stepnf's process and of
  the Kratos worker (``RUSAGE_CHILDREN``: the worker is the run's only child).

Prints a table per part and writes ``bench/results/kratos.json`` (``--out``).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DKT_SCENE = ROOT / "examples" / "shell_kappa25_dkt.toml"
SOLID_SCENE = ROOT / "examples" / "shell_kappa25.toml"
#: size -> (DKT O-grid (n_core, n_ring), hex27 O-grid of similar dofs): dofs 4 038 / 4 113 (a quick check),
#: 11 766 / 11 169 (the paper's ~12k, the scene's default mesh) and 100 374 / 102 681
SIZES = {"4k": ((8, 3), (6, 3)), "12k": ((14, 5), (10, 5)), "100k": ((41, 15), (31, 15))}
PHASES = ("reset", "set", "frames", "rhs", "copy")


def _geometry(scene: Path) -> dict:
    return tomllib.loads(scene.read_text())["model"]


def _load() -> float:
    return round(os.getloadavg()[0], 2)


# ------------------------------------------------------------------------------------------ parts
def part_worker(n_core: int, n_ring: int, fields: int) -> dict:
    import numpy as np

    from stepnf_kratos.client import KratosWorker
    from stepnf_kratos.shellmesh import KRATOS_ELEMENT, cap_surface

    model = _geometry(DKT_SCENE)
    g, mat = model["geometry"], model["material"]
    mesh = cap_surface(g["a"], g["R"], "dkt", n_core=n_core, n_ring=n_ring, core=0.5)
    out: dict = {"n_dofs": 6 * len(mesh.points), "n_cells": len(mesh.cells)}
    t = time.perf_counter()
    w = KratosWorker(threads=1)
    try:
        w.call("timings")  # the first reply: the process is up and Kratos imported
        out["startup"] = time.perf_counter() - t
        request = {"points": mesh.points, "cells": mesh.cells, "element": KRATOS_ELEMENT["dkt"],
                   "properties": [{**{k: mat[k] for k in ("E", "nu", "rho")}, "h": g["h"]}],
                   "cell_property": np.zeros(len(mesh.cells), np.int64), "folder": str(w.folder)}
        for command, payload in (("build", request), ("matrices", None)):
            t = time.perf_counter()
            w.call(command, payload)
            out[command] = time.perf_counter() - t
        clock1 = w.call("timings")
        for command in ("build", "matrices"):
            out[f"{command}_in_worker"] = clock1[command][0]
        n = out["n_dofs"]
        U = g["h"] * np.random.default_rng(0).standard_normal((fields, n)) / np.sqrt(n)
        t = time.perf_counter()
        w.call("forces", U)
        wall = time.perf_counter() - t
        clock2 = w.call("timings")
    finally:
        w.close()
    per = {p: [(clock2[p][i] - clock1.get(p, (0.0, 0.0))[i]) / fields for i in (0, 1)] for p in PHASES}
    per["transfer"] = [wall / fields - sum(v[0] for v in per.values()), None]
    out.update(fields=fields, per_field_wall=wall / fields, phases=per, load=_load())
    return out


def part_fenicsx(n_core: int, n_ring: int, fields: int) -> dict:
    import numpy as np

    from stepnf.plugin.registry import build_model
    from stepnf.scene.parse import parse_scene

    data = tomllib.loads(SOLID_SCENE.read_text())
    data["model"]["geometry"].update(n_core=n_core, n_ring=n_ring)
    ad = build_model(parse_scene(data, file=SOLID_SCENE, base_dir=SOLID_SCENE.parent))
    n = ad.n_dofs
    U = data["model"]["geometry"]["h"] * np.random.default_rng(0).standard_normal((fields, n)) / np.sqrt(n)
    ad.internal_forces(U[:1])  # forms compiled, spaces built: not a field's cost
    wall, cpu = time.perf_counter(), time.process_time()
    ad.internal_forces(U)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {"n_dofs": n, "fields": fields, "per_field_wall": wall / fields, "per_field_cpu": cpu / fields,
            "load": _load()}


def part_run(n_core: int, n_ring: int) -> dict:
    import resource

    import h5py

    from stepnf.cli.console import main

    text = DKT_SCENE.read_text().replace("h = 0.003\n", f"h = 0.003\nn_core = {n_core}\nn_ring = {n_ring}\n", 1)
    with tempfile.TemporaryDirectory(prefix="stepnf_bench_kratos_") as tmp:
        scene = Path(tmp) / "dkt.toml"
        scene.write_text(text.replace('plot = true', 'plot = false'))
        t = time.perf_counter()
        rc = main(["run", str(scene)])
        total = time.perf_counter() - t
        with h5py.File(Path(tmp) / "results" / "dkt.h5") as f:
            timings = dict(f["timings"].attrs)
            run = json.loads(f.attrs["json"])
    kib = 1024.0  # ru_maxrss is in KiB on Linux
    return {"rc": rc, "n_dofs": run["model"]["n_dofs"], "total": total,
            "timings": {k: float(v) for k, v in timings.items()}, "counts": run["counts"],
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / kib,
            "worker_peak_rss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / kib, "load": _load()}


# ------------------------------------------------------------------------------------------ runner
def launch(args: list[str], timeout: float) -> dict:
    """One part in a fresh process with one thread; its JSON record, or ``{"status": why not}``."""
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
        env[var] = "1"
    try:
        p = subprocess.run([sys.executable, __file__, "--part", *args], capture_output=True, text=True, env=env,
                           timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"status": f"timeout after {timeout:.0f} s"}
    if p.returncode != 0:
        return {"status": f"failed (exit {p.returncode}): {(p.stderr.strip().splitlines() or ['-'])[-1][:200]}"}
    return {"status": "ok", **json.loads(p.stdout.strip().splitlines()[-1])}


def print_tables(res: dict) -> None:
    print("\nKratos worker (DKT), one thread: seconds (parent's wall; in the worker)")
    print(f"{'size':>6} {'dofs':>8} {'start-up':>9} {'build':>7} {'(worker)':>9} {'matrices':>9} {'(worker)':>9} "
          f"{'load':>5}")
    for size, r in res["worker"].items():
        if r["status"] != "ok":
            print(f"{size:>6} {r['status']}")
            continue
        print(f"{size:>6} {r['n_dofs']:>8} {r['startup']:9.2f} {r['build']:7.2f} {r['build_in_worker']:9.2f} "
              f"{r['matrices']:9.2f} {r['matrices_in_worker']:9.2f} {r['load']:5.2f}")
    print("\nper force field: ms wall / ms CPU (us per dof), one batch per call")
    print(f"{'size':>6} " + " ".join(f"{p:>20}" for p in (*PHASES, "transfer", "total")) + f" {'load':>5}")
    for size, r in res["worker"].items():
        if r["status"] != "ok":
            continue
        n, cells = r["n_dofs"], []
        for p in (*PHASES, "transfer"):
            wall, cpu = r["phases"][p]
            cells.append(f"{1e3 * wall:.2f}/{'-' if cpu is None else f'{1e3 * cpu:.2f}'} ({1e6 * wall / n:.2f})")
        cells.append(f"{1e3 * r['per_field_wall']:.1f} ({1e6 * r['per_field_wall'] / n:.2f})")
        print(f"{size:>6} " + " ".join(f"{c:>20}" for c in cells) + f" {r['load']:5.2f}")
    print("\nper field per dof against FEniCSx (3D hex27 cap of similar dofs), us")
    print(f"{'size':>6} {'kratos dofs':>11} {'wall':>7} {'CPU':>7} {'fenicsx dofs':>12} {'wall':>7} {'CPU':>7} "
          f"{'CPU ratio':>9} {'load':>5}")
    for size in res["worker"]:
        k, f = res["worker"][size], res["fenicsx"].get(size, {"status": "not run"})
        if k["status"] != "ok" or f["status"] != "ok":
            print(f"{size:>6} kratos: {k['status']}, fenicsx: {f['status']}")
            continue
        kc = sum(k["phases"][p][1] for p in PHASES) / k["n_dofs"] * 1e6
        fc = f["per_field_cpu"] / f["n_dofs"] * 1e6
        print(f"{size:>6} {k['n_dofs']:>11} {1e6 * k['per_field_wall'] / k['n_dofs']:7.2f} {kc:7.2f} "
              f"{f['n_dofs']:>12} {1e6 * f['per_field_wall'] / f['n_dofs']:7.2f} {fc:7.2f} {kc / fc:9.2f} "
              f"{f['load']:5.2f}")
    if res["run"]:
        print("\nstepnf run, DKT kappa = 25 scene (six master modes, DNF MD SMD): seconds, peak RSS MB")
        stages = ("model", "matrices", "eigen", "step", "evaluators")
        print(f"{'size':>6} {'dofs':>8} " + " ".join(f"{s:>10}" for s in stages)
              + f" {'total':>8} {'fields':>7} {'stepnf MB':>9} {'worker MB':>9} {'load':>5}")
        for size, r in res["run"].items():
            if r["status"] != "ok":
                print(f"{size:>6} {r['status']}")
                continue
            print(f"{size:>6} {r['n_dofs']:>8} " + " ".join(f"{r['timings'].get(s, 0.0):10.1f}" for s in stages)
                  + f" {r['total']:8.1f} {r['counts'].get('force_evaluations', 0):>7} {r['peak_rss_mb']:9.0f} "
                  f"{r['worker_peak_rss_mb']:9.0f} {r['load']:5.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="12k,100k", help=f"comma-separated, from {list(SIZES)}")
    ap.add_argument("--fields", type=int, default=12, help="fields per force call (default 12)")
    ap.add_argument("--no-runs", action="store_true", help="skip the whole stepnf runs")
    ap.add_argument("--no-fenicsx", action="store_true", help="skip FEniCSx's forces")
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per part (default 3600)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "kratos.json")
    ap.add_argument("--part", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.part:
        kind, *rest = args.part
        fn = {"worker": part_worker, "fenicsx": part_fenicsx, "run": part_run}[kind]
        print(json.dumps(fn(*map(int, rest))))
        return
    sizes = args.sizes.split(",")
    bad = [s for s in sizes if s not in SIZES]
    if bad:
        ap.error(f"unknown size(s) {bad}: pick from {list(SIZES)}")
    res: dict = {"threads": 1, "cpus": os.cpu_count(), "worker": {}, "fenicsx": {}, "run": {}}
    for size in sizes:
        (kc, kr), (fc, fr) = SIZES[size]
        res["worker"][size] = launch(["worker", str(kc), str(kr), str(args.fields)], args.timeout)
        if not args.no_fenicsx:
            res["fenicsx"][size] = launch(["fenicsx", str(fc), str(fr), str(args.fields)], args.timeout)
        if not args.no_runs:
            res["run"][size] = launch(["run", str(kc), str(kr)], args.timeout)
        print(f"{size}: " + ", ".join(f"{k} {v[size]['status']}" for k, v in res.items()
                                      if isinstance(v, dict) and size in v), flush=True)
    print_tables(res)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=1))
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
