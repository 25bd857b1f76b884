"""Text safe to show on a terminal: the one sanitiser of everything stepnf prints.

A results file, a sweep store, a scene, a mesh or a solver log can come from
someone else; its strings (adapter name, flag messages, labels, keys and values
quoted in error messages, the tail of a solver log) are printed by ``stepnf
show``, ``stepnf run`` and the error messages. A terminal obeys the control
characters in them: ``ESC ] 0 ; ... BEL`` sets the window title, ``ESC [ 2 J``
clears the screen, other sequences recolour or move the cursor, and some
terminals answer back on their input. :func:`printable` replaces every such
character by a visible escape, so a file's content is shown, never obeyed.

Replaced: the C0 controls (U+0000-U+001F) except line feed and tab, DEL
(U+007F), the C1 controls (U+0080-U+009F, U+009B being a one-character CSI), the
bidirectional overrides and isolates (U+202A-U+202E, U+2066-U+2069: they reorder
what is shown) and lone surrogates (U+D800-U+DFFF: text decoded with
``surrogateescape``, which stdout cannot encode). Each becomes ``\\xHH`` (below
U+0100) or ``\\uHHHH``. An escape sequence is thereby harmless: its ``ESC`` is
shown as ``\\x1b`` and the rest as plain characters.

Callers: every ``print`` of :mod:`stepnf.cli.main` (its module-level ``print`` is
:func:`safe_print`), the CLI's warning line, :mod:`stepnf.runtime.progress`, and the
tables returned by :func:`stepnf.report.table.format_table` and :mod:`stepnf.cli.show`.
"""
from __future__ import annotations

import argparse
import builtins
import re
from typing import Any, NoReturn, TextIO

__all__ = ["printable", "safe_print", "SafeArgumentParser"]

_UNSAFE = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069\ud800-\udfff]")


def _escape(ch: str) -> str:
    c = ord(ch)
    return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"


def printable(text: Any) -> str:
    """``str(text)`` with every control character but line feed and tab replaced by a visible escape
    (see the module docstring)."""
    s = text if isinstance(text, str) else str(text)
    if not _UNSAFE.search(s):
        return s
    return _UNSAFE.sub(lambda m: _escape(m.group()), s)


def safe_print(*values: Any, sep: str = " ", end: str = "\n", file: TextIO | None = None,
               flush: bool = False) -> None:
    """:func:`print` with each value passed through :func:`printable` (``sep`` and ``end`` are the caller's)."""
    builtins.print(*(printable(v) for v in values), sep=sep, end=end, file=file, flush=flush)


class SafeArgumentParser(argparse.ArgumentParser):
    """An :class:`argparse.ArgumentParser` whose error messages (``unrecognized arguments: ...``, which
    quote the command line's words raw: a file name ``stepnf run *`` picked up) pass through :func:`printable`;
    its sub-parsers are of the same class."""

    def error(self, message: str) -> NoReturn:
        super().error(printable(message))
