"""The notebook ``docs/plate.ipynb`` runs (nbclient, a Python kernel) and prints the numbers of the CLI;
the README's Python example runs as printed."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time

import pytest

from helpers.paths import EXAMPLES, REPO
from helpers.required import requires

NOTEBOOK = REPO / "docs" / "plate.ipynb"
#: A kernel start and two FEniCSx plate runs (about 15 s each on one core); the limit is for a hung kernel.
CELL_TIMEOUT = 600
KERNEL = "stepnf-tests"


def outputs(cell) -> str:
    """The text a code cell printed or displayed."""
    out = []
    for o in cell.get("outputs", []):
        if o.get("output_type") == "stream":
            out.append(o["text"])
        elif "data" in o and "text/plain" in o["data"]:
            out.append(o["data"]["text/plain"])
    return "".join(out)


@pytest.mark.slow
@pytest.mark.fenicsx
@requires("nbclient", "nbformat", "ipykernel", "pandas", "dolfinx")
def test_notebook_runs_and_prints_the_cli_numbers(tmp_path, monkeypatch):
    """Executed in a copy (docs/ beside examples/, as in the checkout); the T it prints is the CLI's, ==."""
    import nbclient
    import nbformat

    # the kernel is this interpreter (the .venv that has stepnf), not Debian's system-wide "python3" kernel
    spec = tmp_path / "jupyter" / "kernels" / KERNEL
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "stepnf tests", "language": "python"}))
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter"))

    work = tmp_path / "checkout"
    (work / "docs").mkdir(parents=True)
    (work / "examples").mkdir()
    shutil.copy(NOTEBOOK, work / "docs" / NOTEBOOK.name)
    shutil.copy(EXAMPLES / "plate.toml", work / "examples" / "plate.toml")
    nb = nbformat.read(work / "docs" / NOTEBOOK.name, as_version=4)
    t0 = time.perf_counter()
    nbclient.NotebookClient(nb, timeout=CELL_TIMEOUT, kernel_name=KERNEL,
                            resources={"metadata": {"path": str(work / "docs")}}).execute()
    seconds = time.perf_counter() - t0
    code = [c for c in nb.cells if c.cell_type == "code"]
    text = "\n".join(outputs(c) for c in code)
    assert sorted(p.name for p in work.rglob("*")) == ["docs", "examples", "plate.ipynb", "plate.toml"]  # nothing written
    assert "stepnf: fenicsx" in text and "behaviour" in text  # the table
    assert any("text/html" in o.get("data", {}) for c in code for o in c.get("outputs", []))  # the DataFrame
    images = sum("image/png" in o.get("data", {}) for c in code for o in c.get("outputs", []))
    assert images >= 2, "the mode shapes and the backbone are drawn"
    m = re.search(r"T by DNF of mode (\d+) \(.*?\): (\S+) \((\w+);", text)
    assert m, text
    cli = subprocess.run([sys.executable, "-m", "stepnf.cli.main", "run", str(EXAMPLES / "plate.toml"), "--json",
                          "-q", "--no-hdf5", "--no-plot"], capture_output=True, text=True, cwd=tmp_path, timeout=900)
    assert cli.returncode == 0, cli.stderr
    mode = next(d for d in json.loads(cli.stdout)["modes"] if d["index"] == int(m.group(1)))
    assert float(m.group(2)) == mode["methods"]["dnf"]["T"]  # repr round-trips: bit for bit
    assert m.group(3) == mode["methods"]["dnf"]["behaviour"]
    print(f"notebook executed in {seconds:.1f} s")


def readme_example() -> str:
    """The README's ``Python API`` code block."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    section = text.split("## Python API", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_example_runs(tmp_path):
    """The README's example, run from the checkout as printed (it writes nothing there)."""
    code = readme_example()
    assert "stepnf.run(" in code and "stepnf.open(" in code
    before = sorted(p.name for p in (REPO / "examples").iterdir())
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=300,
                       env={**__import__("os").environ, "MPLBACKEND": "Agg"})
    assert p.returncode == 0, p.stderr
    assert "hardening" in p.stdout and sorted(p.name for p in (REPO / "examples").iterdir()) == before
