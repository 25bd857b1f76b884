"""Benchmark: the six-mode kappa = 25 cap from ~10k dofs to the largest that fits (issue 14's table).

Each size and variant runs in a fresh subprocess (its peak memory is its own),
one BLAS/OpenMP thread unless ``--threads``:

* variant ``dnf``: ``methods = ["dnf"]``; variant ``all``: ``["dnf", "nf", "md", "smd"]``;
* with ``--mpi N`` every run is repeated under ``mpirun -n N`` (the distributed
  FEniCSx adapter) and compared with the serial run of the same size.

Per row: dofs, per-stage seconds and per-stage peak RSS (``RunResult.memory``),
total seconds, peak RSS (per rank under MPI), KiB per dof (peak RSS summed over
the ranks / dofs, KiB = 1024 bytes), the counts, the ratio to the floor, and the
Gamma of the six master modes (DNF; the mesh convergence of the table).

The floor is ``t_eigen + (F - F_eigen)``: ``t_eigen`` the wall time of the
``eigen`` stage (the eigen-solve with its own shift-invert factorisation),
``F`` the seconds of all factorisations the core timed
(``counts.factorization_seconds``) and ``F_eigen`` the part of ``F`` spent
while the ``eigen`` stage ran; i.e. the eigen-solve plus the other
factorisations, each counted once. Under MPI the adapter's parallel
factorisations outside the eigen-solve are counted (``factorizations``) but
not timed, so there the floor is the eigen stage (plus the core's own
factorisations) and the ratio is an upper bound.

Memory guard: before a run its peak (summed over the ranks) is estimated
(:func:`estimate_mb`: a least-squares power law through the largest finished
runs of the same kind, or their KiB/dof, or issue 14's 29.5 KiB/dof before
any), times ``--memory-margin`` (1.2: the peak grows a little faster than
linearly, fill-in); a run whose estimate exceeds ``--memory-limit-gb``
(default 22) or the memory available now (not checked with
``--ranks-elsewhere``) is skipped and says so. Every run
has a ``--timeout`` (its process group is killed).

    .venv/bin/python bench/scale.py --sizes 10k,40k                  # serial
    .venv/bin/python bench/scale.py --sizes 10k,40k --mpi 2          # serial and 2 ranks
    .venv/bin/python bench/scale.py --sizes 10k,40k,100k,250k,500k,1M --timeout 3600

Sizes: the names of :data:`SIZES`, ``<number>k``/``<number>M`` (the O-grid with
``n_ring = n_core // 2`` closest to it) or ``<n_core>x<n_ring>``. Writes
``<out>.json`` and ``<out>.png`` (default ``bench/results/scale``).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "shell_kappa25.toml"
#: named sizes -> (n_core, n_ring) of the O-grid: 9,729 / 43,929 / 111,753 / 250,569 / 390,969 / 501,849 /
#: 765,081 / 998,793 dofs (hex27, one element through the thickness, 3 dofs per node)
SIZES = {"10k": (10, 4), "40k": (20, 10), "100k": (32, 16), "250k": (48, 24), "400k": (60, 30),
         "500k": (68, 34), "750k": (84, 42), "1M": (96, 48)}
VARIANTS = {"dnf": ["dnf"], "all": ["dnf", "nf", "md", "smd"]}
PRIOR_KIB_PER_DOF = 29.5  # issue 14, measured on main before this benchmark existed
MARGIN = 1.2  # default safety factor on the memory estimate (--memory-margin)
STAGES = ("model", "matrices", "eigen", "step", "evaluators")


# ------------------------------------------------------------------------------------------- sizes
def cap_dofs(n_core: int, n_ring: int) -> int:
    """Dofs of the scene's cap on this O-grid (3 per node of the hex27 mesh; only the mesh is built)."""
    import tomllib

    from stepnf.geometry import spherical_cap

    g = tomllib.loads(SCENE.read_text())["model"]["geometry"]
    return 3 * spherical_cap(g["a"], g["R"], g["h"], element="hex27", n_core=n_core, n_ring=n_ring).n_points


def resolve_size(name: str) -> tuple[int, int]:
    """(n_core, n_ring) of a ``--sizes`` entry (see the module docstring); ValueError if unreadable."""
    allowed = f"size {name!r}: use one of {list(SIZES)}, 300k, 1.2M or <n_core>x<n_ring> (integers >= 1)"
    if name in SIZES:
        return SIZES[name]
    try:
        if "x" in name:
            nc, nr = (int(v) for v in name.split("x"))
            if nc < 1 or nr < 1:
                raise ValueError(allowed)
            return nc, nr
        scale = {"k": 1e3, "M": 1e6}.get(name[-1:])
        target = float(name[:-1]) * scale if scale is not None else float("nan")
    except ValueError:
        raise ValueError(allowed) from None
    if not target > 0:
        raise ValueError(allowed)
    # dofs = 9 ((2 nc + 1)^2 + 16 nc nr) with one element through the thickness; nr = nc // 2
    return min(((nc, nc // 2) for nc in range(2, 400)),
               key=lambda p: abs(9 * ((2 * p[0] + 1) ** 2 + 16 * p[0] * p[1]) - target))


# ------------------------------------------------------------------------------------------ worker
def _rank() -> int:
    for var in ("OMPI_COMM_WORLD_RANK", "PMIX_RANK", "PMI_RANK"):
        if os.environ.get(var, "").isdigit():
            return int(os.environ[var])
    return 0


def run_worker(n_core: int, n_ring: int, variant: str, out_dir: Path,
               build: Callable[[int, int, str], tuple[dict, Path]] | None = None,
               extra: Callable[[Any], dict] | None = None) -> None:
    """One run in this process (one rank of it under mpirun); writes ``out_dir/rank<r>.json``.

    ``build(n_core, n_ring, variant)`` gives the scene's TOML data and file (default: this benchmark's cap
    with the variant's methods); ``extra(result)`` adds facts of the run to the record (key ``extra``).
    """
    import tomllib

    from stepnf.runtime.counters import Counters
    from stepnf.pipeline.run import run_scene
    from stepnf.runtime.progress import Progress, memory_now
    from stepnf.scene.parse import parse_scene

    class StageTracker(Progress):
        """A silent Progress that knows which stages are running."""

        def __init__(self) -> None:
            super().__init__(enabled=False)
            self.active: list[str] = []

        @contextmanager
        def stage(self, key: str, text: str) -> Iterator[None]:
            self.active.append(key)
            try:
                with super().stage(key, text):
                    yield
            finally:
                self.active.pop()

    progress, in_eigen = StageTracker(), [0.0]

    def counting_setattr(self: Any, name: str, value: Any) -> None:  # F_eigen of the floor
        if name == "factorization_seconds" and "eigen" in progress.active:
            in_eigen[0] += value - self.__dict__.get(name, 0.0)
        object.__setattr__(self, name, value)

    Counters.__setattr__ = counting_setattr
    if build is None:
        src, data = SCENE, tomllib.loads(SCENE.read_text())
        data["model"]["geometry"].update({"n_core": n_core, "n_ring": n_ring})
        data["analysis"]["methods"] = VARIANTS[variant]
        data["output"] = {"hdf5": False}
    else:
        data, src = build(n_core, n_ring, variant)
    methods = data["analysis"]["methods"]
    scene = parse_scene(data, file=src, base_dir=src.parent)
    t0 = time.perf_counter()
    res = run_scene(scene, progress=progress, write=False)
    record = {"rank": _rank(), "n_dofs": res.model["n_dofs"], "total": time.perf_counter() - t0,
              "timings": res.timings, "memory": res.memory, "counts": res.counts,
              "factorization_seconds_in_eigen": in_eigen[0], "peak_rss_mb": memory_now()["peak_rss_mb"],
              "mpi_processes": res.model.get("mpi_processes", 1),
              "gamma": {name: {str(m.label): m.methods[name].gamma for m in res.modes if name in m.methods}
                        for name in methods}}
    if extra is not None:
        record["extra"] = extra(res)
    (out_dir / f"rank{record['rank']}.json").write_text(json.dumps(record))


# ------------------------------------------------------------------------------------------ runner
def child_env(threads: int) -> dict[str, str]:
    """This environment with ``threads`` BLAS/OpenMP threads (and Open MPI allowed as root)."""
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
        env[var] = str(threads)
    return env


def mpirun_prefix(ranks: int) -> list[str]:
    """``mpirun -n ranks`` (Open MPI: with ``--oversubscribe``, as tests/solvers/fenicsx/test_mpi.py); [] for one rank."""
    if ranks == 1:
        return []
    mpirun = shutil.which("mpirun") or shutil.which("mpiexec")
    if mpirun is None:
        print("scale.py: --mpi needs mpirun or mpiexec on PATH (Debian: mpi-default-bin)", file=sys.stderr)
        raise SystemExit(2)
    version = subprocess.run([mpirun, "--version"], capture_output=True, text=True).stdout
    extra = ["--oversubscribe"] if ("Open MPI" in version or "OpenRTE" in version) else []
    return [mpirun, "-n", str(ranks), *extra]


def launch(n_core: int, n_ring: int, variant: str, ranks: int, threads: int, timeout: float,
           script: str = __file__) -> list[dict] | str:
    """Run one size in a fresh process group (``script --worker ...``); the ranks' records, or why there are none."""
    with tempfile.TemporaryDirectory(prefix="stepnf_scale_") as tmp:
        cmd = mpirun_prefix(ranks) + [sys.executable, script, "--worker", str(n_core), str(n_ring), variant, tmp]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=child_env(threads), start_new_session=True)
        try:
            _, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the group this call started (mpirun and its ranks)
            proc.communicate()
            return f"timeout after {timeout:.0f} s"
        records = [json.loads(p.read_text()) for p in sorted(Path(tmp).glob("rank*.json"))]
    if proc.returncode != 0 or len(records) != ranks:
        last = (err or "").strip().splitlines()[-1:] or ["no output"]
        return f"failed (exit {proc.returncode}): {last[0][:150]}"
    return sorted(records, key=lambda r: r["rank"])


def make_row(size: str, variant: str, ranks: int, records: list[dict]) -> dict:
    """The table's row from the ranks' records (times, counts and Gamma: rank 0's; memory: every rank's)."""
    r0 = records[0]
    t, c = r0["timings"], r0["counts"]
    fact = c.get("factorization_seconds", 0.0)
    floor = t.get("eigen", 0.0) + max(fact - r0["factorization_seconds_in_eigen"], 0.0)
    peaks = [r["peak_rss_mb"] for r in records]
    stage_peaks = {k: max(r["memory"].get(k, {}).get("peak_rss_mb") or 0.0 for r in records)
                   for k in r0["memory"]}
    return {"size": size, "variant": variant, "ranks": ranks, "status": "ok", "n_dofs": r0["n_dofs"],
            "mpi_processes": r0["mpi_processes"], "timings": t, "stage_peak_rss_mb": stage_peaks,
            "total": r0["total"], "floor": floor, "ratio_to_floor": r0["total"] / floor if floor else None,
            "factorization_seconds_in_eigen": r0["factorization_seconds_in_eigen"], "counts": c,
            "peak_rss_mb_per_rank": peaks, "kib_per_dof": sum(peaks) * 1024 / r0["n_dofs"],
            "gamma": r0["gamma"]}


# ----------------------------------------------------------------------------------- fits and guard
def fit_power(xs: list[float], ys: list[float]) -> tuple[float, float] | None:
    """Least squares of log y = log a + b log x: (a, b); None with fewer than two distinct x."""
    import numpy as np

    if len(set(xs)) < 2:
        return None
    b, log_a = np.polyfit(np.log(xs), np.log(ys), 1)
    return float(math.exp(log_a)), float(b)


def estimate_mb(rows: list[dict], dofs: int, variant: str, ranks: int, margin: float = MARGIN) -> float:
    """Peak RSS summed over the ranks a run of ``dofs`` should reach, in MiB, times ``margin``.

    The larger of the power law through the three largest finished runs of the same kind (the small
    ones carry the interpreter's fixed ~120 MB and would flatten the exponent) and the largest run's
    KiB/dof times ``dofs`` (never below the truth while memory grows at most linearly).
    """
    done = [r for r in rows if r["status"] == "ok" and r["ranks"] == ranks]
    same = sorted([r for r in done if r["variant"] == variant] or done, key=lambda r: r["n_dofs"])[-3:]
    kib = same[-1]["kib_per_dof"] if same else PRIOR_KIB_PER_DOF * ranks
    fit = fit_power([r["n_dofs"] for r in same], [sum(r["peak_rss_mb_per_rank"]) for r in same])
    by_fit = fit[0] * dofs ** fit[1] if fit is not None else 0.0
    return margin * max(by_fit, kib * dofs / 1024)


def available_mb() -> float:
    """MemAvailable of /proc/meminfo in MiB (infinite where unknown)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return math.inf


def fits(rows: list[dict]) -> dict[str, dict]:
    """Per ``variant/ranks``: the fitted exponents of total time and peak RSS (summed) vs dofs."""
    out = {}
    for key in sorted({(r["variant"], r["ranks"]) for r in rows}):
        ok = [r for r in rows if (r["variant"], r["ranks"]) == key and r["status"] == "ok"]
        t = fit_power([r["n_dofs"] for r in ok], [r["total"] for r in ok])
        m = fit_power([r["n_dofs"] for r in ok], [sum(r["peak_rss_mb_per_rank"]) for r in ok])
        if t and m:
            out[f"{key[0]}/{key[1]}"] = {"time_exponent": t[1], "memory_exponent": m[1],
                                         "time_prefactor_s": t[0], "memory_prefactor_mb": m[0]}
    return out


# ---------------------------------------------------------------------------------------- output
def speedups(rows: list[dict]) -> None:
    """``speedup``: the serial total over this row's at the same size and variant (MPI rows)."""
    serial = {(r["size"], r["variant"]): r["total"] for r in rows if r["ranks"] == 1 and r["status"] == "ok"}
    for r in rows:
        if r["ranks"] > 1 and r["status"] == "ok" and (r["size"], r["variant"]) in serial:
            r["speedup"] = serial[(r["size"], r["variant"])] / r["total"]


def print_tables(rows: list[dict]) -> None:
    head = ("size", "variant", "ranks", "dofs", *STAGES, "total", "fact", "fact s", "floor", "ratio", "speedup",
            "peak MB/rank", "KiB/dof")
    print("\nseconds (rank 0), peak RSS per rank; ratio = total / floor")
    print("  ".join(f"{h:>10}" for h in head))
    for r in rows:
        if r["status"] != "ok":
            print(f"{r['size']:>10}  {r['variant']:>10}  {r['ranks']:>10}  {r.get('n_dofs', '-'):>10}  {r['status']}")
            continue
        t, c = r["timings"], r["counts"]
        vals = (r["size"], r["variant"], r["ranks"], r["n_dofs"], *(f"{t.get(k, 0.0):.1f}" for k in STAGES),
                f"{r['total']:.1f}", c.get("factorizations"), f"{c.get('factorization_seconds', 0.0):.1f}",
                f"{r['floor']:.1f}", f"{r['ratio_to_floor']:.2f}" if r["ratio_to_floor"] else "-",
                f"{r['speedup']:.2f}" if "speedup" in r else "-",
                "/".join(f"{p:.0f}" for p in r["peak_rss_mb_per_rank"]), f"{r['kib_per_dof']:.1f}")
        print("  ".join(f"{v!s:>10}" for v in vals))
    ok = [r for r in rows if r["status"] == "ok"]
    print("\npeak RSS at the end of each stage, MB (largest over the ranks)")
    print("  ".join(f"{h:>10}" for h in ("size", "variant", "ranks", *STAGES, "total")))
    for r in ok:
        sp = r["stage_peak_rss_mb"]
        print("  ".join(f"{v!s:>10}" for v in (r["size"], r["variant"], r["ranks"],
                                                *(f"{sp.get(k, 0.0):.0f}" for k in (*STAGES, "total")))))
    print("\nGamma of the master modes (DNF)")
    for r in ok:
        print(f"{r['size']:>6} {r['variant']:>4} {r['ranks']} rank(s): "
              + "  ".join(f"{lab} {g:+.6e}" for lab, g in r["gamma"].get("dnf", {}).items()))


def plot(rows: list[dict], fitted: dict[str, dict], path: Path) -> None:
    """Log-log time and peak RSS (summed over the ranks) vs dofs, one line per variant/ranks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(11, 4.5))
    for key in sorted({(r["variant"], r["ranks"]) for r in rows}):
        ok = sorted((r for r in rows if (r["variant"], r["ranks"]) == key and r["status"] == "ok"),
                    key=lambda r: r["n_dofs"])
        if not ok:
            continue
        f = fitted.get(f"{key[0]}/{key[1]}")
        n = [r["n_dofs"] for r in ok]
        name = f"{key[0]}, {key[1]} rank{'s' if key[1] > 1 else ''}"
        ax_t.loglog(n, [r["total"] for r in ok], "o-", label=name + (f": n^{f['time_exponent']:.2f}" if f else ""))
        ax_m.loglog(n, [sum(r["peak_rss_mb_per_rank"]) / 1024 for r in ok], "o-",
                    label=name + (f": n^{f['memory_exponent']:.2f}" if f else ""))
    for ax, what in ((ax_t, "total time [s]"), (ax_m, "peak RSS, summed over ranks [GiB]")):
        ax.set_xlabel("dofs")
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("stepnf, kappa = 25 cap, six master modes")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------------------------------- main
def parse_args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10k,40k,100k,250k,500k,1M", help="comma-separated (see the docstring)")
    ap.add_argument("--variants", default="dnf,all", help=f"comma-separated, from {list(VARIANTS)}")
    ap.add_argument("--mpi", type=int, default=0, metavar="N", help="also run every size under mpirun -n N")
    ap.add_argument("--threads", type=int, default=1, help="BLAS/OpenMP threads per process (default 1)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per run (default 1800)")
    ap.add_argument("--memory-limit-gb", type=float, default=22.0, help="skip runs estimated above (GiB)")
    ap.add_argument("--ranks-elsewhere", action="store_true",
                    help="the MPI ranks run on other machines (a batch allocation): the budget is "
                         "--memory-limit-gb alone (set it to the nodes' total), not this machine's free memory")
    ap.add_argument("--memory-margin", type=float, default=MARGIN, help=f"safety factor (default {MARGIN})")
    ap.add_argument("--skip-larger-than", type=float, default=math.inf, metavar="DOFS",
                    help="skip the sizes with more dofs")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "scale",
                    help="writes OUT.json and OUT.png")
    ap.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return args
    try:
        args.grid = {name: resolve_size(name) for name in args.sizes.split(",")}
    except ValueError as exc:
        ap.error(str(exc))
    bad = [v for v in args.variants.split(",") if v not in VARIANTS]
    if bad:
        ap.error(f"unknown variant(s) {bad}: pick from {list(VARIANTS)}")
    if args.mpi == 1 or args.mpi < 0:
        ap.error("--mpi N needs N >= 2")
    if args.mpi and not (shutil.which("mpirun") or shutil.which("mpiexec")):
        ap.error("--mpi: no mpirun or mpiexec on PATH")
    return args


def run_all(args: argparse.Namespace) -> list[dict]:
    """Every size (ascending dofs), variant and rank count, with the memory guard; prints as it goes."""
    rows: list[dict] = []
    dofs = {name: cap_dofs(*grid) for name, grid in args.grid.items()}
    for name in sorted(args.grid, key=dofs.get):
        for variant in args.variants.split(","):
            for ranks in (1, args.mpi) if args.mpi else (1,):
                base = {"size": name, "variant": variant, "ranks": ranks, "n_dofs": dofs[name],
                        "grid": list(args.grid[name])}
                est = estimate_mb(rows, dofs[name], variant, ranks, args.memory_margin)
                budget = args.memory_limit_gb * 1024
                if not args.ranks_elsewhere:
                    budget = min(budget, available_mb())
                if dofs[name] > args.skip_larger_than:
                    rows.append({**base, "status": f"skipped: more than {args.skip_larger_than:.0f} dofs"})
                elif est > budget:
                    rows.append({**base, "status": f"skipped: ~{est / 1024:.1f} GiB estimated > "
                                                   f"{budget / 1024:.1f} GiB budget"})
                else:
                    out = launch(*args.grid[name], variant, ranks, args.threads, args.timeout)
                    rows.append({**base, "status": out} if isinstance(out, str)
                                else {**make_row(name, variant, ranks, out), "grid": base["grid"]})
                r = rows[-1]
                print(f"{name} ({dofs[name]} dofs) {variant} x{ranks}: " + (
                    f"{r['total']:.1f} s, peak {max(r['peak_rss_mb_per_rank']):.0f} MB/rank"
                    if r["status"] == "ok" else r["status"]), flush=True)
    return rows


def main() -> int:
    args = parse_args()
    if args.worker:
        nc, nr, variant, out = args.worker
        run_worker(int(nc), int(nr), variant, Path(out))
        return 0
    rows = run_all(args)
    speedups(rows)
    fitted = fits(rows)
    print_tables(rows)
    for key, f in fitted.items():
        print(f"fit {key}: time ~ n^{f['time_exponent']:.2f}, memory ~ n^{f['memory_exponent']:.2f}")
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True).stdout
    meta = {"scene": str(SCENE.relative_to(ROOT)), "threads": args.threads, "mpi": args.mpi,
            "timeout_s": args.timeout, "memory_limit_gb": args.memory_limit_gb, "commit": commit.strip(),
            "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "cpus": os.cpu_count(),
            "floor": "t_eigen + (factorization_seconds - factorization seconds inside the eigen stage)"}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps({"meta": meta, "rows": rows, "fits": fitted}, indent=1))
    plot(rows, fitted, args.out.with_suffix(".png"))
    print(f"written {args.out.with_suffix('.json')} and {args.out.with_suffix('.png')}")
    return 3 if any(r["status"].startswith(("failed", "timeout")) for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
