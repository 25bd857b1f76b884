"""Issue 33 item 5, 3D side: (2,1), (0,2), (4,0) of the kappa = 25 cap on 1:2 manifolds, against the full model.

The scene is ``examples/shell_kappa25.toml`` (38k dofs, hex27, FEniCSx) with ``methods = ["dnf"]``, one master and
``[analysis.backbone] order = 7, manifolds = [[master, partner]]``, reported at ``w_over_h`` = 0.05 .. 1.0:

* ``m21``: (2,1) on [(2,1), (4,1)] (mode 11 with mode 22, w22/w11 = 1.931; G(phi_11, phi_11) . phi_22 = 1.8e10
  in the model's units, the twin 23: 7e1, i.e. nothing);
* ``m02``: (0,2) on [(0,2), (0,3)] with ``resonance = 0.08`` (mode 13 with mode 28, w28/w13 = 2.130, 6.5 % from
  1:2, outside the default tolerance 0.05). The modes nearer 1:2, (8,0) at 1.967 w (mode 25) and (2,2) at 2.049 w
  (modes 26, 27), are barely coupled to (0,2): G(phi_13, phi_13) . phi_j = 1.7e7 for mode 25 (the O-grid's
  four-fold symmetry lets n = 8 see n = 0), 0.2 for (2,2), against 2.2e10 for (0,3); with their small denominators
  (0.033, 0.047 against 0.118) (0,3)'s term is still ~360 times (8,0)'s. Measured by ``--coupling``
  (G(phi, phi) = (f(a phi) + f(-a phi)) / (2 a^2), exact for St Venant-Kirchhoff; the modes oriented as a run's);
* ``m40``: (4,0) on [(4,0), (0,2)] (mode 5, the lower of the (4,0) twins 5, 6, with mode 13, w13/w5 = 1.903,
  within the default tolerance 0.05 as on the von Karman model; G(phi_5, phi_5) . phi_13 = 1.9e9, the other modes
  with w_s / w_5 in (1.5, 2.5) at most 3e-2, i.e. nothing; the twin 6 the same 1.9e9);
* ``m21o5``, ``m02o5``, ``m40o5``: the same manifolds at order 5; ``m21o9``: (2,1)'s at order 9;
* ``m21x``, ``s02x``, ``m40x``: beyond the validity limits (below), started from (2,1)'s and (4,0)'s manifolds and
  from (0,2)'s single-mode parametrisation (run when its manifold seemed to end at W_max/h = 0.446: an artefact of
  the continuation in the model's units, fixed since; ``m02``'s own ``beyond`` were not rerun);
* ``m02m``: ``m02`` verified once near its w_NL/w minimum (0.92 of the amplitude at W_max/h = 0.65, inside its
  validity limit 0.677);
* ``single``, ``single9``: the single-mode backbones of (2,1) and (0,2) at the same order and ``w_over_h``, and at
  order 9 (beyond their validity limits: the parity swing of docs/backbone/kappa25.md).
  ``single40``, ``single40o9``: (4,0)'s single-mode backbone at orders 7 and 9 (separate runs, so that the
  stored numbers of ``single`` and ``single9`` stay those measured).

A manifold run then checks the master's continuing branch against the full model's orbits (time integration, 3
periods, Richardson; :func:`stepnf.verify.manifold_orbits.manifold_checks`, the code of ``stepnf verify``) at two
amplitudes A of the master's modal coordinate, 0.5 and 0.95 of min(validity limit, A at W_max/h = 0.5), in the
same process as the run (one manifold build instead of two). ``beyond``: the full model's trajectories started
on the continuing branch at W_max/h beyond the validity limit (``stepnf verify`` refuses those amplitudes; the same
integration, :func:`stepnf.verify.manifold_integration.integrate_orbit`, called directly): the full model's own
frequency there, with the distance of its states from the manifold (how far from a periodic orbit on it they
stay). ``stepnf verify --amplitudes A1 A2`` on the scene written to ``/tmp/k25m3d/<name>.toml`` does what the
verify part does and also checks the coupled branches. Each run is a
fresh subprocess (its own peak resident memory), one after the other; raw outputs in ``/tmp/k25m3d/``.

    OMP_NUM_THREADS=1 nice .venv/bin/python bench/kappa25_manifolds_3d.py [--only m21 m02 ...] [--coupling]

Writes ``bench/results/kappa25_manifolds_3d.json`` (the runs asked, merged into the file's earlier ones).
Not a test: the times depend on the machine and its load.
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
OUT = ROOT / "bench" / "results" / "kappa25_manifolds_3d.json"
RAW = Path("/tmp/k25m3d")
ORDER = 7
GRID = [round(0.05 * i, 2) for i in range(1, 21)]
#: The verified amplitudes: these fractions of min(validity limit, A at W_max/h = VERIFY_TOP).
VERIFY_FRACTIONS = (0.5, 0.95)
VERIFY_TOP = 0.5
M21 = {"manifolds": [["(2,1)", "(4,1)"]]}
M02 = {"manifolds": [["(0,2)", "(0,3)"]], "resonance": 0.08}
M40 = {"manifolds": [["(4,0)", "(0,2)"]]}
RUNS = {
    "m21": {"masters": ["(2,1)"], "backbone": M21, "verify": True},
    "m02": {"masters": ["(0,2)"], "backbone": M02, "verify": True, "beyond": [0.7, 1.0]},
    "m21x": {"masters": ["(2,1)"], "backbone": M21, "verify": False, "beyond": [0.5, 0.7]},
    "m21o5": {"masters": ["(2,1)"], "backbone": M21 | {"order": 5}, "verify": False},
    "m02o5": {"masters": ["(0,2)"], "backbone": M02 | {"order": 5}, "verify": False},
    "s02x": {"masters": ["(0,2)"], "backbone": {}, "verify": False, "beyond_single": [0.7, 1.0]},
    "single": {"masters": ["(2,1)", "(0,2)"], "backbone": {}, "verify": False},
    "single9": {"masters": ["(2,1)", "(0,2)"], "backbone": {"order": 9}, "verify": False},
    "m40": {"masters": ["(4,0)"], "backbone": M40, "verify": True},
    # (0,2) near its w_NL/w minimum (W_max/h ~ 0.59, inside the limit 0.677 of the scaled continuation)
    "m02m": {"masters": ["(0,2)"], "backbone": M02, "verify": True, "verify_top": 0.65, "verify_fractions": (0.92,)},
    "m40o5": {"masters": ["(4,0)"], "backbone": M40 | {"order": 5}, "verify": False},
    "m40x": {"masters": ["(4,0)"], "backbone": M40, "verify": False, "beyond": [0.7]},
    "single40": {"masters": ["(4,0)"], "backbone": {}, "verify": False},
    "single40o9": {"masters": ["(4,0)"], "backbone": {"order": 9}, "verify": False},
    # (2,1)'s manifold at order 9: do orders 7 and 9 agree beyond order 7's limit W_max/h 0.383?
    "m21o9": {"masters": ["(2,1)"], "backbone": M21 | {"order": 9}, "verify": False},
}


def scene_data(name: str) -> dict:
    import tomllib

    data = tomllib.loads((ROOT / "examples" / "shell_kappa25.toml").read_text())
    data["analysis"]["methods"] = ["dnf"]
    data["analysis"]["master_modes"] = RUNS[name]["masters"]
    data["analysis"]["backbone"] = {"order": ORDER, "w_over_h": GRID} | RUNS[name]["backbone"]
    data["output"] = {"dir": str(RAW / name), "hdf5": False, "plot": False}
    return data


def write_toml(data: dict, path: Path) -> None:
    """The scene as TOML (the few value types a scene has), for ``stepnf run`` / ``stepnf verify``."""
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)

    lines = []

    def table(prefix: str, d: dict) -> None:
        lines.append(f"[{prefix}]")
        lines.extend(f"{k} = {val(v)}" for k, v in d.items() if not isinstance(v, dict))
        for k, v in d.items():
            if isinstance(v, dict):
                table(f"{prefix}.{k}", v)

    for k, v in data.items():
        table(k, v)
    path.write_text("\n".join(lines) + "\n")


def w_over_h_at(block: dict, A: float | None) -> float | None:
    """W_max/h at amplitude A, interpolated on the run's w_over_h grid (None beyond it)."""
    import numpy as np

    pts = [(a, w) for a, w in zip(block["amplitude"], block.get("w_max_over_h") or []) if a is not None and w is not None]
    if A is None or not pts or A > pts[-1][0]:
        return None
    a, w = np.array(pts).T
    return float(np.interp(A, np.r_[0.0, a], np.r_[0.0, w]))


def branch_end(row: dict) -> float | None:
    """W_max/h where the continuing branch ends (its amplitude folds), read from the run's flag "never reaches
    W_max/h = .. (it spans a to b)": b; None when the branch reaches every W_max/h asked."""
    import re

    ends = [float(g.group(1)) for f in row.get("flags", []) if f and (g := re.search(r"it spans \S+ to (\S+)\)", f))]
    return max(ends) if ends else None


def mode_row(m: dict) -> dict:
    bb = m.get("backbone") or {}
    row = {"index": m.get("index"), "label": m["label"], "omega": m["omega"], "order": bb.get("order"),
           "w_over_h": GRID, "omega_ratio": bb.get("omega_ratio"), "amplitude": bb.get("amplitude"),
           "valid_up_to_A": bb.get("valid_up_to"), "valid_reason": bb.get("valid_reason"),
           "valid_up_to_w_over_h": w_over_h_at(bb, bb.get("valid_up_to")),
           "flags": [f.get("message") for f in bb.get("flags", [])]}
    row["branch_end_w_over_h"] = branch_end(row)
    if row["valid_up_to_w_over_h"] is None and row["valid_reason"] == "amplitude folds":
        row["valid_up_to_w_over_h"] = row["branch_end_w_over_h"]  # the limit is the fold, the branch's end
    if bb.get("manifold"):
        row["manifold"] = bb["manifold"]
        row["branch"] = {k: bb["branch"].get(k) for k in ("kind", "ratios", "valid_up_to", "valid_reason")}
        row["coupled_branches"] = [{k: b.get(k) for k in ("kind", "ratios", "valid_up_to", "valid_reason")}
                                   for b in bb.get("coupled_branches", [])]
    return row


def child(name: str, verify: bool = True) -> dict:
    """One run in this process: the scene, its measured rows, and with ``verify`` the full model's checks the run
    asks for (its ``"verify"`` orbits, its ``beyond`` trajectories)."""
    import resource

    import numpy as np

    import stepnf.verify.manifold_orbits as mo
    from stepnf.pipeline.model import open_model
    from stepnf.pipeline.run import run_on_adapter
    from stepnf.scene.parse import parse_scene
    from stepnf.verify.integrate import JACOBIANS  # noqa: F401  (as stepnf verify: the default Newton "auto")

    data = scene_data(name)
    RAW.mkdir(parents=True, exist_ok=True)
    write_toml(data, RAW / f"{name}.toml")
    scene = parse_scene(data, file=RAW / f"{name}.toml", base_dir=ROOT / "examples")
    say = lambda s: print(f"[{time.strftime('%H:%M:%S')}] {s}", file=sys.stderr, flush=True)  # noqa: E731
    adapter = open_model(scene)
    out: dict = {"name": name, "scene": str(RAW / f"{name}.toml"), "order": data["analysis"]["backbone"]["order"]}
    try:
        t0 = time.perf_counter()
        result, model = run_on_adapter(scene, adapter)
        out["run_seconds"] = round(time.perf_counter() - t0, 1)
        out["run_peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
        doc = result.to_dict()
        out["n_dofs"], out["counts"], out["timings"] = doc.get("model", {}).get("n_dofs"), result.counts, result.timings
        out["modes"] = [mode_row(m) for m in doc["modes"]]
        (RAW / f"{name}_run.json").write_text(json.dumps(doc, indent=1, default=str))
        say(f"{name}: run {out['run_seconds']} s, peak {out['run_peak_rss_mb']} MB")
        row = out["modes"][0]
        if not verify:
            return out
        if RUNS[name].get("beyond_single"):
            out["beyond"] = beyond_single(result, model, adapter, row, RUNS[name]["beyond_single"], say)
        if RUNS[name].get("beyond"):
            out["beyond"] = beyond(result, model, adapter, row, RUNS[name]["beyond"], say)
        if not RUNS[name]["verify"]:
            return out
        grid_a = [(a, w) for a, w in zip(row["amplitude"], GRID) if a is not None]
        top, fractions = RUNS[name].get("verify_top", VERIFY_TOP), RUNS[name].get("verify_fractions", VERIFY_FRACTIONS)
        a_top = float(np.interp(top, [w for _, w in grid_a], [a for a, _ in grid_a]))
        cap = min(a_top, row["valid_up_to_A"] or a_top)
        amps = [f * cap for f in fractions]
        out["verify_amplitudes"] = amps
        out["verify_w_over_h"] = [w_over_h_at(doc["modes"][0]["backbone"], a) for a in amps]
        out["verify_command"] = (f"stepnf verify --amplitudes {' '.join(f'{a:.6g}' for a in amps)} --json "
                                 f"{RAW / name}.toml")
        every = mo.branches_of
        # the continuing branch only (stepnf verify also checks the coupled ones: not in the time there was)
        mo.branches_of = lambda *a, **k: [b for b in every(*a, **k) if b.kind.startswith("continues mode")]
        vdoc = {"scene": str(RAW / f"{name}.toml"), "n_dofs": int(model.K.shape[0]), "method": "integration",
                "periods": 3.0, "modes": []}
        t1 = time.perf_counter()
        vdoc = mo.manifold_checks(vdoc, result, model, adapter, say, shooting=False, amplitudes=amps, scene=scene)
        out["verify_seconds"] = round(time.perf_counter() - t1, 1)
        (RAW / f"{name}_verify.json").write_text(json.dumps(vdoc, indent=1, default=str))
        out["verify"] = [{k: c.get(k) for k in ("amplitude", "orbit_amplitude", "omega_dpim_over_omega",
                                                  "omega_check_over_omega", "relative_difference",
                                                  "manifold_distance", "error_estimate", "seconds", "kind", "start")}
                         for m in vdoc["modes"] for c in m.get("checks", [])]
        out["verify_failed"] = [f for m in vdoc["modes"] for f in m.get("failed", [])]
        out["verify_not_verified"] = [m.get("not_verified") for m in vdoc["modes"] if m.get("not_verified")]
    finally:
        adapter.close()
        out["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    return out


def beyond(result, model, adapter, row: dict, targets: list, say) -> list:
    """The full model's trajectories from the continuing branch at W_max/h = ``targets`` (module docstring)."""
    import stepnf.verify.manifold_orbits as mo
    from stepnf.dpim.multimode.backbone import point_at
    from stepnf.plugin.dofs import translation_mask

    K, M = model.K, model.M
    mode = next(m for m in result.modes if int(m.index) == int(row["index"]))
    block = mode.backbone
    man = mo.manifold_of(result.arrays, int(block["manifold"].get("stored_with", mode.index)), M)
    branch = next(b for b in mo.branches_of(result.arrays, int(mode.index), block) if b.kind.startswith("continues"))
    chart = mo.ManifoldChart(man, K, M)
    mask = translation_mask(getattr(model, "dirs", None))
    tangent = adapter.tangent_stiffness if adapter.provides_tangent_stiffness else None

    def integrate(A: float) -> dict:
        return mo.integrate_orbit(man, chart, branch, A, mo.start_point(man, chart, branch, point_at(man, branch, A)),
                                  K, M, adapter.internal_forces, tangent=tangent, jacobian="auto", periods=3.0,
                                  rtol=1e-6, per_period=None, mask=mask)
    return trajectories(row, targets, say, integrate, "beyond validity", "manifold", KEYS + ("start",))


def beyond_single(result, model, adapter, row: dict, targets: list, say) -> list:
    """As :func:`beyond`, started from the single-mode parametrisation (``stepnf verify``'s by_integration)."""
    from stepnf.plugin.dofs import translation_mask
    from stepnf.verify.command import by_integration, check_dict

    res = result.backbones[int(row["index"])]
    mask = translation_mask(getattr(model, "dirs", None))
    tangent = adapter.tangent_stiffness if adapter.provides_tangent_stiffness else None

    def integrate(A: float) -> dict:
        return check_dict(by_integration(res, model.K, model.M, adapter.internal_forces, A, periods=3.0, rtol=1e-6,
                                         tangent=tangent, jacobian="auto", mask=mask), float(res.omega))
    return trajectories(row, targets, say, integrate, "beyond validity (single-mode start)", "single-mode", KEYS)


#: What a trajectory's record keeps of the check.
KEYS = ("amplitude", "orbit_amplitude", "omega_dpim_over_omega", "omega_check_over_omega", "relative_difference",
        "manifold_distance", "error_estimate", "seconds")


def trajectories(row: dict, targets: list, say, integrate, what: str, start: str, keys: tuple) -> list:
    """``integrate(A)`` at the amplitude of each ``W_max/h`` in ``targets`` (the row's curve interpolated): one
    record per target, the failure's message as its result."""
    import numpy as np

    out = []
    for w in targets:
        A = float(np.interp(w, GRID, [a if a is not None else np.nan for a in row["amplitude"]]))
        say(f"{what}: W_max/h = {w}, A = {A:.6g}")
        try:
            chk = integrate(A)
        except Exception as exc:  # noqa: BLE001 (a bench: the failure is the result)
            out.append({"w_over_h": w, "amplitude": A, "error": f"{type(exc).__name__}: {exc}"})
            continue
        out.append({"w_over_h": w, **{k: chk.get(k) for k in keys}})
        say(f"  w/w full {chk['omega_check_over_omega']:.6f}, {start} {chk['omega_dpim_over_omega']:.6f}, "
            f"distance {chk['manifold_distance']:.3g}")
    return out


#: The masters whose couplings ``--coupling`` measures: (2,1) and (0,2) (modes 11, 13), and every mode labelled (4,0)
#: (both twins: the O-grid may split them; a scene's "(4,0)" names the lower one).
COUPLING_MASTERS = ((2, 1), (0, 2), (4, 0))


def coupling() -> dict:
    """G(phi_p, phi_p) . phi_s of the masters :data:`COUPLING_MASTERS` against every mode with w_s / w_p in
    (1.5, 2.5), the modes oriented as a run's (:func:`stepnf.pipeline.modes.modes_stage`'s twins)."""
    import numpy as np

    import stepnf.pipeline.modes as pm
    from stepnf.linalg.modal_analysis import modal_analysis
    from stepnf.pipeline.model import model_stage, open_model
    from stepnf.pipeline.outputs import RunContext
    from stepnf.runtime.progress import Progress
    from stepnf.scene.parse import parse_scene

    data = scene_data("single")
    scene = parse_scene(data, file=ROOT / "examples" / "shell_kappa25.toml", base_dir=ROOT / "examples")
    adapter = open_model(scene)
    try:
        model = model_stage(RunContext.start(scene, Progress(enabled=False)), adapter)
        basis = modal_analysis(model.K, model.M, 36, rigid_tolerance=scene.rigid_tolerance,
                               rigid_modes=scene.rigid_modes, degeneracy_tolerance=scene.degeneracy_tolerance,
                               backend=model.backend, rigid_candidates=model.candidates)
        pm.orient_degenerate(basis, model.M, pm.translations_only(pm.probe_vector(model.X, model.dirs, model.n),
                                                                  model.dirs))
        labels = pm.ModeLabels(adapter).of(basis)
        phi, om, a, out = basis.phi, basis.omega, 1e-3, {}
        hits = {k: [s for s, lab in enumerate(labels) if lab is not None and tuple(lab) == k] for k in COUPLING_MASTERS}
        masters = [s for k, ss in hits.items() for s in (ss if k == (4, 0) else ss[:1])]
        for p in masters:
            F = adapter.internal_forces(np.stack([a * phi[:, p], -a * phi[:, p]]))
            g = phi.T @ ((F[0] + F[1]) / (2 * a * a))
            out[str(p)] = {"label": list(labels[p]), "partners": [
                {"mode": j, "label": list(labels[j]), "ratio": float(om[j] / om[p]), "G_pp_s": float(g[j]),
                 "denominator": float(1 - (2 * om[p] / om[j]) ** 2)}
                for j in range(len(om)) if 1.5 < om[j] / om[p] < 2.5]}
        return out
    finally:
        adapter.close()


def run(name: str, verify: bool = True) -> dict:
    RAW.mkdir(parents=True, exist_ok=True)
    with open(RAW / f"{name}.err", "w") as err:
        p = subprocess.run([sys.executable, __file__, "--child", name] + ([] if verify else ["--no-verify"]),
                           stdout=subprocess.PIPE, stderr=err,
                           text=True, env=dict(os.environ), cwd=ROOT)
    if p.returncode:
        raise SystemExit(f"{name} failed (stderr in {RAW / name}.err)")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", choices=list(RUNS), default=list(RUNS))
    ap.add_argument("--child", choices=list(RUNS))
    ap.add_argument("--coupling", action="store_true", help="measure the quadratic couplings (partners) first")
    ap.add_argument("--no-verify", action="store_true",
                    help="rerun the scenes only, no full-model checks: a run's stored verify and beyond records "
                         "are kept, marked as from its earlier build (for a change that moves no point where "
                         "they were checked)")
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child, verify=not args.no_verify), default=str))
        return
    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    doc.update({"scene": "examples/shell_kappa25.toml, methods = [dnf], order 7, w_over_h 0.05 .. 1.0",
                "verify": "continuing branch, time integration (3 periods, Richardson), amplitudes "
                          f"{VERIFY_FRACTIONS} x min(validity limit, A at W_max/h = {VERIFY_TOP})"})
    doc.setdefault("runs", {})
    if args.coupling:
        doc["coupling"] = coupling()
        OUT.write_text(json.dumps(doc, indent=1) + "\n")
        for p, c in doc["coupling"].items():
            print(p, c["label"], [(q["mode"], q["label"], round(q["ratio"], 4), f"{q['G_pp_s']:.2e}") for q in c["partners"]])
    for r in doc["runs"].values():  # runs written before branch_end existed
        for m in r["modes"]:
            if "branch_end_w_over_h" not in m:
                m["branch_end_w_over_h"] = branch_end(m)
                if m["valid_up_to_w_over_h"] is None and m["valid_reason"] == "amplitude folds":
                    m["valid_up_to_w_over_h"] = m["branch_end_w_over_h"]
    done: list[str] = []  # the runs of this invocation
    for name in args.only:
        load = [round(x, 2) for x in os.getloadavg()]
        r = run(name, verify=not args.no_verify)
        r["load_average_before"] = load
        if OUT.exists():  # runs another invocation wrote meanwhile are kept (this one's own override them)
            doc["runs"] = json.loads(OUT.read_text()).get("runs", {}) | {k: doc["runs"][k] for k in done}
        old = doc["runs"].get(name, {})
        done.append(name)
        kept = {k: v for k, v in old.items() if k.startswith("verify") or k == "beyond"} if args.no_verify else {}
        if kept:
            r.update(kept)
            r["checks_from_earlier_build"] = sorted(kept)
        doc["runs"][name] = r
        OUT.parent.mkdir(parents=True, exist_ok=True)
        OUT.write_text(json.dumps(doc, indent=1) + "\n")
        for m in r["modes"]:
            print(name, m["label"], m.get("manifold", {}).get("modes"), "valid to W/h", m["valid_up_to_w_over_h"])
            print("   ", {w: x for w, x in zip(GRID, m["omega_ratio"] or []) if w in (0.3, 0.5, 0.7, 1.0)})
        for c in r.get("beyond", []):
            print(f"    beyond W/h = {c['w_over_h']}: {c}")
        for c in r.get("verify", []):
            print(f"    verify A = {c['amplitude']:.4g}: w/w {c['omega_check_over_omega']:.6f}, "
                  f"error {c['relative_difference']:.2e}")
    print(f"wrote {OUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
