"""What determines a stored result: the key under which checkpoints and sweep stores keep it.

A stored result (the forces of a checkpoint chunk, a sweep case) may be reused only by a run that
would compute the same thing. That is decided by a *key*, a JSON-able dict with a SHA-256
:func:`digest`:

- ``solver`` and ``adapter``: the solver name and the class that computes (module, class and the
  version of the distribution that ships it, so an upgraded adapter is another model);
- ``model``: the resolved ``[model]`` table, dotted keys -> values, as the solver's own
  :meth:`~stepnf.keys.schema.FromScene.validate_config` checks them (file paths made absolute, a
  generated cap's geometry completed) with the declared defaults of the keys not given filled in;
  the run settings that say how a solver runs and not what it computes (:data:`RUN_SETTINGS`:
  time-out, work folder, kept folders, parallel runs, threads, cores, memory) are left out, so a
  rerun with a longer time-out still resumes;
- ``files``: the SHA-256 of the content of every input file the scene names: every value of a
  key the solver declares as a ``file`` or ``folder`` (a folder: every file under it, with its
  relative path); the heavy-data files an XDMF file (``.xdmf``, ``.xmf``) references
  (``model.mesh.data[0]``: the ``.h5`` beside a mesh, :func:`xdmf_data_files`); and every file the
  adapter's :meth:`~stepnf.keys.schema.FromScene.input_files` lists (CalculiX: the files a deck or mesh
  ``*INCLUDE`` s). Nothing else is read: another string that happens to name a file is a value like
  any other (an adapter whose model reads more lists it in ``input_files``), and only regular files
  and folders outside ``/proc``, ``/sys`` and ``/dev`` are read (:func:`input_sha256`: a device, a
  FIFO or ``/proc/kcore`` is recorded as not read). What the key cannot see (another build of the
  same adapter version, a solver executable upgraded in place) is what the checkpoint's probe
  catches (:mod:`stepnf.step.checkpoint`);
- ``analysis`` (:func:`scene_key` only): every ``[analysis]`` value after defaults.

A checkpoint holds forces of prescribed displacement fields: they depend on the model alone (which
fields are asked for is the business of each chunk's fingerprint), so it is keyed by
:func:`model_key` and a rerun that adds a method still resumes. A sweep case holds the whole
result, so it is keyed by :func:`scene_key` (``[output]`` decides where results go, not what they
are, and is left out). :func:`describe_change` says in a few words what differs between two keys.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import stat
import time
from pathlib import Path
from typing import Any, Mapping

from stepnf.io.canonical import dumps  # the key as canonical JSON: what digest hashes, what a store keeps
from stepnf.keys.schema import Schema

#: Version of the key's layout: a key of another version is another key.
KEY_VERSION = 1
#: ``[model]`` keys that say how a solver is run, not what it computes (stepnf.external.keys).
RUN_SETTINGS = ("timeout", "workdir", "keep", "parallel_runs", "threads", "ncpus", "memory_mb")
#: Scene fields that are not ``[analysis]`` values (the model, where results go, the file itself, the
#: user's permission to run programs); any other field, one added later included, enters the key.
_NOT_ANALYSIS = ("solver", "model", "output_dir", "output_name", "write_hdf5", "plot", "fields", "file",
                 "base_dir", "text", "allow_programs")
_INCLUDED: dict[tuple, list[Path]] = {}  # (adapter, files the scene names) -> the files they include
_HASHED: dict[tuple, str] = {}  # (path, size, mtime, ctime, inode) -> sha256: a sweep's shared mesh read once
#: Folders whose files are never read as model input (kernel and device files; /proc/kcore is "regular").
SYSTEM_FOLDERS = ("/proc", "/sys", "/dev")
#: Suffixes of XDMF files, whose heavy data (HDF5, binary) lives in other files they name.
XDMF_SUFFIXES = (".xdmf", ".xmf")


def model_key(scene: Any) -> dict[str, Any]:
    """The key of the scene's model (see the module docstring); reads every input file once."""
    from stepnf.plugin.registry import get_solver
    from stepnf.scene.parse import check_model_keys

    cls = get_solver(scene.solver)
    given = check_model_keys(scene)
    checked = dict(given)
    schema = cls.model_schema()
    if schema is not None:
        for k in schema:
            if k.name not in checked and k.default is not None:
                checked[k.name] = k.default
    for name in RUN_SETTINGS:
        checked.pop(name, None)
    model = _flatten(_plain(checked), "model")
    files: dict[str, dict[str, str]] = {}
    declared = _declared_paths(schema, "model") if schema is not None else {}
    base = Path(scene.base_dir)
    for dotted, value in model.items():
        kind = _kind_of(declared, dotted)
        if kind not in ("file", "folder") or not isinstance(value, str) or not value or "\n" in value \
                or "\0" in value or len(value) > 4096:
            continue
        p = Path(value) if Path(value).is_absolute() else base / value
        files[dotted] = {"path": str(p), "sha256": input_sha256(p)}
        if kind == "file" and p.suffix.lower() in XDMF_SUFFIXES:
            for i, q in enumerate(xdmf_data_files(p)):
                files[f"{dotted}.data[{i}]"] = {"path": str(q), "sha256": input_sha256(q)}
    for i, p in enumerate(_included(cls, given, files)):
        files[f"include[{i}]"] = {"path": str(p), "sha256": input_sha256(Path(p))}
    return {"key_version": KEY_VERSION, "solver": scene.solver, "adapter": _adapter(cls), "model": model,
            "files": files}


def _included(cls: type, checked: Mapping[str, Any], files: Mapping[str, Mapping[str, str]]) -> list[Path]:
    """The adapter's :meth:`~stepnf.keys.schema.FromScene.input_files` (a deck's includes), cached per adapter and
    content of the files the scene names (a sweep's shared deck is read once)."""
    tag = (cls, tuple(sorted((k, f["path"], f["sha256"]) for k, f in files.items())))
    if tag not in _INCLUDED:
        finder = getattr(cls, "input_files", None)
        _INCLUDED[tag] = [Path(p) for p in finder(checked)] if finder is not None else []
    return _INCLUDED[tag]


def scene_key(scene: Any) -> dict[str, Any]:
    """:func:`model_key` and every ``[analysis]`` value after defaults: the key of a whole result."""
    key = model_key(scene)
    an = {f.name: getattr(scene, f.name) for f in dataclasses.fields(scene) if f.name not in _NOT_ANALYSIS}
    key["analysis"] = _flatten(_plain(an), "analysis")
    return key


def digest(key: Mapping[str, Any]) -> str:
    """SHA-256 of the key's canonical JSON (sorted keys)."""
    return hashlib.sha256(dumps(key).encode("utf-8")).hexdigest()


def describe_change(old: Mapping[str, Any] | None, new: Mapping[str, Any], limit: int = 3) -> str:
    """What differs from ``old`` to ``new``, in a few words ("model.file /x/s.npz changed", ...)."""
    if not isinstance(old, Mapping) or old.get("key_version") != new.get("key_version"):
        return "stored by an earlier stepnf, which did not record the model"
    try:
        return _changes(old, new, limit)
    except (TypeError, AttributeError, KeyError, ValueError):  # a stored key edited into another shape
        return "the stored key is damaged (edited by hand?)"


def _changes(old: Mapping[str, Any], new: Mapping[str, Any], limit: int) -> str:
    """:func:`describe_change` of two keys of the same version (raises on a key of another shape)."""
    out = []
    for what in ("solver", "adapter"):
        if old.get(what) != new.get(what):
            out.append(f"{what} {old.get(what)} -> {new.get(what)}")
    of, nf = old.get("files") or {}, new.get("files") or {}
    for k in sorted(set(of) | set(nf)):
        a, b = of.get(k), nf.get(k)
        if a == b:
            continue
        if a is None or b is None or a.get("path") != b.get("path"):
            out.append(f"{k} names {b['path'] if b else 'no file'} (was {a['path'] if a else 'no file'})")
        else:
            out.append(f"{'' if k.startswith('include[') else k + ' '}{b['path']} changed")
    for part in ("model", "analysis"):
        o, n = old.get(part) or {}, new.get(part) or {}
        for k in sorted(set(o) | set(n)):
            if o.get(k) != n.get(k) and k not in of and k not in nf:
                out.append(f"{k} {_show(o, k)} -> {_show(n, k)}")
    if not out:
        return "another key"
    return "; ".join(out[:limit]) + (f" and {len(out) - limit} more" if len(out) > limit else "")


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's content (cached per path, size, modification time and inode, for files not
    modified in the last 2 s: a file system's clock may tick in milliseconds, a rewrite may keep the size)."""
    st = os.stat(path)
    tag = (str(path), st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)
    if tag in _HASHED:
        return _HASHED[tag]
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    if time.time_ns() - max(st.st_mtime_ns, st.st_ctime_ns) > 2_000_000_000:
        _HASHED[tag] = h.hexdigest()
    return h.hexdigest()


def input_sha256(path: Path) -> str:
    """What the key records for an input file or folder: its :func:`content_sha256`, or
    ``"unreadable: why"`` (missing, no permission), or ``"not read: why"`` for what is no model input:
    neither a regular file nor a folder (a device, a FIFO) or under :data:`SYSTEM_FOLDERS` (links
    followed)."""
    try:
        st = os.stat(path)
    except (OSError, ValueError) as exc:
        return f"unreadable: {getattr(exc, 'strerror', None) or exc}"
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        return "not read: not a regular file or folder"
    if _in_system_folder(path):
        return f"not read: a system file (under {', '.join(SYSTEM_FOLDERS)})"
    try:
        return content_sha256(path)
    except OSError as exc:  # unreadable now: the run will say so when it reads it
        return f"unreadable: {exc.strerror or exc}"


def _in_system_folder(path: Path) -> bool:
    """``path`` (links followed) lies under one of :data:`SYSTEM_FOLDERS` (a loop counts as such)."""
    try:
        real = Path(os.path.realpath(path))
    except (OSError, RuntimeError, ValueError):
        return True
    return any(real == Path(s) or Path(s) in real.parents for s in SYSTEM_FOLDERS)


def xdmf_data_files(path: Path) -> list[Path]:
    """The files an XDMF file's ``DataItem`` s keep their data in (``Format="HDF"``: ``mesh.h5:/data0``;
    ``Format="Binary"``: a file name), relative to the XDMF file's folder as meshio reads them; in order,
    once each. An unreadable or malformed file names none (the run will say why it cannot read it)."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError, ValueError):
        return []
    out: dict[Path, None] = {}
    for item in root.iter():
        fmt = item.get("Format", "")
        if not str(item.tag).endswith("DataItem") or fmt not in ("HDF", "Binary") or not (item.text or "").strip():
            continue
        name = item.text.strip().split(":")[0] if fmt == "HDF" else item.text.strip()
        if name and "\0" not in name:
            out[path.parent / name] = None
    return list(out)


def content_sha256(path: Path) -> str:
    """SHA-256 of a file's content, or over every file under a folder (its relative path and content;
    only regular files outside :data:`SYSTEM_FOLDERS`, a link to /proc/kcore in a folder is not read)."""
    if not path.is_dir():
        return file_sha256(path)
    folder = path
    h = hashlib.sha256()
    for p in sorted(q for q in folder.rglob("*") if q.is_file() and not _in_system_folder(q)):
        h.update(f"{p.relative_to(folder).as_posix()}\0{file_sha256(p)}\n".encode("utf-8", "surrogatepass"))
    return h.hexdigest()


def _show(values: Mapping[str, Any], k: str) -> str:
    return json.dumps(values[k], default=str) if k in values else "(not given)"


def _adapter(cls: type) -> str:
    """``module.Class distribution version`` of the adapter class (the distribution if it is installed)."""
    return f"{cls.__module__}.{cls.__qualname__}{_distribution(cls.__module__.split('.')[0])}"


@functools.lru_cache(maxsize=None)
def _distribution(top: str) -> str:
    """`` name version`` of the installed distribution providing the top-level module ``top`` ("" if none);
    cached: reading every distribution's metadata takes 0.2 s, a sweep asks once per case."""
    from importlib import metadata

    try:
        dists = metadata.packages_distributions().get(top, [])
        return f" {dists[0]} {metadata.version(dists[0])}" if dists else ""
    except Exception:  # noqa: BLE001 - broken metadata: the class alone names the adapter
        return ""


def _declared_paths(schema: Schema, where: str) -> dict[str, str]:
    """Dotted key -> kind, for the keys of ``schema`` (nested tables too; arrays of tables as ``key[]``)."""
    out = {}
    for k in schema:
        dotted = f"{where}.{k.name}"
        out[dotted] = k.kind
        if k.table is not None:
            out.update(_declared_paths(k.table, dotted + ("[]" if k.kind == "tables" else "")))
    return out


def _kind_of(declared: Mapping[str, str], dotted: str) -> str | None:
    """The declared kind of a flattened key (``model.boundary[2].set`` is ``model.boundary[].set``)."""
    import re

    return declared.get(re.sub(r"\[\d+\]", "[]", dotted))


def _plain(v: Any) -> Any:
    """``v`` as JSON values: paths as text, tuples and arrays as lists, dataclasses as dicts."""
    if isinstance(v, Mapping):
        return {("null" if k is None else str(k)): _plain(x) for k, x in v.items()}
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {f.name: _plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
    if isinstance(v, (list, tuple, set, frozenset)):
        items = [_plain(x) for x in v]
        return sorted(items, key=repr) if isinstance(v, (set, frozenset)) else items
    if isinstance(v, Path):
        return str(v)
    if hasattr(v, "tolist"):  # numpy arrays and scalars
        return _plain(v.tolist())
    if isinstance(v, float) and not math.isfinite(v):
        return repr(v)
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    return repr(v)


def _flatten(v: Any, where: str) -> dict[str, Any]:
    """Nested dicts and lists of dicts -> dotted keys (``model.boundary[0].set``) -> leaf values."""
    out: dict[str, Any] = {}
    if isinstance(v, dict) and v:
        for k, x in v.items():
            out.update(_flatten(x, f"{where}.{k}"))
    elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
        for i, x in enumerate(v):
            out.update(_flatten(x, f"{where}[{i}]"))
    else:
        out[where] = v
    return out
