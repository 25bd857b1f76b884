"""``stepnf modes``, ``stepnf show`` and ``stepnf --version``."""
import json

import h5py
import numpy as np
import pytest

from stepnf import __version__
from stepnf.cli.main import main
from stepnf.cli.modes import modal_survey
from stepnf.scene.parse import load_scene
from stepnf_polynomial import save_system
from helpers.systems import random_system
from helpers.paths import EXAMPLES


def fe_like_scene(tmp_path, n_nodes=4, extra="", methods='"nf"', hdf5="false"):
    """A polynomial system with ux, uy, uz dofs at each of ``n_nodes`` nodes (directions and coordinates)."""
    n = 3 * n_nodes
    M, K, G, H = random_system(n, seed=7)
    X = np.repeat(np.column_stack([np.arange(float(n_nodes)), np.zeros(n_nodes), np.zeros(n_nodes)]), 3, axis=0)
    save_system(tmp_path / "s.npz", M, K, G, H, coordinates=X, directions=np.tile([0, 1, 2], n_nodes))
    p = tmp_path / "s.toml"
    p.write_text('[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0, 2]\n'
                 f'methods = [{methods}]\n{extra}[output]\ndir = "out"\nhdf5 = {hdf5}\n')
    return p


def vonkarman_scene(tmp_path):
    p = tmp_path / "vk.toml"
    p.write_text('[model]\nsolver = "vonkarman"\nkappa = 0.0\n[analysis]\nmaster_modes = ["(2,0)"]\n'
                 'methods = ["nf"]\n[output]\ndir = "out"\n')
    return p


def test_modes_on_the_polynomial_example(capsys):
    assert main(["modes", str(EXAMPLES / "polynomial.toml"), "-q"]) == 0
    out = capsys.readouterr().out
    assert "first 12 elastic modes" in out and "rigid-body modes found: 0" in out
    rows = [line.split() for line in out.splitlines() if line[:1].isdigit()]
    assert [int(r[0]) for r in rows] == list(range(12))
    assert "labels: - (the polynomial solver gives no mode labels)" in out
    assert "kinetic-energy shares: - (the solver gives no dof directions)" in out
    assert main(["modes", str(EXAMPLES / "polynomial.toml"), "-q", "-n", "3"]) == 0
    assert len([line for line in capsys.readouterr().out.splitlines() if line[:1].isdigit()]) == 3


def test_modes_omegas_are_the_runs(tmp_path):
    """The same modes, indexed as master_modes counts them, as the run computes."""
    from stepnf.pipeline.run import run_scene

    scene = load_scene(fe_like_scene(tmp_path))
    survey = modal_survey(scene, 12)
    spectrum = run_scene(scene, write=False).spectrum
    assert np.allclose(survey.omega, spectrum["omega"][:12], rtol=1e-12)
    assert survey.n_rigid == spectrum["n_rigid"] == 0
    assert modal_survey(load_scene(EXAMPLES / "polynomial.toml")).energy is None


def test_modes_vonkarman_labels_and_pairs(tmp_path, capsys):
    assert main(["modes", str(vonkarman_scene(tmp_path)), "-q", "-n", "6", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    labels = [tuple(m["label"]) for m in doc["modes"]]
    assert len(labels) == 6 and (2, 0) in labels and doc["labels"] is True
    assert all("omega_bar" in m for m in doc["modes"])
    for group in doc["degenerate_groups"]:  # an axisymmetric shell: (k, n) with k > 0 come in pairs
        assert len({tuple(doc["modes"][i]["label"]) for i in group if i < 6}) == 1
    assert any(len(g) == 2 for g in doc["degenerate_groups"])
    assert main(["modes", str(vonkarman_scene(tmp_path)), "-q", "-n", "6"]) == 0
    out = capsys.readouterr().out
    assert "(2,0)" in out and "w_bar" in out and "degenerate: modes" in out


def test_kinetic_energy_shares_sum_to_one(tmp_path, capsys):
    survey = modal_survey(load_scene(fe_like_scene(tmp_path)), 12)
    assert set(survey.energy) == {"ux", "uy", "uz"}
    total = sum(survey.energy.values())
    assert np.abs(total - 1).max() < 1e-12
    assert main(["modes", str(fe_like_scene(tmp_path)), "-q", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["n_dofs"] == 12 and doc["n_rigid"] == 0 and len(doc["modes"]) == 12
    for m in doc["modes"]:
        assert sum(m["energy"].values()) == pytest.approx(1, abs=1e-12)
        assert set(m) >= {"index", "omega", "label", "energy", "degenerate_with"}
    assert main(["modes", str(fe_like_scene(tmp_path)), "-q"]) == 0
    out = capsys.readouterr().out
    assert "ux" in out.splitlines()[1] and "uz" in out.splitlines()[1]


def test_modes_n_too_large_or_not_positive(tmp_path, capsys):
    scene = str(fe_like_scene(tmp_path))
    assert main(["modes", scene, "-q", "-n", "13"]) == 2
    err = capsys.readouterr().err
    assert "-n 13" in err and "12 elastic modes" in err and "allowed 1..12" in err
    assert main(["modes", str(fe_like_scene(tmp_path, extra="rigid_modes = 2\n")), "-q", "-n", "11"]) == 2
    assert "allowed 1..10" in capsys.readouterr().err
    assert main(["modes", str(vonkarman_scene(tmp_path)), "-q", "-n", "100000"]) == 2
    assert "-n 100000" in capsys.readouterr().err
    for bad in ("0", "-3", "two"):
        with pytest.raises(SystemExit) as exc:
            main(["modes", scene, "-n", bad])
        assert exc.value.code == 2
        assert "positive integer" in capsys.readouterr().err


def test_modes_missing_scene(tmp_path, capsys):
    assert main(["modes", str(tmp_path / "nope.toml"), "-q"]) in (2, 3)
    assert "nope.toml" in capsys.readouterr().err


def test_show_prints_the_runs_table_again(tmp_path, capsys):
    scene = fe_like_scene(tmp_path, methods='"nf", "dnf", "md", "smd"', hdf5="true")
    assert main(["run", str(scene), "-q", "--no-plot"]) == 0
    run_out = capsys.readouterr().out
    h5 = tmp_path / "out" / "s.h5"
    assert h5.is_file()
    assert main(["show", str(h5)]) == 0
    show_out = capsys.readouterr().out

    def body(text):
        return [line for line in text.splitlines() if not line.startswith("results:")]

    assert body(show_out) == body(run_out)
    assert f"results: {h5}" in show_out


def test_show_refuses_a_file_that_is_not_a_run(tmp_path, capsys):
    """A file given to `show` that is no results file is bad input: exit 2 (issue 29, finding 11)."""
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.arange(3)
    assert main(["show", str(other)]) == 2
    err = capsys.readouterr().err
    assert "not a stepnf run file" in err and "other.h5" in err
    text = tmp_path / "notes.h5"
    text.write_text("hello")
    assert main(["show", str(text)]) == 2
    assert "cannot read the HDF5 file" in capsys.readouterr().err
    assert main(["show", str(tmp_path / "missing.h5")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"stepnf {__version__}"


def test_default_listing_reaches_the_scenes_master_modes(tmp_path, capsys):
    """Without -n the listing goes on until the scene's masters are in it, and marks them."""
    p = fe_like_scene(tmp_path, n_nodes=6)
    p.write_text(p.read_text().replace("master_modes = [0, 2]", "master_modes = [0, 14]"))
    assert main(["modes", str(p), "-q"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line[:1].isdigit()]
    assert len(rows) == 15, out
    assert [r[0] for r in rows if r[-1] == "*"] == ["0", "14"]
    assert "master: * marks the scene's master modes" in out
    doc = modal_survey(load_scene(p)).to_dict()
    assert doc["masters"] == [0, 14] and [m["master"] for m in doc["modes"]].count(True) == 2


def test_a_master_label_the_model_lacks_is_said_not_raised(tmp_path, capsys):
    """stepnf modes is how to find the right label: a wrong one is reported under the listing, exit 0."""
    p = vonkarman_scene(tmp_path)
    p.write_text(p.read_text().replace('"(2,0)"', '"(40,0)"'))
    assert main(["modes", str(p), "-q"]) == 0
    out = capsys.readouterr().out
    assert "master modes: [analysis.master_modes[0]]: no mode is labelled '(40,0)'" in out
    assert len([line for line in out.splitlines() if line[:1].isdigit()]) == 12
