"""The tools the test suite requires on this machine: a missing one fails its tests, it is not skipped.

``tests/required_tools.txt`` declares, per Debian release, what ``bash scripts/setup.sh tests``
installs and the tests drive (programs on PATH, Python modules). On a release that lists a tool
the set-up has promised it, so a test that needs it and finds it missing is a failure of the set-up
(issue 29: a set-up that dropped CalculiX left every CalculiX test skipped and the suite green);
elsewhere (Debian 13's ccx, another system) the test is skipped with the reason.

* ``requires("ccx")`` is a mark (``pytestmark = requires("ccx")``, or on one test), checked by
  ``tests/conftest.py`` before the test runs;
* ``need("mpirun")`` does the same from inside a test or fixture;
* ``conftest.py`` also turns any other skip whose reason names a required tool that is missing
  (``pytest.importorskip("dolfinx")``, an old ``skipif``) into a failure: :func:`promised_in`; a whole
  module skipped so at collection stays skipped (the other modules run) and fails the run at its end.
"""
from __future__ import annotations

import importlib.util
import os
import re
import shutil
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

from helpers.paths import TESTS

TABLE = TESTS / "required_tools.txt"
OS_RELEASE = Path(os.environ.get("STEPNF_TEST_OS_RELEASE", "/etc/os-release"))  # another one: tests of this module


@dataclass(frozen=True)
class Tool:
    """One row of ``required_tools.txt``: a program on PATH or an importable module."""

    name: str
    kind: str  # "program" | "module"
    releases: frozenset[str]  # Debian VERSION_IDs whose set-up installs it
    package: str  # the Debian package, or "editable:FOLDER" (installed by setup.sh from the checkout)
    why: str

    def present(self) -> bool:
        if self.kind == "program":
            return shutil.which(self.name) is not None
        return importlib.util.find_spec(self.name) is not None


def load(path: Path = TABLE) -> dict[str, Tool]:
    """The table, by tool name (blank lines and ``#`` comments ignored)."""
    tools = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = line.split(None, 4)
        if len(fields) < 5 or fields[1] not in ("program", "module"):
            raise ValueError(f"{path}:{n}: expected 'name program|module releases package why', got {line!r}")
        name, kind, releases, package, why = fields
        tools[name] = Tool(name, kind, frozenset(releases.split(",")), package, why.strip())
    return tools


def debian_release(path: Path = OS_RELEASE) -> str | None:
    """Debian's ``VERSION_ID`` ("12", "13") from os-release, None elsewhere (or on Debian testing/sid)."""
    try:
        text = path.read_text()
    except OSError:
        return None
    fields = {k: v.strip().strip('"') for k, v in (line.split("=", 1) for line in text.splitlines() if "=" in line)}
    if fields.get("ID") != "debian":
        return None
    return fields.get("VERSION_ID") or None


@cache
def required(release: str | None = None) -> dict[str, Tool]:
    """The tools the set-up installs on ``release`` (default: this machine's Debian release)."""
    release = debian_release() if release is None else release
    return {name: t for name, t in load().items() if release in t.releases}


def missing_required() -> list[Tool]:
    """The required tools of this machine that are not there (empty after a good set-up)."""
    return [t for t in required().values() if not t.present()]


def message(tool: Tool) -> str:
    release = debian_release()
    return (f"{tool.name} is missing, and on Debian {release} `bash scripts/setup.sh tests` installs it "
            f"({tool.package}; {tool.why}): the set-up is broken (a failure, not a skip: "
            f"tests/required_tools.txt)")


def _absent(name: str) -> bool:
    tool = load().get(name)
    if tool is not None:
        return not tool.present()
    return shutil.which(name) is None and importlib.util.find_spec(name) is None


def need(*names: str) -> None:
    """Fail the calling test if a required tool of ``names`` is missing; skip it if another one is."""
    for name in names:
        if not _absent(name):
            continue
        if name in required():
            pytest.fail(message(required()[name]), pytrace=False)
        tool = load().get(name)
        where = "module" if tool is not None and tool.kind == "module" else "on PATH"
        pytest.skip(f"no {name} {where}: not installed by the set-up on this system")


def requires(*names: str) -> pytest.MarkDecorator:
    """The mark of a test that needs ``names``: see :func:`need` (applied by ``tests/conftest.py``)."""
    unknown = [n for n in names if n not in load()]
    if unknown:
        raise ValueError(f"requires{names}: {unknown} not in {TABLE.name}")
    return pytest.mark.requires(*names)


def promised_in(reason: str) -> list[Tool]:
    """The required tools, missing here, that a skip ``reason`` names (each as a whole word)."""
    return [t for t in missing_required() if re.search(rf"(?<!\w){re.escape(t.name)}(?!\w)", reason)]
