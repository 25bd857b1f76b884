"""The template-driven external-solver machinery (stepnf.external), with a fake solver script.

The fake "solver" is a small Python script that reads ``fields.txt`` and writes
``forces.txt`` = f(U) = 2 U + U**3 row by row, or misbehaves on request (exit
code, time-out, missing or short output), so every failure path is exercised
without any FE code.
"""
from __future__ import annotations

import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.errors import SolverRunError
from stepnf.external import (
    CommandTemplate,
    ExternalSolverAdapter,
    TemplateError,
    WorkFolder,
    find_executable,
    missing_output,
    require_files,
    run_command,
)

FAKE_SOLVER = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    mode = sys.argv[1]
    print("fake solver starting, mode", mode, flush=True)
    U = np.atleast_2d(np.loadtxt("fields.txt"))
    if mode == "fail":
        print("*ERROR: singular matrix in element 42", flush=True)
        sys.exit(3)
    if mode == "sleep":
        time.sleep(30)
    if mode == "nooutput":
        print("done, but wrote nothing", flush=True)
        sys.exit(0)
    F = 2.0 * U + U**3
    if mode == "short":
        F = F[:-1]
    np.savetxt("forces.txt", F, fmt="%.17e")
    print("fake solver finished", flush=True)
    """
)


class FakeAdapter(ExternalSolverAdapter):
    """f(u) = 2 u + u**3 computed by the fake solver script (n = 4)."""

    name = "fake"
    program = sys.executable

    def __init__(self, mode: str = "ok", **kw):
        super().__init__(**kw)
        self.mode = mode

    @property
    def n_dofs(self) -> int:
        return 4

    def mass_matrix(self):
        return sp.identity(4, format="csr")

    def stiffness_matrix(self):
        return 2.0 * sp.identity(4, format="csr")

    def write_force_job(self, workdir: Path, U: np.ndarray):
        np.savetxt(workdir / "fields.txt", U, fmt="%.17e")
        (workdir / "fake.py").write_text(FAKE_SOLVER)
        return [self.program, "fake.py", self.mode]

    def read_forces(self, workdir: Path, m: int) -> np.ndarray:
        (path,) = require_files(workdir, ["forces.txt"], log=workdir / "solver.log")
        F = np.atleast_2d(np.loadtxt(path))
        if len(F) != m:
            raise missing_output(workdir, f"forces.txt holds {len(F)} fields, expected {m}")
        return F


U = np.array([[0.1, -0.2, 0.3, 0.0], [1.0, 2.0, -1.0, 0.5], [0.0, 0.0, 0.0, 0.0]])
F_EXACT = 2.0 * U + U**3


# ------------------------------------------------------------------ templates
def test_template_renders_and_lists_placeholders():
    t = CommandTemplate("*STEP\n${amp} $$HOME ${name} ${amp}\n", source="x.inp")
    assert t.placeholders == ["amp", "name"]
    assert t.render(amp="1.0e+00", name="cap", unused=3) == "*STEP\n1.0e+00 $HOME cap 1.0e+00\n"


def test_template_unfilled_placeholder_is_named():
    t = CommandTemplate("a=${alpha}\nb=${beta}\n", source="deck.inp")
    with pytest.raises(TemplateError, match=r"deck\.inp.*\['beta'\]"):
        t.render(alpha=1)


def test_template_stray_dollar_is_an_error():
    with pytest.raises(TemplateError, match="line 2"):
        CommandTemplate("ok\ncost $5\n")


def test_template_from_missing_file(tmp_path):
    with pytest.raises(TemplateError, match="does not exist"):
        CommandTemplate.from_file(tmp_path / "nope.inp")


# -------------------------------------------------------------- work folders
@pytest.mark.parametrize("keep, fail, kept", [
    ("never", False, False), ("never", True, False),
    ("on_error", False, False), ("on_error", True, True),
    ("always", False, True), ("always", True, True),
])
def test_work_folder_keep_policy(tmp_path, keep, fail, kept):
    wf = WorkFolder(tmp_path / "runs", prefix="t-", keep=keep)
    try:
        with wf as d:
            (d / "x").write_text("1")
            assert d.parent == tmp_path / "runs"
            if fail:
                raise RuntimeError("boom")
    except RuntimeError:
        pass
    assert wf.path.exists() == kept


def test_work_folder_rejects_unknown_policy():
    with pytest.raises(ValueError, match="on_error"):
        WorkFolder(keep="sometimes")


# ------------------------------------------------------------------ commands
def test_missing_executable(tmp_path):
    with pytest.raises(SolverRunError, match="not found on PATH") as ei:
        run_command(["no-such-solver-xyz", "-i", "job"], cwd=tmp_path)
    assert ei.value.workdir == str(tmp_path)
    with pytest.raises(SolverRunError, match="does not exist"):
        find_executable(tmp_path / "bin" / "ccx")


def test_nonzero_exit_quotes_log_tail(tmp_path):
    (tmp_path / "fields.txt").write_text("1 2\n")
    (tmp_path / "fake.py").write_text(FAKE_SOLVER)
    with pytest.raises(SolverRunError, match="exited with code 3") as ei:
        run_command([sys.executable, "fake.py", "fail"], cwd=tmp_path)
    assert "singular matrix in element 42" in ei.value.log_tail
    assert "singular matrix in element 42" in str(ei.value)
    assert str(tmp_path) in str(ei.value)


def test_timeout_kills_and_reports(tmp_path):
    (tmp_path / "fields.txt").write_text("1 2\n")
    (tmp_path / "fake.py").write_text(FAKE_SOLVER)
    t0 = time.perf_counter()
    with pytest.raises(SolverRunError, match="timed out after 1 s") as ei:
        run_command([sys.executable, "fake.py", "sleep"], cwd=tmp_path, timeout=1.0)
    assert time.perf_counter() - t0 < 10.0  # killed, not waited for (the script sleeps 30 s)
    assert "fake solver starting" in ei.value.log_tail


# ------------------------------------------------------------------- adapter
def test_adapter_batch_in_one_run(tmp_path):
    ad = FakeAdapter(workdir=tmp_path, keep="never")
    F = ad.internal_forces(U)
    assert np.allclose(F, F_EXACT, rtol=1e-15, atol=1e-15)  # %.17e round-trips float64 exactly
    assert len(ad.runs) == 1  # the whole batch in ONE solver run
    assert list(tmp_path.iterdir()) == []  # work folder cleaned
    ad.internal_forces(U[:2])
    assert len(ad.runs) == 1  # fields already computed are not sent again


def test_adapter_chunks_when_solver_limits_batch(tmp_path):
    class Limited(FakeAdapter):
        max_fields_per_run = 2

    ad = Limited(workdir=tmp_path)
    assert np.allclose(ad.internal_forces(U), F_EXACT, rtol=1e-15, atol=1e-15)
    assert len(ad.runs) == 2


@pytest.mark.parametrize("mode, message", [
    ("fail", "exited with code 3"),
    ("nooutput", r"did not write \['forces.txt'\]"),
    ("short", "holds 2 fields, expected 3"),
])
def test_adapter_failures_keep_folder_and_quote_log(tmp_path, mode, message):
    ad = FakeAdapter(mode, workdir=tmp_path, keep="on_error")
    with pytest.raises(SolverRunError, match=message) as ei:
        ad.internal_forces(U)
    wd = Path(ei.value.workdir)
    assert wd.parent == tmp_path and (wd / "fields.txt").is_file()  # kept for inspection
    assert "fake solver starting" in ei.value.log_tail


def test_adapter_missing_executable(tmp_path):
    ad = FakeAdapter(executable="no-such-solver-xyz", workdir=tmp_path)
    with pytest.raises(SolverRunError, match="no-such-solver-xyz"):
        ad.internal_force(U[0])


def test_adapter_failure_keeps_earlier_chunks(tmp_path):
    """A failing chunk does not lose the chunks computed before it (they stay cached)."""

    class FailSecond(FakeAdapter):
        max_fields_per_run = 2

        def write_force_job(self, workdir, U_):
            argv = super().write_force_job(workdir, U_)
            return argv[:-1] + ["fail" if self.runs else "ok"]

    ad = FailSecond(workdir=tmp_path, keep="never")
    with pytest.raises(SolverRunError) as ei:
        ad.internal_forces(U)
    assert sorted(ei.value.partial) == [0, 1]
    assert np.allclose(ei.value.partial[1], F_EXACT[1], rtol=1e-15)
    ad.mode = "ok"
    FailSecond.write_force_job = FakeAdapter.write_force_job  # the solver is repaired
    F = ad.internal_forces(U)
    assert np.allclose(F, F_EXACT, rtol=1e-15, atol=1e-15)
    assert len(ad.runs) == 2  # one failed-then-not-recorded run + one run for the last field only


def test_parallel_runs_share_the_batch(tmp_path):
    ad = FakeAdapter(workdir=tmp_path, keep="never", parallel_runs=2)
    U4 = np.vstack([U, U[:1] + 1.0])
    F = ad.internal_forces(U4)
    assert np.allclose(F, 2.0 * U4 + U4**3, rtol=1e-15, atol=1e-15)
    assert len(ad.runs) == 2  # two solver processes, two fields each
    with pytest.raises(ValueError, match="parallel_runs"):
        FakeAdapter(parallel_runs=0)


def test_parallel_failure_keeps_the_other_share(tmp_path):
    class FailOnSecondRow(FakeAdapter):
        def write_force_job(self, workdir, U_):
            argv = super().write_force_job(workdir, U_)
            bad = any(np.array_equal(u, U[1]) for u in U_)
            return argv[:-1] + ["fail" if bad else "ok"]

    ad = FailOnSecondRow(workdir=tmp_path, parallel_runs=2)
    U4 = np.vstack([U, U[:1] + 1.0])  # shares: rows [0, 1] (fails) and [2, 3] (succeeds)
    with pytest.raises(SolverRunError, match="exited with code 3") as ei:
        ad.internal_forces(U4)
    assert sorted(ei.value.partial) == [2, 3]
    np.testing.assert_allclose(ei.value.partial[3], 2.0 * U4[3] + U4[3] ** 3, rtol=1e-15)
