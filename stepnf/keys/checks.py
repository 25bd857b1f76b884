"""Scene keys: the one TOML reader and one set of typed checks, with one wording.

Every key stepnf reads from a TOML file (a scene's ``[analysis]`` and
``[output]``, a sweep's tables, and each adapter's ``[model]`` table) goes
through these checks, so that a mistake reads the same wherever it is made::

    shell.toml: [model.geometry.h]: must lie in [1e-12, 1e+12] (a length in model units), got -0.003
    plate.toml: [model.fiel]: unknown key (did you mean 'file'?); allowed keys of [model]: ['file', 'solver']
    plate.toml: [model.element]: expected one of ['hex27', 'tet10'], got 'hex8' (a string)

Each check returns the value (a :class:`~pathlib.Path` for files and folders,
a float or an int for numbers) or raises :class:`~stepnf.errors.SceneError`
``(file, key, message)`` (exit code 2): the message says what was expected
and what was given. Adapters declare their keys with
:class:`stepnf.keys.schema.Schema`, which is built from these checks; a
third-party adapter may call them directly in its ``validate_config``.
"""
from __future__ import annotations

import difflib
import math
import tomllib
from pathlib import Path
from typing import Any, Mapping, Sequence

from stepnf.errors import SceneError, allowed

__all__ = ["MAX_FILE_BYTES", "describe_value", "interval", "check_number", "check_bool", "check_text",
           "check_name", "check_choice", "check_unknown", "check_table", "check_path", "read_toml"]

#: A scene or sweep file is a few hundred bytes; anything this large is not one (and a device such
#: as /dev/zero would otherwise be read for ever).
MAX_FILE_BYTES = 4 * 2**20


def describe_value(value: Any) -> str:
    """``value`` as a message shows it: its TOML spelling (shortened) and its kind."""
    if isinstance(value, bool):
        return f"{str(value).lower()} (a boolean)"
    if isinstance(value, int):
        text = str(value)
        return text if len(text) <= 24 else f"an integer of {len(text)} digits ({text[:12]}...)"
    if isinstance(value, float):
        return repr(value)
    kind = ("a string" if isinstance(value, str) else "a table" if isinstance(value, Mapping)
            else "an array" if isinstance(value, list) else f"a {type(value).__name__}")
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({kind})"


def _bound(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def interval(lo: float | None, hi: float | None, *, lo_open: bool = False, hi_open: bool = False) -> str:
    """``[lo, hi]``, ``(lo, hi]``, ``>= lo``... as a message shows an allowed range."""
    if lo is not None and hi is not None:
        return f"{'(' if lo_open else '['}{_bound(lo)}, {_bound(hi)}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {_bound(lo)}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {_bound(hi)}"
    return "(any finite value)"


def check_number(file: str | Path | None, key: str, value: Any, *, integer: bool = False,
                 lo: float | None = None, hi: float | None = None, lo_open: bool = False,
                 hi_open: bool = False, why: str = "") -> int | float:
    """``value`` if it is a number (an integer when ``integer``) in the range; else a SceneError.

    Booleans, strings, tables, arrays, NaN and inf are refused; huge integers are compared
    exactly (never converted to float first). ``why`` is appended to the message.
    """
    rng = interval(lo, hi, lo_open=lo_open, hi_open=hi_open)
    ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok_type or not (isinstance(value, int) or math.isfinite(value)):
        what = ("an integer" if integer else "a finite number") + ("" if lo is None and hi is None else f" in {rng}")
        raise SceneError(file, key, f"expected {what}{why}, got {describe_value(value)}")
    if not ((lo is None or (value > lo if lo_open else value >= lo))
            and (hi is None or (value < hi if hi_open else value <= hi))):
        verb = "must lie in" if lo is not None and hi is not None else "must be"
        raise SceneError(file, key, f"{verb} {rng}{why}, got {describe_value(value)}")
    return value


def check_bool(file: str | Path | None, key: str, value: Any) -> bool:
    """``value`` if it is true or false; else a SceneError."""
    if not isinstance(value, bool):
        raise SceneError(file, key, f"expected true or false, got {describe_value(value)}")
    return value


def check_text(file: str | Path | None, key: str, value: Any, what: str, max_len: int = 4096) -> str:
    """``value`` if it is a non-empty string without NUL of at most ``max_len`` characters (a file or folder
    name, a command, an address); else a SceneError saying ``what`` was expected."""
    if not isinstance(value, str) or not value.strip() or "\x00" in value or len(value) > max_len:
        raise SceneError(file, key, f"expected {what} (a non-empty string without NUL, at most {max_len} "
                         f"characters), got {describe_value(value)}")
    return value


def check_name(file: str | Path | None, key: str, value: Any) -> str:
    """A file stem written into an output folder: no path separator, not '.', '..' or empty."""
    bad = (not isinstance(value, str) or not value.strip() or value in (".", "..")
           or any(c in value for c in "/\\") or any(ord(c) < 32 or ord(c) == 127 for c in value)
           or len(value.encode("utf-8", "surrogatepass")) > 200)
    if bad:
        raise SceneError(file, key, "expected a file stem: a non-empty string of at most 200 bytes, without "
                         f"'/', '\\', control characters, and not '.' or '..'; got {describe_value(value)}")
    return value


def check_choice(file: str | Path | None, key: str, value: Any, choices: Sequence[Any], why: str = "") -> Any:
    """``value`` if it is one of ``choices`` (compared by type too: ``true`` is not ``1``); else a SceneError."""
    if not any(type(value) is type(c) and value == c for c in choices):
        raise SceneError(file, key, f"expected one of {allowed(choices)}{why}, got {describe_value(value)}")
    return value


def check_unknown(file: str | Path | None, where: str, table: Mapping[str, Any], known: Sequence[str]) -> None:
    """Refuse the first key of ``table`` (the table at dotted path ``where``, '' for the top level) that
    is not in ``known``, suggesting the closest known key."""
    for key in table:
        if key not in known:
            near = difflib.get_close_matches(str(key), [str(k) for k in known], n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise SceneError(file, f"{where}.{key}" if where else str(key),
                             f"unknown key{hint}; allowed keys of [{where or 'top level'}]: {allowed(known)}")


def check_table(file: str | Path | None, key: str, value: Any, what: str = "") -> Mapping[str, Any]:
    """``value`` if it is a TOML table; else a SceneError (``what`` says which keys it should hold)."""
    if not isinstance(value, Mapping):
        raise SceneError(file, key, f"expected a table [{key}]{' ' + what if what else ''}, got "
                         f"{describe_value(value)}")
    return value


def check_path(file: str | Path | None, key: str, value: Any, base_dir: str | Path, *, what: str = "a file name",
               exists: str | None = "file", suffixes: Sequence[str] = ()) -> Path:
    """``value`` as a path, relative paths taken from ``base_dir`` (the scene's folder).

    ``exists``: ``"file"`` (an existing regular file), ``"folder"`` (an existing folder) or
    ``None`` (created later, e.g. a work folder). ``suffixes``: the allowed file name endings
    (case-insensitive), if any.
    """
    path = Path(check_text(file, key, value, what))
    path = path if path.is_absolute() else Path(base_dir) / path
    if suffixes and path.suffix.lower() not in suffixes:
        raise SceneError(file, key, f"expected {what} ending in one of {allowed(suffixes)}, got {str(value)!r}")
    if exists is not None:
        try:
            ok = path.is_file() if exists == "file" else path.is_dir()
        except OSError:  # e.g. a name too long for the file system
            ok = False
        if not ok:
            raise SceneError(file, key, f"{'file' if exists == 'file' else 'folder'} {str(path)!r} does not exist "
                             f"(or is not a {'regular file' if exists == 'file' else 'folder'}); expected {what}, "
                             "relative to the scene's folder")
    return path


def read_toml(path: str | Path, what: str = "scene") -> tuple[dict[str, Any], str]:
    """The table and the text of a TOML file; a SceneError naming the file for anything else.

    Refused: unreadable or non-regular files, files over :data:`MAX_FILE_BYTES`, text that is
    not UTF-8 (Latin-1, UTF-16, binary), invalid or absurdly nested TOML. A UTF-8 byte-order
    mark is allowed.
    """
    path = Path(path)
    need = f"a {what} file must be UTF-8 encoded TOML"
    try:
        if path.exists() and not path.is_file():
            raise SceneError(path, None, f"not a regular file; {need}")
        with open(path, "rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise SceneError(path, None, f"cannot read the {what} file: {exc.strerror or exc}") from exc
    if len(raw) > MAX_FILE_BYTES:
        raise SceneError(path, None, f"larger than {MAX_FILE_BYTES // 2**20} MiB; {need} of a few lines")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(path, None, f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}; "
                         f"Latin-1, UTF-16 or binary?); {need}") from exc
    if "\x00" in text:
        raise SceneError(path, None, f"contains NUL bytes (UTF-16 or binary?); {need}")
    text = text.removeprefix("\ufeff")
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(path, None, f"not valid TOML: {exc}") from exc
    except RecursionError as exc:
        raise SceneError(path, None, "not valid TOML: arrays or tables nested too deeply") from exc
