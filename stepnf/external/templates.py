"""Command templates: solver input text with named placeholders ``${name}`` (``$$`` is a literal ``$``)."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Mapping

from stepnf.errors import StepnfError


class TemplateError(StepnfError, ValueError):
    """A command template is malformed or a placeholder was left unfilled."""


# ---------------------------------------------------------------- templates
_PATTERN = re.compile(r"\$(?:(?P<escaped>\$)|\{(?P<braced>[A-Za-z_][A-Za-z0-9_]*)\}|(?P<invalid>))")


class CommandTemplate:
    """A solver command file with named placeholders ``${name}``.

    ``$$`` stands for a literal ``$``; any other ``$`` is an error (so a typo
    cannot silently pass through to the solver). Values are converted with
    ``str``; format numbers before rendering (e.g. ``%.13e`` for CalculiX).
    """

    def __init__(self, text: str, *, source: str | Path | None = None):
        self.text = text
        self.source = None if source is None else str(source)
        for m in _PATTERN.finditer(text):
            if m.group("invalid") is not None:
                line = text.count("\n", 0, m.start()) + 1
                raise TemplateError(
                    f"{self._where()}: line {line}: '$' must start a placeholder '${{name}}' or be doubled '$$'"
                )

    @classmethod
    def from_file(cls, path: str | Path) -> "CommandTemplate":
        """Read a template file (UTF-8)."""
        path = Path(path)
        if not path.is_file():
            raise TemplateError(f"template file {path} does not exist")
        return cls(path.read_text(encoding="utf-8"), source=path)

    def _where(self) -> str:
        return self.source or "<template>"

    @property
    def placeholders(self) -> list[str]:
        """Names of the placeholders, in order of first appearance."""
        seen: dict[str, None] = {}
        for m in _PATTERN.finditer(self.text):
            if m.group("braced"):
                seen.setdefault(m.group("braced"), None)
        return list(seen)

    def render(self, values: Mapping[str, Any] | None = None, /, **kw: Any) -> str:
        """Fill every placeholder; raise :class:`TemplateError` naming those left unfilled.

        Values for names the template does not use are ignored (a template may
        leave out what it does not need).
        """
        vals = dict(values or {}, **kw)
        missing = [p for p in self.placeholders if p not in vals]
        if missing:
            raise TemplateError(
                f"{self._where()}: placeholder(s) {missing} left unfilled; given {sorted(vals)}"
            )

        def sub(m: re.Match) -> str:
            return "$" if m.group("escaped") else str(vals[m.group("braced")])

        return _PATTERN.sub(sub, self.text)
