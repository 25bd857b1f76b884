"""The packages of stepnf are layered as docs/design.md's table says: a package imports only from the
packages above it in that table (and from the top-level modules), every package is in the table, and
the top level keeps only the package's face."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from helpers.paths import REPO

STEPNF = REPO / "stepnf"
DESIGN = REPO / "docs" / "design.md"
#: The top-level modules: the face (``__init__``, ``__main__``) and what every layer may use (the
#: exceptions and the declared vocabularies).
TOP_LEVEL = {"__init__.py", "__main__.py", "errors.py", "flags.py", "methods.py"}


def declared_layers(text: str) -> list[str]:
    """The package names of the design notes' layer table, bottom first."""
    block = re.search(r"<!-- layers:.*?-->(.*?)<!-- end layers -->", text, re.S)
    assert block, "docs/design.md has no layer table between '<!-- layers:' and '<!-- end layers -->'"
    return re.findall(r"^\| `(\w+)/` \|", block.group(1), re.M)


def imports_between_packages(root: Path) -> list[tuple[str, str, str]]:
    """``(importing package, imported package, where)`` for every import of one stepnf package by
    another, anywhere in a module (inside functions and ``TYPE_CHECKING`` blocks too)."""
    found = []
    for f in sorted(root.rglob("*.py")):
        rel = f.relative_to(root)
        if len(rel.parts) == 1:
            continue  # the top level: the face and the vocabularies
        src = rel.parts[0]
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"), str(f))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                parts = name.split(".")
                if parts[0] == "stepnf" and len(parts) > 1 and (root / parts[1]).is_dir() and parts[1] != src:
                    found.append((src, parts[1], f"{rel}:{node.lineno}"))
    return found


def upward(layers: list[str], edges: list[tuple[str, str, str]]) -> list[str]:
    rank = {name: i for i, name in enumerate(layers)}
    return [f"{where}: {src}/ imports {dst}/, which is above it" for src, dst, where in edges
            if src in rank and dst in rank and rank[dst] > rank[src]]


def test_every_package_is_in_the_table_and_every_row_is_a_package():
    layers = declared_layers(DESIGN.read_text(encoding="utf-8"))
    packages = {p.name for p in STEPNF.iterdir() if (p / "__init__.py").is_file()}
    assert len(layers) == len(set(layers)), f"a package is listed twice: {layers}"
    assert set(layers) == packages, (f"not in docs/design.md's table: {sorted(packages - set(layers))}; "
                                     f"listed but no package: {sorted(set(layers) - packages)}")


def test_no_package_imports_one_above_it():
    bad = upward(declared_layers(DESIGN.read_text(encoding="utf-8")), imports_between_packages(STEPNF))
    assert not bad, "imports that go up the layers of docs/design.md:\n" + "\n".join(bad)


def test_the_top_level_is_only_the_face():
    modules = {p.name for p in STEPNF.glob("*.py")}
    assert modules <= TOP_LEVEL, f"top-level modules beyond the face: {sorted(modules - TOP_LEVEL)}"


def test_the_check_sees_an_upward_import(tmp_path):
    """The checks above can fail: a low package importing a high one is reported, with its line."""
    (tmp_path / "low").mkdir()
    (tmp_path / "high").mkdir()
    for pkg in ("low", "high"):
        (tmp_path / pkg / "__init__.py").write_text("")
    (tmp_path / "low" / "a.py").write_text("def f():\n    from stepnf.high.b import g\n")
    (tmp_path / "high" / "b.py").write_text("from stepnf.low.a import f\n")
    edges = imports_between_packages(tmp_path)
    assert upward(["low", "high"], edges) == ["low/a.py:2: low/ imports high/, which is above it"]
    table = "<!-- layers: x -->\n| package | job |\n|---|---|\n| `low/` | a |\n| `high/` | b |\n<!-- end layers -->"
    assert declared_layers(table) == ["low", "high"]


@pytest.mark.parametrize("face", ["stepnf", "stepnf.plugin", "stepnf.scene", "stepnf.testing", "stepnf.keys",
                                  "stepnf.geometry", "stepnf.models", "stepnf.external", "stepnf.methods"])
def test_a_package_face_imports_no_numpy(face):
    """``import stepnf`` (and a face an adapter imports) loads no numpy: the command line checks the
    memory limit before numpy starts OpenBLAS (stepnf/runtime/limits.py)."""
    import subprocess
    import sys

    code = f"import sys, {face}; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stderr or out.stdout
