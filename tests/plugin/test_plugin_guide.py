"""The adapter guide (docs/adapters.md) shows the example plugin's code (examples/plugin) verbatim.

Every fenced code block of the guide follows a comment
``<!-- include: PATH#REGION -->`` naming a file of the plugin and a region of it,
the lines between ``[guide:REGION]`` and ``[/guide:REGION]`` markers (dedented;
in a Markdown file, the fence around the region's code is left out). The block
must equal the region; every region of the plugin must be shown; the guide's
table of checks must list exactly the harness's checks. After editing the
plugin, ``STEPNF_UPDATE_GUIDE=1 pytest tests/plugin/test_plugin_guide.py`` rewrites
the blocks (then review the prose around them).
"""
from __future__ import annotations

import os
import re
import textwrap
from pathlib import Path

from stepnf.testing.harness import CHECKS
from helpers.paths import REPO

ROOT = REPO
GUIDE = ROOT / "docs" / "adapters.md"
PLUGIN = ROOT / "examples" / "plugin"
INCLUDE = re.compile(r"^<!-- include: (?P<path>[\w./-]+)#(?P<region>[\w-]+) -->$")
FENCE = re.compile(r"^```(?P<lang>\w*)$")
MARK = re.compile(r"\[(?P<end>/?)guide:(?P<region>[\w-]+)\]")


def regions(path: Path) -> dict[str, str]:
    """The ``[guide:NAME]`` regions of ``path``: their lines, dedented, without a Markdown fence."""
    out: dict[str, str] = {}
    open_: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        m = MARK.search(line)
        if m and not m.group("end"):
            assert m.group("region") not in open_ and m.group("region") not in out, f"{path}: {line}"
            open_[m.group("region")] = []
        elif m:
            lines = open_.pop(m.group("region"))
            if lines and FENCE.match(lines[0].strip()) and lines[-1].strip() == "```":
                lines = lines[1:-1]
            out[m.group("region")] = textwrap.dedent("\n".join(lines))
        else:
            for body in open_.values():
                body.append(line)
    assert not open_, f"{path}: regions never closed: {list(open_)}"
    return out


def guide_blocks(text: str) -> list[tuple[int, str | None, str, int, int]]:
    """``(line, include target or None, block text, first body line, end line)`` of every fenced block."""
    lines = text.splitlines()
    out, i = [], 0
    while i < len(lines):
        if FENCE.match(lines[i]):
            j = i + 1
            while j < len(lines) and lines[j] != "```":
                j += 1
            k = i - 1
            while k >= 0 and not lines[k].strip():
                k -= 1
            m = INCLUDE.match(lines[k]) if k >= 0 else None
            out.append((i + 1, f"{m.group('path')}#{m.group('region')}" if m else None, "\n".join(lines[i + 1:j]),
                        i + 1, j))
            i = j + 1
        else:
            i += 1
    return out


def plugin_regions() -> dict[str, str]:
    out = {}
    for path in sorted(PLUGIN.rglob("*")):
        if path.is_file() and path.suffix in (".py", ".toml", ".md") and "__pycache__" not in path.parts:
            for name, body in regions(path).items():
                out[f"{path.relative_to(ROOT)}#{name}"] = body
    return out


def problems(text: str, known: dict[str, str]) -> list[str]:
    """What is wrong with the guide ``text`` against the plugin's regions ``known`` (empty: nothing)."""
    blocks = guide_blocks(text)
    out = [] if blocks else ["the guide has no code blocks"]
    for line, target, body, _, _ in blocks:
        if target is None:
            out.append(f"docs/adapters.md:{line}: a code block without <!-- include: PATH#REGION -->")
        elif target not in known:
            out.append(f"docs/adapters.md:{line}: no region {target}; the plugin has {sorted(known)}")
        elif body != known[target]:
            out.append(f"docs/adapters.md:{line}: the block differs from {target}; rerun with "
                       "STEPNF_UPDATE_GUIDE=1 to copy the plugin's code into the guide")
    missing = set(known) - {target for _, target, _, _, _ in blocks}
    if missing:
        out.append(f"regions of the plugin the guide does not show: {sorted(missing)}")
    return out


def test_every_block_of_the_guide_is_the_plugins_code():
    known = plugin_regions()
    if os.environ.get("STEPNF_UPDATE_GUIDE"):
        lines = GUIDE.read_text().splitlines()
        for _, target, _, start, end in reversed(guide_blocks(GUIDE.read_text())):
            if target in known:
                lines[start:end] = known[target].splitlines()
        GUIDE.write_text("\n".join(lines) + "\n")
    assert problems(GUIDE.read_text(), known) == []


def test_a_drifted_block_is_caught():
    known = plugin_regions()
    text = GUIDE.read_text()
    line = known["examples/plugin/stepnf_truss/adapter.py#forces"].splitlines()[-1]
    assert text.count(line) == 1
    found = problems(text.replace(line, line.replace("self.nodal", "-self.nodal")), known)
    assert len(found) == 1 and "differs from examples/plugin/stepnf_truss/adapter.py#forces" in found[0]
    bare = text.replace("<!-- include: examples/plugin/truss.toml#scene -->\n", "")
    assert any("without <!-- include" in f for f in problems(bare, known))


def test_the_guide_lists_every_check_of_the_harness():
    text = GUIDE.read_text()
    table = text[text.index("## The conformance harness"):]
    listed = re.findall(r"^\| `(\w+)` \|", table, flags=re.M)
    assert listed == list(CHECKS), listed


def test_regions_strip_a_markdown_fence(tmp_path):
    md = tmp_path / "r.md"
    md.write_text("x\n<!-- [guide:a] -->\n```sh\necho hi\n```\n<!-- [/guide:a] -->\n")
    assert regions(md) == {"a": "echo hi"}
