"""MPI is started only where it is needed, and an unusable TMPDIR there is one line (stepnf.runtime.mpi_env).

Open MPI aborts the process with ~50 lines when it cannot create its session folder under TMPDIR (exit 1,
issue 29). A TMPDIR that is a regular file stops it even for root (who may write anywhere), so the tests
use one.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from stepnf.runtime.mpi_env import mpi_tmpdir_problem
from helpers.paths import REPO


#: Runs the command line in-process, then prints which MPI modules the run imported.
PROBE = textwrap.dedent("""
    import json, sys
    from stepnf.cli.main import main
    code = main(sys.argv[1:])
    mods = sorted(m for m in sys.modules if m.split(".")[0] in ("petsc4py", "mpi4py", "dolfinx"))
    print(json.dumps({"code": code, "mpi_modules": mods}), file=sys.stderr)
    """)


def bad_tmpdir_env(tmp_path: Path) -> dict:
    (tmp_path / "not_a_folder").write_text("")
    env = {k: v for k, v in os.environ.items() if k not in ("OMPI_MCA_orte_tmpdir_base", "TEMP", "TMP")}
    env["TMPDIR"] = str(tmp_path / "not_a_folder")
    return env


def polynomial_backbone_scene(tmp_path: Path, extra: str = "") -> Path:
    """examples/polynomial.toml (12 dofs) with a DPIM backbone of order 7 (block products of several columns)."""
    (tmp_path / "system12.npz").write_bytes((REPO / "examples" / "system12.npz").read_bytes())
    scene = tmp_path / "s.toml"
    scene.write_text((REPO / "examples" / "polynomial.toml").read_text().replace('dir = "results"', 'dir = "out"')
                     + f"\n[analysis.backbone]\norder = 7\n{extra}")
    return scene


def test_a_12_dof_backbone_run_starts_no_mpi_and_an_unusable_tmpdir_does_not_matter(tmp_path):
    scene = polynomial_backbone_scene(tmp_path)
    res = subprocess.run([sys.executable, "-c", PROBE, "run", str(scene), "--json", "-q", "--no-plot"],
                         env=bad_tmpdir_env(tmp_path), cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    report = json.loads(res.stderr.strip().splitlines()[-1])
    assert report == {"code": 0, "mpi_modules": []}  # petsc4py was imported here for 12 dofs (and aborted)
    doc = json.loads(res.stdout)
    assert all(m["backbone"] for m in doc["modes"])


def test_mumps_asked_for_with_an_unusable_tmpdir_is_one_line(tmp_path):
    # 12 dofs with linear_solver = "mumps": MUMPS needs petsc4py, so MPI
    scene = polynomial_backbone_scene(tmp_path)
    scene.write_text(scene.read_text().replace("retained_modes = 12", 'retained_modes = 12\nlinear_solver = "mumps"'))
    res = subprocess.run([sys.executable, "-m", "stepnf", "run", str(scene), "-q"], env=bad_tmpdir_env(tmp_path),
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 3
    assert res.stderr.strip().splitlines() == [res.stderr.strip()]
    assert "TMPDIR=" in res.stderr and "is not a folder" in res.stderr and "mumps" in res.stderr


def test_fenicsx_with_an_unusable_tmpdir_is_one_line(tmp_path):
    scene = tmp_path / "plate.toml"
    scene.write_text((REPO / "examples" / "plate.toml").read_text())
    res = subprocess.run([sys.executable, "-m", "stepnf", "run", str(scene), "-q"], env=bad_tmpdir_env(tmp_path),
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert res.returncode == 3, res.stderr[-3000:]
    assert res.stderr.strip().splitlines() == [
        f"stepnf: error: solver 'fenicsx' needs MPI, and Open MPI cannot start: its temporary folder "
        f"TMPDIR={tmp_path / 'not_a_folder'} is not a folder; set TMPDIR to a writable folder"]


@pytest.mark.parametrize("case, problem", [
    ("missing_under_a_folder", None),  # Open MPI creates the missing levels
    ("a_folder", None),
    ("a_file", "is not a folder"),
    ("under_a_file", "cannot be created"),
])
def test_the_tmpdir_check(tmp_path, monkeypatch, case, problem):
    (tmp_path / "a_folder").mkdir()
    (tmp_path / "a_file").write_text("")
    path = {"missing_under_a_folder": tmp_path / "a_folder" / "x" / "y", "a_folder": tmp_path / "a_folder",
            "a_file": tmp_path / "a_file", "under_a_file": tmp_path / "a_file" / "x"}[case]
    for var in ("OMPI_MCA_orte_tmpdir_base", "TEMP", "TMP"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("TMPDIR", str(path))
    monkeypatch.delitem(sys.modules, "petsc4py.PETSc", raising=False)  # as if MPI were not started yet
    monkeypatch.delitem(sys.modules, "mpi4py.MPI", raising=False)
    got = mpi_tmpdir_problem()
    assert (got is None) if problem is None else (problem in got and f"TMPDIR={path}" in got)


def test_auto_takes_superlu_with_a_warning_when_mpi_cannot_start(tmp_path, monkeypatch):
    from stepnf.linalg.factorization import DENSE_LIMIT, choose_backend

    for var in ("OMPI_MCA_orte_tmpdir_base", "TEMP", "TMP"):
        monkeypatch.delenv(var, raising=False)
    (tmp_path / "a_file").write_text("")
    monkeypatch.setenv("TMPDIR", str(tmp_path / "a_file"))
    monkeypatch.delitem(sys.modules, "petsc4py.PETSc", raising=False)  # as if MPI were not started yet
    monkeypatch.delitem(sys.modules, "mpi4py.MPI", raising=False)
    with pytest.warns(UserWarning, match="MUMPS .petsc4py. not used: Open MPI cannot start"):
        assert choose_backend(DENSE_LIMIT + 1) == "superlu"
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    assert choose_backend(DENSE_LIMIT + 1) == "mumps"
