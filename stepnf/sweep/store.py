"""The sweep store: one HDF5 file of finished cases, each keyed by the model that computed it.

One group per case (``/cases/<id>``) with attributes: ``status`` (``done`` or ``failed``), ``params``
(the varied values, JSON), ``result`` (the case's JSON document) or ``error``, ``elapsed``, and, since
issue 29, ``key`` (the SHA-256 :func:`stepnf.scene.model_key.digest` of the case's
:func:`~stepnf.scene.model_key.scene_key`: its resolved scene and the content of every input file) and
``inputs`` (that key as JSON, so a rerun can say what changed). Root attributes ``format =
"stepnf-sweep"``, ``format_version = 1`` (stores without a version, written by earlier stepnf, have
the same layout), ``sweep`` (name, file, case ids).

A store never mixes models (:func:`stale_cases`): a stored case whose key is not the key its case has
now (the base scene names another model file, a file's content changed, a scene key changed, the
adapter was upgraded) is *stale*, and so is a case stored without a key (by an earlier stepnf: of
which model cannot be told) and a stored case no longer in the sweep whose recorded input files
changed. :func:`stepnf.sweep.dask_sweep.run_sweep` refuses a store with stale cases (exit 2, naming the store and
what changed) unless asked to compute them again (``stepnf sweep --recompute-stale``), which replaces
them and removes the stale cases no longer in the sweep. Refusing by default keeps hours of stored
results from being replaced by a mistaken edit; recomputing silently would hide that the results changed.

Only the sweep's client writes the store, and every write builds the new store in memory and writes it
atomically (:mod:`stepnf.io.atomic`), so a killed sweep or a full disk leaves the previous, complete store.
"""
from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

from stepnf.errors import StoreError
from stepnf.scene.model_key import describe_change, digest, input_sha256

STORE_FORMAT = "stepnf-sweep"
STORE_FORMAT_VERSION = 1  # stores written before versions existed have the same layout


def read_store(path: str | Path) -> dict[str, dict[str, Any]]:
    """Stored cases by id: ``{"status", "params", "result" (dict) or "error", "elapsed"}``."""
    import h5py

    path = Path(path)
    if not path.exists():
        return {}
    out: dict[str, dict[str, Any]] = {}
    try:
        with h5py.File(path, "r") as f:
            _check_store(f, path)
            for cid, g in f.get("cases", {}).items():
                rec = {k: g.attrs[k] for k in g.attrs}
                for k in ("params", "result"):
                    if k in rec:
                        rec[k] = json.loads(rec[k])
                        if not isinstance(rec[k], dict):
                            raise TypeError(f"case {cid}: {k} holds a {type(rec[k]).__name__}, not a table")
                out[cid] = rec
    except (OSError, KeyError, ValueError, TypeError, AttributeError, RecursionError) as exc:  # ValueError: JSON
        raise StoreError(f"{path}: the sweep store is unreadable (corrupt or truncated): {exc}; "
                         "it was left untouched") from exc
    return out


def _check_store(f: Any, path: Path) -> int:
    from stepnf.io.atomic import check_format

    try:
        return check_format(f.attrs, path, format=STORE_FORMAT, version=STORE_FORMAT_VERSION, what="sweep store")
    except StoreError as exc:
        if "not a stepnf" in str(exc):
            raise StoreError(f"{exc}; move it away or choose another [output] dir / [sweep] name") from None
        raise


def write_case(path: Path, case_id: str, record: Mapping[str, Any], sweep_info: Mapping[str, Any]) -> None:
    """Add one case to the store safely: update a copy in memory, then write it atomically.

    The store is read, updated in memory and written by :func:`stepnf.io.atomic.write_bytes`: a
    failed write (full disk) raises :class:`stepnf.errors.OutputError` and leaves the previous
    store untouched. A store of a newer ``format_version`` is refused (:class:`StoreError`).
    Concurrent writers (two sweeps of one store) are serialised by a lock on the folder.
    """
    path = Path(path)
    with _folder_lock(path.parent):  # two sweeps on one store: no case lost between read and replace
        _write_case_locked(path, case_id, record, sweep_info)


@contextlib.contextmanager
def _folder_lock(folder: Path):
    """Exclusive ``flock`` on the store's folder while a case is added (best effort: no lock if refused).

    The folder itself is locked, not a lock file, so nothing is left beside the store.
    """
    import fcntl

    fd = -1
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        fcntl.flock(fd, fcntl.LOCK_EX)
    except OSError:
        pass  # the write below reports a folder that cannot be used
    try:
        yield
    finally:
        if fd >= 0:
            os.close(fd)  # releases the lock


def _write_case_locked(path: Path, case_id: str | None, record: Mapping[str, Any] | None,
                       sweep_info: Mapping[str, Any], remove: Sequence[str] = ()) -> None:
    from stepnf.io.atomic import hdf5_bytes, write_bytes

    try:
        base = path.read_bytes()
    except FileNotFoundError:
        base = None
    except OSError as exc:
        raise StoreError(f"{path}: cannot read the sweep store: {exc}") from exc

    def fill(f: Any) -> None:
        if base is not None:
            _check_store(f, path)
        f.attrs["sweep"] = json.dumps(sweep_info, default=str)
        cases = f.require_group("cases")
        for cid in remove:
            if cid in cases:
                del cases[cid]
        if case_id is None or record is None:
            return
        if case_id in cases:
            del cases[case_id]
        g = cases.create_group(case_id)
        for k, v in record.items():
            g.attrs[k] = json.dumps(v, default=str) if isinstance(v, (dict, list)) else v

    try:
        data = hdf5_bytes(fill, format=STORE_FORMAT, format_version=STORE_FORMAT_VERSION, base=base)
    except (OSError, KeyError) as exc:
        raise StoreError(f"{path}: the sweep store is unreadable (corrupt or truncated): {exc}; "
                         "it was left untouched") from exc
    write_bytes(path, data, what="sweep store")


def remove_cases(path: Path, case_ids: Sequence[str], sweep_info: Mapping[str, Any]) -> None:
    """Remove cases from the store (one atomic write, as :func:`write_case`)."""
    if case_ids:
        with _folder_lock(Path(path).parent):
            _write_case_locked(Path(path), None, None, sweep_info, remove=case_ids)


def stale_cases(stored: Mapping[str, Mapping[str, Any]], keys: Mapping[str, Mapping[str, Any]]
                ) -> tuple[dict[str, str], dict[str, str]]:
    """The stale cases of a store (see the module docstring), each with what changed.

    ``stored``: :func:`read_store`; ``keys``: the sweep's case ids -> their keys now
    (:func:`stepnf.scene.model_key.scene_key`). Returns ``(stale cases of the sweep, stale stored cases no
    longer in the sweep)``, both ``{id: what changed}``.
    """
    stale, gone = {}, {}
    for cid, rec in stored.items():
        old = _inputs(rec)
        if cid in keys:
            if rec.get("key") != digest(keys[cid]):
                stale[cid] = describe_change(old, keys[cid])
        elif old is None:
            gone[cid] = describe_change(None, {})
        else:
            try:
                changed = [f"{k} {f.get('path')} changed" for k, f in sorted((old.get("files") or {}).items())
                           if _sha_now(f.get("path")) != f.get("sha256")]
            except (AttributeError, TypeError):  # a recorded key edited into another shape
                changed = ["its recorded key is damaged (edited by hand?)"]
            if changed:
                gone[cid] = "; ".join(changed)
    return stale, gone


def _inputs(rec: Mapping[str, Any]) -> dict[str, Any] | None:
    """The key a case was stored with (``None``: none recorded, or unreadable)."""
    try:
        old = json.loads(rec["inputs"]) if isinstance(rec.get("inputs"), str) else None
    except ValueError:
        return None
    return old if isinstance(old, dict) else None


def _sha_now(path: Any) -> str | None:
    """What the key would record now for a recorded input file or folder (:func:`stepnf.scene.model_key.input_sha256`:
    a device, a FIFO or a file under /proc, /sys, /dev an edited store names is never read); ``None`` for a
    recorded path that is no path."""
    try:
        return input_sha256(Path(path))
    except TypeError:
        return None
