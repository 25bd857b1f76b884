"""Sweeps: many scenes run on Dask, each finished case stored at once, resumable.

A sweep file (TOML) names a base scene and the parameters to vary (their
cartesian product), or lists scenes::

    [sweep]
    name = "table2"                       # store: <output dir>/<name>.h5
    base = "shell_kappa25.toml"           # relative to the sweep file
    [sweep.vary]                          # dotted scene keys -> values
    "model.geometry.R" = [3.5, 2.5, 1.5]
    "model.geometry.h" = [0.001, 0.003]
    # or: scenes = ["a.toml", "b.toml"]   (instead of base/vary)
    [sweep.dask]
    scheduler = "tcp://10.0.0.5:8786"     # optional: an existing dask.distributed scheduler
    n_workers = 2                          # local cluster size (default: cores)
    threads_per_worker = 1
    [output]
    dir = "results"

Every key is checked when the file is read (:func:`load_sweep`): its type, its range
(``n_workers`` in [1, 1024], ``threads_per_worker`` in [1, 256], at most 10 000 cases),
``name`` a plain file stem (no path separator, not ``..``), and every case as a scene; anything
else is a :class:`~stepnf.errors.SceneError` naming the sweep file and the key, before a worker
starts or the store is touched.

``stepnf sweep FILE`` runs every case not yet stored. The store is one HDF5
file with one group per case (``/cases/<id>``: status ``done`` or ``failed``,
the parameters, the case's JSON result or its error; root attributes
``format = "stepnf-sweep"``, ``format_version = 1``; stores without a version,
written by earlier stepnf, are read as version 1). Only this process (the
client) writes it, and every write builds the new store in memory and writes
it atomically (:mod:`stepnf.io.atomic`), so a killed sweep or a full disk leaves
the previous, complete store: a
rerun resumes where it stopped and never recomputes a stored case (failed
cases are retried only with ``--retry-failed``). Each case is stored with the
key of what determined it (its resolved scene and the content of every input
file, :mod:`stepnf.scene.model_key`): a store never mixes models, and a rerun whose
cases have another key refuses, or with ``recompute_stale`` computes the stale
cases again (:mod:`stepnf.sweep.store`).
"""
from __future__ import annotations

import copy
import itertools
import logging
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from stepnf.keys.checks import check_name, check_number, check_table, check_text, check_unknown, describe_value, read_toml
from stepnf.sweep.dask_address import check_scheduler, unreachable
from stepnf.errors import SceneError, StaleWarning
from stepnf.scene.model_key import digest
from stepnf.sweep.store import (STORE_FORMAT, STORE_FORMAT_VERSION, read_store, remove_cases, stale_cases,  # noqa: F401
                          write_case)

TOP_KEYS = ("sweep", "output")
SWEEP_KEYS = ("name", "base", "vary", "scenes", "dask")
DASK_KEYS = ("scheduler", "n_workers", "threads_per_worker")
OUTPUT_KEYS = ("dir",)
#: Bounds of a sweep file: a sweep stores every case in one HDF5 file rewritten per case, so tens of
#: thousands of cases are already a store of gigabytes written quadratically; a local cluster of more
#: than 1024 processes, or a worker of more than 256 threads, exceeds any single machine.
MAX_CASES = 10_000
MAX_WORKERS = 1024
MAX_THREADS = 256


@dataclass
class Case:
    """One scene of a sweep: its id, the parameters that define it and the scene data."""

    id: str
    params: dict[str, Any]
    data: dict[str, Any]
    file: str
    base_dir: str
    #: What determines the case's result (:func:`stepnf.scene.model_key.scene_key`), set when the sweep is read.
    key: dict[str, Any] | None = None


@dataclass
class Sweep:
    name: str
    cases: list[Case]
    store: Path
    scheduler: str | None = None
    n_workers: int | None = None
    threads_per_worker: int = 1
    file: Path | None = None
    #: The user's permission for programs the scenes name (:mod:`stepnf.runtime.programs`), decided when the sweep
    #: was loaded and passed to every case (workers never decide it again).
    allow_programs: bool = False


def _set(data: dict, dotted: str, value: Any) -> None:
    keys = dotted.split(".")
    d = data
    for k in keys[:-1]:
        d = d.setdefault(k, {})
        if not isinstance(d, dict):
            raise KeyError(dotted)
    d[keys[-1]] = value


def _fmt(v: Any) -> str:
    # "/" separates HDF5 groups and the id names the case's group in the store: spell it %2F
    return (f"{v:g}" if isinstance(v, float) else str(v)).replace("%", "%25").replace("/", "%2F")


def load_sweep(path: str | Path, *, allow_programs: bool | None = None) -> Sweep:
    """Read a sweep file, check every key and expand its cases (each validated as a scene).

    Anything malformed is a :class:`SceneError` naming the sweep file and the key (exit code 2)
    before a worker starts or the store is touched. ``allow_programs``: the user's permission for the
    programs the scenes name (:mod:`stepnf.runtime.programs`; ``None``: the permission in force), kept on the sweep.
    """
    from stepnf.runtime.programs import allow_programs as allowing, programs_allowed

    with allowing(allow_programs):
        sweep = _load_sweep(path)
        sweep.allow_programs = programs_allowed()
    return sweep


def _load_sweep(path: str | Path) -> Sweep:
    path = Path(path).resolve()
    raw, _ = read_toml(path, "sweep")
    check_unknown(path, "", raw, TOP_KEYS)
    if "sweep" not in raw:
        raise SceneError(path, "sweep", "missing table [sweep] (with base + vary, or scenes)")
    sw = check_table(path, "sweep", raw["sweep"], "(with base + vary, or scenes)")
    check_unknown(path, "sweep", sw, SWEEP_KEYS)
    name = check_name(path, "sweep.name", sw["name"]) if "name" in sw else path.stem  # a stem has no '/'
    cases = _listed_cases(path, sw) if "scenes" in sw else _varied_cases(path, sw)
    ids = [c.id for c in cases]
    if len(set(ids)) != len(ids):
        twice = sorted({i for i in ids if ids.count(i) > 1})
        raise SceneError(path, "sweep", f"two cases have the same id {twice[0]!r} (the same parameters, as "
                         "shown with 6 significant digits, or two scenes with the same file name)")
    store = _output_dir(path, raw.get("output", {})) / f"{name}.h5"
    scheduler, n_workers, threads = _dask(path, sw.get("dask", {}))
    return Sweep(name, cases, store, scheduler, n_workers, threads, path)


def _read_scene(path: Path, key: str, name: Any) -> tuple[Path, dict[str, Any]]:
    """The scene file ``name`` (relative to the sweep file), read as TOML; errors name ``key``."""
    sp = (path.parent / check_text(path, key, name, "a scene file name")).resolve()
    try:
        return sp, read_toml(sp, "scene")[0]
    except SceneError as exc:
        raise SceneError(path, key, f"cannot use the scene: {exc}") from exc


def _check_case(path: Path, key: str, case: Case) -> Case:
    """Validate the case's scene now (fail early, before any worker starts) and compute its key."""
    if case.id in ("", ".", "..") or len(case.id.encode("utf-8", "surrogatepass")) > 1000:
        raise SceneError(path, key, f"case id {case.id!r} cannot name a group of the store; rename the scene "
                         "or shorten the values")
    try:
        case_key(case)
    except SceneError as exc:
        raise SceneError(path, key, f"case {case.id}: {exc}") from exc
    return case


def _listed_cases(path: Path, sw: Mapping[str, Any]) -> list[Case]:
    """``scenes = [...]``: one case per scene file."""
    if "base" in sw or "vary" in sw:
        raise SceneError(path, "sweep.scenes", "give either scenes or base + vary, not both")
    scenes = sw["scenes"]
    if not isinstance(scenes, list) or not scenes or len(scenes) > MAX_CASES:
        raise SceneError(path, "sweep.scenes", f"expected a non-empty list (at most {MAX_CASES}) of scene file "
                         f"names, relative to the sweep file; got {describe_value(scenes)}")
    cases = []
    for i, s in enumerate(scenes):
        sp, data = _read_scene(path, f"sweep.scenes[{i}]", s)
        case = Case(sp.stem, {"scene": str(sp)}, data, str(sp), str(sp.parent))
        cases.append(_check_case(path, f"sweep.scenes[{i}]", case))
    return cases


def _vary(path: Path, vary: Any) -> dict[str, list]:
    """``[sweep.vary]``: dotted scene keys -> non-empty lists, at most :data:`MAX_CASES` combinations."""
    if not isinstance(vary, Mapping):
        raise SceneError(path, "sweep.vary", f"expected a table of dotted scene keys -> non-empty lists, "
                         f"got {describe_value(vary)}")
    n = 1
    for k, v in vary.items():
        parts = k.split(".")
        if parts[0] not in ("model", "analysis", "output") or len(parts) < 2 or not all(p.strip() for p in parts):
            raise SceneError(path, f"sweep.vary.{k}", "expected a dotted scene key such as "
                             "\"model.geometry.R\" (starting with model, analysis or output)")
        if not isinstance(v, list) or not v:
            raise SceneError(path, f"sweep.vary.{k}", f"expected a non-empty list of values, got {describe_value(v)}")
        n *= len(v)
    if n > MAX_CASES:
        raise SceneError(path, "sweep.vary", f"{n} combinations; a sweep may have at most {MAX_CASES} cases")
    return dict(vary)


def _varied_cases(path: Path, sw: Mapping[str, Any]) -> list[Case]:
    """``base`` + ``[sweep.vary]``: the cartesian product of the varied values."""
    if "base" not in sw:
        raise SceneError(path, "sweep.base", "missing: the base scene the parameters vary (or give scenes = [...])")
    bp, base = _read_scene(path, "sweep.base", sw["base"])
    vary = _vary(path, sw.get("vary", {}))
    keys = list(vary)
    cases = []
    for values in itertools.product(*(vary[k] for k in keys)):
        data = copy.deepcopy(base)
        params = dict(zip(keys, values))
        for k, v in params.items():
            try:
                _set(data, k, v)
            except KeyError:
                raise SceneError(path, f"sweep.vary.{k}", "this key crosses a value that is not a table") from None
        cid = "_".join(f"{k.split('.')[-1]}={_fmt(v)}" for k, v in params.items()) or "base"
        cases.append(_check_case(path, "sweep.vary" if keys else "sweep.base",
                                 Case(cid, params, data, str(bp), str(bp.parent))))
    return cases


def _output_dir(path: Path, out: Any) -> Path:
    """``[output] dir`` (relative to the sweep file), the folder of the store."""
    check_unknown(path, "output", check_table(path, "output", out, "with dir"), OUTPUT_KEYS)
    d = Path(check_text(path, "output.dir", out.get("dir", "results"), "a folder path"))
    return d if d.is_absolute() else path.parent / d


def _dask(path: Path, dk: Any) -> tuple[str | None, int | None, int]:
    """``[sweep.dask]``: ``(scheduler, n_workers, threads_per_worker)``, each checked."""
    check_unknown(path, "sweep.dask", check_table(path, "sweep.dask", dk), DASK_KEYS)
    scheduler = None
    if "scheduler" in dk:
        scheduler = check_text(path, "sweep.dask.scheduler", dk["scheduler"], "a scheduler address such as "
                          "\"tcp://10.0.0.5:8786\"")
        check_scheduler(path, "sweep.dask.scheduler", scheduler)
        from stepnf.runtime.programs import check_allowed  # Dask unpickles the cluster's answers: code the file's cluster sends

        check_allowed(path, "sweep.dask.scheduler", f"scheduler = {scheduler!r}: the sweep file names the Dask "
                      "cluster whose answers stepnf unpickles (runs); or give it with --scheduler")
    n_workers = None
    if "n_workers" in dk:
        n_workers = int(check_number(path, "sweep.dask.n_workers", dk["n_workers"], integer=True, lo=1,
                                     hi=MAX_WORKERS, why=" (worker processes of the local cluster)"))
    threads = int(check_number(path, "sweep.dask.threads_per_worker", dk.get("threads_per_worker", 1),
                               integer=True, lo=1, hi=MAX_THREADS))
    return scheduler, n_workers, threads


# ------------------------------------------------------------------ execution
def run_case(data: dict, file: str, base_dir: str, allow_programs: bool = False) -> dict:
    """Worker task: run one scene and return its JSON document (nothing written by the worker).

    ``allow_programs``: the permission the user gave where the sweep started (:mod:`stepnf.runtime.programs`),
    whatever the worker's environment says."""
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import parse_scene

    logging.getLogger("distributed").setLevel(logging.WARNING)  # in the worker too
    scene = parse_scene(data, file=Path(file), base_dir=Path(base_dir), allow_programs=bool(allow_programs))
    t0 = time.perf_counter()
    res = run_scene(scene, write=False)
    doc = res.to_dict()
    doc["elapsed"] = time.perf_counter() - t0
    return doc


@dataclass
class SweepReport:
    done: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    stale: list[str] = field(default_factory=list)  # stored for another model, computed again


def run_sweep(sweep: Sweep, *, scheduler: str | None = None, n_workers: int | None = None,
              retry_failed: bool = False, recompute_stale: bool = False,
              progress: Callable[[str], None] | None = None) -> SweepReport:
    """Run every case not yet stored on Dask; store each one as it finishes.

    A store holding cases of another model (:func:`stepnf.sweep.store.stale_cases`) is refused with
    a :class:`SceneError` naming the store and what changed, before anything runs or is written;
    with ``recompute_stale`` those cases are computed again (one :class:`StaleWarning` says how many)
    and the stale ones no longer in the sweep are removed.
    """
    from dask.distributed import Client, LocalCluster, as_completed

    say = progress or (lambda s: None)
    stored = read_store(sweep.store)
    info = {"name": sweep.name, "file": str(sweep.file), "cases": [c.id for c in sweep.cases]}
    keys = {c.id: case_key(c) for c in sweep.cases}
    stale, gone = stale_cases(stored, keys)
    if stale or gone:
        _stale(sweep, stale, gone, recompute_stale)
        remove_cases(sweep.store, sorted(gone), info)
    report = SweepReport(stale=sorted(stale))
    todo = []
    for c in sweep.cases:
        rec = stored.get(c.id)
        if rec is not None and c.id not in stale and (rec.get("status") == "done" or not retry_failed):
            report.skipped.append(c.id)
        else:
            todo.append(c)
    say(f"sweep {sweep.name}: {len(sweep.cases)} cases, {len(report.skipped)} already stored, "
        f"{len(todo)} to run -> {sweep.store}")
    if not todo:
        return report
    # the store's folder must take a file: checked before any worker starts
    from stepnf.io.atomic import check_folder

    why = check_folder(sweep.store.parent)
    if why is not None:
        raise SceneError(sweep.file, "output.dir", f"the sweep store's folder {sweep.store.parent} is not "
                         f"usable: {why}")
    address = scheduler or sweep.scheduler
    # Dask's own INFO chatter (event-loop warnings while FE workers compute) would bury the progress
    logging.getLogger("distributed").setLevel(logging.WARNING)
    cluster = None
    if address:
        try:
            client = Client(address)
        except OSError as exc:  # refused, timed out (Dask's "Timed out trying to connect"), unknown host
            raise unreachable(sweep.file, address, scheduler is not None, exc) from exc
    else:
        cluster = LocalCluster(n_workers=n_workers or sweep.n_workers or min(len(todo), os.cpu_count() or 1),
                               threads_per_worker=sweep.threads_per_worker, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        futures = {client.submit(run_case, c.data, c.file, c.base_dir, sweep.allow_programs,
                                 key=f"stepnf-{sweep.name}-{c.id}",
                                 pure=False): c for c in todo}
        running = len(futures)
        for fut in as_completed(futures):
            c = futures[fut]
            running -= 1
            if fut.status == "finished":
                doc = fut.result()
                write_case(sweep.store, c.id, {"status": "done", "params": c.params, "result": doc,
                                               "elapsed": float(doc.get("elapsed", 0.0)),
                                               "key": digest(keys[c.id]), "inputs": keys[c.id]}, info)
                report.done.append(c.id)
            else:
                exc = fut.exception()
                write_case(sweep.store, c.id, {"status": "failed", "params": c.params,
                                               "error": f"{type(exc).__name__}: {exc}",
                                               "key": digest(keys[c.id]), "inputs": keys[c.id]}, info)
                report.failed.append(c.id)
            total = len(sweep.cases)
            ndone = len(report.done) + len([s for s in report.skipped if stored[s].get("status") == "done"])
            say(f"sweep {sweep.name}: {ndone}/{total} done, {running} running, "
                f"{len(report.failed)} failed  (last: {c.id})")
    except KeyboardInterrupt as exc:  # Ctrl-C or a signal (stepnf.runtime.signals): our workers' solver processes too
        if cluster is not None:  # (never on a shared scheduler's workers: other clients' runs are theirs)
            from stepnf.runtime.signals import stop_children

            try:
                client.run(stop_children, getattr(exc, "signum", 2))
            except Exception:  # noqa: BLE001 - a worker already gone: its processes went with it or never were
                pass
        raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return report


def case_key(case: Case) -> dict[str, Any]:
    """The case's key (:func:`stepnf.scene.model_key.scene_key` of its scene): computed here only, once per case
    (kept in ``case.key``; :func:`load_sweep` computes it while checking the case)."""
    from stepnf.scene.model_key import scene_key
    from stepnf.scene.parse import parse_scene

    if case.key is None:
        case.key = scene_key(parse_scene(case.data, file=Path(case.file), base_dir=Path(case.base_dir)))
    return case.key


def _stale(sweep: Sweep, stale: Mapping[str, str], gone: Mapping[str, str], recompute: bool) -> None:
    """Refuse a store with cases of another model (exit 2), or with ``recompute`` say what is computed again."""
    cid, why = next(iter({**stale, **gone}.items()))
    n = len(stale) + len(gone)
    if not recompute:
        raise SceneError(sweep.file, None, f"the sweep store {sweep.store} holds {n} case{'s' * (n != 1)} computed "
                         f"for another model (case {cid}: {why}); a store never mixes models: rerun with "
                         "--recompute-stale to compute them again (their stored results are replaced), or give "
                         "this sweep a new store ([sweep] name or [output] dir)")
    said = []
    if stale:
        sid, swhy = next(iter(stale.items()))
        said.append(f"{len(stale)} stored case{'s' * (len(stale) != 1)} computed for another model recomputed "
                    f"(case {sid}: {swhy})")
    if gone:
        gid, gwhy = next(iter(gone.items()))
        said.append(f"{len(gone)} stale case{'s' * (len(gone) != 1)} no longer in the sweep removed "
                    f"(case {gid}: {gwhy})")
    warnings.warn(f"{sweep.store}: {'; '.join(said)}", StaleWarning, stacklevel=3)
