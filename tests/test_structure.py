"""The house's shape: no import circle between stepnf's modules (core and bundled adapters), and no module
past ~450 lines (a module that grows past it is doing two jobs and is split along its seams)."""
from __future__ import annotations

import ast
import graphlib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: Top-level packages and their folders: the core and every bundled adapter.
PACKAGES = {"stepnf": REPO / "stepnf", **{p.name: p for p in sorted((REPO / "solvers").glob("*/stepnf_*"))}}
MAX_LINES = 450


def modules() -> dict[str, tuple[Path, bool]]:
    """Dotted module name -> (file, is a package's __init__)."""
    out = {}
    for pkg, root in PACKAGES.items():
        for f in root.rglob("*.py"):
            parts = [pkg, *f.relative_to(root).with_suffix("").parts]
            init = parts[-1] == "__init__"
            out[".".join(parts[:-1] if init else parts)] = (f, init)
    return out


def imports(name: str, path: Path, init: bool, known: dict) -> set[str]:
    """Our modules that ``name`` imports anywhere in its body (inside functions too)."""
    package = name if init else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            targets = [f"{base}.{a.name}" for a in node.names] + [base]
        else:
            continue
        for t in targets:
            parts = t.split(".")
            hit = next((".".join(parts[:i]) for i in range(len(parts), 0, -1) if ".".join(parts[:i]) in known), None)
            # a module's own packages are imported before it in any case (Python imports parents
            # first): an edge to one of them is no circle of ours
            if hit and hit != name and not name.startswith(hit + "."):
                found.add(hit)
    return found


def test_the_module_list_is_complete():
    mods = modules()
    assert {"stepnf.scene", "stepnf.config", "stepnf.schema", "stepnf_fenicsx.parallel",
            "stepnf_calculix.adapter", "stepnf.external.keys"} <= set(mods)


def test_no_import_circle():
    mods = modules()
    graph = {m: imports(m, f, init, mods) for m, (f, init) in mods.items()}
    try:
        list(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as exc:
        pytest.fail(f"import circle: {' -> '.join(exc.args[1])}")


@pytest.mark.parametrize("name", sorted(modules()))
def test_module_size(name):
    path, _ = modules()[name]
    n = len(path.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_LINES, f"{path.relative_to(REPO)} has {n} lines; split it along its seams"


def test_no_private_name_imported_across_modules():
    """A helper two modules need is public in the module that owns it (private modules such as
    ``_compat`` may be imported: their names are the module's business)."""
    mods = modules()
    bad = []
    for name, (path, init) in mods.items():
        package = name if init else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if not isinstance(node, ast.ImportFrom):
                continue
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            if base.split(".")[0] not in PACKAGES:
                continue
            for a in node.names:
                if a.name.startswith("_") and not a.name.startswith("__") and f"{base}.{a.name}" not in mods:
                    bad.append(f"{path.relative_to(REPO)}:{node.lineno}: {a.name} from {base}")
    assert not bad, "private names imported across modules:\n" + "\n".join(bad)
