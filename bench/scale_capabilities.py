"""Benchmark: the cost of the newer capabilities from ~10k dofs to the largest that fits (issue 35, item 4).

A sibling of ``bench/scale.py`` (its sizes, worker, launcher, memory guard and fits are imported): each
size and variant runs in a fresh subprocess, one BLAS/OpenMP thread, with a timeout and a memory guard.
The variants are scene changes on top of scale.py's ``dnf`` run (``examples/shell_kappa25.toml``, hex27,
FEniCSx, six masters, ``methods = ["dnf"]``):

* ``dnf``: that run itself (the reference of the ratios, at the same n_core x n_ring);
* ``order7``: ``[analysis.backbone] order = 7`` (DPIM backbones of the six masters, as
  ``bench/backbone_order7.py``);
* ``frc``: order7 plus ``[analysis.damping] modal = 0.01`` and ``[analysis.forcing] modal = LEVELS,
  frequency_range = [0.9, 1.25]`` (the levels of ``bench/frc_cost.py``);
* ``manifold``: ``[analysis.backbone] order = 5, manifolds = [["(2,1)", "(4,1)"]]`` (the keys of
  ``bench/manifold_order7.py``; a mesh where (4,1) is not found is a failed row that says why);
* ``dkt``: the shell adapter, ``examples/table2_dkt_base.toml`` (Kratos, DKT triangles on the generated
  cap's mid-surface, same a, R, h), DNF; its mid-surface O-grid is sized to the dofs of the size name
  (``n_ring ~ 0.35 n_core``, 6 dofs per node), so its ratio is against the 3D model's ``dnf`` row of
  about the same dofs, not the same grid.

Per row: dofs, per-stage seconds (``RunResult.timings``: model, matrices, eigen, step, evaluators,
backbone, forced), total, peak RSS, counts, the load average before and after, and the ratios of total
time and peak RSS to the ``dnf`` row of the same size (run here, else ``bench/results/scale.json``).
Sizes run in ascending order, every variant at a size before the next size; a variant stops when its
next size is estimated above ``--memory-limit-gb`` (scale.py's :func:`estimate_mb`), its last run took
more than ``--stop-after`` seconds or failed, or at ``--until`` (UTC, HH:MM: no run starts after it).

    .venv/bin/python bench/scale_capabilities.py                       # 10k, 40k, 100k, 250k, 500k, 1M
    .venv/bin/python bench/scale_capabilities.py --variants dkt --sizes 10k,40k
    .venv/bin/python bench/scale_capabilities.py --table               # the stored table only

Writes ``bench/results/scale_capabilities.json`` after every run (an interrupted run keeps what it
measured; a rerun skips the stored size/variant pairs except the skipped ones). Not a test.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import scale  # noqa: E402  (bench/scale.py, a sibling script)

ROOT = scale.ROOT
OUT = ROOT / "bench" / "results" / "scale_capabilities.json"
DKT_SCENE = ROOT / "examples" / "table2_dkt_base.toml"
#: modal force levels of bench/frc_cost.py (model units)
LEVELS = [0.5, 2.0, 8.0]
#: scene changes on top of scale.py's "dnf" run: [analysis] sub-tables
CHANGES: dict[str, dict[str, Any]] = {
    "dnf": {},
    "order7": {"backbone": {"order": 7}},
    "frc": {"backbone": {"order": 7}, "damping": {"modal": 0.01},
            "forcing": {"modal": LEVELS, "frequency_range": [0.9, 1.25]}},
    "manifold": {"backbone": {"order": 5, "manifolds": [["(2,1)", "(4,1)"]]}},
    "dkt": {},
}
VARIANTS = list(CHANGES)
STAGES = ("model", "matrices", "eigen", "step", "evaluators", "backbone", "forced")
DKT_RING = 0.35  # n_ring / n_core of the DKT grids (bench/shell_dkt.py's 20x7, 28x10, 40x14)


def dkt_grid(dofs: float) -> tuple[int, int]:
    """(n_core, n_ring) of the DKT mid-surface O-grid closest to ``dofs`` (6 per node of the quad9 plan grid)."""
    return min(((nc, max(1, round(DKT_RING * nc))) for nc in range(2, 600)),
               key=lambda p: abs(dkt_dofs(*p) - dofs))


def dkt_dofs(n_core: int, n_ring: int) -> int:
    """Dofs of the DKT cap: 6 per node, the quad9 O-grid's (2 n_core + 1)^2 + 16 n_core n_ring nodes."""
    return 6 * ((2 * n_core + 1) ** 2 + 16 * n_core * n_ring)


def grid_of(size: str, variant: str) -> tuple[int, int]:
    """The O-grid of a size name for this variant (the solid's from scale.py, or the DKT one of its dofs)."""
    solid = scale.resolve_size(size)
    return dkt_grid(scale.cap_dofs(*solid)) if variant == "dkt" else solid


def build(n_core: int, n_ring: int, variant: str) -> tuple[dict, Path]:
    """The scene's TOML data and file of ``variant`` on this grid (for :func:`scale.run_worker`)."""
    import tomllib

    src = DKT_SCENE if variant == "dkt" else scale.SCENE
    data = tomllib.loads(src.read_text())
    data["model"]["geometry"].update({"n_core": n_core, "n_ring": n_ring})
    data["analysis"]["methods"] = ["dnf"]
    data["analysis"].update(json.loads(json.dumps(CHANGES[variant])))
    data["output"] = {"hdf5": False}
    return data, src


def extra(res: Any) -> dict:
    """What the capability produced: per master the backbone's reach, the manifold's modes, the FRC curves."""
    out = {}
    for m in res.to_dict().get("modes", []):
        bb, frc = m.get("backbone") or {}, m.get("frc")
        out[str(m.get("label"))] = {k: v for k, v in {
            "backbone_points": len(bb.get("amplitude") or []) if bb else None,
            "valid_up_to": bb.get("valid_up_to"),
            "manifold": (bb.get("manifold") or {}).get("modes"),
            "frc_levels": len(frc) if isinstance(frc, list) else None,
            "frc_reason": m.get("frc_reason")}.items() if v is not None}
    return out


# ------------------------------------------------------------------------------------------ table
def dnf_reference(rows: list[dict]) -> dict[str, dict]:
    """Per size name: the ``dnf`` row run here, else scale.json's serial one (same grid)."""
    ref: dict[str, dict] = {}
    stored = scale.ROOT / "bench" / "results" / "scale.json"
    if stored.exists():
        for r in json.loads(stored.read_text())["rows"]:
            if r["variant"] == "dnf" and r["ranks"] == 1 and r["status"] == "ok":
                ref[r["size"]] = {**r, "source": "scale.json"}
    for r in rows:
        if r["variant"] == "dnf" and r["status"] == "ok":
            ref[r["size"]] = {**r, "source": "here"}
    return ref


def add_ratios(rows: list[dict]) -> None:
    """``ratio_time`` and ``ratio_memory`` of every finished row to its size's ``dnf`` row."""
    ref = dnf_reference(rows)
    for r in rows:
        d = ref.get(r["size"])
        if r["status"] == "ok" and d is not None and r["variant"] != "dnf":
            r["ratio_time"] = r["total"] / d["total"]
            r["ratio_memory"] = max(r["peak_rss_mb_per_rank"]) / max(d["peak_rss_mb_per_rank"])
            r["ratio_to"] = f"dnf {d['size']} ({d['n_dofs']} dofs, {d['source']})"


def print_table(rows: list[dict], fitted: dict[str, dict]) -> None:
    head = ("variant", "size", "dofs", *STAGES, "total", "peak MB", "fact", "f.evals", "x dnf t", "x dnf m", "load")
    print("seconds per stage and total, peak RSS (MB); x dnf: ratio to the dnf row of the size; load: 1-min "
          "load average before/after")
    print(" ".join(f"{h:>9}" for h in head))
    for r in sorted(rows, key=lambda r: (VARIANTS.index(r["variant"]), r["n_dofs"])):
        if r["status"] != "ok":
            print(f"{r['variant']:>9} {r['size']:>9} {r['n_dofs']:>9} {r['status']}")
            continue
        t, c = r["timings"], r["counts"]
        load = r.get("load_before", [0])[0], r.get("load_after", [0])[0]
        vals = (r["variant"], r["size"], r["n_dofs"], *(f"{t[k]:.1f}" if k in t else "-" for k in STAGES),
                f"{r['total']:.1f}", f"{max(r['peak_rss_mb_per_rank']):.0f}", c.get("factorizations"),
                c.get("force_evaluations"), f"{r['ratio_time']:.2f}" if "ratio_time" in r else "-",
                f"{r['ratio_memory']:.2f}" if "ratio_memory" in r else "-", f"{load[0]:.1f}/{load[1]:.1f}")
        print(" ".join(f"{v!s:>9}" for v in vals))
    for key, f in fitted.items():
        print(f"fit {key}: time ~ n^{f['time_exponent']:.2f}, memory ~ n^{f['memory_exponent']:.2f}")


# ------------------------------------------------------------------------------------------- main
def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10k,40k,100k,250k,500k,1M", help="comma-separated, as bench/scale.py")
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"comma-separated, from {VARIANTS}")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per run (default 900)")
    ap.add_argument("--stop-after", type=float, default=600.0,
                    help="a variant stops after a run longer than this (seconds, default 600)")
    ap.add_argument("--memory-limit-gb", type=float, default=20.0, help="skip runs estimated above (GiB)")
    ap.add_argument("--until", default=None, metavar="HH:MM", help="start no run after this UTC time")
    ap.add_argument("--table", action="store_true", help="print the stored table, run nothing")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker or args.table:
        return args
    try:
        args.grid = {name: scale.resolve_size(name) for name in args.sizes.split(",")}
    except ValueError as exc:
        ap.error(str(exc))
    args.variant_list = args.variants.split(",")
    bad = [v for v in args.variant_list if v not in CHANGES]
    if bad:
        ap.error(f"unknown variant(s) {bad}: pick from {VARIANTS}")
    if args.until is not None:
        try:
            hh, mm = (int(x) for x in args.until.split(":"))
            now = dt.datetime.now(dt.timezone.utc)
            args.until_ts = now.replace(hour=hh, minute=mm, second=0, microsecond=0).timestamp()
        except ValueError:
            ap.error(f"--until {args.until!r}: use HH:MM (UTC, 24 h)")
    else:
        args.until_ts = float("inf")
    return args


def load_doc(path: Path) -> dict:
    return json.loads(path.read_text()) if path.exists() else {"meta": {}, "rows": []}


def save(doc: dict, path: Path) -> None:
    add_ratios(doc["rows"])
    doc["fits"] = scale.fits([r for r in doc["rows"] if r["variant"] in CHANGES])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1) + "\n")


def run_all(args: argparse.Namespace, doc: dict) -> None:
    """Sizes ascending, every variant at each, with the guard and the stopping rules; saves after each run."""
    rows = doc["rows"]
    stopped: dict[str, str] = {}
    grids = {(s, v): grid_of(s, v) for s in args.grid for v in args.variant_list}
    dofs = {k: (dkt_dofs(*g) if k[1] == "dkt" else scale.cap_dofs(*g)) for k, g in grids.items()}
    for size in sorted(args.grid, key=lambda s: dofs[(s, "dnf")] if (s, "dnf") in dofs else scale.cap_dofs(
            *args.grid[s])):
        for variant in args.variant_list:
            n = dofs[(size, variant)]
            old = next((r for r in rows if (r["size"], r["variant"]) == (size, variant)), None)
            if old is not None and not old["status"].startswith("skipped"):
                if old["status"] == "ok" and old["total"] > args.stop_after:
                    stopped[variant] = f"stopped: the {size} run took {old['total']:.0f} s > {args.stop_after:.0f} s"
                elif old["status"] != "ok":
                    stopped[variant] = f"stopped: the {size} run {old['status']}"
                continue
            if old is not None:
                rows.remove(old)
            base = {"size": size, "variant": variant, "ranks": 1, "n_dofs": n, "grid": list(grids[(size, variant)])}
            same = [r for r in rows if r["variant"] == variant]
            est = scale.estimate_mb(same or rows, n, variant, 1)
            budget = min(args.memory_limit_gb * 1024, scale.available_mb())
            if variant in stopped:
                status = stopped[variant]
            elif time.time() > args.until_ts:
                status = f"skipped: budget (no run starts after {args.until} UTC)"
            elif est > budget:
                status = f"skipped: ~{est / 1024:.1f} GiB estimated > {budget / 1024:.1f} GiB budget"
            else:
                status = None
            if status is not None:
                rows.append({**base, "status": status})
                print(f"{size} ({n} dofs) {variant}: {status}", flush=True)
                save(doc, args.out)
                continue
            load0 = [round(x, 2) for x in os.getloadavg()]
            out = scale.launch(*grids[(size, variant)], variant, 1, 1, args.timeout, script=__file__)
            load1 = [round(x, 2) for x in os.getloadavg()]
            if isinstance(out, str):
                row = {**base, "status": out}
                stopped[variant] = f"stopped: the {size} run {out}"
            else:
                row = {**scale.make_row(size, variant, 1, out), "grid": base["grid"], "extra": out[0].get("extra")}
                if row["total"] > args.stop_after:
                    stopped[variant] = f"stopped: the {size} run took {row['total']:.0f} s > {args.stop_after:.0f} s"
            row.update(load_before=load0, load_after=load1, estimate_mb=round(est), commit=commit(),
                       date=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
            rows.append(row)
            print(f"{size} ({n} dofs) {variant}: " + (
                f"{row['total']:.1f} s, peak {max(row['peak_rss_mb_per_rank']):.0f} MB, load {load0[0]}->{load1[0]}"
                if row["status"] == "ok" else row["status"]), flush=True)
            save(doc, args.out)


def commit() -> str:
    """The checked-out commit (12 hex digits) as ``bench/scale.py`` reads it, ``git rev-parse HEAD`` (a git
    worktree included), '' where git cannot tell."""
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    except OSError:
        return ""
    return out.stdout.strip()[:12] if out.returncode == 0 else ""


def main() -> int:
    args = parse_args()
    if args.worker:
        nc, nr, variant, out = args.worker
        scale.run_worker(int(nc), int(nr), variant, Path(out), build=build, extra=extra)
        return 0
    doc = load_doc(args.out)
    if not args.table:
        doc["meta"] = {"scenes": {"solid": str(scale.SCENE.relative_to(ROOT)), "dkt": str(DKT_SCENE.relative_to(ROOT))},
                       "changes": CHANGES, "threads": 1, "timeout_s": args.timeout, "stop_after_s": args.stop_after,
                       "memory_limit_gb": args.memory_limit_gb, "cpus": os.cpu_count(),
                       "note": "shared 2-core machine: other jobs ran beside; see load_before/after per row"}
        run_all(args, doc)
        save(doc, args.out)
    add_ratios(doc["rows"])
    print_table(doc["rows"], doc.get("fits") or scale.fits(doc["rows"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
