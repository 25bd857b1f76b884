"""Where FEniCSx compiles its forms, and compiling without a word on the terminal (any dolfinx version).

:func:`cache_dir` picks the form cache folder; :func:`quiet_jit` silences the
just-in-time compilation. The version-specific part (the name of dolfinx's
table of default JIT options) is :func:`stepnf_fenicsx._compat.jit_defaults`,
which hands the table in.
"""
from __future__ import annotations

import contextlib
import functools
import io
import logging
import os
import sys
import tempfile
import warnings
from pathlib import Path

from stepnf.io.atomic import private_folder


def cache_dir() -> Path:
    """Folder of FEniCSx's form-compilation cache, created and tested writable (a probe file).

    ``$STEPNF_CACHE_DIR/fenicsx`` when that variable is set (an :class:`OutputError`
    naming it if no file can be written there); else ``<repository>/.cache/fenicsx``
    when the adapter runs from a writable source checkout; else
    ``$XDG_CACHE_HOME/stepnf/fenicsx`` (``~/.cache/stepnf/fenicsx``); else, with one
    :class:`OutputWarning`, ``<temporary folder>/stepnf-<uid>/fenicsx`` (a read-only
    image run by a user without a writable home). Resolved once per environment.

    The cache holds compiled ``.so`` files the next run loads, so it must be the user's
    alone (:func:`stepnf.io.atomic.private_folder`): folders made for it are created 0700 whatever the
    umask, and a folder (or its parent) that belongs to another user or is group- or
    world-writable is not used: an error for ``STEPNF_CACHE_DIR``, else the next
    candidate with one :class:`OutputWarning` (in the temporary folder, a fresh
    ``stepnf-<uid>-XXXX`` made by :func:`tempfile.mkdtemp`).
    """
    env = os.environ.get("STEPNF_CACHE_DIR")
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    try:
        tmp = tempfile.gettempdir()
    except FileNotFoundError:  # no writable temporary folder at all: the message names STEPNF_CACHE_DIR
        tmp = None
    return _resolve_cache(env or None, xdg, tmp)


@functools.lru_cache(maxsize=None)
def _resolve_cache(env: str | None, xdg: str, tmp: str | None) -> Path:
    from stepnf.errors import OutputError, OutputWarning

    if env is not None:
        path = Path(env).expanduser() / "fenicsx"
        why, unsafe = private_folder(path)
        if why or unsafe:
            raise OutputError(f"STEPNF_CACHE_DIR={env}: the FEniCSx form cache {path} is not usable "
                              f"({why or unsafe}); set STEPNF_CACHE_DIR to a writable folder or unset it", path=path)
        return path
    refused = []  # caches writable by others: said in the warning of the one used instead
    repo = Path(__file__).resolve().parents[3]
    if (repo / "stepnf").is_dir() and (repo / "solvers").is_dir():
        why, unsafe = private_folder(repo / ".cache" / "fenicsx")
        if not why and not unsafe:
            return repo / ".cache" / "fenicsx"
        refused += [unsafe] if unsafe else []
    home = Path(xdg).expanduser() / "stepnf" / "fenicsx"
    why_home, unsafe = private_folder(home)
    refused += [unsafe] if unsafe else []
    if not why_home and not unsafe:
        if refused:
            _warn(f"form cache: {refused[0]}: not used (another user could put code in it); using {home}",
                  OutputWarning)
        return home
    if tmp is None:
        raise OutputError(f"no writable folder for the FEniCSx form cache: {why_home or unsafe}; no writable "
                          "temporary folder either; set STEPNF_CACHE_DIR to a writable folder", path=home)
    uid = os.getuid() if hasattr(os, "getuid") else os.getpid()
    path = Path(tmp) / f"stepnf-{uid}" / "fenicsx"
    why, unsafe_tmp = private_folder(path)
    if why or unsafe_tmp:  # another user's folder in /tmp, or one others can write: a fresh one of our own
        try:
            path = Path(tempfile.mkdtemp(prefix=f"stepnf-{uid}-", dir=tmp)) / "fenicsx"
        except OSError as exc:
            why = why or f"cannot create a folder in {tmp}: {exc.strerror or exc}"
        else:
            why, unsafe_tmp = private_folder(path)
            why = why or unsafe_tmp
    if why:
        raise OutputError(f"no writable folder for the FEniCSx form cache: {why_home or unsafe}; {why}; "
                          "set STEPNF_CACHE_DIR to a writable folder", path=home)
    if refused:
        _warn(f"form cache: {refused[0]}: not used (another user could put code in it); using {path}",
              OutputWarning)
    else:
        _warn(f"form cache: {home} not writable ({why_home}), using {path}", OutputWarning)
    return path


def _warn(text: str, category: type[Warning]) -> None:
    plain_warnings()
    warnings.warn(text, category, stacklevel=4)


@contextlib.contextmanager
def quiet_jit(defaults: dict | None = None):
    """Compile in :func:`cache_dir` without a word on the terminal.

    Forms AND elements (at mesh and function-space creation) are compiled on
    first use. Three kinds of chatter are silenced: (1) INFO lines ("running
    build_ext", the gcc command lines): the build logs through the root logger,
    to which dolfinx attached a handler, and lowers that logger's level itself
    (distutils' ``set_threshold``), so a filter on the root logger drops what is
    below WARNING, and the level is put back afterwards; (2) what gcc or a C
    library prints on the process's own stdout/stderr (file descriptors 1 and 2,
    redirected to a temporary file meanwhile; its text is attached to an
    exception raised in the block, so a failed compilation still says why);
    (3) Python warnings are kept and shown after the block. dolfinx's default
    cache folder (``~/.cache/fenics``, used for elements) is :func:`cache_dir`
    meanwhile, so a read-only home does not matter.
    """
    folder = cache_dir()  # before the redirection: its warning must reach the user
    root = logging.getLogger()
    level = root.level
    drop_info = _BelowWarning()
    root.addFilter(drop_info)
    saved = defaults.get("cache_dir") if defaults is not None else None
    if saved is not None:
        defaults["cache_dir"] = (folder, *saved[1:])
    try:
        with warnings.catch_warnings(record=True) as caught, _silent_fds() as captured:
            try:
                yield
            except BaseException as exc:
                text = _read_tail(captured)
                if text and hasattr(exc, "add_note"):
                    exc.add_note(f"output of the just-in-time compilation:\n{text}")
                raise
    finally:
        if saved is not None:
            defaults["cache_dir"] = saved
        root.removeFilter(drop_info)
        root.setLevel(level)
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)


@functools.lru_cache(maxsize=None)
def plain_warnings() -> None:
    """Undo ``logging.captureWarnings(True)`` done by ``import ffcx``: it showed every warning of a
    run as ``WARNING:py.warnings:...`` through the root logger instead of stepnf's own line."""
    with contextlib.suppress(ImportError):
        import ffcx  # noqa: F401
        logging.captureWarnings(False)


@contextlib.contextmanager
def _silent_fds():
    """Point file descriptors 1 and 2 to a temporary file (yielded) for the block's duration."""
    for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
        with contextlib.suppress(Exception):
            stream.flush()
    try:
        sink = tempfile.TemporaryFile()
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no file descriptors to spare: chatter is better than a failure
        yield None, None
        return
    text = io.StringIO()  # what Python code prints (sys.stdout may be a wrapper that is no file descriptor)
    try:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
            yield sink, text
    finally:
        for stream in (sys.__stdout__, sys.__stderr__):
            with contextlib.suppress(Exception):
                stream.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])
        sink.close()


def _read_tail(captured, limit: int = 4000) -> str:
    sink, text = captured
    if sink is None:
        return ""
    out = text.getvalue()
    with contextlib.suppress(OSError):
        sink.seek(0)
        out = sink.read().decode("utf-8", "replace") + out
    return out[-limit:].strip()


class _BelowWarning(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno >= logging.WARNING


