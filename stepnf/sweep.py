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

``stepnf sweep FILE`` runs every case not yet stored. The store is one HDF5
file with one group per case (``/cases/<id>``: status ``done`` or ``failed``,
the parameters, the case's JSON result or its error). Only this process (the
client) writes it, and every write goes to a copy that then replaces the file
(``os.replace``), so a killed sweep leaves the previous, complete store: a
rerun resumes where it stopped and never recomputes a stored case (failed
cases are retried only with ``--retry-failed``).
"""
from __future__ import annotations

import copy
import itertools
import json
import logging
import os
import shutil
import tempfile
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from .errors import SceneError, StoreError, allowed

SWEEP_KEYS = ("name", "base", "vary", "scenes", "dask")
DASK_KEYS = ("scheduler", "n_workers", "threads_per_worker")


@dataclass
class Case:
    """One scene of a sweep: its id, the parameters that define it and the scene data."""

    id: str
    params: dict[str, Any]
    data: dict[str, Any]
    file: str
    base_dir: str


@dataclass
class Sweep:
    name: str
    cases: list[Case]
    store: Path
    scheduler: str | None = None
    n_workers: int | None = None
    threads_per_worker: int = 1
    file: Path | None = None


def _set(data: dict, dotted: str, value: Any) -> None:
    keys = dotted.split(".")
    d = data
    for k in keys[:-1]:
        d = d.setdefault(k, {})
        if not isinstance(d, dict):
            raise KeyError(dotted)
    d[keys[-1]] = value


def _fmt(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def load_sweep(path: str | Path) -> Sweep:
    """Read a sweep file and expand its cases (each validated as a scene)."""
    from .scene import parse_scene

    path = Path(path).resolve()
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as exc:
        raise SceneError(path, None, f"cannot read the sweep file: {exc.strerror or exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(path, None, f"not valid TOML: {exc}") from exc
    sw = raw.get("sweep")
    if not isinstance(sw, Mapping):
        raise SceneError(path, "sweep", "missing table [sweep] (with base + vary, or scenes)")
    for k in sw:
        if k not in SWEEP_KEYS:
            raise SceneError(path, f"sweep.{k}", f"unknown key; allowed keys: {allowed(SWEEP_KEYS)}")
    name = sw.get("name", path.stem)
    cases: list[Case] = []
    if "scenes" in sw:
        if "base" in sw or "vary" in sw:
            raise SceneError(path, "sweep.scenes", "give either scenes or base + vary, not both")
        for i, s in enumerate(sw["scenes"]):
            sp = (path.parent / s).resolve()
            try:
                data = tomllib.loads(sp.read_text())
            except (OSError, tomllib.TOMLDecodeError) as exc:
                raise SceneError(path, f"sweep.scenes[{i}]", f"cannot read scene {sp}: {exc}") from exc
            cases.append(Case(sp.stem, {"scene": str(sp)}, data, str(sp), str(sp.parent)))
    else:
        if "base" not in sw:
            raise SceneError(path, "sweep.base", "missing: the base scene the parameters vary")
        bp = (path.parent / sw["base"]).resolve()
        try:
            base = tomllib.loads(bp.read_text())
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise SceneError(path, "sweep.base", f"cannot read the base scene {bp}: {exc}") from exc
        vary = sw.get("vary", {})
        if not isinstance(vary, Mapping) or not all(isinstance(v, list) and v for v in vary.values()):
            raise SceneError(path, "sweep.vary", "expected a table of dotted scene keys -> non-empty lists")
        keys = list(vary)
        for values in itertools.product(*(vary[k] for k in keys)):
            data = copy.deepcopy(base)
            params = dict(zip(keys, values))
            for k, v in params.items():
                try:
                    _set(data, k, v)
                except KeyError:
                    raise SceneError(path, f"sweep.vary.{k}", "this key crosses a value that is not a table")
            cid = "_".join(f"{k.split('.')[-1]}={_fmt(v)}" for k, v in params.items()) or "base"
            cases.append(Case(cid, params, data, str(bp), str(bp.parent)))
    if len({c.id for c in cases}) != len(cases):
        raise SceneError(path, "sweep", "two cases have the same parameters")
    for c in cases:  # fail early, before any worker starts
        try:
            parse_scene(c.data, file=Path(c.file), base_dir=Path(c.base_dir))
        except SceneError as exc:
            raise SceneError(path, "sweep", f"case {c.id}: {exc}") from exc
    out = raw.get("output", {})
    d = Path(out.get("dir", "results"))
    store = (d if d.is_absolute() else path.parent / d) / f"{name}.h5"
    dk = sw.get("dask", {})
    for k in dk:
        if k not in DASK_KEYS:
            raise SceneError(path, f"sweep.dask.{k}", f"unknown key; allowed keys: {allowed(DASK_KEYS)}")
    return Sweep(name, cases, store, dk.get("scheduler"), dk.get("n_workers"),
                 int(dk.get("threads_per_worker", 1)), path)


# ------------------------------------------------------------------ the store
def read_store(path: str | Path) -> dict[str, dict[str, Any]]:
    """Stored cases by id: ``{"status", "params", "result" (dict) or "error", "elapsed"}``."""
    import h5py

    path = Path(path)
    if not path.exists():
        return {}
    out: dict[str, dict[str, Any]] = {}
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != "stepnf-sweep":
                raise StoreError(f"{path}: not a stepnf sweep store; move it away or choose another "
                                 "[output] dir / [sweep] name")
            for cid, g in f.get("cases", {}).items():
                rec = {k: g.attrs[k] for k in g.attrs}
                for k in ("params", "result"):
                    if k in rec:
                        rec[k] = json.loads(rec[k])
                out[cid] = rec
    except (OSError, KeyError, json.JSONDecodeError) as exc:
        raise StoreError(f"{path}: the sweep store is unreadable (corrupt or truncated): {exc}; "
                         "it was left untouched") from exc
    return out


def write_case(path: Path, case_id: str, record: Mapping[str, Any], sweep_info: Mapping[str, Any]) -> None:
    """Add one case to the store safely: write a copy, then replace the file."""
    import h5py

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        if path.exists():
            shutil.copyfile(path, tmp)
            mode = "a"
        else:
            mode = "w"
        with h5py.File(tmp, mode) as f:
            f.attrs["format"] = "stepnf-sweep"
            f.attrs["sweep"] = json.dumps(sweep_info, default=str)
            cases = f.require_group("cases")
            if case_id in cases:
                del cases[case_id]
            g = cases.create_group(case_id)
            for k, v in record.items():
                g.attrs[k] = json.dumps(v, default=str) if isinstance(v, (dict, list)) else v
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


# ------------------------------------------------------------------ execution
def run_case(data: dict, file: str, base_dir: str) -> dict:
    """Worker task: run one scene and return its JSON document (nothing written by the worker)."""
    from .pipeline import run_scene
    from .scene import parse_scene

    logging.getLogger("distributed").setLevel(logging.WARNING)  # in the worker too
    scene = parse_scene(data, file=Path(file), base_dir=Path(base_dir))
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


def run_sweep(sweep: Sweep, *, scheduler: str | None = None, n_workers: int | None = None,
              retry_failed: bool = False, progress: Callable[[str], None] | None = None) -> SweepReport:
    """Run every case not yet stored on Dask; store each one as it finishes."""
    from dask.distributed import Client, LocalCluster, as_completed

    say = progress or (lambda s: None)
    stored = read_store(sweep.store)
    report = SweepReport()
    todo = []
    for c in sweep.cases:
        rec = stored.get(c.id)
        if rec is not None and (rec.get("status") == "done" or not retry_failed):
            report.skipped.append(c.id)
        else:
            todo.append(c)
    info = {"name": sweep.name, "file": str(sweep.file), "cases": [c.id for c in sweep.cases]}
    say(f"sweep {sweep.name}: {len(sweep.cases)} cases, {len(report.skipped)} already stored, "
        f"{len(todo)} to run -> {sweep.store}")
    if not todo:
        return report
    address = scheduler or sweep.scheduler
    # Dask's own INFO chatter (event-loop warnings while FE workers compute) would bury the progress
    logging.getLogger("distributed").setLevel(logging.WARNING)
    cluster = None
    if address:
        client = Client(address)
    else:
        cluster = LocalCluster(n_workers=n_workers or sweep.n_workers or min(len(todo), os.cpu_count() or 1),
                               threads_per_worker=sweep.threads_per_worker, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        futures = {client.submit(run_case, c.data, c.file, c.base_dir, key=f"stepnf-{sweep.name}-{c.id}",
                                 pure=False): c for c in todo}
        running = len(futures)
        for fut in as_completed(futures):
            c = futures[fut]
            running -= 1
            if fut.status == "finished":
                doc = fut.result()
                write_case(sweep.store, c.id, {"status": "done", "params": c.params, "result": doc,
                                               "elapsed": float(doc.get("elapsed", 0.0))}, info)
                report.done.append(c.id)
            else:
                exc = fut.exception()
                write_case(sweep.store, c.id, {"status": "failed", "params": c.params,
                                               "error": f"{type(exc).__name__}: {exc}"}, info)
                report.failed.append(c.id)
            total = len(sweep.cases)
            ndone = len(report.done) + len([s for s in report.skipped if stored[s].get("status") == "done"])
            say(f"sweep {sweep.name}: {ndone}/{total} done, {running} running, "
                f"{len(report.failed)} failed  (last: {c.id})")
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return report
