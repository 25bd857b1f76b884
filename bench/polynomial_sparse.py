"""Benchmark of issue 35, item 1: the ``polynomial`` adapter on sparse tensors, at the size peers use.

The model is SSMTool's von Karman beam (``examples/vonKarmanBeam``: L = 1, h = 1e-3, b = 1, E = 70e9,
nu unused, rho = 2700), here clamped at both ends: two-node elements with an axial u (linear) and a
transverse w (Hermite cubic) per node, strain u' + w'^2 / 2, so f is exactly cubic. Its tensors are
assembled element by element as coordinate lists, the quadratic one NOT symmetrised (as YetAnotherFEcode
assembles it), and written to an ``.npz`` of the sparse format (M_subs/M_vals, K_subs/K_vals,
G_subs/G_vals, H_subs/H_vals, n; docs/adapters.md). 34 elements give 99 dofs, 100 give 297,
3334 give 9999.

Each case is one ``stepnf run`` in a fresh process (wall time and peak resident memory of that process,
imports included), master mode 0, ``methods = ["dnf"]`` and ``[analysis.backbone] order = N``, no HDF5
and no figures; then the same scene in-process for the stage timings (what dominates). Targets (issue 35):
297 dofs, order 13: < 2 s and < 300 MB; 9999 dofs, order 7: < 60 s.

    OMP_NUM_THREADS=1 .venv/bin/python bench/polynomial_sparse.py [--cases 297:13 9999:7] [--dense 99:13]

``--dense`` also runs the dense form (today's keys M, K, G, H; n^4 doubles) of the same beam, for the
same numbers (memory: 8 n^4 bytes, 0.77 GB at 99 dofs). Writes ``bench/results/polynomial_sparse.json``.
Not a test: the numbers depend on the machine and its load.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "polynomial_sparse.json"
BEAM = {"L": 1.0, "h": 1e-3, "b": 1.0, "E": 70e9, "rho": 2700.0}


def element_tensors(le: float, E: float, A: float, I: float, rho: float):
    """Ke (6, 6), Me (6, 6), Ge (6, 6, 6) (unsymmetrised), He (6, 6, 6, 6) of one element, local dofs
    (u1, w1, t1, u2, w2, t2), by 5-point Gauss quadrature (exact: the integrands are of degree <= 8)."""
    xi, wq = np.polynomial.legendre.leggauss(5)
    xi, wq = (xi + 1) / 2, wq / 2 * le
    Ke, Me = np.zeros((6, 6)), np.zeros((6, 6))
    Ge, He = np.zeros((6,) * 3), np.zeros((6,) * 4)
    for s, w in zip(xi, wq):
        Nu = np.array([1 - s, 0, 0, s, 0, 0])
        Nw = np.array([0, 1 - 3 * s**2 + 2 * s**3, le * (s - 2 * s**2 + s**3), 0, 3 * s**2 - 2 * s**3, le * (s**3 - s**2)])
        Bu = np.array([-1 / le, 0, 0, 1 / le, 0, 0])
        Bw = np.array([0, (6 * s**2 - 6 * s) / le, 1 - 4 * s + 3 * s**2, 0, (6 * s - 6 * s**2) / le, 3 * s**2 - 2 * s])
        Cw = np.array([0, (12 * s - 6) / le**2, (6 * s - 4) / le, 0, (6 - 12 * s) / le**2, (6 * s - 2) / le])
        Ke += w * (E * A * np.outer(Bu, Bu) + E * I * np.outer(Cw, Cw))
        Me += w * rho * A * (np.outer(Nu, Nu) + np.outer(Nw, Nw))
        # f_a = EA/2 [Bu_a (Bw q)^2 + 2 Bw_a (Bu q)(Bw q)] + EA/2 Bw_a (Bw q)^3
        Ge += w * E * A / 2 * (np.einsum("a,b,c->abc", Bu, Bw, Bw) + 2 * np.einsum("a,b,c->abc", Bw, Bu, Bw))
        He += w * E * A / 2 * np.einsum("a,b,c,d->abcd", Bw, Bw, Bw, Bw)
    return Ke, Me, Ge, He


def beam_lists(n_el: int):
    """The clamped-clamped beam of ``n_el`` elements: coordinate lists (0-based, free dofs) of M, K, G, H,
    the dof count, and each dof's coordinates and direction code (u: ux, w: uz, t: ry)."""
    L, h, b, E, rho = (BEAM[k] for k in ("L", "h", "b", "E", "rho"))
    Ke, Me, Ge, He = element_tensors(L / n_el, E, b * h, b * h**3 / 12, rho)
    nodes = n_el + 1
    free = np.full(3 * nodes, -1)
    keep = np.arange(3, 3 * nodes - 3)  # both end nodes clamped
    free[keep] = np.arange(len(keep))
    edofs = 3 * np.arange(n_el)[:, None] + np.arange(6)[None, :]  # (n_el, 6) global dofs of each element
    out = {}
    for name, T in (("M", Me), ("K", Ke), ("G", Ge), ("H", He)):
        loc = np.argwhere(np.abs(T) > 0)
        glob = free[edofs[:, loc]]  # (n_el, k, order)
        vals = np.broadcast_to(T[tuple(loc.T)], glob.shape[:2])
        ok = (glob >= 0).all(axis=2)
        out[f"{name}_subs"], out[f"{name}_vals"] = glob[ok].astype(np.int64), vals[ok].astype(float)
    x = np.repeat(np.linspace(0, L, nodes), 3)[keep]
    out["coordinates"] = np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1)
    out["directions"] = np.tile([0, 2, 4], nodes)[keep]
    out["length"], out["n"] = np.asarray(h), np.asarray(len(keep))
    return out


def dense_arrays(lists: dict) -> dict:
    """The dense form (today's keys) of the same system."""
    n = int(lists["n"])
    out = {k: v for k, v in lists.items() if k in ("coordinates", "directions", "length")}
    for name, order in (("M", 2), ("K", 2), ("G", 3), ("H", 4)):
        T = np.zeros((n,) * order)
        np.add.at(T, tuple(lists[f"{name}_subs"].T), lists[f"{name}_vals"])
        out[name] = T
    return out


SCENE = ('[model]\nsolver = "polynomial"\nfile = "{file}"\n[analysis]\nmaster_modes = [0]\nmethods = ["dnf"]\n'
         '[analysis.backbone]\norder = {order}\n[output]\ndir = "out"\nhdf5 = false\nplot = false\n')


def child(scene: str) -> dict:
    """The scene in this process: stage timings, T, the backbone's last point."""
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import load_scene

    t0 = time.perf_counter()
    res = run_scene(load_scene(Path(scene)), write=False)
    m = res.modes[0]
    return {"wall_in_process": round(time.perf_counter() - t0, 3), "timings": res.timings, "counts": res.counts,
            "omega": m.omega, "T_dnf": m.methods["dnf"].T,
            "backbone_end": {k: float(m.backbone[k][-1]) for k in ("amplitude", "omega_ratio")},
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)}


def timed_run(args: list[str], env: dict) -> tuple[float, float, int]:
    """Wall seconds, peak RSS (MB) and exit code of one subprocess (its own rusage, via wait4)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if status:
        sys.stderr.write(proc.stderr.read().decode())
    return wall, usage.ru_maxrss / 1024, os.waitstatus_to_exitcode(status)


def case(n_dofs: int, order: int, dense: bool, folder: Path, env: dict) -> dict:
    n_el = (n_dofs + 3) // 3  # 3 (n_el + 1) - 6 free dofs
    t0 = time.perf_counter()
    lists = beam_lists(n_el)
    name = f"beam{int(lists['n'])}_{'dense' if dense else 'sparse'}"
    np.savez(folder / f"{name}.npz", **(dense_arrays(lists) if dense else lists))
    build = time.perf_counter() - t0
    scene = folder / f"{name}_o{order}.toml"
    scene.write_text(SCENE.format(file=f"{name}.npz", order=order))
    wall, rss, code = timed_run([str(ROOT / ".venv" / "bin" / "stepnf"), "run", str(scene), "-q"], env)
    row = {"form": "dense" if dense else "sparse", "n_dofs": int(lists["n"]), "order": order,
           "nnz_G": len(lists["G_vals"]), "nnz_H": len(lists["H_vals"]), "build_write_seconds": round(build, 2),
           "stepnf_run_seconds": round(wall, 2), "stepnf_run_peak_rss_mb": round(rss, 1), "exit_code": code}
    if code == 0:
        out = subprocess.run([sys.executable, __file__, "--child", str(scene)], env=env, capture_output=True,
                             text=True, check=True)
        row.update(json.loads(out.stdout.strip().splitlines()[-1]))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="*", default=["297:13", "9999:7"], help="N_DOFS:ORDER of the sparse runs")
    ap.add_argument("--dense", nargs="*", default=[], help="N_DOFS:ORDER of dense-form runs (n^4 memory)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(a.child), default=float))
        return
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for spec, dense in [(c, False) for c in a.cases] + [(c, True) for c in a.dense]:
            n, order = map(int, spec.split(":"))
            rows.append(case(n, order, dense, Path(tmp), env))
            r = rows[-1]
            print(f"{r['form']:6s} {r['n_dofs']:6d} dofs order {r['order']:2d}: stepnf run {r['stepnf_run_seconds']:7.2f} s "
                  f"{r['stepnf_run_peak_rss_mb']:7.1f} MB  omega = {r.get('omega', float('nan')):.6g} T = {r.get('T_dnf', float('nan')):.6e}  "
                  f"stages {r.get('timings', {})}", flush=True)
    for r in rows:  # the dense form against the sparse one of the same beam and order: the same numbers
        twin = next((s for s in rows if s["form"] == "sparse" and (s["n_dofs"], s["order"]) == (r["n_dofs"], r["order"])
                     and "T_dnf" in s), None)
        if r["form"] == "dense" and twin and "T_dnf" in r:
            r["vs_sparse"] = {"T_rel": abs(r["T_dnf"] / twin["T_dnf"] - 1),
                              "omega_ratio_end_rel": abs(r["backbone_end"]["omega_ratio"] / twin["backbone_end"]["omega_ratio"] - 1),
                              "time_ratio": r["stepnf_run_seconds"] / twin["stepnf_run_seconds"],
                              "memory_ratio": r["stepnf_run_peak_rss_mb"] / twin["stepnf_run_peak_rss_mb"]}
            print(f"dense / sparse at {r['n_dofs']} dofs, order {r['order']}: " + ", ".join(
                f"{k} {v:.3g}" for k, v in r["vs_sparse"].items()))
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text(json.dumps({"beam": BEAM, "omp_num_threads": env["OMP_NUM_THREADS"], "rows": rows},
                              indent=1, default=float) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
