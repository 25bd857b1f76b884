"""The house's shape: no import circle between stepnf's modules (core and bundled adapters), and no module
past ~450 lines (a module that grows past it is doing two jobs and is split along its seams); the test suite
laid out like the packages (every test file in a sub-folder of tests/, unique names, no test file importing
another: what tests share lives in tests/helpers/ or tests/conftest.py)."""
from __future__ import annotations

import ast
import graphlib
import re
from pathlib import Path

import pytest

from helpers.paths import REPO, TESTS

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
    assert {"stepnf.scene.parse", "stepnf.keys.checks", "stepnf.keys.schema", "stepnf_fenicsx.parallel",
            "stepnf_calculix.adapter", "stepnf.external.keys"} <= set(mods)


def test_no_import_circle():
    mods = modules()
    graph = {m: imports(m, f, init, mods) for m, (f, init) in mods.items()}
    try:
        list(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as exc:
        pytest.fail(f"import circle: {' -> '.join(exc.args[1])}")


def test_no_module_is_too_long():
    """One check over every module (core and bundled adapters): the failure lists each one past MAX_LINES."""
    long = []
    for name, (path, _) in sorted(modules().items()):
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > MAX_LINES:
            long.append(f"{path.relative_to(REPO)} has {n} lines")
    assert not long, f"modules past {MAX_LINES} lines (split each along its seams):\n" + "\n".join(long)


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


# ------------------------------------------------------------------ the test suite's own layout
def suite_files() -> list[Path]:
    """Every test module under tests/ (test data excluded)."""
    return sorted(p for p in TESTS.rglob("test_*.py") if "data" not in p.relative_to(TESTS).parts)


def test_every_test_file_lives_in_a_sub_folder():
    """tests/ holds conftest.py, required_tools.txt and folders: a test file goes to the folder of what it
    tests (tests/<package>/, tests/solvers/<solver>/, tests/hostile/, tests/env/)."""
    at_root = [p.name for p in suite_files() if p.parent == TESTS]
    assert not at_root, f"test files at the root of tests/ (move each into the folder of what it tests): {at_root}"


def test_test_file_names_are_unique():
    """pytest imports test modules by their base name (no __init__.py in the test folders): two files of one
    name in two folders would stop the collection."""
    seen: dict[str, list[str]] = {}
    for p in suite_files():
        seen.setdefault(p.name, []).append(str(p.relative_to(REPO)))
    twins = {name: paths for name, paths in seen.items() if len(paths) > 1}
    assert not twins, f"test files of the same name: {twins}"


def test_no_test_file_imports_another():
    """What several test files share lives in tests/helpers/ (a package) or tests/conftest.py, never in a
    test module: importing one runs its module-level code and ties two files' names together."""
    bad = []
    for path in sorted(TESTS.rglob("*.py")):
        if "data" in path.relative_to(TESTS).parts:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            else:
                continue
            bad += [f"{path.relative_to(REPO)}:{node.lineno}: {n}" for n in names
                    if any(part.startswith("test_") for part in n.split("."))]
    assert not bad, "test files imported by other files (move what they share to tests/helpers/):\n" + "\n".join(bad)


#: a path of a test or helper file, as the suite, the docs and CI name them (not examples/plugin/tests/...)
TEST_PATH = re.compile(r"(?<![\w/.-])tests/[\w/]*\.py\b")
#: named as written in examples/orthotropic_plate/plate_mesh.inp (a hashed input file whose first lines
#: tests/solvers/fenicsx/test_fenicsx_materials.py rewrites byte for byte): its old path stays
KEPT_AS_WRITTEN = {"tests/test_fenicsx_materials.py"}


def test_named_test_paths_exist():
    """Every ``tests/...py`` path in the suite's strings (lists of tests run in a chroot, docstrings), the
    README, docs/, .ci/run, bench/ and scripts/ names a file that exists (the suite moves; its mentions follow)."""
    texts = {p: p.read_text(encoding="utf-8") for p in [REPO / "README.md", REPO / ".ci" / "run",
                                                       *REPO.glob("docs/*.md"), *REPO.glob("bench/*.py"),
                                                       *REPO.glob("scripts/*.sh")] if p.is_file()}
    for path in sorted(TESTS.rglob("*.py")):
        if "data" not in path.relative_to(TESTS).parts:
            texts[path] = "\n".join(n.value for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                                    if isinstance(n, ast.Constant) and isinstance(n.value, str))
    missing = sorted({f"{path.relative_to(REPO)}: {m}" for path, text in texts.items()
                      for m in TEST_PATH.findall(text) if m not in KEPT_AS_WRITTEN and not (REPO / m).is_file()})
    assert not missing, "paths of test files that do not exist:\n" + "\n".join(missing)

