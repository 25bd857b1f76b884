"""SIGTERM and SIGHUP end a run like Ctrl-C: the external solver's whole process group killed, its work
folder removed (keep = "on_error": an interruption is no solver error), exit 128 + signal, and the
checkpoints kept so that a rerun resumes (stepnf.runtime.signals, stepnf.external.process)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from stepnf_polynomial import save_system
from helpers.plugins import fake_plugin
from helpers.systems import random_system
from helpers.paths import TESTS


#: ``stepnf run`` of a 9-dof polynomial system whose adapter, past ``budget`` force evaluations, first runs
#: an external "solver" (sh, with a grandchild ``sleep``) in a work folder, through stepnf.external.process.
DRIVER = textwrap.dedent(
    f"""
    import sys
    from pathlib import Path
    sys.path.insert(0, {str(TESTS)!r})
    from stepnf.pipeline import model as pipeline
    from stepnf.plugin import registry
    from stepnf.external.process import WorkFolder, run_command
    from stepnf_polynomial import PolynomialAdapter

    work, budget = Path(sys.argv[1]), int(sys.argv[2])

    class Slow(PolynomialAdapter):
        seen = 0

        def _internal_forces(self, U):
            type(self).seen += len(U)
            if type(self).seen > budget:
                with WorkFolder(work / "runs", prefix="slow-", keep="on_error") as wd:
                    run_command(["sh", "-c", "sleep 300 & echo $! > " + str(work / "grandchild.pid")
                                 + "; echo $$ > " + str(work / "child.pid") + "; wait"], cwd=wd)
            return super()._internal_forces(U)

    registry.get_solver = pipeline.get_solver = lambda name: Slow
    from stepnf.cli.main import main
    sys.exit(main(["run", str(work / "s.toml"), "-q", "--no-plot", "--json"]))
    """
)


def make_scene(work: Path) -> None:
    M, K, G, H = random_system(9, seed=21)  # the system of tests/step/test_resume.py: its checkpoint chunks are known
    save_system(work / "s.npz", M, K, G, H)
    (work / "s.toml").write_text(textwrap.dedent("""
        [model]
        solver = "slow"
        file = "s.npz"
        [analysis]
        master_modes = [0, 1]
        methods = ["nf", "dnf"]
        retained_modes = 6
        tensors = "full"
        [output]
        dir = "out"
        """))
    (work / "driver.py").write_text(DRIVER)


def alive(pid: int) -> bool:
    """The process exists and is not a zombie (a killed child of a dead parent is reaped by init)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def wait_for(path: Path, seconds: float = 120.0) -> int:
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        if path.is_file() and path.read_text().strip():
            return int(path.read_text())
        time.sleep(0.05)
    raise AssertionError(f"{path} never appeared")


def default_signals() -> None:
    """In the driver, before it starts: SIGINT, SIGTERM and SIGHUP at their default action. A suite started under
    ``nohup`` (or as a background job) passes them on IGNORED, and stepnf keeps an ignored one ignored
    (test_an_ignored_sighup_stays_ignored): the driver would not stop."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_signal_kills_the_solver_group_removes_its_folder_and_the_rerun_resumes(tmp_path, sig):
    make_scene(tmp_path)
    cmd = [sys.executable, str(tmp_path / "driver.py"), str(tmp_path)]
    # past 80 fields: the targeted plan (8 fields) and the first full-plan chunk (64) are checkpointed
    # (tests/step/test_resume.py::test_killed_run_resumes counts them)
    proc = subprocess.Popen([*cmd, "80"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=default_signals)
    try:
        child = wait_for(tmp_path / "child.pid")
        grandchild = wait_for(tmp_path / "grandchild.pid")
        assert alive(child) and alive(grandchild)
        assert len(list((tmp_path / "runs").glob("slow-*"))) == 1
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        for name in ("child.pid", "grandchild.pid"):  # no sleeper left behind when the test fails
            pid = int((tmp_path / name).read_text() or 0) if (tmp_path / name).is_file() else 0
            if pid and alive(pid):
                os.kill(pid, signal.SIGKILL)
    assert proc.returncode == 128 + sig, err
    assert f"interrupted by {sig.name}" in err and "Traceback" not in err
    assert not alive(child) and not alive(grandchild)  # the whole process group, not only its leader
    assert list((tmp_path / "runs").iterdir()) == []  # keep = "on_error": an interruption is no error
    partial = tmp_path / "out" / ".s.partial"
    assert len(list(partial.glob("*.npz"))) == 2 and not (tmp_path / "out" / "s.h5").exists()
    rerun = subprocess.run([*cmd, str(10**9)], capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert json.loads(rerun.stdout)["counts"]["force_evaluations_reused"] == 72
    assert (tmp_path / "out" / "s.h5").exists() and not partial.exists()


def test_an_ignored_sighup_stays_ignored(tmp_path):
    """``nohup stepnf run ...``: SIGHUP was ignored when stepnf started, and stays so."""
    code = textwrap.dedent("""
        import signal
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
        from stepnf.runtime.signals import handled
        with handled():
            assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) not in (signal.SIG_DFL, signal.SIG_IGN)
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL  # put back after the command
        print("ok")
        """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.stdout.strip() == "ok", res.stderr


def test_a_signal_while_the_solver_starts_stops_it_once_tracked(tmp_path, monkeypatch):
    """Review item 8: a SIGTERM between ``Popen`` returning and :func:`stepnf.runtime.signals.track` (sent here from
    inside Popen, right after the child started) used to raise in between and leave the child running in its
    own session. Now the handler holds the Interrupted back until the child is tracked: the child is killed
    (SIGKILL: return code -9), nothing stays registered, and the thread's signal mask is the one it had."""
    from stepnf.runtime import signals
    from stepnf.external import process

    real, started = subprocess.Popen, []

    def popen(*args, **kwargs):
        started.append(real(*args, **kwargs))
        os.kill(os.getpid(), signal.SIGTERM)  # the handler runs before this returns
        return started[-1]

    monkeypatch.setattr(process.subprocess, "Popen", popen)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    try:
        with signals.handled(), pytest.raises(signals.Interrupted) as info:
            process.run_command(["sleep", "300"], cwd=tmp_path)
        assert info.value.signum == signal.SIGTERM
        assert started and started[0].wait(timeout=30) == -signal.SIGKILL  # tracked, then killed
        assert signals._groups == {} and signals.received() is None
        assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == mask
    finally:
        for proc in started:  # no sleeper left behind when the test fails
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def test_a_signal_while_a_solver_fails_to_start_is_not_lost(tmp_path, monkeypatch):
    """The signal held back while the solver starts (stepnf.runtime.signals.deferred) still stops the run when the
    start fails (an OSError: the SolverRunError "could not start" would otherwise hide it, and a sweep go on)."""
    from stepnf.runtime import signals
    from stepnf.external import process

    def popen(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        raise OSError("no such file")

    monkeypatch.setattr(process.subprocess, "Popen", popen)
    with signals.handled(), pytest.raises(signals.Interrupted) as info:
        process.run_command(["sleep", "300"], cwd=tmp_path)
    assert info.value.signum == signal.SIGTERM and signals._groups == {}


def test_the_solver_starts_with_the_handled_signals_unblocked(tmp_path):
    """The child inherits no blocked SIGINT, SIGTERM or SIGHUP from the start (why stepnf.runtime.signals.deferred
    does not use signal.pthread_sigmask): /proc/self/status of the solver, read by the solver itself."""
    from stepnf.runtime import signals
    from stepnf.external.process import run_command

    with signals.handled():
        run = run_command(["grep", "SigBlk", "/proc/self/status"], cwd=tmp_path)
    blocked = int(run.log.read_text().split()[1], 16)
    for name in signals.HANDLED:
        assert not blocked & (1 << (getattr(signal, name) - 1)), (name, hex(blocked))


def group_members(pgid: int) -> list[int]:
    """Live processes of the process group ``pgid`` (from /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if fields[0] != "Z" and int(fields[2]) == pgid:
            out.append(int(stat.parent.name))
    return out


def test_sigterm_to_a_sweep_closes_its_dask_cluster_and_the_rerun_resumes(tmp_path):
    from helpers.plugins import SLOW_PLUGIN, write_slow_sweep  # the sweep of tests/sweep/test_sweep.py
    from stepnf.sweep.dask_sweep import read_store
    from stepnf.errors import StoreError

    env = fake_plugin(tmp_path / "site", "slowmodel", SLOW_PLUGIN, "slow = slowmodel:Slow")
    sweep = write_slow_sweep(tmp_path)
    store = tmp_path / "out" / "demo.h5"
    cmd = [sys.executable, "-m", "stepnf", "sweep", str(sweep), "--quiet"]
    # its own process group, so that the test sees the Dask workers and kills what is left if it fails
    proc = subprocess.Popen(cmd, env={**env, "SLOW_DELAY": "1.5"}, cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        stored: dict = {}
        while time.monotonic() < deadline and proc.poll() is None and len(stored) < 2:
            time.sleep(0.2)
            try:
                stored = read_store(store)
            except StoreError:
                stored = {}
        assert len(group_members(proc.pid)) >= 3  # the client and its two Dask workers (at least)
        proc.send_signal(signal.SIGTERM)  # to the client alone, as `kill PID` does
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 143, err
        assert "interrupted by SIGTERM" in err and "Traceback" not in err
        t0 = time.monotonic()
        while group_members(proc.pid) and time.monotonic() - t0 < 10:
            time.sleep(0.2)
        assert group_members(proc.pid) == []  # the cluster was closed: no worker left behind
    finally:
        if group_members(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
    kept = read_store(store)
    assert 2 <= len(kept) < 6
    rerun = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 4, rerun.stderr  # kappa = 3 fails on purpose (tests/sweep/test_sweep.py)
    assert f"{len(kept)} already stored" in rerun.stdout


#: A solver plugin whose every force call runs an external "solver" (sh with a grandchild sleep) that never ends.
SLOWEXT = textwrap.dedent("""
    import os
    from pathlib import Path
    from stepnf.external.process import WorkFolder, run_command
    from stepnf_polynomial import PolynomialAdapter

    class SlowExt(PolynomialAdapter):
        def _internal_forces(self, U):
            work = Path(os.environ["SLOWEXT_DIR"])
            with WorkFolder(work / "runs", prefix="slow-", keep="on_error") as wd:
                run_command(["sh", "-c", f"sleep 300 & echo $! >> {work / 'pids'}; echo $$ >> {work / 'pids'}; wait"],
                            cwd=wd)
            return super()._internal_forces(U)
    """)


def test_sigterm_to_a_sweep_kills_the_solvers_its_dask_workers_run(tmp_path):
    plugin_env = fake_plugin(tmp_path / "site", "slowext", SLOWEXT, "slowext = slowext:SlowExt")
    save_system(tmp_path / "s.npz", *random_system(6, seed=2))
    (tmp_path / "base.toml").write_text('[model]\nsolver = "slowext"\nfile = "s.npz"\n'
                                        '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\nretained_modes = 4\n')
    (tmp_path / "sweep.toml").write_text('[sweep]\nname = "demo"\nbase = "base.toml"\n[sweep.vary]\n'
                                         '"analysis.retained_modes" = [4, 5]\n[sweep.dask]\nn_workers = 2\n'
                                         '[output]\ndir = "out"\n')
    env = {**plugin_env, "SLOWEXT_DIR": str(tmp_path)}
    cmd = [sys.executable, "-m", "stepnf", "sweep", str(tmp_path / "sweep.toml"), "--quiet", "--allow-programs"]
    proc = subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    pids: list[int] = []
    try:
        t0 = time.monotonic()
        while len(pids) < 4 and time.monotonic() - t0 < 120 and proc.poll() is None:  # two cases: sh + sleep each
            time.sleep(0.1)
            text = (tmp_path / "pids").read_text() if (tmp_path / "pids").is_file() else ""
            pids = [int(p) for p in text.split()]
        assert len(pids) == 4 and all(alive(p) for p in pids)
        assert len(list((tmp_path / "runs").iterdir())) == 2
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 143, err
        # (Dask's workers may log a stale lock file of an earlier killed run; no traceback from them)
        assert err.strip().splitlines()[-1] == ("stepnf: interrupted by SIGTERM; results already written are "
                                                "intact (a rerun resumes from the checkpoints)")
        assert "Traceback" not in err
        assert [p for p in pids if alive(p)] == []  # each solver's whole group, in the worker processes
        assert list((tmp_path / "runs").iterdir()) == []
    finally:
        text = (tmp_path / "pids").read_text() if (tmp_path / "pids").is_file() else ""
        for pid in map(int, text.split()):  # no sleeper left behind when the test fails
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
        if group_members(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
