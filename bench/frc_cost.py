"""Benchmark of issue 34: the forced responses' cost on top of the backbone, on the 38k-dof main-job mesh.

The scene is ``examples/shell_kappa25.toml`` (38k dofs, hex27, FEniCSx) with ``methods = ["dnf"]`` and
``[analysis.backbone] order = 7`` for its six masters, run twice in fresh subprocesses:

* ``backbone``: as it is;
* ``frc``: the same plus ``[analysis.damping] modal = 0.01`` and ``[analysis.forcing] modal = [k1, k2, k3]``
  (three levels, ``frequency_range = [0.9, 1.25]``): the FRC of every master at each level.

The table gives the backbone stage's and the forced stage's time (the issue's target: the FRCs under 10% of
the backbone's time), the whole run's wall time and peak memory. The forced stage makes no force evaluation and
no factorisation (the FRC lives on the backbone's manifold): the counts say so.

    .venv/bin/python bench/frc_cost.py

Writes ``bench/results/frc_cost.json``. Not a test: the numbers depend on the machine and its load.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "frc_cost.json"
#: Modal force levels k of F = k M phi_p cos(Omega t) (model units): the linear peak k / (2 xi w^2) of the
#: strongest is 3.6e-4 for (2,0) (w = 1057), beyond its backbone's validity, 6e-6 for (0,2) (w = 8168): the
#: same work per curve either way (this measures cost, not accuracy).
LEVELS = [0.5, 2.0, 8.0]


def child(kind: str) -> dict:
    """One run in this process: the scene, its timings, counts and peak memory."""
    import resource
    import tomllib

    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    src = ROOT / "examples" / "shell_kappa25.toml"
    data = tomllib.loads(src.read_text())
    data["analysis"]["methods"] = ["dnf"]
    data["analysis"]["backbone"] = {"order": 7}
    if kind == "frc":
        data["analysis"]["damping"] = {"modal": 0.01}
        data["analysis"]["forcing"] = {"modal": LEVELS, "frequency_range": [0.9, 1.25]}
    data["output"] = {"hdf5": False, "plot": False}
    scene = parse_scene(data, file=src, base_dir=src.parent)
    t0 = time.perf_counter()
    res = run_scene(scene, write=False)
    wall = time.perf_counter() - t0
    doc = res.to_dict()
    modes = [{"label": m["label"], "frc": [{"peak": lv.get("peak"), "folds": len(lv.get("folds") or [])}
                                           for lv in (m.get("frc") or [])], "frc_reason": m.get("frc_reason")}
             for m in doc["modes"]]
    return {"kind": kind, "wall_seconds": round(wall, 2),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            "n_dofs": doc.get("model", {}).get("n_dofs"), "counts": res.counts, "timings": res.timings,
            "modes": modes}


def run(kind: str) -> dict:
    p = subprocess.run([sys.executable, __file__, "--child", kind], capture_output=True, text=True,
                       env=dict(os.environ), cwd=ROOT)
    if p.returncode:
        raise SystemExit(f"{kind} run failed:\n{p.stderr[-4000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        print(json.dumps(child(sys.argv[2])))
        return
    load = os.getloadavg()
    bb, frc = run("backbone"), run("frc")
    t_bb, t_frc = frc["timings"].get("backbone"), frc["timings"].get("forced")
    rows = [("backbone stage (s)", bb["timings"].get("backbone"), t_bb),
            ("forced stage (s)", None, t_frc),
            ("wall time (s)", bb["wall_seconds"], frc["wall_seconds"]),
            ("peak RSS (MB)", bb["peak_rss_mb"], frc["peak_rss_mb"]),
            ("force evaluations", bb["counts"].get("force_evaluations"), frc["counts"].get("force_evaluations")),
            ("factorisations", bb["counts"].get("factorizations"), frc["counts"].get("factorizations"))]
    print(f"{'':22s}{'backbone':>12s}{'backbone + FRC':>16s}")
    for name, a, b in rows:
        a_s = "-" if a is None else (f"{a:.2f}" if isinstance(a, float) else str(a))
        b_s = "-" if b is None else (f"{b:.2f}" if isinstance(b, float) else str(b))
        print(f"{name:22s}{a_s:>12s}{b_s:>16s}")
    ratio = round(t_frc / t_bb, 4) if t_frc is not None and t_bb else None
    print(f"forced stage / backbone stage = {ratio} (target < 0.10), {len(LEVELS)} levels x "
          f"{len(frc['modes'])} masters")
    doc = {"scene": "examples/shell_kappa25.toml, methods = [dnf], backbone order 7, modal damping 0.01",
           "levels": LEVELS, "load_average_before": [round(x, 2) for x in load],
           "load_average_after": [round(x, 2) for x in os.getloadavg()], "target": "forced stage < 10% of backbone",
           "ratio": ratio, "backbone": bb, "frc": frc}
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
