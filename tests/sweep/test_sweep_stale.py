"""A sweep store never keeps, nor mixes in, results of another model (issue 29, finding 3).

Each stored case records the key of what determined it (the resolved scene and the content of every input
file, :mod:`stepnf.scene.model_key`); a rerun whose cases have another key refuses (exit 2, naming the store and
what changed) unless ``--recompute-stale`` asks for the stale cases to be computed again.
"""
import warnings

import pytest

from stepnf.cli.main import main as cli_main
from stepnf.sweep.dask_sweep import load_sweep, read_store, run_case, write_case
from stepnf_polynomial import save_system
from helpers.systems import random_system


def main(argv):
    """``stepnf ARGV`` with its warnings printed on stderr as the CLI prints them (pytest would record them)."""
    import sys

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = cli_main(argv)
    for w in caught:
        print(f"stepnf: warning: {w.message}", file=sys.stderr)
    return code


def write_model(path, G_scale=1.0):
    M, K, G, H = random_system(6, seed=5)
    save_system(path, M, K, G_scale * G, G_scale * H)


def write_sweep(tmp_path, values=(3, 4), model="s.npz"):
    (tmp_path / "base.toml").write_text(f'[model]\nsolver = "polynomial"\nfile = "{model}"\n'
                                        '[analysis]\nmaster_modes = [0]\nmethods = ["nf", "dnf"]\n')
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('[sweep]\nname = "st"\nbase = "base.toml"\n'
                     f'[sweep.vary]\n"analysis.retained_modes" = {list(values)}\n'
                     '[sweep.dask]\nn_workers = 1\n[output]\ndir = "out"\n')
    return sweep


def T_of(rec):
    return rec["result"]["modes"][0]["methods"]["nf"]["T"]


def assert_store_is_of_the_model(sweep):
    """Every stored case equals a serial run of its case as the sweep file now defines it."""
    final = read_store(sweep.parent / "out" / "st.h5")
    cases = load_sweep(sweep).cases
    assert sorted(final) == sorted(c.id for c in cases)
    for case in cases:
        serial = run_case(case.data, case.file, case.base_dir)
        for m in ("nf", "dnf"):
            # a Dask worker (one BLAS thread) against this process: the 6-dof sums in another order, so a
            # few ulps of the eigen-solve and the modal sums; a stale case is off by the G scaling (tens of %)
            assert final[case.id]["result"]["modes"][0]["methods"][m]["T"] == pytest.approx(
                serial["modes"][0]["methods"][m]["T"], rel=1e-10)


def test_a_changed_model_file_is_refused_then_recomputed_never_kept(tmp_path, capsys):
    write_model(tmp_path / "s.npz")
    sweep = write_sweep(tmp_path)
    store = tmp_path / "out" / "st.h5"
    assert main(["sweep", str(sweep), "--quiet"]) == 0
    old = read_store(store)
    assert sorted(old) == ["retained_modes=3", "retained_modes=4"]
    capsys.readouterr()
    write_model(tmp_path / "s.npz", G_scale=1.6)  # the base scene's model file changes content
    before = store.read_bytes()
    assert main(["sweep", str(sweep), "--quiet"]) == 2
    out, err = capsys.readouterr()
    assert "already stored" not in out
    assert str(store) in err and "model.file" in err and "s.npz" in err and "--recompute-stale" in err
    assert store.read_bytes() == before  # refused: the store is left as it was
    assert main(["sweep", str(sweep), "--quiet", "--recompute-stale"]) == 0
    out, err = capsys.readouterr()
    assert "2 cases run" in out and "0 already stored" in out
    assert "2 stored cases" in err and "recomputed" in err
    assert all(abs(T_of(read_store(store)[c]) - T_of(old[c])) > 1e-3 * abs(T_of(old[c])) for c in old)
    assert_store_is_of_the_model(sweep)
    # an unchanged rerun keeps what is stored
    assert main(["sweep", str(sweep), "--quiet"]) == 0
    assert "0 cases run" in capsys.readouterr().out


def test_a_case_added_after_the_model_changed_never_mixes_two_models(tmp_path, capsys):
    """The base scene names another model file and a case is added: refused; recomputed, every case is new."""
    write_model(tmp_path / "s.npz")
    write_model(tmp_path / "t.npz", G_scale=0.5)
    sweep = write_sweep(tmp_path)
    store = tmp_path / "out" / "st.h5"
    assert main(["sweep", str(sweep), "--quiet"]) == 0
    capsys.readouterr()
    write_sweep(tmp_path, values=(3, 4, 5), model="t.npz")
    assert main(["sweep", str(sweep), "--quiet"]) == 2
    out, err = capsys.readouterr()
    assert "t.npz" in err and str(store) in err
    assert sorted(read_store(store)) == ["retained_modes=3", "retained_modes=4"]  # nothing added to a stale store
    assert main(["sweep", str(sweep), "--quiet", "--recompute-stale"]) == 0
    assert "3 cases run" in capsys.readouterr().out
    assert_store_is_of_the_model(sweep)


def test_a_store_of_an_earlier_stepnf_is_refused(tmp_path, capsys):
    """Cases stored without a key (by an earlier stepnf) cannot be told of which model: refused, never kept."""
    write_model(tmp_path / "s.npz")
    sweep = write_sweep(tmp_path)
    store = tmp_path / "out" / "st.h5"
    for case in load_sweep(sweep).cases:
        doc = run_case(case.data, case.file, case.base_dir)
        write_case(store, case.id, {"status": "done", "params": case.params, "result": doc}, {"name": "st"})
    assert main(["sweep", str(sweep), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(store) in err and "earlier stepnf" in err and "--recompute-stale" in err


def test_a_stored_case_naming_a_system_file_is_stale_and_nothing_is_read(tmp_path, monkeypatch):
    """Review N4: the recorded input paths of a store (which anyone could edit) are checked through the key's
    own rule: /proc/kcore-like files (regular, huge), devices and FIFOs are never read, the case is stale."""
    import json
    import os

    from stepnf.scene import model_key

    from stepnf.sweep.store import stale_cases

    read = []
    monkeypatch.setattr(model_key, "file_sha256", lambda p: read.append(p) or "x")
    os.mkfifo(tmp_path / "fifo")
    for path in ("/proc/self/status", "/dev/zero", str(tmp_path / "fifo")):
        rec = {"key": "0" * 64, "inputs": json.dumps({"key_version": 1, "files": {
            "model.file": {"path": path, "sha256": "x"}}})}
        stale, gone = stale_cases({"old": rec}, {})
        assert gone == {"old": f"model.file {path} changed"} and not stale
    assert read == []


def test_the_key_of_a_case_is_computed_in_one_place_once(tmp_path, monkeypatch):
    """Review N2: load_sweep computes each case's key (sweep.case_key) and the run reuses it, never again."""
    from stepnf.scene import model_key

    from stepnf.sweep import dask_sweep as sweep

    write_model(tmp_path / "s.npz")
    calls = []
    real = model_key.scene_key
    monkeypatch.setattr(model_key, "scene_key", lambda scene: calls.append(scene) or real(scene))
    sw = load_sweep(write_sweep(tmp_path))
    assert len(calls) == 2 and all(c.key is not None for c in sw.cases)
    assert [sweep.case_key(c) for c in sw.cases] == [c.key for c in sw.cases] and len(calls) == 2
