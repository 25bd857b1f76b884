"""Command-line interface: ``stepnf run SCENE``, ``stepnf solvers``.

Exit codes: 0 success; 2 bad input (scene, unknown solver, bad model); 3 a
solver or numerical failure; 4 a sweep with failed cases; 1 anything unexpected.
"""
from __future__ import annotations

import argparse
import sys
import warnings
from typing import Sequence

from .errors import NumericalError, SceneError, SolverRunError, StepnfError, UnknownSolverError


def _cmd_solvers(args: argparse.Namespace) -> int:
    from .registry import installed_solvers

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solvers = installed_solvers(refresh=True)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    if not solvers:
        print("no stepnf solver adapters installed (entry-point group 'stepnf.solvers')")
        return 0
    width = max(len(n) for n in solvers)
    for name, info in sorted(solvers.items()):
        print(f"{name.ljust(width)}  {info.kind:11s}  {info.distribution} {info.version}  "
              f"[{', '.join(info.capabilities)}]")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from .pipeline import run_scene
    from .progress import Progress
    from .scene import load_scene
    from .table import format_table

    scene = load_scene(args.scene)
    if args.output:
        from pathlib import Path

        scene.output_dir = Path(args.output)
    if args.no_hdf5:
        scene.write_hdf5 = False
    progress = Progress(enabled=not args.quiet)
    result = run_scene(scene, progress=progress)
    if scene.plot and not args.no_plot:
        try:
            from .plots import plot_mode_shapes

            path = plot_mode_shapes(result, scene.output_dir / f"{scene.output_name}_modes.png")
            if path is not None:
                result.extra_files.append(str(path))
        except ImportError as exc:  # matplotlib missing: results are still there
            print(f"warning: no figure ({exc})", file=sys.stderr)
    if args.json:
        print(result.to_json(indent=None if args.compact else 2))
    else:
        print(format_table(result))
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from .sweep import load_sweep, run_sweep

    sweep = load_sweep(args.file)
    say = (lambda s: None) if args.quiet else (lambda s: print(f"[stepnf] {s}", file=sys.stderr, flush=True))
    rep = run_sweep(sweep, scheduler=args.scheduler, n_workers=args.workers, retry_failed=args.retry_failed,
                    progress=say)
    from .sweep import read_store

    failed = sorted(cid for cid, rec in read_store(sweep.store).items() if rec.get("status") != "done")
    print(f"sweep {sweep.name}: {len(rep.done) + len(rep.failed)} cases run ({len(rep.done)} done, "
          f"{len(rep.failed)} failed), {len(rep.skipped)} already stored; store {sweep.store}")
    if failed:
        print(f"failed cases in the store: {failed} (rerun with --retry-failed)")
    return 0 if not failed else 4


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="stepnf", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="compute what a scene asks for")
    p_run.add_argument("scene", help="scene file (TOML)")
    p_run.add_argument("--json", action="store_true", help="print one JSON document on stdout instead of the table")
    p_run.add_argument("--compact", action="store_true", help="JSON on one line")
    p_run.add_argument("--quiet", "-q", action="store_true", help="no progress messages on stderr")
    p_run.add_argument("--output", "-o", help="output folder (overrides [output] dir)")
    p_run.add_argument("--no-hdf5", action="store_true", help="do not write the HDF5 file")
    p_run.add_argument("--no-plot", action="store_true", help="do not draw figures")
    p_run.set_defaults(func=_cmd_run)
    p_sw = sub.add_parser("sweep", help="run every case of a sweep file on Dask (resumable)")
    p_sw.add_argument("file", help="sweep file (TOML)")
    p_sw.add_argument("--scheduler", help="address of an existing dask.distributed scheduler")
    p_sw.add_argument("--workers", type=int, help="local cluster size")
    p_sw.add_argument("--retry-failed", action="store_true", help="run again the cases stored as failed")
    p_sw.add_argument("--quiet", "-q", action="store_true")
    p_sw.set_defaults(func=_cmd_sweep)
    p_sol = sub.add_parser("solvers", help="list the installed solver adapters")
    p_sol.set_defaults(func=_cmd_solvers)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (SceneError, UnknownSolverError) as exc:
        print(f"stepnf: error: {exc}", file=sys.stderr)
        return 2
    except (SolverRunError, NumericalError) as exc:
        print(f"stepnf: solver failure: {exc}", file=sys.stderr)
        return 3
    except StepnfError as exc:
        print(f"stepnf: error: {exc}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("stepnf: interrupted; results already written are intact", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
