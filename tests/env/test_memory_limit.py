"""A memory limit is a message, never a hang (stepnf.runtime.limits), and running out of memory names the stage.

Under ``ulimit -v`` of 150000 to 400000 kB a 12-dof run used to spin for ever in OpenBLAS's buffer allocation
(issue 29: killed after 40 s here); now a limit too low for OpenBLAS's 128 MiB buffer is refused at once
(exit 3, naming the limit) and one that leaves room runs.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from stepnf.cli.main import main
from stepnf_polynomial import PolynomialAdapter
from helpers.systems import use_solver
from helpers.paths import REPO


def polynomial_scene(tmp_path: Path) -> Path:
    (tmp_path / "system12.npz").write_bytes((REPO / "examples" / "system12.npz").read_bytes())
    scene = tmp_path / "s.toml"
    scene.write_text((REPO / "examples" / "polynomial.toml").read_text().replace('dir = "results"', 'dir = "out"'))
    return scene


def run_limited(scene: Path, kb: int) -> subprocess.CompletedProcess:
    # a hang is a time-out here: the limited run itself takes ~2 s (0.9 s when refused)
    return subprocess.run(["bash", "-c", f'ulimit -v {kb} && exec "$0" -m stepnf run "$1" -q --no-plot',
                           sys.executable, str(scene)], cwd=scene.parent, capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("kb", [200_000, 250_000])
def test_a_limit_too_low_for_openblas_is_one_line_naming_it(tmp_path, kb):
    res = run_limited(polynomial_scene(tmp_path), kb)
    assert res.returncode == 3, res.stderr[-2000:]
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("stepnf: error: memory limit: ")
    assert f"(ulimit -v {kb})" in lines[0] and "raise or remove the limit" in lines[0]


def test_a_limit_with_room_runs(tmp_path):
    # 400000 kB hung before (OpenBLAS with a buffer per core); one BLAS thread and its buffer taken up front
    # leave the run (peak ~280 MB of address space) room
    res = run_limited(polynomial_scene(tmp_path), 400_000)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (tmp_path / "out" / "s.h5").is_file()


@pytest.mark.parametrize("how", ["console script", "python -m stepnf"])
def test_a_limit_too_low_for_numpy_is_one_line_naming_it(tmp_path, how):
    """Below ~105 MB Python cannot import numpy and scipy (stepnf.runtime.limits): one line naming the limit, exit 3
    (before: Python's MemoryError traceback from the import, exit 1, before stepnf's own handling ran)."""
    command = ('"$(dirname "$0")/stepnf"' if how == "console script" else '"$0" -m stepnf')
    res = subprocess.run(["bash", "-c", f'ulimit -v 100000 && exec {command} run "$1" -q --no-plot',
                          sys.executable, str(polynomial_scene(tmp_path))], cwd=tmp_path, capture_output=True,
                         text=True, timeout=60)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 3 and len(lines) == 1, res.stderr[-2000:]
    assert lines[0].startswith("stepnf: error: memory limit: ") and "(ulimit -v 100000, RLIMIT_AS)" in lines[0]


@pytest.mark.parametrize("error, caught", [(MemoryError(), True),
                                           (ImportError("libopenblas.so.0: failed to map segment from shared "
                                                        "object"), True),
                                           (ImportError("No module named 'numpy'"), False)])
def test_the_console_entry_turns_a_want_of_memory_importing_the_cli_into_one_line(monkeypatch, capsys, error,
                                                                                  caught):
    """``stepnf.cli.console.main`` (the console script, ``python -m stepnf``) imports the command line inside
    its guard: a want of memory there is one line naming the limit, exit 3; another ImportError stays one."""
    import importlib.abc

    from stepnf.cli import console
    class Starved(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):
            if name == "stepnf.cli.main":
                raise error
            return None
    monkeypatch.delitem(sys.modules, "stepnf.cli.main")
    monkeypatch.setattr(sys, "meta_path", [Starved(), *sys.meta_path])
    monkeypatch.setattr(console, "address_space_limit", lambda: 100_000 * 1024)
    if not caught:
        with pytest.raises(ImportError, match="numpy"):
            console.main(["solvers"])
        return
    assert console.main(["solvers"]) == 3
    assert capsys.readouterr().err.splitlines() == [
        "stepnf: error: memory limit: the address-space limit (ulimit -v 100000, RLIMIT_AS) is 98 MiB, too little "
        "for Python to load the modules stepnf needs (numpy, scipy); raise or remove the limit (a small model "
        "runs from about ulimit -v 300000)"]


def blas_note(env: dict) -> list[str]:
    """stderr lines of ``stepnf solvers`` under ``ulimit -v 400000`` (room for one OpenBLAS buffer) saying
    the BLAS threads were limited."""
    res = subprocess.run(["bash", "-c", 'ulimit -v 400000 && exec "$0" -m stepnf solvers', sys.executable],
                         capture_output=True, text=True, timeout=60, env=env)
    assert res.returncode == 0, res.stderr[-2000:]
    return [line for line in res.stderr.splitlines() if "OpenBLAS" in line]


def test_one_blas_thread_is_said_only_when_it_changed_the_count():
    """N12: stepnf limiting OpenBLAS to one thread under ``ulimit -v`` says so, once; not when the
    environment already fixes the count (OPENBLAS_NUM_THREADS set, or OMP_NUM_THREADS=1: one anyway)."""
    import os

    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS",
                                                            "OMP_NUM_THREADS")}
    cores = len(os.sched_getaffinity(0))
    said = blas_note(env)
    # OpenBLAS's own default is one thread per core it may run on
    assert said == ([f"stepnf: note: under the address-space limit (ulimit -v 400000) OpenBLAS runs on 1 "
                     f"thread instead of {cores} (its 128 MiB work buffer per thread); set OPENBLAS_NUM_THREADS "
                     "to choose"] if cores > 1 else [])
    assert blas_note({**env, "OPENBLAS_NUM_THREADS": "1"}) == []
    assert blas_note({**env, "OMP_NUM_THREADS": "1"}) == []


class Hungry(PolynomialAdapter):
    """Runs out of memory when asked for forces (as a solver whose fields do not fit)."""

    def _internal_forces(self, U):
        raise MemoryError


def test_out_of_memory_names_the_stage(tmp_path, monkeypatch, capsys):
    use_solver(monkeypatch, lambda name: Hungry)
    code = main(["run", str(polynomial_scene(tmp_path)), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 3
    assert len(err) == 1 and err[0].startswith("stepnf: out of memory in stage 'STEP")
