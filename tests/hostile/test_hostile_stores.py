"""Stored files edited or damaged by hand, and command-line values of `sweep`, `curves` and `fig4`.

Each is a message naming the file or the option, exit 2 (input: an option, a results file given to
`show`) or 3 (a sweep store of stepnf's own output that cannot be used), never an internal error
(exit 1); numbers stepnf never stores (NaN) are refused, not printed.
"""
from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.errors import StoreError
from stepnf.scene.parse import parse_scene
from stepnf.sweep.dask_sweep import read_store, write_case
from stepnf_polynomial import save_system
from helpers.systems import random_system


@pytest.fixture(scope="module")
def stored_run(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("stored")
    save_system(d / "s.npz", *random_system(6, seed=3))
    (d / "s.toml").write_text('[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\n'
                              'methods = ["dnf", "nf"]\n[output]\ndir = "out"\n')
    assert main(["run", str(d / "s.toml"), "-q", "--no-plot"]) == 0
    return d / "out" / "s.h5"


def edited(src: Path, dst: Path, edit) -> Path:
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "r+") as f:
        edit(f)
    return dst


def set_json(value):
    def edit(f):
        f.attrs["json"] = value
    return edit


def set_in_document(change):
    def edit(f):
        doc = json.loads(f.attrs["json"])
        change(doc)
        f.attrs["json"] = json.dumps(doc)  # json.dumps writes NaN as the token NaN, which json.loads reads
    return edit


def replace_arrays(f):
    del f["arrays"]
    f["arrays"] = np.arange(3)


@pytest.mark.parametrize("name, edit", [
    ("not_json", set_json("{not json")),
    ("a_list", set_json("[1, 2]")),
    ("an_int", set_json(5)),
    ("deep", set_json("[" * 100000 + "]" * 100000)),
    ("arrays_dataset", replace_arrays),
    ("nan_T", set_in_document(lambda d: d["modes"][0]["methods"]["nf"].update(T=float("nan")))),
    ("nan_omega", set_in_document(lambda d: d["modes"][0].update(omega=float("nan")))),
    ("bool_T", set_in_document(lambda d: d["modes"][0]["methods"]["dnf"].update(T=True))),
])
def test_show_of_a_damaged_file_exit_2(stored_run, tmp_path, capsys, name, edit):
    """The results file given to `stepnf show` is the user's input: damaged, it is bad input (exit 2, as the
    README's exit codes say of a scene, mesh or model file), no longer exit 3 (issue 29, finding 11)."""
    path = edited(stored_run, tmp_path / f"{name}.h5", edit)
    assert main(["show", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{name}.h5" in err and "internal error" not in err and "Traceback" not in err


def sweep_store(path: Path) -> Path:
    write_case(path, "retained_modes=6", {"status": "done", "params": {"analysis.retained_modes": 6},
                                          "result": {"modes": []}, "elapsed": 0.1}, {"name": "st"})
    return path


@pytest.mark.parametrize("edit", [
    lambda f: f["cases/retained_modes=6"].attrs.__setitem__("params", 5),
    lambda f: f["cases/retained_modes=6"].attrs.__setitem__("result", "[1, 2]"),
    lambda f: f["cases/retained_modes=6"].attrs.__setitem__("result", "[" * 100000 + "]" * 100000),
    lambda f: (f.__delitem__("cases"), f.__setitem__("cases", np.arange(3))),
], ids=["params_int", "result_list", "result_deep", "cases_dataset"])
def test_damaged_sweep_store_is_a_store_error(tmp_path, edit):
    good = sweep_store(tmp_path / "good.h5")
    assert read_store(good)["retained_modes=6"]["params"] == {"analysis.retained_modes": 6}
    bad = edited(good, tmp_path / "bad.h5", edit)
    with pytest.raises(StoreError, match="bad.h5: the sweep store is unreadable"):
        read_store(bad)


def test_fig4_of_a_damaged_store_exit_2(tmp_path, capsys):
    """A store named on fig4's command line is input, as the results file of `show`: damaged, exit 2."""
    bad = edited(sweep_store(tmp_path / "good.h5"), tmp_path / "bad.h5", set_json_of_case("[1, 2]"))
    assert main(["fig4", str(bad), "--out", str(tmp_path / "fig"), "--n-kappa", "20"]) == 2
    err = capsys.readouterr().err
    assert "bad.h5: the sweep store is unreadable" in err and "internal error" not in err


def set_json_of_case(value):
    def edit(f):
        f["cases/retained_modes=6"].attrs["result"] = value
    return edit


@pytest.mark.parametrize("address", ["garbage", "localhost", "tcp://", "foo://x:1", "inproc://x", " "])
def test_sweep_bad_scheduler_exit_2(tmp_path, capsys, address):
    (tmp_path / "base.toml").write_text('[model]\nsolver = "polynomial"\nfile = "x.npz"\n'
                                        '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\n')
    s = tmp_path / "s.toml"
    s.write_text('[sweep]\nname = "st"\nbase = "base.toml"\n[sweep.vary]\n"analysis.retained_modes" = [2, 3]\n')
    assert main(["sweep", str(s), "--quiet", "--scheduler", address]) == 2
    err = capsys.readouterr().err
    assert "s.toml: --scheduler: expected a scheduler address" in err and "Traceback" not in err


@pytest.mark.parametrize("args, text", [
    (["curves", "--modes", "(2,0)", "(2,0)"], "--modes lists (2, 0) more than once"),
    (["curves", "--out", ""], "--out must name a folder"),
    (["fig4", "A", "B", "--names", "solid"], "--names: expected 2 non-empty comma-separated names"),
    (["fig4", "A", "--n-kappa", "-5"], "--n-kappa: expected an integer in [2, 100000]"),
    (["fig4", "A", "--n-kappa", "100000000"], "--n-kappa: expected an integer in [2, 100000]"),
])
def test_curves_and_fig4_options_exit_2(capsys, args, text):
    assert main([*args, "-q"] if args[0] == "curves" else args) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err


def test_output_folder_name_too_long_names_the_key(stored_run, capsys):
    scene = stored_run.parent.parent / "s.toml"
    assert main(["run", str(scene), "-q", "--output", str(stored_run.parent / ("x" * 300))]) == 2
    err = capsys.readouterr().err
    assert "[output.dir]" in err and "ENAMETOOLONG" in err


def test_tiny_transverse_direction_is_a_direction(tmp_path):
    """[1e-300, 0, 0]: the squared norm underflows, the direction does not (math.hypot)."""
    save_system(tmp_path / "s.npz", *random_system(6, seed=3))
    base = {"model": {"solver": "polynomial", "file": "s.npz"}, "analysis": {"master_modes": [0]}}
    for vec, unit in (([1e-300, 0, 0], (1.0, 0.0, 0.0)), ([1e-200, 1e-200, 0], (2 ** -0.5, 2 ** -0.5, 0.0))):
        base["analysis"]["transverse"] = vec
        sc = parse_scene(base, file=tmp_path / "t.toml", base_dir=tmp_path)
        assert sc.transverse == pytest.approx(unit, rel=1e-15)
