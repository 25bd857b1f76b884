"""Mesh convergence of DNF Gamma (issue 3): plate and kappa = 25 shell on three O-grid resolutions.

    .venv/bin/python bench/mesh_convergence.py

Prints, per mode, Gamma on each mesh and the change of the default mesh's
value against the finest; writes ``bench/results/mesh_convergence.json``.
Modes within 5% of a 1:2 internal resonance are marked: their T depends on
the small frequency errors of the resonant partner and converges last.
"""
from __future__ import annotations

import json
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MESHES = {"default": {}, "38k": {"n_core": 18, "n_ring": 10}, "63k": {"n_core": 24, "n_ring": 12}}
SCENES = {"plate": "inf", "kappa25": 1.5}


def main() -> None:
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    base = tomllib.loads((ROOT / "examples" / "plate.toml").read_text())
    base["analysis"]["methods"] = ["dnf"]
    base["output"] = {"hdf5": False}
    rows: dict = {}
    for sname, R in SCENES.items():
        for mname, res in MESHES.items():
            data = json.loads(json.dumps(base))
            g = data["model"]["geometry"]
            g["R"] = R
            for k in ("n_core", "n_ring"):
                g.pop(k, None)
            g.update(res)
            t0 = time.perf_counter()
            r = run_scene(parse_scene(data, file=ROOT / "examples" / "plate.toml", base_dir=ROOT / "examples"),
                          write=False)
            rows.setdefault(sname, {})[mname] = {
                "n_dofs": r.model["n_dofs"], "seconds": time.perf_counter() - t0,
                "gamma": {f"({m.label[0]},{m.label[1]})": m.methods["dnf"].gamma for m in r.modes},
                "near_resonance": [f"({m.label[0]},{m.label[1]})" for m in r.modes
                                   if any(f["kind"] == "internal_resonance_1_2" for f in m.methods["dnf"].flags)],
            }
            print(f"{sname} {mname}: {r.model['n_dofs']} dofs, {time.perf_counter() - t0:.1f} s", flush=True)
    finest = list(MESHES)[-1]
    changes: dict = {}
    for sname, meshes in rows.items():
        print(f"\n{sname}: Gamma (DNF) per mesh, change of the default mesh against {finest}")
        print(f"{'mode':8s}" + "".join(f"{m + ' (' + str(v['n_dofs']) + ')':>18s}" for m, v in meshes.items())
              + f"{'change':>10s}")
        for mode in meshes["default"]["gamma"]:
            vals = [meshes[m]["gamma"][mode] for m in meshes]
            ch = abs(vals[0] / vals[-1] - 1)
            mark = "  near 1:2" if any(mode in meshes[m]["near_resonance"] for m in meshes) else ""
            print(f"{mode:8s}" + "".join(f"{v:18.5f}" for v in vals) + f"{100 * ch:9.2f}%{mark}")
            changes.setdefault(sname, {})[mode] = ch
    out = ROOT / "bench" / "results" / "mesh_convergence.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"meshes": rows, "change_default_vs_finest": changes}, indent=1))
    print(f"written {out}")


if __name__ == "__main__":
    main()
