"""Cantilever strips against the inextensible-cantilever theory (issue 31, item 1), by both routes.

    .venv/bin/python bench/cantilever.py                      # both solvers, every strip, both amplitudes, + plate
    .venv/bin/python bench/cantilever.py --solver fenicsx     # the FEniCSx mesh route only
    .venv/bin/python bench/cantilever.py --refine             # also the refinement study along the length
    .venv/bin/python bench/cantilever.py --only tet10:300 --amplitude 20 --solver calculix

Strips [0, L] x [-1.5h, 1.5h] x [-h/2, h/2], clamped at x = 0, steel with nu = 0, L/h = 30, 100, 300, 1000
(tests/helpers/cantilever.py): "hex20" = C3D20, nx x 1 x 1; "tet10" = C3D10, nx x 3 x 2 boxes of 6
tetrahedra (two layers through the thickness); nx = 40/40/80/100 (``STRIP_NX``). "plate" = the issue's
300 x 30 x 1 plate deck (C3D20 15 x 1 x 1, nu = 0.3, mm-tonne). Each deck is first run by ccx's own
*FREQUENCY (reference frequencies, and the masters: the first two modes with >= 90% of their squared
displacement in uz, bending in the thickness direction: 0 and 2 for the strips, mode 1 bends in the width),
then by ``stepnf run --json`` (methods = ["dnf"], a subprocess):

- ``calculix``: the deck as brought (``deck =``, its *BOUNDARY and *MATERIAL);
- ``fenicsx``: the same file as a mesh (``mesh =``, ``[model.material]`` E, nu, rho,
  ``[[model.boundary]] set = "CLAMP"``; C3D20 is read as a 27-node Q2 brick, C3D10 as a P2 tetrahedron);

each at the default STEP amplitude (the new code raises it itself when the scene leaves it out) and at
``[analysis.step] relative_amplitude = 20`` (the issue's setting). A run refused for a rigid-body mode is
run again with ``rigid_modes = 0`` (marked * after the amplitude). The JSON's ``transverse_share`` of each
master confirms it bends in z (``share`` column).

Theory: w_r = (beta_r L)^2 sqrt(EI/(rho A L^4)) (E, not E/(1-nu^2), for the plate too) and Gamma_r =
c_r (h/L)^2, c_1 = +0.019384, c_2 = -6.4544 (column ``err``); ``err.ext`` against the same with the first
correction of the finite axial stiffness (mode 2: 8.8% at L/h = 30, 0.74% at 100), the better reference
of a 3D solid at finite L/h. A case is WRONG BUT SHOWN when T is not n/a and |err.ext| > 3 T_error +
allowance (3%, the issue's target; the plate: 15%, the issue's "done means" for it): the number printed
is off by more than stepnf says it may be. ``mech`` lists the mechanisms of docs/design.md, "Round-off of
T" that ran: R = ``step_amplitude_raised`` (by the factor), M = ``manifold_probe`` (M* its T kept),
t = ``t_roundoff`` flag.

Measured (working tree of 2026-12-06, bench/results/cantilever*.json): fenicsx, both meshes, L/h = 100-1000,
both modes within 2.4% (refined along the length, nx = 160/200, within 1.3%); L/h = 30 mode 1 -7.6..-8.2%
at every mesh (a model limit of the Euler-Bernoulli reference: it falls as (h/L)^2, -0.55% at L/h = 100
converged). The reference at L/h = 30 is the model's own periodic orbits (``stepnf verify``, rtol 1e-8,
W_max/h = 1 and 2, tests/pipeline/test_slender_reference.py): their slope (w_NL/w - 1)/a^2 is 1.10632
(hex20 nx = 40; T = 1.10622) and 1.10251 (tet10 nx = 40; T = 1.10236), 1e-4 from T: stepnf's T is the
model's, and mode 1's c1 = 0.019, a 15-fold cancellation of curvature stiffening against axial inertia,
shows the solid's O((h/L)^2) departures from thin-beam theory (shear, rotary inertia, the section) ~15
times enlarged; tet10 at L/h = 1000 refused on both routes (lowest/largest eigenvalue 4e-15); calculix mode 1
n/a from L/h = 300, both modes at 1000. The plate deck as brought (15 elements, nu = 0.3, b = 30h) is far
from the beam theory for the model's own reasons (``--refine``: nx = 60 and nu = 0 bring it to 3%).

Writes ``bench/results/cantilever.json`` (and ``cantilever_refine.json`` with --refine; ``--out NAME``
changes the name). ``--code DIR`` runs another source tree (``git archive HEAD | tar -x -C DIR``: the
baseline of the committed code while the working tree is being edited).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from helpers import cantilever as cv  # noqa: E402  (the theory and the decks: no stepnf import)

STEPNF = ROOT / ".venv" / "bin" / "stepnf"
CODE: Path | None = None  # --code DIR: run the stepnf (and its adapters) of that source tree instead
AMPLITUDES = (None, 20.0)  # None: the default STEP amplitude (stepnf raises it where rounding needs it)
SOLVERS = ("calculix", "fenicsx")
MESHES = ("hex20", "tet10")
#: model allowance of "wrong but shown": |err.ext| > 3 T_error + ALLOWANCE (the plate: the issue's 15%)
ALLOWANCE = {"hex20": 0.03, "tet10": 0.03, "plate": 0.15, "plate_nu0": 0.15}
MECHANISMS = ("step_amplitude_raised", "manifold_probe", "t_roundoff")
#: (mesh, L/h, (ny, nz) through width and thickness or None for the default): elements along the length
REFINE = {("hex20", 30, None): (20, 40, 80), ("hex20", 30, (3, 2)): (40,), ("tet10", 30, None): (20, 40, 80),
          ("tet10", 30, (6, 4)): (40,), ("hex20", 100, None): (20, 40, 80), ("tet10", 100, None): (20, 40, 80),
          ("hex20", 300, None): (40, 80, 160), ("tet10", 300, None): (80, 160),
          ("hex20", 1000, None): (50, 100, 200), ("tet10", 1000, None): (100, 200),
          ("plate", 300, None): (15, 60), ("plate", 300, (4, 1)): (60,),
          ("plate_nu0", 300, None): (15, 60), ("plate_nu0", 300, (4, 1)): (60,)}
TIMEOUT = 900.0
PLATE = {"L": 300.0, "b": 30.0, "h": 1.0, "material": (209000.0, 0.3, 7.85e-9), "nx": 15}


def write_deck(folder: Path, mesh: str, slenderness: float, nx: int, cross, frequency=None, name="deck.inp") -> Path:
    """The deck of one structure: a strip, or the plate (``mesh`` "plate": the issue's deck as brought when
    ``nx`` = 15 and no ``cross``, else nx x ny x 1 bricks; "plate_nu0": the same with nu = 0)."""
    if mesh.startswith("plate"):
        path = folder / name
        if mesh == "plate" and nx == PLATE["nx"] and not cross:
            path.write_text(cv.plate_deck_text(frequency=frequency))
        else:
            E, nu, rho = geometry(mesh, slenderness)["material"]
            pts, cells = cv.block_hex20(nx, (cross or (1, 1))[0], 1, (PLATE["L"], PLATE["b"], PLATE["h"]))
            path.write_text(cv.deck_text(pts, cells, "C3D20", E=E, nu=nu, rho=rho, frequency=frequency))
        return path
    return cv.write_strip_deck(folder, slenderness, mesh, nx, cross=cross, frequency=frequency, name=name)


def geometry(mesh: str, slenderness: float) -> dict:
    """L, b, h, (E, nu, rho) of the structure."""
    if mesh == "plate":
        return PLATE
    if mesh == "plate_nu0":
        return dict(PLATE, material=(PLATE["material"][0], 0.0, PLATE["material"][2]))
    L, b, h = cv.strip_size(slenderness)
    return {"L": L, "b": b, "h": h, "material": (cv.E, cv.NU, cv.RHO)}


def ccx_reference(folder: Path, mesh: str, slenderness: float, nx: int, cross=None) -> dict:
    """ccx's own *FREQUENCY on the deck: frequencies (rad/s), the bending masters and ccx's wall time."""
    t0 = time.perf_counter()
    deck = write_deck(folder, mesh, slenderness, nx, cross, frequency=10, name="freq.inp")
    subprocess.run(["ccx", "-i", "freq"], cwd=folder, capture_output=True, check=True, timeout=TIMEOUT)
    omega, shapes = cv.ccx_modes(deck.with_suffix(".dat"))
    return {"omega": omega.tolist(), "masters": cv.bending_modes(shapes),
            "seconds": round(time.perf_counter() - t0, 2)}


def run_stepnf(scene: Path) -> tuple[dict | None, str, float, int]:
    t0 = time.perf_counter()
    cmd, env = [str(STEPNF)], None
    if CODE is not None:  # e.g. a `git archive HEAD` of the checkout: a baseline while the tree is edited
        cmd = [sys.executable, "-m", "stepnf"]
        paths = [CODE] + sorted(p for p in (CODE / "solvers").iterdir() if p.is_dir())
        env = dict(os.environ, PYTHONPATH=":".join(map(str, paths)))
    try:
        p = subprocess.run(cmd + ["run", "--json", scene.name], cwd=scene.parent, capture_output=True,
                           text=True, timeout=TIMEOUT, env=env)
    except subprocess.TimeoutExpired:
        return None, f"timeout after {TIMEOUT:g} s", time.perf_counter() - t0, -1
    secs = time.perf_counter() - t0
    try:
        doc = json.loads(p.stdout)
    except json.JSONDecodeError:
        doc = None
    err = [ln for ln in p.stderr.splitlines() if ln.strip() and not ln.startswith("[stepnf]")]
    return doc, " | ".join(err[-2:]), secs, p.returncode


def write_scene(solver: str, deck: Path, masters, mesh: str, slenderness: float, amplitude, analysis="") -> Path:
    g = geometry(mesh, slenderness)
    if solver == "calculix":
        return cv.write_strip_scene(deck, masters, h=g["h"], relative_amplitude=amplitude, analysis=analysis)
    return cv.write_mesh_scene(deck, masters, solver=solver, material=g["material"], h=g["h"],
                               relative_amplitude=amplitude, analysis=analysis)


def mechanisms(d: dict) -> dict:
    """Which of the slender-structure mechanisms ran for one DNF result (its flags and extra keys)."""
    kinds = {f["kind"]: f.get("value") for f in d.get("flags", [])}
    return {"step_amplitude_raised": kinds.get("step_amplitude_raised"),
            "manifold_probe": kinds.get("manifold_probe"),
            "manifold_kept": d.get("probe_amplitude") is not None,
            "t_roundoff": kinds.get("t_roundoff")}


def verdict(row: dict) -> None:
    """within_3pct, wrong_but_shown (see the module docstring) of a row that ran."""
    err, te = row["gamma_rel_error_ext"], row["T_error"]
    te = float("inf") if te is None else te
    row["within_3pct"] = bool(row["na"] is None and abs(err) <= 0.03)
    row["wrong_but_shown"] = bool(row["na"] is None and abs(err) > 3 * te + ALLOWANCE[row["mesh"]])


def stepnf_rows(solver: str, folder: Path, deck: Path, ref: dict, mesh: str, slenderness: float, nx: int,
                amplitude, cross) -> list[dict]:
    """One structure by one solver at one STEP amplitude: a row per master (bending mode 1 and 2)."""
    g = geometry(mesh, slenderness)
    scene = write_scene(solver, deck, ref["masters"], mesh, slenderness, amplitude)
    doc, err, secs, code = run_stepnf(scene)
    refused = None
    if doc is None and "rigid_modes" in err:  # the fundamental taken for a rigid-body mode (issue 31, 2):
        refused = err  # run again as the issue's work-around, to see the T it would print
        scene = write_scene(solver, deck, ref["masters"], mesh, slenderness, amplitude, "rigid_modes = 0\n")
        doc, err, secs, code = run_stepnf(scene)
    E, _nu, rho = g["material"]
    L, b, h = g["L"], g["b"], g["h"]
    rows = []
    for r, master in enumerate(ref["masters"], start=1):
        row = {"solver": solver, "mesh": mesh, "L/h": slenderness, "nx": nx, "cross": cross, "mode": r,
               "master": master, "relative_amplitude": amplitude, "seconds": round(secs, 2), "exit": code,
               "refused": refused, "w_ccx": ref["omega"][master],
               "w_theory": float(cv.linear_frequency(r, E, b * h**3 / 12, rho, b * h, L)),
               "gamma_theory": float(cv.gamma_theory(r, slenderness)),
               "gamma_theory_ext": float(cv.gamma_theory(r, slenderness, extensible=True)),
               "T_theory": float(cv.t_theory(r, rho, b * h, L))}
        m = None if doc is None else next((x for x in doc["modes"] if x["index"] == master), None)
        if m is None or "dnf" not in m.get("methods", {}):
            row["error"] = err or f"no DNF result for mode {master}"
            rows.append(row)
            continue
        d = m["methods"]["dnf"]
        row.update({"dofs": doc["model"]["n_dofs"], "cell_type": doc["model"].get("cell_type"),
                    "w_stepnf": m["omega"], "transverse_share": m.get("transverse_share"),
                    "T": d["T"], "gamma": d["gamma"], "T_error": d.get("T_error"),
                    "roundoff": d.get("roundoff"), "cancellation": d.get("cancellation"),
                    "na": (d.get("na") or {}).get("kind"),
                    "flags": sorted({f["kind"] for f in d["flags"] + m["flags"]}),
                    "mechanisms": mechanisms(d), "step_amplitude": m["step"]["amplitude"],
                    "step_amplitude_used": d.get("step_amplitude")})
        row["w_rel_theory"] = m["omega"] / row["w_theory"] - 1
        row["w_rel_ccx"] = m["omega"] / row["w_ccx"] - 1
        if d["gamma"] is None:
            row["gamma_rel_error"] = row["gamma_rel_error_ext"] = None
            row["within_3pct"] = row["wrong_but_shown"] = False
        else:
            row["gamma_rel_error"] = (d["gamma"] - row["gamma_theory"]) / abs(row["gamma_theory"])
            row["gamma_rel_error_ext"] = (d["gamma"] - row["gamma_theory_ext"]) / abs(row["gamma_theory_ext"])
            verdict(row)
        rows.append(row)
    return rows


def structure_rows(mesh: str, slenderness: float, nx: int, solvers, amplitudes, cross=None, echo=print) -> list[dict]:
    """Every (solver, amplitude) of one structure, on one deck and one ccx reference."""
    with tempfile.TemporaryDirectory(prefix="stepnf_cant_") as tmp:
        folder = Path(tmp)
        ref = ccx_reference(folder, mesh, slenderness, nx, cross)
        deck = write_deck(folder, mesh, slenderness, nx, cross, name="strip.inp")
        rows = []
        for solver in solvers:
            for amp in amplitudes:
                for row in stepnf_rows(solver, folder, deck, ref, mesh, slenderness, nx, amp, cross):
                    row["ccx_frequency_seconds"] = ref["seconds"]
                    rows.append(row)
                    echo(fmt(row))
    return rows


def _pct(x) -> str:
    return f"{'n/a' if x is None else format(x, '+.2%')}"


def fmt(row: dict) -> str:
    amp = "def" if row["relative_amplitude"] is None else f"{row['relative_amplitude']:g}"
    amp += "*" if row.get("refused") else ""  # refused as rigid: run again with rigid_modes = 0
    mesh = row["mesh"] + ("" if not row.get("cross") else "({},{})".format(*row["cross"]))
    head = f"{row['solver']:>8} {mesh:>11} {row['L/h']:>5} {row['nx']:>3}"
    if "w_stepnf" not in row:
        return (f"{head} {'-':>6} {row['mode']:>2} {amp:>4}  stepnf failed (exit {row['exit']}): "
                f"{row.get('error', '')[:100]}")
    mech = row["mechanisms"]
    tags = []
    if mech["step_amplitude_raised"] is not None:
        tags.append(f"R{mech['step_amplitude_raised']:.3g}")
    if mech["manifold_probe"] is not None:
        tags.append("M*" if mech["manifold_kept"] else "M")
    if mech["t_roundoff"] is not None:
        tags.append("t")
    wccx = _pct(row["w_rel_ccx"]) if row["solver"] == "calculix" else "-"
    share = "-" if row["transverse_share"] is None else f"{row['transverse_share']:.4f}"
    gamma = "n/a" if row["gamma"] is None else f"{row['gamma']:+.4e}"
    bad = " WRONG" if row.get("wrong_but_shown") else ""
    return (f"{head} {row['dofs']:>6} {row['mode']:>2} {amp:>4} {row['w_stepnf']:>10.5g} "
            f"{_pct(row['w_rel_theory']):>8} {wccx:>8} {share:>6} {gamma:>11} {row['gamma_theory']:>+11.4e} "
            f"{_pct(row['gamma_rel_error']):>9} {row['gamma_theory_ext']:>+11.4e} {_pct(row['gamma_rel_error_ext']):>9} "
            f"{(row['T_error'] if row['T_error'] is not None else float('nan')):>8.1e} {row['na'] or '-':>12} "
            f"{' '.join(tags) or '-':>12} {row['seconds']:>6.1f}{bad}")


HEADER = (f"{'solver':>8} {'mesh':>11} {'L/h':>5} {'nx':>3} {'dofs':>6} {'r':>2} {'amp':>4} {'w_stepnf':>10} "
          f"{'dw.th':>8} {'dw.ccx':>8} {'share':>6} {'Gamma_DNF':>11} {'Gamma_th':>11} {'err':>9} "
          f"{'Gamma_ext':>11} {'err.ext':>9} {'T_error':>8} {'n/a':>12} {'mech':>12} {'s':>6}")


def summarise(rows: list[dict]) -> list[dict]:
    """Per (solver, mesh, amplitude): cases, within 3% of the extensible theory, n/a, failed, wrong but shown."""
    out = []
    keys = sorted({(r["solver"], r["mesh"], r["relative_amplitude"] is None, r["relative_amplitude"] or 0.0)
                   for r in rows}, key=lambda k: (k[0], k[1], not k[2], k[3]))
    for solver, mesh, _dflt, _a in keys:
        amp = None if _dflt else _a
        sel = [r for r in rows if (r["solver"], r["mesh"], r["relative_amplitude"]) == (solver, mesh, amp)]
        ran = [r for r in sel if "w_stepnf" in r]
        wrong = [r for r in ran if r.get("wrong_but_shown")]
        out.append({"solver": solver, "mesh": mesh, "relative_amplitude": amp, "cases": len(sel),
                    "within_3pct": sum(bool(r.get("within_3pct")) for r in ran),
                    "na": sum(r["na"] is not None for r in ran), "failed": len(sel) - len(ran),
                    "wrong_but_shown": [{k: r.get(k) for k in ("L/h", "nx", "mode", "gamma", "gamma_theory_ext",
                                                              "gamma_rel_error_ext", "T_error", "flags")}
                                        for r in wrong]})
    return out


def cross_route(rows: list[dict]) -> list[dict]:
    """Each calculix row against the fenicsx row of the same deck, mode and amplitude (both shown): on tet10 both
    routes have the same element (C3D10 = P2 tetrahedron) and the same discrete model, so their Gammas differ
    only by the numerics, which T_error must cover (``covered``); on hex20 fenicsx runs 27-node Q2 bricks, not
    C3D20 (a discretisation difference as well: shown, not judged)."""
    key = ("mesh", "L/h", "nx", "cross", "mode", "relative_amplitude")
    fx = {tuple(str(r[k]) for k in key): r for r in rows if r["solver"] == "fenicsx" and r.get("gamma") is not None}
    out = []
    for r in rows:
        f = fx.get(tuple(str(r[k]) for k in key))
        if r["solver"] != "calculix" or f is None or r.get("gamma") is None:
            continue
        diff = r["gamma"] / f["gamma"] - 1
        r["gamma_vs_fenicsx"] = diff
        te = r["T_error"] if r["T_error"] is not None else float("inf")
        out.append({"mesh": r["mesh"], "L/h": r["L/h"], "nx": r["nx"], "cross": r["cross"], "mode": r["mode"],
                    "relative_amplitude": r["relative_amplitude"], "gamma_calculix": r["gamma"],
                    "gamma_fenicsx": f["gamma"], "diff": diff, "T_error_calculix": r["T_error"],
                    "T_error_fenicsx": f["T_error"], "na_calculix": r["na"],
                    "covered": None if r["mesh"] != "tet10" or r["na"] else
                    bool(abs(diff) <= 3 * te + 3 * (f["T_error"] or 0))})
    return out


def fmt_cross(c: dict) -> str:
    amp = "def" if c["relative_amplitude"] is None else f"{c['relative_amplitude']:g}"
    verdict = {None: "(different elements)", True: "covered by 3 T_error", False: "NOT COVERED by 3 T_error"}
    if c["na_calculix"] and not c["mesh"].startswith("plate"):  # n/a: does the bound cover the error it stands
        # for (the figure the note prints)? on a coarse plate the elements' difference dominates: not judged
        te = c["T_error_calculix"]
        verdict[None] = f"error/bound = {abs(c['diff']) / te:.3g}" if te else "n/a"
    return (f"{c['mesh']:>6} {c['L/h']:>5} {c['nx']:>3} r={c['mode']} {amp:>4}: calculix {c['gamma_calculix']:+.4e} "
            f"fenicsx {c['gamma_fenicsx']:+.4e} diff {c['diff']:+.2%}, T_error {c['T_error_calculix']:.1e} "
            f"{'(n/a)' if c['na_calculix'] else '(shown)'} {verdict[c['covered']]}")


def fmt_summary(s: dict) -> str:
    amp = "default" if s["relative_amplitude"] is None else f"relative_amplitude = {s['relative_amplitude']:g}"
    line = (f"{s['solver']:>8} {s['mesh']:>6} ({amp}): {s['within_3pct']}/{s['cases']} within 3% of the extensible "
            f"theory, {s['na']} n/a, {s['failed']} failed, WRONG BUT SHOWN: {len(s['wrong_but_shown'])}")
    for w in s["wrong_but_shown"]:
        line += (f"\n      L/h = {w['L/h']} nx = {w['nx']} mode {w['mode']}: Gamma {w['gamma']:+.4e} against "
                 f"{w['gamma_theory_ext']:+.4e} ({w['gamma_rel_error_ext']:+.2%}), T_error {w['T_error']:.1e}, "
                 f"flags {','.join(w['flags']) or '-'}")
    return line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solver", choices=("calculix", "fenicsx", "both"), default="both")
    ap.add_argument("--refine", action="store_true", help="also the refinement study (cantilever_refine.json)")
    ap.add_argument("--refine-only", action="store_true", help="only the refinement study")
    ap.add_argument("--only", help="cases MESH:L/h, comma-separated (e.g. hex20:300,plate:300; plate_nu0:300)")
    ap.add_argument("--nx", type=int, help="elements along the length (default: STRIP_NX of L/h)")
    ap.add_argument("--amplitude", type=float, help="only this relative_amplitude (default: the default and 20)")
    ap.add_argument("--no-plate", action="store_true")
    ap.add_argument("--code", type=Path, help="a stepnf source tree to run (default: the installed one)")
    ap.add_argument("--out", default="cantilever", help="results name under bench/results (no suffix)")
    args = ap.parse_args()
    global CODE
    CODE = args.code.resolve() if args.code else None
    solvers = SOLVERS if args.solver == "both" else (args.solver,)
    amps = AMPLITUDES if args.amplitude is None else (args.amplitude,)
    cases = [(m, s) for m in MESHES for s in cv.SLENDERNESS]
    if not args.no_plate:
        cases.append(("plate", 300))
    only = None if not args.only else {(m, int(s)) for m, s in (c.split(":") for c in args.only.split(","))}
    if only:
        cases = sorted(only)
    rows = []
    if not args.refine_only:
        print(HEADER, flush=True)
        for mesh, s in cases:
            nx = PLATE["nx"] if mesh.startswith("plate") else (args.nx or cv.strip_nx(s))
            rows += structure_rows(mesh, s, nx, solvers, amps, echo=lambda t: print(t, flush=True))
        cross = cross_route(rows)
        if cross:
            print("\nthe same deck by both routes (Gamma of calculix against fenicsx)")
            for c in cross:
                print(fmt_cross(c))
        summary = summarise(rows)
        print("\nsummary (WRONG BUT SHOWN: not n/a and |err.ext| > 3 T_error + 3%, the plate 15%)")
        for s in summary:
            print(fmt_summary(s), flush=True)
        doc = {"theory": {"c": [cv.backbone_coefficient(r) for r in (1, 2)],
                          "gamma": {s: [cv.gamma_theory(r, s) for r in (1, 2)] for s in cv.SLENDERNESS},
                          "gamma_extensible": {s: [cv.gamma_theory(r, s, extensible=True) for r in (1, 2)]
                                               for s in cv.SLENDERNESS}},
               "summary": summary, "cross_route": cross, "rows": rows, "code": str(CODE) if CODE else "installed"}
        (ROOT / "bench" / "results" / f"{args.out}.json").write_text(json.dumps(doc, indent=1) + "\n")
    if args.refine or args.refine_only:
        ref_rows = []
        print("\nrefinement study (elements along the length; default STEP amplitude)\n" + HEADER, flush=True)
        for (mesh, s, cross), nxs in REFINE.items():
            if only and (mesh, s) not in only:
                continue
            for nx in nxs:
                ref_rows += structure_rows(mesh, s, nx, solvers, (None,), cross, echo=lambda t: print(t, flush=True))
        (ROOT / "bench" / "results" / f"{args.out}_refine.json").write_text(json.dumps(ref_rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
