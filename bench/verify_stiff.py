"""Benchmark of issue 29 (finding 8): ``stepnf verify`` on stiff models, explicit against implicit shooting.

Cases (each a polynomial scene verified at ``--amplitudes 0.4 0.8``, DPIM order 21):

* ``stiff_1e2``, ``stiff_1e4``, ``stiff_1e6``: 2 dofs, modal frequencies 1 (the master) and
  ``1.05 sqrt(ratio)`` (tests/helpers/systems.stiff_two_dof: stiffness ratio ``1.1 ratio``);
* ``two_dof``: the scene of tests/verify/test_verify.py (frequencies 1 and 3.6);
* ``system12``: ``examples/polynomial.toml`` (12 dofs, masters 0 and 2) with ``[analysis.backbone] order = 7``
  at its default amplitudes (1/3, 2/3 and 1 of the validity limit).

each with the shooting's integrator ``auto`` (implicit Gauss-Legendre where ``w_max / w`` > 5) and
forced ``explicit`` (DOP853 rtol 1e-12, what ``verify`` did before: ``--before``) or ``implicit``.
Each run is a fresh subprocess with a time limit (``--limit``, default 600 s: the explicit 1e6 run
takes longer). The table: wall time of the whole ``verify_scene`` (backbone run included), the
orbits' seconds, force fields evaluated by the shooting, the method, and the frequency ratio at A = 0.8.

    .venv/bin/python bench/verify_stiff.py [--integrators auto explicit] [--cases stiff_1e6 ...]

Writes ``bench/results/verify_stiff.json`` (keeping the rows of earlier runs for the pairs not rerun:
``--integrators auto`` after a change leaves the slow explicit rows as they were). Not a test: times depend on the machine and its load
(tests/verify/test_verify_stiff.py bounds the force evaluations instead).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "verify_stiff.json"
CASES = ("stiff_1e2", "stiff_1e4", "stiff_1e6", "two_dof", "system12")
SCENE = """[model]
solver = "polynomial"
file = "{file}"

[analysis]
master_modes = {masters}
methods = ["dnf"]
retained_modes = {retained}

[analysis.backbone]
order = {order}
points = 4

[output]
dir = "results"
"""


def write_case(case: str, folder: Path) -> tuple[Path, list[float] | None]:
    """The scene of ``case`` in ``folder`` and the amplitudes asked (None: the defaults)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from stepnf_polynomial.adapter import save_system

    if case.startswith("stiff_"):
        from helpers.systems import stiff_two_dof

        save_system(folder / "s.npz", *stiff_two_dof(float(case.split("_")[1])))
        text, amps = SCENE.format(file="s.npz", masters=[0], retained=2, order=21), [0.4, 0.8]
    elif case == "two_dof":
        from helpers.systems import two_dof

        save_system(folder / "s.npz", *two_dof())
        text, amps = SCENE.format(file="s.npz", masters=[0], retained=2, order=21), [0.4, 0.8]
    else:
        text = SCENE.format(file=str(ROOT / "examples" / "system12.npz"), masters=[0, 2], retained=12, order=7)
        amps = None
    path = folder / "scene.toml"
    path.write_text(text)
    return path, amps


def child(case: str, integrator: str) -> dict:
    """One verify run in this process."""
    from stepnf.verify import command as verify
    from stepnf.scene.parse import load_scene

    with tempfile.TemporaryDirectory() as tmp:
        path, amps = write_case(case, Path(tmp))
        t0 = time.perf_counter()
        doc = verify.verify_scene(load_scene(path), amplitudes=amps, integrator=integrator)
        wall = time.perf_counter() - t0
    checks = [c for m in doc["modes"] for c in m["checks"]]
    return {"case": case, "integrator": integrator, "wall_seconds": round(wall, 2),
            "orbit_seconds": round(sum(c["seconds"] for c in checks), 2),
            "force_evaluations": sum(c["work"].get("force_evaluations", 0) for c in checks),
            "force_calls": sum(c["work"].get("force_calls", 0) for c in checks) or None,
            "methods": sorted({c["work"].get("method", "explicit") for c in checks}),
            "stiffness_ratio": checks[0]["work"].get("stiffness_ratio") if checks else None,
            "failed": verify.failed_orbits(doc),
            "checks": [{k: c[k] for k in ("amplitude", "omega_check_over_omega", "relative_difference",
                                          "manifold_distance", "seconds")} for c in checks]}


def run(case: str, integrator: str, limit: float) -> dict:
    t0 = time.perf_counter()
    try:
        out = subprocess.run([sys.executable, __file__, "--child", case, integrator], capture_output=True,
                             text=True, timeout=limit, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"case": case, "integrator": integrator, "wall_seconds": None,
                "error": f"not finished in {limit:g} s (killed)"}
    if out.returncode:
        return {"case": case, "integrator": integrator, "error": out.stderr.strip().splitlines()[-1:],
                "process_seconds": round(time.perf_counter() - t0, 2)}
    row = json.loads(out.stdout)
    row["process_seconds"] = round(time.perf_counter() - t0, 2)
    return row


def table(rows: list[dict]) -> str:
    lines = [f"{'case':<10s} {'integrator':<9s} {'method':<18s} {'w_max/w':>8s} {'wall s':>8s} {'orbits s':>9s} "
             f"{'forces':>8s} {'calls':>7s} {'w/w0 at last A':>15s} {'rel. diff':>10s}"]
    for r in rows:
        if "error" in r:
            lines.append(f"{r['case']:<10s} {r['integrator']:<9s} {r['error']}")
            continue
        last = r["checks"][-1] if r["checks"] else {}
        lines.append(f"{r['case']:<10s} {r['integrator']:<9s} {','.join(r['methods']):<18s} "
                     f"{r['stiffness_ratio'] or float('nan'):8.3g} {r['wall_seconds']:8.2f} {r['orbit_seconds']:9.2f} "
                     f"{r['force_evaluations']:8d} {r['force_calls'] or 0:7d} "
                     f"{last.get('omega_check_over_omega', float('nan')):15.10f} "
                     f"{last.get('relative_difference', float('nan')):10.2e}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", nargs=2, metavar=("CASE", "INTEGRATOR"), help=argparse.SUPPRESS)
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--integrators", nargs="+", default=["auto", "explicit"],
                    choices=["auto", "explicit", "implicit"])
    ap.add_argument("--limit", type=float, default=600.0, help="seconds a run may take (default 600)")
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(*args.child)))
        return
    rows = []
    for case in args.cases:
        for integ in args.integrators:
            rows.append(run(case, integ, args.limit))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    # rows of earlier runs for other (case, integrator) pairs are kept: the slow explicit ones need not rerun
    old = json.loads(OUT.read_text())["rows"] if OUT.exists() else []
    new = {(r["case"], r["integrator"]) for r in rows}
    rows = [r for r in old if (r["case"], r["integrator"]) not in new] + rows
    rows.sort(key=lambda r: (CASES.index(r["case"]), r["integrator"]))
    print(table(rows))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"benchmark": "verify_stiff", "date": time.strftime("%Y-%m-%d %H:%M:%S"),
                               "rows": rows}, indent=2) + "\n")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
