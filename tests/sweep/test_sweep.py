"""Sweeps on a local Dask cluster: killed part-way, resumed, every case stored exactly once."""
import os
import signal
import subprocess
import sys
import time

import pytest

from stepnf.errors import SceneError, StoreError
from stepnf.sweep.dask_sweep import load_sweep, read_store, run_case

from helpers.plugins import SLOW_PLUGIN, fake_plugin, write_slow_sweep


@pytest.fixture
def plugin_env(tmp_path):
    site = tmp_path / "site"
    return site, fake_plugin(site, "slowmodel", SLOW_PLUGIN, "slow = slowmodel:Slow")


def test_sweep_killed_and_resumed(tmp_path, plugin_env):
    site, env = plugin_env
    sweep = write_slow_sweep(tmp_path)
    store = tmp_path / "out" / "demo.h5"
    cmd = [sys.executable, "-m", "stepnf", "sweep", str(sweep)]
    proc = subprocess.Popen(cmd, env={**env, "SLOW_DELAY": "1.5"}, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    deadline = time.time() + 120
    stored_before = {}
    while time.time() < deadline and proc.poll() is None:
        try:
            stored_before = read_store(store)
        except StoreError:
            stored_before = {}
        if len(stored_before) >= 2:
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)  # kill the client and its Dask workers at once
    proc.wait()
    assert 2 <= len(stored_before) < 6, "the sweep must be killed part-way"
    stored_before = read_store(store)  # what survived the kill is a readable store
    # resume (faster now): only the missing cases run
    r = subprocess.run(cmd + ["--quiet"], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 4, r.stderr  # one case fails on purpose: the sweep is not complete
    assert f"{6 - len(stored_before)} cases run" in r.stdout
    assert f"{len(stored_before)} already stored" in r.stdout
    final = read_store(store)
    # this process reads the sweep too (its cases are checked against the plugin's keys): install it here
    sys.path.insert(0, str(site))
    try:
        from stepnf.plugin import registry
        registry.installed_solvers(refresh=True)
        assert sorted(final) == sorted(c.id for c in load_sweep(sweep).cases)  # every case exactly once
        assert final["kappa=3"]["status"] == "failed" and "fails on purpose" in final["kappa=3"]["error"]
        # same numbers as a serial run (the stored pre-kill cases included)
        for case in load_sweep(sweep).cases:
            if case.id == "kappa=3":
                continue
            serial = run_case(case.data, case.file, case.base_dir)
            got = final[case.id]["result"]
            for m in ("nf", "md", "smd"):
                # a Dask worker (one BLAS thread) against this process: the two-mode model's sums are
                # scalar arithmetic with no BLAS reduction, so only a few ulps could differ (SIMD paths)
                assert got["modes"][0]["methods"][m]["T"] == pytest.approx(
                    serial["modes"][0]["methods"][m]["T"], rel=1e-14)
    finally:
        sys.path.remove(str(site))
        registry.installed_solvers(refresh=True)


def test_bad_sweep_file(tmp_path):
    (tmp_path / "base.toml").write_text('[model]\nsolver = "polynomial"\nfile = "x.npz"\n'
                                        '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\n')
    s = tmp_path / "s.toml"
    s.write_text('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"analysis.methods" = [["nope"]]\n')
    with pytest.raises(SceneError, match=r"case methods=\['nope'\].*expected one of"):
        load_sweep(s)
    s.write_text('[sweep]\nbase = "base.toml"\nworkers = 3\n')
    with pytest.raises(SceneError, match=r"sweep.workers.*unknown key"):
        load_sweep(s)


def test_corrupt_store_is_a_clear_error_and_stays_intact(tmp_path, capsys):
    from stepnf.cli.main import main

    (tmp_path / "base.toml").write_text('[model]\nsolver = "polynomial"\nfile = "x.npz"\n'
                                        '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\n')
    s = tmp_path / "s.toml"
    s.write_text('[sweep]\nname = "st"\nbase = "base.toml"\n[sweep.vary]\n"analysis.retained_modes" = [2, 3]\n')
    (tmp_path / "results").mkdir()
    bad = tmp_path / "results" / "st.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + b"garbage" * 100)  # a truncated HDF5 file
    (tmp_path / "x.npz").write_bytes(b"")  # exists (checked when the sweep is read); never loaded: the store fails first
    before = bad.read_bytes()
    assert main(["sweep", str(s), "--quiet"]) == 3
    err = capsys.readouterr().err
    assert "st.h5" in err and "corrupt or truncated" in err
    assert bad.read_bytes() == before


@pytest.mark.fenicsx
@pytest.mark.slow
def test_fe_sweep_killed_and_resumed(tmp_path):
    """Issue 6: coarse FEniCSx caps on a local Dask cluster, killed after the first stored case, resumed."""
    (tmp_path / "base.toml").write_text(
        '[model]\nsolver = "fenicsx"\n[model.geometry]\nshape = "spherical_cap"\na = 0.15\nR = 1.5\nh = 0.003\n'
        'n_core = 6\nn_ring = 3\n[model.material]\nE = 1.04e11\nnu = 0.3\nrho = 4400.0\n'
        '[analysis]\nmaster_modes = ["(2,0)", "(0,1)"]\nmethods = ["dnf", "smd"]\n')
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('[sweep]\nname = "fe"\nbase = "base.toml"\n'
                     '[sweep.vary]\n"model.geometry.R" = ["inf", 3.5, 2.5, 1.5, 0.9]\n'
                     '[sweep.dask]\nn_workers = 1\n[output]\ndir = "out"\n')
    store = tmp_path / "out" / "fe.h5"
    cmd = [sys.executable, "-m", "stepnf", "sweep", str(sweep), "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.time() + 240
    n_before = 0
    while time.time() < deadline and proc.poll() is None:
        try:
            n_before = len(read_store(store))
        except StoreError:
            n_before = 0
        if n_before >= 1:
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    stored_before = read_store(store)
    assert 1 <= len(stored_before) < 5, "the sweep must be killed part-way"
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert f"{5 - len(stored_before)} cases run" in r.stdout
    final = read_store(store)
    cases = load_sweep(sweep).cases
    assert sorted(final) == sorted(c.id for c in cases)
    for cid, rec in stored_before.items():  # stored cases were never recomputed
        assert final[cid]["result"] == rec["result"]
    for case in cases[:2]:  # the same numbers as a serial run
        serial = run_case(case.data, case.file, case.base_dir)
        got = final[case.id]["result"]
        for a, b in zip(got["modes"], serial["modes"]):
            for m in ("dnf", "smd"):
                # not bit-identical across processes (threaded BLAS in the factorisations); the eigen-solver's
                # 1e-12 residual over frequency gaps of 1e-4 (split pairs) bounds the change near 1e-8: measured 8e-9
                assert a["methods"][m]["T"] == pytest.approx(b["methods"][m]["T"], rel=1e-7)
