"""Command-line interface: ``stepnf run SCENE``, ``stepnf modes SCENE``, ``stepnf show RESULT.h5``, ``stepnf solvers``,
``stepnf check SCENE`` (the conformance harness on a scene's adapter: exit 3 when a check fails),
``stepnf verify SCENE`` (backbones against the full model's periodic orbits).

Exit codes: 0 success; 2 bad input (scene, unknown solver, bad model, a file given to show or fig4); 3 a
solver or numerical failure, or a file that cannot be written (also a run whose T table was computed and
printed but the backbone of a master failed); 4 a sweep with
failed cases; 1 anything unexpected (a bug: the message says so, and ``stepnf --debug ...`` prints the
traceback); interrupted, 128 + the signal: 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP (:mod:`stepnf.runtime.signals`).
"""
from __future__ import annotations

import argparse
import os
import sys
import traceback
import warnings
from typing import Sequence

from stepnf.errors import NumericalError, SceneError, SolverRunError, StepnfError, UnknownSolverError
from stepnf.runtime.limits import out_of_memory, reserve_blas_buffer
from stepnf.runtime.signals import handled, interruption
from stepnf.runtime.programs import allow_programs, program_flag
from stepnf.runtime.printable import SafeArgumentParser, printable, safe_print as print  # noqa: A001 - control characters escaped


def _cmd_solvers(args: argparse.Namespace) -> int:
    from stepnf.plugin.registry import installed_solvers

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solvers = installed_solvers(refresh=True)
    for w in caught:
        print(f"stepnf: warning: {w.message}", file=sys.stderr)
    if args.keys is not None:
        return _print_keys(args.keys, solvers)
    if not solvers:
        print("no stepnf solver adapters installed (entry-point group 'stepnf.solvers')")
        return 0
    width = max(len(n) for n in solvers)
    for name, info in sorted(solvers.items()):
        print(f"{name.ljust(width)}  {info.kind:11s}  {info.distribution} {info.version}  "
              f"[{', '.join(info.capabilities)}]")
    return 0


def _print_keys(name: str, solvers: dict) -> int:
    """``stepnf solvers --keys NAME``: the keys the solver's ``[model]`` table accepts."""
    if name not in solvers:
        raise UnknownSolverError(name, solvers)
    info = solvers[name]
    schema = info.cls.model_schema()
    print(f"[model] keys of solver {name!r} ({info.cls.__name__}, {info.kind}, {info.distribution} {info.version}):")
    if schema is None:
        print("  not declared (the adapter sets no model_keys): they are checked only when the model is built")
        return 0
    print(schema.format())
    return 0


def _launcher(keys: tuple[str, ...], default: int) -> int:
    """An integer the MPI launcher (``mpirun``/``srun``) put in the environment: stepnf never imports MPI."""
    import os

    for key in keys:
        value = os.environ.get(key, "")
        if value.isdigit():
            return int(value)
    return default


def _mpi_rank() -> int:
    """This process's rank when started by ``mpirun``/``srun`` (0 otherwise)."""
    return _launcher(("OMPI_COMM_WORLD_RANK", "PMIX_RANK", "PMI_RANK"), 0)


def _cmd_run(args: argparse.Namespace) -> int:
    from stepnf.errors import OutputError
    from stepnf.pipeline.run import run_scene
    from stepnf.runtime.progress import Progress
    from stepnf.scene.parse import load_scene
    from stepnf.report.table import format_table

    scene = load_scene(args.scene)
    if args.output is not None:
        from pathlib import Path

        if not args.output.strip():
            raise SceneError(args.scene, None, f"--output must name a folder, got {args.output!r}")
        scene.output_dir = Path(args.output)
    rank = _mpi_rank()
    if args.no_hdf5 or rank:
        scene.write_hdf5 = False
    progress = Progress(enabled=not args.quiet and not rank)

    def show(result) -> None:
        if args.json:
            print(result.to_json(indent=None if args.compact else 2), flush=True)
        else:
            print(format_table(result), flush=True)

    # run_scene checks the output folder before any computation (SceneError on output.dir: exit 2)
    try:
        result = run_scene(scene, progress=progress)
    except OutputError as exc:
        # the results file could not be written (full disk): the computed results are not lost,
        # they are shown as usual, then main() reports the error (exit 3)
        if exc.result is not None and not rank:
            show(exc.result)
        raise
    if rank:  # under mpirun every rank computes the same results; rank 0 alone writes and prints
        return 0
    if scene.plot and not args.no_plot:  # a figure that cannot be made is a warning: the results are there
        from stepnf.report.run_figures import draw_run_figures

        for line in draw_run_figures(scene, result):
            print(line, file=sys.stderr)
    show(result)
    failed = result.failed_backbones()
    for p, reason in failed:  # T and the results are there (printed, stored); what was asked is not all there
        print(f"stepnf: solver failure: the backbone of master mode {p} failed (the rest of the run is printed "
              f"and stored): {reason}", file=sys.stderr)
    return 3 if failed else 0


def _cmd_modes(args: argparse.Namespace) -> int:
    """``stepnf modes SCENE [-n N]``: the first elastic modes from one eigen-solve, no STEP."""
    from stepnf.cli.modes import format_survey, modal_survey
    from stepnf.runtime.progress import Progress
    from stepnf.scene.parse import load_scene

    survey = modal_survey(load_scene(args.scene), args.n, Progress(enabled=not args.quiet))
    print(survey.to_json(indent=2) if args.json else format_survey(survey))
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    """``stepnf show RESULT.h5``: the table of a stored run."""
    from stepnf.cli.show import stored_table

    print(stored_table(args.file))
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    """``stepnf check SCENE``: the conformance harness on the scene's adapter (:mod:`stepnf.cli.check`)."""
    from stepnf.cli.check import check_scene, format_check

    report = check_scene(args.scene)
    print(format_check(report))
    return 3 if report.failed else 0


def _cmd_verify(args: argparse.Namespace) -> int:
    """``stepnf verify SCENE``: the scene's backbones against the full model's orbits (:mod:`stepnf.verify.command`)."""
    import json

    from stepnf.scene.parse import load_scene
    from stepnf.verify.command import failed_orbits, format_report, verify_scene

    say = None if args.quiet else (lambda s: print(f"stepnf: {s}", file=sys.stderr, flush=True))
    doc = verify_scene(load_scene(args.scene), amplitudes=args.amplitudes, periods=args.periods, progress=say,
                       tangent=args.tangent, per_period=args.steps_per_period)
    print(json.dumps(doc, indent=2) if args.json else format_report(doc))
    failed = failed_orbits(doc)
    if failed:  # the checks that worked are printed above; the run as a whole did not verify
        total = failed + sum(len(m["checks"]) for m in doc["modes"])
        print(f"stepnf: solver failure: verify: {failed} of {total} orbits could not be computed (listed above)",
              file=sys.stderr)
        return 3
    return 0


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"stepnf {version('stepnf')}"
    except PackageNotFoundError:  # a source tree that is not installed
        from stepnf import __version__

        return f"stepnf {__version__}"


def _mpi_size() -> int:
    """Number of ranks started by ``mpirun``/``srun`` (1 otherwise)."""
    return _launcher(("OMPI_COMM_WORLD_SIZE", "PMIX_SIZE", "PMI_SIZE"), 1)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from stepnf.sweep.dask_address import check_scheduler
    from stepnf.sweep.dask_sweep import MAX_WORKERS, load_sweep, run_sweep

    if _mpi_size() > 1:
        raise StepnfError("`stepnf sweep` must not run under mpirun: its store has one writer. Run it once and "
                          "let each case use MPI through the solver, or give it a Dask scheduler (docs/cluster.md)")

    if args.workers is not None and not 1 <= args.workers <= MAX_WORKERS:
        raise SceneError(args.file, None, f"--workers: expected an integer in [1, {MAX_WORKERS}], got {args.workers}")
    if args.scheduler is not None:
        check_scheduler(args.file, None, args.scheduler, prefix="--scheduler: ")
    sweep = load_sweep(args.file)
    say = (lambda s: None) if args.quiet else (lambda s: print(f"[stepnf] {s}", file=sys.stderr, flush=True))
    rep = run_sweep(sweep, scheduler=args.scheduler, n_workers=args.workers, retry_failed=args.retry_failed,
                    recompute_stale=args.recompute_stale, progress=say)
    from stepnf.sweep.dask_sweep import read_store

    failed = sorted(cid for cid, rec in read_store(sweep.store).items() if rec.get("status") != "done")
    print(f"sweep {sweep.name}: {len(rep.done) + len(rep.failed)} cases run ({len(rep.done)} done, "
          f"{len(rep.failed)} failed), {len(rep.skipped)} already stored; store {sweep.store}")
    if failed:
        print(f"failed cases in the store: {failed} (rerun with --retry-failed)")
    return 0 if not failed else 4


def _cmd_curves(args: argparse.Namespace) -> int:
    """``stepnf curves``: the von Karman shell's Figs. 2 and 3 (T_p, Gamma, rho_p versus kappa)."""
    from pathlib import Path

    from stepnf.report.curves import CurveOptions, CurvesError, compute_curves, format_summary, parse_mode, write_all
    from stepnf.nf.evaluators import Tolerances
    from stepnf.runtime.progress import Progress

    progress = Progress(enabled=not args.quiet)
    try:
        modes = tuple(parse_mode(m) for m in args.modes) if args.modes else None
        if modes and len(set(modes)) < len(modes):
            twice = sorted({m for m in modes if modes.count(m) > 1})
            raise CurvesError(f"--modes lists {', '.join(map(str, twice))} more than once")
        if not args.out.strip():
            raise CurvesError(f"--out must name a folder, got {args.out!r}")
        kw = {"kappa_max": args.kappa_max, "n_kappa": args.n_kappa, "nu": args.nu,
              "tolerances": Tolerances(resonance=args.resonance_tol),
              "gap_resonance": args.gap_tol, "omega_max": args.omega_max, "edge": args.edge}
        if modes:
            kw["modes"] = modes
        options = CurveOptions(**kw)
        with progress.stage("curves", f"von Karman shell ({args.edge} edge): {args.n_kappa} kappa values in "
                                      f"[0, {args.kappa_max:g}]"):
            curves = compute_curves(options, progress=lambda i, n: progress.bar(i, n, "kappa"))
        quantities = ("T", "gamma") if args.quantity == "both" else (args.quantity,)
        with progress.stage("write", "HDF5, CSV and figures"):
            files = write_all(curves, Path(args.out), quantities=quantities, plots=not args.no_plot)
    except CurvesError as exc:
        print(f"stepnf: error: {exc}", file=sys.stderr)
        return 2
    print(f"{len(curves.modes)} modes x 3 methods x {len(curves.kappa)} kappa values in {curves.seconds:.1f} s")
    for key, path in files.items():
        print(f"  {key:16s} {path}")
    print(format_summary(curves))
    return 0


#: Points of the von Karman curves ``stepnf fig4`` draws (each a modal eigen-solve and NF).
FIG4_N_KAPPA = (2, 100_000)


def _cmd_fig4(args: argparse.Namespace) -> int:
    from stepnf.report.fig4 import figure4, format_summary

    where = args.stores[0]
    lo, hi = FIG4_N_KAPPA
    if not lo <= args.n_kappa <= hi:
        raise SceneError(where, None, f"--n-kappa: expected an integer in [{lo}, {hi}], got {args.n_kappa}")
    names = None
    if args.names is not None:
        names = [n.strip() for n in args.names.split(",")]
        if len(names) != len(args.stores) or not all(names):
            raise SceneError(where, None, f"--names: expected {len(args.stores)} non-empty comma-separated names, "
                             f"one per store, got {args.names!r}")
    if not args.out.strip():
        raise SceneError(where, None, f"--out must name a folder, got {args.out!r}")
    res = figure4(args.stores, args.out, names=names, n_kappa=args.n_kappa)
    print(format_summary(res["summary"]))
    print(f"figure: {res['figure']}\ntable: {res['table']}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = SafeArgumentParser(prog="stepnf", description=__doc__.splitlines()[0])
    parser.add_argument("--debug", action="store_true",
                        help="on failure, also print the Python traceback (for bug reports)")
    parser.add_argument("--version", action="version", version=_version())
    # --debug after the command too (`stepnf run s.toml --debug`); SUPPRESS keeps the top-level value
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    programs = program_flag()  # --allow-programs: a program a scene names runs only so (stepnf.runtime.programs)
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", parents=[common, programs], help="compute what a scene asks for")
    p_run.add_argument("scene", help="scene file (TOML)")
    p_run.add_argument("--json", action="store_true", help="print one JSON document on stdout instead of the table")
    p_run.add_argument("--compact", action="store_true", help="JSON on one line")
    p_run.add_argument("--quiet", "-q", action="store_true", help="no progress messages on stderr")
    p_run.add_argument("--output", "-o", help="output folder (overrides [output] dir)")
    p_run.add_argument("--no-hdf5", action="store_true", help="do not write the HDF5 file")
    p_run.add_argument("--no-plot", action="store_true", help="do not draw figures")
    p_run.set_defaults(func=_cmd_run)
    p_md = sub.add_parser("modes", parents=[common, programs], help="list the first elastic modes (frequency, label, "
                          "kinetic-energy shares) from one eigen-solve, no STEP")
    p_md.add_argument("scene", help="scene file (TOML)")
    p_md.add_argument("-n", type=_positive, default=None, metavar="N", help="number of modes (default 12)")
    p_md.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p_md.add_argument("--quiet", "-q", action="store_true", help="no progress messages on stderr")
    p_md.set_defaults(func=_cmd_modes)
    p_sh = sub.add_parser("show", parents=[common], help="print the table of a stored run again")
    p_sh.add_argument("file", help="results file (HDF5) written by `stepnf run`")
    p_sh.set_defaults(func=_cmd_show)
    p_sw = sub.add_parser("sweep", parents=[common, programs],
                          help="run every case of a sweep file on Dask (resumable)")
    p_sw.add_argument("file", help="sweep file (TOML)")
    p_sw.add_argument("--scheduler", help="address of an existing dask.distributed scheduler")
    p_sw.add_argument("--workers", type=int, help="local cluster size")
    p_sw.add_argument("--retry-failed", action="store_true", help="run again the cases stored as failed")
    p_sw.add_argument("--recompute-stale", action="store_true", help="compute again the cases stored for another "
                      "model (another model file or content, scene keys, adapter); refused without it")
    p_sw.add_argument("--quiet", "-q", action="store_true")
    p_sw.set_defaults(func=_cmd_sweep)
    p_cv = sub.add_parser("curves", parents=[common], help="von Karman shell: T_p by NF/MD/SMD and rho_p versus kappa "
                          "(paper Figs. 2 and 3) to HDF5, CSV and PNG")
    p_cv.add_argument("--kappa-max", type=float, default=100.0, help="largest kappa (grid from 0; default 100)")
    p_cv.add_argument("--n-kappa", type=int, default=200, help="number of kappa values (default 200)")
    p_cv.add_argument("--modes", nargs="+", metavar="(K,N)",
                      help="master modes, e.g. --modes \"(2,0)\" \"(0,1)\" (default: the six of Fig. 3; with "
                           "--edge clamped its first six, (0,1) (1,1) (2,1) (0,2) (3,1) (1,2))")
    p_cv.add_argument("--edge", choices=["free", "clamped"], default="free",
                      help="edge of the shell: free (the paper) or clamped (w = dw/dr = 0, immovable in-plane; "
                           "labels count the edge as a nodal circle). Default free")
    p_cv.add_argument("--nu", type=float, default=0.3, help="Poisson ratio (default 0.3)")
    p_cv.add_argument("--quantity", choices=["T", "gamma", "both"], default="both",
                      help="y quantity of Fig. 3: the paper's T_p, Gamma = T_p/max|phi|^2, or both figures")
    p_cv.add_argument("--resonance-tol", type=float, default=0.05,
                      help="relative window of the evaluators' internal-resonance flags (default 0.05)")
    p_cv.add_argument("--gap-tol", type=float, default=0.02,
                      help="relative window in which a significant resonance breaks the plotted line (default 0.02)")
    p_cv.add_argument("--omega-max", type=float, default=80.0,
                      help="Fig. 2 shows the (k, n) modes with frequency below this at kappa = 0 (default 80)")
    p_cv.add_argument("--out", "-o", default="results/curves", help="output folder (default results/curves)")
    p_cv.add_argument("--no-plot", action="store_true", help="data only, no PNG")
    p_cv.add_argument("--quiet", "-q", action="store_true", help="no progress messages on stderr")
    p_cv.set_defaults(func=_cmd_curves)
    p_f4 = sub.add_parser("fig4", parents=[common], help="FE points of sweeps on the von Karman Gamma(kappa) curves (paper Fig. 4)")
    p_f4.add_argument("stores", nargs="+", help="sweep stores (HDF5) written by `stepnf sweep`")
    p_f4.add_argument("--names", help="comma-separated legend names, one per store")
    p_f4.add_argument("--out", default="results/fig4", help="output folder")
    p_f4.add_argument("--n-kappa", type=int, default=300, help="points of the von Karman curves")
    p_f4.set_defaults(func=_cmd_fig4)
    p_ck = sub.add_parser("check", parents=[common, programs],
                          help="run the adapter conformance checks on a scene's model")
    p_ck.add_argument("scene", help="scene file (TOML)")
    p_ck.set_defaults(func=_cmd_check)
    p_vf = sub.add_parser("verify", parents=[common, programs],
                          help="check the scene's backbone curves against periodic "
                          "orbits of the full model (shooting, or time integration for large models)")
    p_vf.add_argument("scene", help="scene file (TOML) with an [analysis.backbone] table")
    p_vf.add_argument("--amplitudes", nargs="+", type=float, metavar="A",
                      help="amplitudes of the master coordinate q = phi^T M x (default: 3 up to the validity limit, "
                           "capped at W_max/h = 2 when [analysis] thickness is set)")
    p_vf.add_argument("--periods", type=float, default=3.0, help="periods integrated (large models; default 3)")
    p_vf.add_argument("--tangent", choices=("auto", "modified", "tangent", "differences"), default="auto",
                      help="the time integration's Newton: modified (K only, then a secant iteration on K), tangent "
                      "(the model's own), differences (Newton-Krylov, J v by directional differences of the forces), "
                      "auto (default: modified, then the model's tangent, else secant and differences); a step none "
                      "converges is halved, 3 times at most")
    p_vf.add_argument("--steps-per-period", type=int, metavar="N", help="time steps per period of the coarse "
                      "integration (halved once for Richardson; default 71) or of the implicit shooting (default 32)")
    p_vf.add_argument("--json", action="store_true", help="print one JSON document on stdout instead of the table")
    p_vf.add_argument("--quiet", "-q", action="store_true", help="no progress messages on stderr")
    p_vf.set_defaults(func=_cmd_verify)
    p_sol = sub.add_parser("solvers", parents=[common], help="list the installed solver adapters")
    p_sol.add_argument("--keys", metavar="NAME", help="list the keys the [model] table of solver NAME accepts "
                       "(type, range, default, meaning)")
    p_sol.set_defaults(func=_cmd_solvers)
    args = parser.parse_args(argv)
    keep_sigpipe_ignored()
    formatwarning = warnings.formatwarning
    if not args.debug:  # "stepnf: warning: ..." rather than a source line that means nothing to a user
        warnings.formatwarning = _format_warning
    try:
        reserve_blas_buffer()  # under `ulimit -v`: a message now rather than OpenBLAS spinning later
        with allow_programs(True if getattr(args, "allow_programs", False) else None), handled():
            return int(args.func(args))
    except BaseException as exc:  # noqa: BLE001 - every failure becomes a message and an exit code
        if args.debug and not isinstance(exc, (SystemExit, KeyboardInterrupt)):
            traceback.print_exc()
        return report_failure(exc)
    finally:
        warnings.formatwarning = formatwarning


def keep_sigpipe_ignored() -> None:
    """Ask PETSc (through ``PETSC_OPTIONS``, read when petsc4py starts) not to install its signal handlers.

    Python ignores SIGPIPE, so a closed stdout (``stepnf run ... --json | head``) is a BrokenPipeError that
    :func:`report_failure` takes quietly; PETSc's handler would instead print a crash banner and abort MPI.
    """
    opts = os.environ.get("PETSC_OPTIONS", "")
    if "-no_signal_handler" not in opts.split():
        os.environ["PETSC_OPTIONS"] = f"{opts} -no_signal_handler".strip()


def _format_warning(message, category, filename, lineno, line=None) -> str:
    return f"stepnf: warning: {printable(message)}\n"


def report_failure(exc: BaseException) -> int:
    """Print what went wrong as one message on stderr and return the exit code (see the module docstring)."""
    if isinstance(exc, SystemExit):
        raise exc
    if isinstance(exc, KeyboardInterrupt):  # Ctrl-C, or a signal turned into one (stepnf.runtime.signals)
        return interruption(exc)
    if isinstance(exc, (SceneError, UnknownSolverError)):
        print(f"stepnf: error: {exc}", file=sys.stderr)
        return 2
    if isinstance(exc, (SolverRunError, NumericalError)):
        print(f"stepnf: solver failure: {exc}", file=sys.stderr)
        return 3
    if isinstance(exc, StepnfError):
        print(f"stepnf: error: {exc}", file=sys.stderr)
        return 3
    if out_of_memory(exc):  # MemoryError & co (stepnf.runtime.limits): names the stage and any ulimit
        return 3
    if isinstance(exc, BrokenPipeError):  # the reader of stdout left (`| head`): nothing failed here
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit's flush
        except (OSError, ValueError):
            pass
        return 0
    if isinstance(exc, OSError):  # a file or folder stepnf could not read or write
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"stepnf: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return 3
    print(f"stepnf: internal error (a bug in stepnf or an adapter; please report it): {type(exc).__name__}: {exc}\n"
          "  rerun with --debug to see where it happened", file=sys.stderr)
    return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
