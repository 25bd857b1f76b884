"""The paper's DKT model (issue 32, item 5): Gamma of its six modes at the Table 2 kappa values, DKT
shells (Kratos, ``solver = "kratos"``, ``element = "dkt"``) against the 3D solid (hex27, FEniCSx)
against the von Karman model, and the mesh convergence of the DKT model.

    .venv/bin/python bench/shell_dkt.py            # runs what bench/results/shell_dkt.json lacks
    .venv/bin/python bench/shell_dkt.py --table    # prints the tables of the stored JSON only

Sources: the sweep stores of Fig. 4, ``docs/fig4/table2.h5`` (3D solid, default 17.6k-dof mesh) and
``docs/fig4/table2_dkt.h5`` (DKT, the generated cap's default mid-surface mesh, 11 766 dofs: the
paper's ~12k; ``examples/table2_dkt.toml``); the von Karman model's NF with every mode at each case's
kappa (:func:`stepnf.report.fig4.vonkarman_at`). Run here: kappa = 25 at h = 1 mm (R = 4.5 m, not a
Table 2 case) with both FE models, and the DKT model of a few Table 2 cases on meshes of 2 and 4 times
the dofs (n_core x n_ring = 20 x 7: 23 526 dofs, 28 x 10: 46 374), and kappa = 25 at h = 3 mm at 8 times
(40 x 14: 93 126). DNF, one thread. Every run is
stored in the JSON as it ends (an interrupted run resumes).
"""
from __future__ import annotations

import argparse
import json
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "shell_dkt.json"
STORES = {"3d": ROOT / "docs" / "fig4" / "table2.h5", "dkt": ROOT / "docs" / "fig4" / "table2_dkt.h5"}
BASES = {"3d": ROOT / "examples" / "table2_base.toml", "dkt": ROOT / "examples" / "table2_dkt_base.toml"}
MODES = ["(2,0)", "(3,0)", "(4,0)", "(0,1)", "(0,2)", "(2,1)"]
#: DKT meshes: the default (the store's value) and 2x, 4x its dofs
MESHES = {"12k": None, "24k": {"n_core": 20, "n_ring": 7}, "46k": {"n_core": 28, "n_ring": 10}}
#: Table 2 cases (R, h) refined: kappa = 4.59, 25 (h = 3 and 5 mm), 87.9, 225
REFINED = [(3.5, 0.003), (1.5, 0.003), (0.9, 0.005), (0.8, 0.003), (0.5, 0.003)]
#: and 8x the dofs for the paper's cap, kappa = 25 at h = 3 mm (where (2,1) and (0,2) converge)
FINEST = ("93k", {"n_core": 40, "n_ring": 14}, (1.5, 0.003))
#: kappa = 25 at h = 1 mm: R = a^2 / (5 h) = 4.5 m
KAPPA25_H1 = (4.5, 0.001)


def case_id(R: float, h: float) -> str:
    return f"R={R:g}_h={h:g}"


def run_case(model: str, R: float, h: float, mesh: dict | None = None) -> dict:
    """One DNF run of the Table 2 base scene of ``model`` ("3d" or "dkt") at (R, h) on ``mesh``."""
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    data = tomllib.loads(BASES[model].read_text())
    data["model"]["geometry"].update({"R": R, "h": h, **(mesh or {})})
    data["output"] = {"hdf5": False}
    t0 = time.perf_counter()
    r = run_scene(parse_scene(data, file=BASES[model], base_dir=BASES[model].parent), write=False)
    return {"n_dofs": r.model["n_dofs"], "seconds": round(time.perf_counter() - t0, 1), "kappa": r.kappa,
            "gamma": {f"({m.label[0]},{m.label[1]})": m.methods["dnf"].gamma for m in r.modes},
            "omega": {f"({m.label[0]},{m.label[1]})": m.omega for m in r.modes},
            "near_resonance": [f"({m.label[0]},{m.label[1]})" for m in r.modes
                               if any(f["kind"].startswith("internal_resonance") for f in m.methods["dnf"].flags)]}


def stored_points() -> dict:
    """``{case: {kappa, h, modes: {mode: {3d, dkt, vk, resonant}}}}`` of the two stores, von Karman at each kappa."""
    from stepnf.report.fig4 import fe_points, vonkarman_at

    pts = [p for name, store in STORES.items() for p in fe_points(store, name)]
    vonkarman_at(pts)
    out: dict = {}
    for p in sorted(pts, key=lambda p: (p.h or 0.0, p.kappa)):
        c = out.setdefault(p.case, {"kappa": p.kappa, "h": p.h, "modes": {}})
        m = c["modes"].setdefault(f"({p.mode[0]},{p.mode[1]})", {"vk": p.gamma_vk, "resonant": False})
        m[p.store] = p.gamma_fe
        m["resonant"] = m["resonant"] or p.resonant
    return out


def vonkarman_gamma(kappa: float) -> dict[str, float]:
    from stepnf.report.fig4 import Point, vonkarman_at

    pts = [Point("vk", "", kappa, tuple(int(x) for x in m.strip("()").split(",")), 0.0) for m in MODES]
    vonkarman_at(pts)
    return {f"({p.mode[0]},{p.mode[1]})": p.gamma_vk for p in pts}


def compute(doc: dict) -> dict:
    doc["stored"] = stored_points()
    save(doc)
    runs = doc.setdefault("runs", {})
    todo = [("3d", *KAPPA25_H1, None), ("dkt", *KAPPA25_H1, None)]
    todo += [("dkt", R, h, MESHES[m]) for R, h in REFINED for m in MESHES if MESHES[m]]
    todo += [("dkt", *FINEST[2], FINEST[1])]
    names = {**{str(v): k for k, v in MESHES.items()}, str(FINEST[1]): FINEST[0]}
    for model, R, h, mesh in todo:
        mname = names[str(mesh)] if model == "dkt" else "17.6k"
        key = f"{model} {case_id(R, h)} {mname}"
        if key not in runs:
            runs[key] = {"model": model, "case": case_id(R, h), "R": R, "h": h, "mesh": mname,
                         **run_case(model, R, h, mesh)}
            print(f"{key}: {runs[key]['n_dofs']} dofs, {runs[key]['seconds']} s", flush=True)
            save(doc)
    doc["vk_kappa25"] = vonkarman_gamma(25.0)
    doc["largest"] = {"kappa<=100": largest(doc["stored"], 100.0), "all": largest(doc["stored"], float("inf"))}
    save(doc)
    return doc


def save(doc: dict) -> None:
    OUT.write_text(json.dumps(doc, indent=1) + "\n")


def rel(a: float | None, b: float | None) -> str:
    return "-" if a is None or b is None or b == 0 else f"{100 * (a / b - 1):+.1f}%"


def largest(stored: dict, kappa_max: float) -> dict:
    """Per pair (DKT/3D, DKT/vK, 3D/vK) and mode: the largest relative difference (%) and its case, over the cases
    up to ``kappa_max`` away from resonances where |Gamma_vK| > 0.02 (relative differences of a Gamma near 0
    mean nothing: fig4.summary's rule)."""
    out: dict = {}
    for cid, c in stored.items():
        for mode, v in c["modes"].items():
            if c["kappa"] > kappa_max or v["resonant"] or abs(v["vk"]) <= 0.02:
                continue
            for pair, a, b in (("DKT/3D", v["dkt"], v["3d"]), ("DKT/vK", v["dkt"], v["vk"]),
                               ("3D/vK", v["3d"], v["vk"])):
                r = 100 * abs(a / b - 1)
                if r > out.setdefault(pair, {}).get(mode, {"percent": -1.0})["percent"]:
                    out[pair][mode] = {"percent": round(r, 2), "case": cid, "kappa": round(c["kappa"], 3)}
    return out


def tables(doc: dict) -> str:
    st, runs = doc["stored"], doc["runs"]
    lines = ["Gamma (DNF) at the paper's Table 2 cases: DKT (11 766 dofs) | 3D hex27 (17 649 dofs) | von Karman NF;"
             " * near a 1:2 or 1:1 internal resonance",
             f"{'case':15s} {'kappa':>8s} {'mode':6s} {'DKT':>9s} {'3D':>9s} {'vK':>9s} {'DKT/3D':>8s} {'DKT/vK':>8s}"]
    for cid, c in sorted(st.items(), key=lambda kv: (kv[1]["h"], kv[1]["kappa"])):
        for mode in MODES:
            m = c["modes"].get(mode)
            if m is None:
                continue
            lines.append(f"{cid:15s} {c['kappa']:8.4g} {mode:6s} {m.get('dkt', float('nan')):+9.5f} "
                         f"{m.get('3d', float('nan')):+9.5f} {m['vk']:+9.5f} {rel(m.get('dkt'), m.get('3d')):>8s} "
                         f"{rel(m.get('dkt'), m['vk']):>8s}{' *' if m['resonant'] else ''}")
    for kmax in (100.0, float("inf")):
        lines += ["", f"largest relative difference, kappa <= {kmax:g}, away from resonances, |Gamma_vK| > 0.02 "
                  "(% at kappa)", f"{'pair':8s} " + " ".join(f"{m:>15s}" for m in MODES)]
        big = largest(st, kmax)
        for pair, per in big.items():
            lines.append(f"{pair:8s} " + " ".join(f"{per[m]['percent']:6.1f} ({per[m]['kappa']:6.4g})" if m in per
                                                   else f"{'-':>15s}" for m in MODES))
    h1 = {k.split()[0]: v for k, v in runs.items() if v["case"] == case_id(*KAPPA25_H1)}
    lines += ["", f"kappa = 25 at h = 1, 3, 5 mm: DKT | 3D (h = 1 mm: {case_id(*KAPPA25_H1)}, run here) | von Karman"]
    for h, cid in [(0.001, None), (0.003, case_id(1.5, 0.003)), (0.005, case_id(0.9, 0.005))]:
        for mode in MODES:
            if cid is None:
                d, s = h1.get("dkt", {}).get("gamma", {}).get(mode), h1.get("3d", {}).get("gamma", {}).get(mode)
            else:
                d, s = st[cid]["modes"][mode].get("dkt"), st[cid]["modes"][mode].get("3d")
            v = doc["vk_kappa25"][mode]
            lines.append(f"h = {1e3 * h:g} mm {mode:6s} {d:+9.5f} {s:+9.5f} {v:+9.5f} {rel(d, s):>8s} {rel(d, v):>8s}")
    lines += ["", "DKT mesh convergence: Gamma on 12k (the store), 24k and 46k dofs; change of 12k and 24k against 46k"]
    for R, h in REFINED:
        cid = case_id(R, h)
        fine = [runs.get(f"dkt {cid} {m}") for m in MESHES if MESHES[m]]
        if not all(fine):
            continue
        lines.append(f"{cid} (kappa = {st[cid]['kappa']:.4g}; {fine[0]['n_dofs']}, {fine[1]['n_dofs']} dofs)")
        for mode in MODES:
            g = [st[cid]["modes"][mode]["dkt"], fine[0]["gamma"][mode], fine[1]["gamma"][mode]]
            near = " *" if st[cid]["modes"][mode]["resonant"] or mode in fine[1]["near_resonance"] else ""
            lines.append(f"  {mode:6s} " + " ".join(f"{x:+9.5f}" for x in g)
                         + f" {rel(g[0], g[2]):>8s} {rel(g[1], g[2]):>8s}{near}")
    finest = runs.get(f"dkt {case_id(*FINEST[2])} {FINEST[0]}")
    if finest:
        cid = case_id(*FINEST[2])
        seq = [st[cid]["modes"]] + [runs[f"dkt {cid} {m}"]["gamma"] for m in MESHES if MESHES[m]] + [finest["gamma"]]
        lines += ["", f"{cid}: Gamma on 12k, 24k, 46k, {finest['n_dofs']} dofs ({finest['seconds']} s); change of each"
                  " against the finest"]
        for mode in MODES:
            g = [seq[0][mode]["dkt"]] + [x[mode] for x in seq[1:]]
            lines.append(f"  {mode:6s} " + " ".join(f"{x:+9.5f}" for x in g) + " "
                         + " ".join(f"{rel(x, g[-1]):>8s}" for x in g[:-1]))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", action="store_true", help="print the tables of the stored JSON, run nothing")
    args = ap.parse_args()
    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    if not args.table:
        doc = compute(doc)
    print(tables(doc))


if __name__ == "__main__":
    main()
