"""A memory limit is a message, never a hang (stepnf.limits), and running out of memory names the stage.

Under ``ulimit -v`` of 150000 to 400000 kB a 12-dof run used to spin for ever in OpenBLAS's buffer allocation
(issue 29: killed after 40 s here); now a limit too low for OpenBLAS's 128 MiB buffer is refused at once
(exit 3, naming the limit) and one that leaves room runs.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from stepnf.cli import main
from stepnf_polynomial import PolynomialAdapter
from systems import use_solver

REPO = Path(__file__).resolve().parents[1]


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
