"""Scenes and the CLI: JSON schema, counts of the targeted plan, HDF5 output, clear errors."""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.io.results import read_hdf5
from stepnf.scene.parse import load_scene
from stepnf.step.procedure import n_full_step_evaluations
from stepnf_polynomial import save_system
from helpers.systems import random_system
from helpers.paths import REPO


def write_scene(tmp_path: Path, analysis: str, n: int = 10, rigid: int = 0, extra: str = "") -> Path:
    M, K, G, H = random_system(n, seed=5, rigid=rigid)
    save_system(tmp_path / "sys.npz", M, K, G, H)
    scene = tmp_path / "scene.toml"
    scene.write_text(f'[model]\nsolver = "polynomial"\nfile = "sys.npz"\n\n[analysis]\n{analysis}\n'
                     f'[output]\ndir = "out"\n{extra}')
    return scene


def run_json(scene: Path, capsys) -> dict:
    code = main(["run", str(scene), "--json", "--quiet"])
    out = capsys.readouterr().out
    assert code == 0
    return json.loads(out)


def test_json_schema_and_targeted_counts(tmp_path, capsys):
    scene = write_scene(tmp_path, 'master_modes = [1]\nmethods = ["nf", "dnf", "md", "smd"]\nretained_modes = 10\n')
    doc = run_json(scene, capsys)
    (mode,) = doc["modes"]
    assert mode["index"] == 1 and mode["label"] is None
    assert set(mode) >= {"index", "label", "omega", "rho", "methods"}
    assert set(mode["methods"]) == {"nf", "dnf", "md", "smd"}
    for r in mode["methods"].values():
        assert len(r["C"]) == 6 and isinstance(r["T"], float) and isinstance(r["flags"], list)
    # targeted plan: 2 evaluations + 2 for the amplitude check, whatever the model size
    assert doc["counts"]["force_evaluations"] == 4
    # DNF: two solves (K^+ and K - 4w^2 M); full-order SMD reuses K^+; full-order MD one bordered solve;
    # the STEP check amplitude costs no solve (every T_error is a linearisation)
    assert doc["counts"]["linear_solves"] == 3
    # DNF equals NF with every mode (10 of 10 retained) to round-off
    assert math.isclose(mode["methods"]["dnf"]["T"], mode["methods"]["nf"]["T"], rel_tol=1e-10)


def test_counts_do_not_grow_with_model_size(tmp_path, capsys):
    scene = write_scene(tmp_path, 'master_modes = [0]\nmethods = ["dnf"]\n', n=30)
    doc = run_json(scene, capsys)
    assert doc["counts"]["force_evaluations"] == 4
    assert doc["counts"]["linear_solves"] == 2


def test_full_tensors_only_when_asked(tmp_path, capsys):
    n_ret = 4
    scene = write_scene(tmp_path, f'master_modes = [0]\nmethods = ["nf"]\nretained_modes = {n_ret}\n'
                        'tensors = "full"\n')
    doc = run_json(scene, capsys)
    # full plan + 2n check evaluations, and no targeted STEP (nf uses the full tensors)
    assert doc["counts"]["force_evaluations"] == n_full_step_evaluations(n_ret) + 2 * n_ret
    stored = read_hdf5(tmp_path / "out" / "scene.h5")
    assert stored["arrays"]["g"].shape == (n_ret, n_ret, n_ret)
    assert stored["arrays"]["h"].shape == (n_ret,) * 4


def test_hdf5_holds_the_json_and_is_atomic(tmp_path, capsys):
    scene = write_scene(tmp_path, 'master_modes = [0, 2]\nmethods = ["nf", "dnf"]\n')
    doc = run_json(scene, capsys)
    path = tmp_path / "out" / "scene.h5"
    stored = read_hdf5(path)
    assert stored["modes"][1]["methods"]["dnf"]["T"] == doc["modes"][1]["methods"]["dnf"]["T"]
    import h5py

    import stepnf

    assert stored["stepnf_version"] == stepnf.__version__
    with h5py.File(path) as f:
        assert json.loads(f.attrs["versions"])["numpy"] == np.__version__
        assert "master_modes = [0, 2]" in f["inputs"].attrs["scene_text"]
    assert not [p for p in path.parent.iterdir() if p.name.endswith(".tmp")]


def test_rigid_modes_are_excluded_from_indices(tmp_path, capsys):
    scene = write_scene(tmp_path, 'master_modes = [0]\nmethods = ["nf", "dnf"]\nretained_modes = 20\n',
                        n=12, rigid=3)
    doc = run_json(scene, capsys)
    assert doc["spectrum"]["n_rigid"] == 3
    assert doc["modes"][0]["omega"] > 0.5  # not a rigid mode
    nf, dnf = doc["modes"][0]["methods"]["nf"]["T"], doc["modes"][0]["methods"]["dnf"]["T"]
    assert math.isclose(nf, dnf, rel_tol=1e-9)


@pytest.mark.parametrize("analysis, key, text", [
    ('methods = ["nf"]\n', "analysis.master_modes", "non-empty list"),
    ('master_modes = [0]\nmethods = ["nnf"]\n', "analysis.methods[0]", "expected one of"),
    ('master_modes = [0]\nmethods = ["nf"]\nretained_modes = 0\n', "analysis.retained_modes", "must lie in"),
    ('master_modes = [0]\nmethods = ["nf"]\ncolour = 1\n', "analysis.colour", "unknown key"),
    ('master_modes = [-1]\nmethods = ["nf"]\n', "analysis.master_modes[0]", "start at 0"),
    ('master_modes = [0]\nmethods = ["nf"]\n[analysis.step]\ncheck_ratio = 1.0\n', "analysis.step.check_ratio",
     "must differ from 1"),
])
def test_malformed_scene_names_file_and_key(tmp_path, capsys, analysis, key, text):
    scene = write_scene(tmp_path, analysis)
    code = main(["run", str(scene), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert str(scene) in err and f"[{key}]" in err and text in err


def test_mode_that_does_not_exist(tmp_path, capsys):
    scene = write_scene(tmp_path, 'master_modes = [12]\nmethods = ["nf"]\n', n=6)
    assert main(["run", str(scene), "--quiet"]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_label_on_unlabelled_model(tmp_path, capsys):
    scene = write_scene(tmp_path, 'master_modes = ["(2,0)"]\nmethods = ["nf"]\n', n=6)
    assert main(["run", str(scene), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "'(2,0)' is a mode label, but the polynomial model gives no labels" in err and "0-based mode index" in err


def test_unknown_solver_lists_installed(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text('[model]\nsolver = "nastran"\n[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\n')
    assert main(["run", str(scene), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "'nastran'" in err and "polynomial" in err


def test_not_toml(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text("[model\nsolver=")
    assert main(["run", str(scene)]) == 2
    assert "not valid TOML" in capsys.readouterr().err


def test_solvers_command_lists_polynomial():
    r = subprocess.run([sys.executable, "-m", "stepnf", "solvers"], capture_output=True, text=True)
    assert r.returncode == 0 and "polynomial" in r.stdout


def test_example_scene_runs(tmp_path):
    root = REPO
    scene = load_scene(root / "examples" / "polynomial.toml")
    scene.output_dir = tmp_path
    from stepnf.pipeline.run import run_scene

    res = run_scene(scene)
    # stored reference for the documented example (DNF = NF over all 12 modes)
    T = {m.index: m.methods["dnf"].T for m in res.modes}
    assert np.isclose(T[0], res.modes[0].methods["nf"].T, rtol=1e-10)
