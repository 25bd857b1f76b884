"""Declared key schemas: what a TOML table accepts, checked before anything is computed.

An adapter declares the keys of its ``[model]`` table as a :class:`Schema` of
:class:`Key` s; ``stepnf`` checks a scene's ``[model]`` against it when the
scene (or a sweep's every case) is read, before any model is built or a Dask
cluster starts, and ``stepnf solvers --keys NAME`` prints it (as xarray's
backends list their open parameters)::

    class MySolverAdapter(SolverAdapter):
        model_keys = Schema(
            Key("file", "file", "the model, a .dat file", required=True, suffixes=(".dat",)),
            Key("order", "integer", "polynomial order of the elements", default=2, lo=1, hi=4),
        )

:meth:`Schema.check` refuses unknown keys (one wording, the closest known key
suggested), missing required keys and every value of the wrong kind or out
of its range (:mod:`stepnf.keys.checks` words every message); it returns the
checked values of the keys given (numbers as float or int, files and folders
as absolute paths, tables checked recursively), never filling in defaults:
the adapter's constructor owns them, and :class:`Key` repeats them only to
show them. Checks across keys ("a mesh or a geometry, not both") belong in the
adapter's ``validate_config``, which calls :meth:`Schema.check` first and must
stay pure (no solver run, no mesh read, no assembly).

:class:`FromScene` gives every adapter (and modal model) the three class
methods that tie it to a scene: :meth:`~FromScene.model_schema`,
:meth:`~FromScene.validate_config` and :meth:`~FromScene.from_config`.
"""
from __future__ import annotations

import inspect
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Iterator, Mapping, Sequence

from stepnf.keys.checks import (check_bool, check_choice, check_number, check_path, check_table, check_text, check_unknown,
                     describe_value, interval)
from stepnf.errors import SceneError, allowed

#: Kinds of :class:`Key` and the phrase that names each in messages and in ``stepnf solvers --keys``.
KINDS = {"number": "a number", "integer": "an integer", "bool": "true or false", "choice": "one of",
         "list": "a list of", "text": "a string", "file": "a file name", "folder": "a folder name",
         "path": "a path", "table": "a table", "tables": "an array of tables", "custom": "a value",
         "any": "any value"}
_EXISTS = {"file": "file", "folder": "folder", "path": None}


@dataclass(frozen=True)
class Key:
    """One key of a TOML table.

    ``kind``: one of :data:`KINDS`. ``number``/``integer``: ``lo``, ``hi`` (``lo_open``,
    ``hi_open`` for open ends), ``allow_inf`` (the string ``"inf"`` gives ``math.inf``);
    ``choice``: ``choices``; ``list``: a non-empty list of ``choices`` without repeats;
    ``file``: an existing file, relative to the scene, with one of ``suffixes`` if given;
    ``folder``: an existing folder; ``path``: a path created later; ``table``: a nested
    :class:`Schema` in ``table``; ``tables``: an array of such tables (``[[model.boundary]]``),
    checked as ``where.name[i]``; ``custom``: ``check(file, key, value)`` returns the checked
    value (``what`` describes it). ``default`` is shown, not applied;
    ``why`` is appended to range and choice messages (units, reasons); ``what`` names a
    ``text``, ``file``, ``folder`` or ``path`` value in messages ("a mesh file name").
    """

    name: str
    kind: str
    doc: str = ""
    default: Any = None
    required: bool = False
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple = ()
    suffixes: tuple[str, ...] = ()
    table: "Schema | None" = None
    allow_inf: bool = False
    why: str = ""
    what: str = ""
    check_value: Any = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"key {self.name!r}: unknown kind {self.kind!r}; pick one of {list(KINDS)}")
        if ((self.kind in ("choice", "list")) != bool(self.choices)
                or (self.kind in ("table", "tables")) != (self.table is not None)
                or (self.kind == "custom") != (self.check_value is not None)):
            raise ValueError(f"key {self.name!r}: 'choices' go with kinds 'choice' and 'list', 'table' with "
                             "'table' and 'tables', 'check_value' with 'custom'")

    def check(self, value: Any, *, file: str | Path | None, where: str, base_dir: str | Path) -> Any:
        """The checked ``value`` of this key in the table at dotted path ``where``."""
        key = f"{where}.{self.name}" if where else self.name
        kind = self.kind
        if kind in ("number", "integer"):
            if self.allow_inf and (value == math.inf or isinstance(value, str)
                                   and value.strip().lower() in ("inf", "infinity")):
                return math.inf
            v = check_number(file, key, value, integer=kind == "integer", lo=self.lo, hi=self.hi,
                             lo_open=self.lo_open, hi_open=self.hi_open,
                             why=self.why + (' (or "inf")' if self.allow_inf else ""))
            return int(v) if kind == "integer" else float(v)
        if kind == "bool":
            return check_bool(file, key, value)
        if kind == "choice":
            return check_choice(file, key, value, self.choices, self.why)
        if kind == "list":
            if not isinstance(value, list) or not value or len(set(map(repr, value))) != len(value):
                raise SceneError(file, key, f"expected a non-empty list without repeats of {allowed(self.choices)}"
                                 f"{self.why}, got {describe_value(value)}")
            return [check_choice(file, f"{key}[{i}]", v, self.choices, self.why) for i, v in enumerate(value)]
        if kind == "custom":
            return self.check_value(file, key, value)
        if kind == "tables":
            assert self.table is not None
            if not isinstance(value, list) or not value:
                raise SceneError(file, key, f"expected an array of tables [[{key}]], got {describe_value(value)}")
            return [self.table.check(v, file=file, where=f"{key}[{i}]", base_dir=base_dir) for i, v in enumerate(value)]
        if kind == "text":
            return check_text(file, key, value, self.what or KINDS["text"])
        if kind in _EXISTS:
            return check_path(file, key, value, base_dir, what=self.what or KINDS[kind],
                              exists=_EXISTS[kind], suffixes=self.suffixes)
        if kind == "table":
            assert self.table is not None
            return self.table.check(value, file=file, where=key, base_dir=base_dir)
        return value

    def type_text(self) -> str:
        """What the key takes, as ``stepnf solvers --keys`` shows it."""
        if self.kind in ("number", "integer"):
            rng = interval(self.lo, self.hi, lo_open=self.lo_open, hi_open=self.hi_open)
            return f"{self.kind} {rng}" + (' or "inf"' if self.allow_inf else "")
        if self.kind == "choice":
            return "one of " + ", ".join(_toml(c) for c in self.choices)
        if self.kind == "list":
            return "list of " + ", ".join(_toml(c) for c in self.choices)
        if self.kind == "custom":
            return self.what or "value"
        if self.kind == "tables":
            return "array of tables"
        if self.kind == "file" and self.suffixes:
            return "file (" + ", ".join(self.suffixes) + ")"
        return {"bool": "true/false", "text": "string"}.get(self.kind, self.kind)


def _toml(value: Any) -> str:
    """``value`` as written in TOML (for the key listing)."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float) and math.isinf(value):
        return '"inf"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


class Schema:
    """The keys of one TOML table (see the module docstring)."""

    def __init__(self, *keys: Key, doc: str = ""):
        names = [k.name for k in keys]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"schema declares {repeated} more than once")
        self.keys: tuple[Key, ...] = tuple(keys)
        self.doc = doc

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(k.name for k in self.keys)

    def __iter__(self) -> Iterator[Key]:
        return iter(self.keys)

    def __contains__(self, name: object) -> bool:
        return name in self.names

    def __getitem__(self, name: str) -> Key:
        for k in self.keys:
            if k.name == name:
                return k
        raise KeyError(name)

    def __add__(self, other: "Schema") -> "Schema":
        return Schema(*self.keys, *other.keys, doc=self.doc or other.doc)

    def check(self, table: Any, *, file: str | Path | None = None, where: str = "model",
              base_dir: str | Path = ".", reserved: Sequence[str] = ()) -> dict[str, Any]:
        """The checked values of the keys given in ``table`` (the table at dotted path ``where``).

        ``reserved`` are keys read elsewhere (``solver`` of ``[model]``): listed as allowed in the
        unknown-key message, and left out of ``table`` by the caller.
        """
        table = check_table(file, where, table)
        check_unknown(file, where, table, (*reserved, *self.names))
        for key in self.keys:
            if key.required and key.name not in table:
                raise SceneError(file, f"{where}.{key.name}" if where else key.name,
                                 f"missing; expected {key.type_text()}" + (f": {key.doc}" if key.doc else ""))
        return {name: self[name].check(value, file=file, where=where, base_dir=base_dir)
                for name, value in table.items()}

    def rows(self, where: str = "model") -> list[tuple[str, str, str, str]]:
        """``(dotted key, type, default, meaning)`` of every key, nested tables after their own row."""
        out = []
        for k in self.keys:
            default = "(required)" if k.required else "" if k.default is None else _toml(k.default)
            out.append((f"{where}.{k.name}", k.type_text(), default, k.doc))
            if k.table is not None:
                out.extend(k.table.rows(f"{where}.{k.name}" + ("[]" if k.kind == "tables" else "")))
        return out

    def format(self, where: str = "model", reserved: Sequence[str] = ("solver",)) -> str:
        """The key listing printed by ``stepnf solvers --keys``."""
        rows = [(f"{where}.{r}", "string", "(required)", "read by stepnf") for r in reserved] + self.rows(where)
        head = ("key", "type", "default", "meaning")
        widths = [max(len(r[i]) for r in rows + [head]) for i in range(3)]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r[:3], widths)) + "  " + r[3] for r in [head] + rows]
        return "\n".join(line.rstrip() for line in lines)


def signature_schema(init: Any) -> Schema | None:
    """The keys of a constructor ``init``, for an adapter built with ``cls(**config)``: one
    :class:`Key` of kind ``any`` per keyword parameter (required without a default); ``None``
    when the constructor takes ``**kwargs`` (any key may be meant)."""
    try:
        params = list(inspect.signature(init).parameters.values())[1:]  # drop self
    except (TypeError, ValueError):
        return None
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return None
    keys = [Key(p.name, "any", required=p.default is p.empty, default=None if p.default is p.empty else p.default)
            for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    return Schema(*keys)


class FromScene:
    """How an adapter or a modal model is built from a scene's ``[model]`` table.

    Declare :attr:`model_keys`, or override :meth:`validate_config` (checks across keys) and
    :meth:`from_config` (the build). Without either, the keys are the constructor's keyword
    parameters and :meth:`from_config` calls ``cls(**config)``.
    """

    #: The keys of ``[model]`` besides ``solver`` (``None``: see :meth:`model_schema`).
    model_keys: ClassVar[Schema | None] = None

    @classmethod
    def model_schema(cls) -> Schema | None:
        """:attr:`model_keys`; for a class that keeps the default :meth:`from_config`, its
        constructor's keywords; else ``None`` (the keys are not known before the build)."""
        if cls.model_keys is not None:
            return cls.model_keys
        if cls.from_config.__func__ is FromScene.from_config.__func__:  # type: ignore[attr-defined]
            return signature_schema(cls.__init__)
        return None

    @classmethod
    def validate_config(cls, config: Mapping[str, Any], *, base_dir: str | Path,
                        scene_file: str | Path | None = None) -> dict[str, Any]:
        """The checked ``[model]`` keys (every key but ``solver``); a :class:`SceneError` naming
        the key otherwise. Pure: called when the scene is read, before anything is computed."""
        schema = cls.model_schema()
        if schema is None:
            return dict(config)
        return schema.check(config, file=scene_file, where="model", base_dir=base_dir, reserved=("solver",))

    @classmethod
    def input_files(cls, checked: Mapping[str, Any]) -> list[Path]:
        """Files the model reads that no ``file`` or ``folder`` key names (a deck's ``*INCLUDE`` s), from the
        keys :meth:`validate_config` returned: their content enters the key of stored results
        (:mod:`stepnf.scene.model_key`). Reads, never runs anything; none by default."""
        return []

    @classmethod
    def from_config(cls, config: Mapping[str, Any], *, base_dir: Path, scene_file: Path | None = None) -> Any:
        """Build from the scene's ``[model]`` table (every key but ``solver``); relative paths are
        relative to ``base_dir`` (the scene's folder)."""
        checked = cls.validate_config(config, base_dir=base_dir, scene_file=scene_file)
        try:
            return cls(**checked)
        except TypeError as exc:
            raise SceneError(scene_file, "model", f"{cls.__name__} rejected the keys: {exc}") from exc
