"""The Python API (:mod:`stepnf.api`): ``stepnf.run`` on a TOML file and on a dict gives the numbers of
``stepnf run --json`` bit for bit, raises the message the command prints, and ``stepnf.open`` reads the
run back into the same object."""
from __future__ import annotations

import json
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import stepnf
from helpers.hostile import run_cli
from helpers.paths import EXAMPLES, REPO
from stepnf.errors import InputFileError, SceneError

POLYNOMIAL = EXAMPLES / "polynomial.toml"
#: A von Karman shell in modal coordinates (labels, Gamma, a DPIM backbone) that runs in about a second.
VK = """[model]
solver = "vonkarman"
kappa = 25.0
k_max = 4
n_transverse = 4

[analysis]
master_modes = ["(2,0)", "(0,1)"]
methods = ["nf", "md", "smd"]

[analysis.backbone]
order = 5
points = 6

[output]
dir = "out"
"""
#: What differs between two runs of the same scene: wall-clock and memory figures, where files went.
VOLATILE = ("timings", "memory", "hdf5", "files")


def timeless(x):
    """``x`` without the wall-clock figures it holds at any depth (keys ``seconds``, ``*_seconds``)."""
    if isinstance(x, dict):
        return {k: timeless(v) for k, v in x.items() if not (k == "seconds" or k.endswith("_seconds"))}
    if isinstance(x, list):
        return [timeless(v) for v in x]
    return x


def numbers(doc: dict, *, scene_file: bool = True) -> dict:
    """The document without what differs between two runs (:data:`VOLATILE`, the seconds of the counts,
    the model's build and the backbone's orders; without ``scene_file``, the scene's file name, which a
    dict has not)."""
    out = timeless({k: v for k, v in doc.items() if k not in VOLATILE})
    if not scene_file:
        out["scene"] = {k: v for k, v in doc["scene"].items() if k != "file"}
    return out


def cli_json(capsys, scene: Path, *extra: str) -> dict:
    o = run_cli(["run", scene, "--json", "-q", *extra], capsys)
    assert o.code == 0, o.err
    return json.loads(o.out)


@pytest.fixture
def vk(tmp_path) -> Path:
    s = tmp_path / "vk.toml"
    s.write_text(VK)
    return s


@pytest.mark.parametrize("example", ["polynomial", "vk"])
def test_run_on_a_file_and_on_a_dict_gives_the_cli_numbers(example, vk, tmp_path, capsys, monkeypatch):
    """Every number of the JSON document equal (==, not approx: the same run, the same arithmetic)."""
    if example == "polynomial":  # a copy: nothing is written beside it
        (tmp_path / "system12.npz").write_bytes((EXAMPLES / "system12.npz").read_bytes())
        scene = tmp_path / "polynomial.toml"
        scene.write_text(POLYNOMIAL.read_text())
    else:
        scene = vk
    monkeypatch.chdir(tmp_path)
    cli = cli_json(capsys, scene, "--no-hdf5")
    before = sorted(tmp_path.rglob("*"))
    view = stepnf.run(scene)
    assert numbers(view.to_dict()) == numbers(cli)
    assert json.loads(view.to_json()) == view.to_dict()
    data = tomllib.loads(scene.read_text())
    from_dict = stepnf.run(data, base_dir=scene.parent)
    assert numbers(from_dict.to_dict(), scene_file=False) == numbers(cli, scene_file=False)
    assert from_dict.to_dict()["scene"]["file"] is None
    # nothing written by default
    assert view.hdf5_path is None and view.files == () and sorted(tmp_path.rglob("*")) == before


def test_the_typed_view(vk, tmp_path, capsys, monkeypatch):
    """Modes, T per method, Gamma, behaviour, rho, backbones read from the document (the same floats)."""
    monkeypatch.chdir(tmp_path)
    cli = cli_json(capsys, vk, "--no-hdf5")
    view = stepnf.run(vk)
    assert view.methods == ("nf", "md", "smd")
    assert [m.label for m in view.modes] == [(2, 0), (0, 1)]
    for m, d in zip(view.modes, cli["modes"]):
        assert m.index == d["index"] and m.omega == d["omega"] and m.rho == d["rho"]
        assert m.frequency == d["omega"] / (2 * math.pi)
        for name, r in m.methods.items():
            c = d["methods"][name]
            assert (r.T, r.gamma, r.behaviour) == (c["T"], c["gamma"], c["behaviour"])
            assert r.hardening == (c["behaviour"] == "hardening") and r.softening == (c["behaviour"] == "softening")
            assert view.T(name)[m.index] == c["T"] and view.gamma(name)[m.index] == c["gamma"]
        bb = m.backbone
        assert bb.order == 5 and list(bb.amplitude) == d["backbone"]["amplitude"]
        assert list(bb.frequency_ratio) == d["backbone"]["omega_ratio"] and len(bb.amplitude) == 6
        assert view.backbones[m.index] is bb
    assert view.mode(view.modes[1].index) is view.modes[1]
    with pytest.raises(KeyError, match="not a master mode"):
        view.mode(999)
    # read-only
    with pytest.raises(AttributeError):
        view.modes[0].omega = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        view.modes[0].methods["nf"] = None  # type: ignore[index]
    with pytest.raises(ValueError):
        view.modes[0].backbone.amplitude[0] = 1.0


def test_table_is_the_cli_table(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    o = run_cli(["run", POLYNOMIAL, "-q", "--no-hdf5"], capsys)
    table = stepnf.run(POLYNOMIAL).table()
    # the counts line carries the run's seconds: every other line equal
    assert "counts:" in table and [line for line in table.splitlines() if not line.startswith("counts:")] == \
           [line for line in o.out.rstrip("\n").splitlines() if not line.startswith("counts:")]


def test_dataframe(vk, tmp_path, monkeypatch):
    """One row per master mode x method, the columns of stepnf.api.frame, the document's numbers."""
    pandas = pytest.importorskip("pandas")
    from stepnf.api.frame import COLUMNS

    monkeypatch.chdir(tmp_path)
    view = stepnf.run(vk)
    df = view.to_dataframe()
    assert isinstance(df, pandas.DataFrame)
    assert df.shape == (2 * 3, len(COLUMNS)) and tuple(df.columns) == COLUMNS
    assert list(df["method"]) == ["nf", "md", "smd"] * 2
    assert list(df["label"]) == ["(2,0)"] * 3 + ["(0,1)"] * 3
    assert list(df["T"]) == [view.modes[i].methods[m].T for i in (0, 1) for m in ("nf", "md", "smd")]


def test_dataframe_without_pandas_names_the_package(vk, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    view = stepnf.run(vk)
    monkeypatch.setitem(sys.modules, "pandas", None)  # import pandas -> ImportError
    with pytest.raises(ImportError, match="python3-pandas"):
        view.to_dataframe()


def test_open_round_trip(vk, tmp_path, capsys, monkeypatch):
    """output=True writes what `stepnf run` writes; stepnf.open reads the same numbers back, and the
    table `stepnf show` prints."""
    monkeypatch.chdir(tmp_path)
    vk.write_text(VK.replace('dir = "out"', 'dir = "out"\nplot = true'))
    cli = cli_json(capsys, vk, "--output", "cli")
    view = stepnf.run(vk, output=True)
    h5 = tmp_path / "out" / "vk.h5"
    assert view.hdf5_path == str(h5) and h5.is_file()
    assert [Path(f).name for f in view.files] == [Path(f).name for f in cli["files"]] == ["vk_backbone.png"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(p.name for p in (tmp_path / "cli").iterdir())
    back = stepnf.open(h5)
    assert numbers(back.to_dict()) == numbers(view.to_dict())
    for a, b in zip(back.modes, view.modes):
        assert (a.index, a.label, a.omega, a.rho, a.methods) == (b.index, b.label, b.omega, b.rho, b.methods)
        assert list(a.backbone.amplitude) == list(b.backbone.amplitude)
        assert list(a.backbone.frequency_ratio) == list(b.backbone.frequency_ratio)
    o = run_cli(["show", h5], capsys)
    assert back.table() == o.out.rstrip("\n")
    assert back.array_names and sorted(back.array_names) == sorted(view.array_names)
    for name in view.array_names:
        assert np.array_equal(back.array(name), view.array(name), equal_nan=True), name
    # --output: another folder, as the command line's
    other = stepnf.run(vk, output=tmp_path / "elsewhere")
    assert other.hdf5_path == str(tmp_path / "elsewhere" / "vk.h5")


@pytest.mark.parametrize("what", ["missing", "folder", "not_hdf5"])
def test_open_bad_file_raises_what_show_prints(what, tmp_path, capsys):
    path = tmp_path / "r.h5"
    if what == "folder":
        path.mkdir()
    elif what == "not_hdf5":
        path.write_text("not a results file")
    o = run_cli(["show", path], capsys)
    assert o.code == 2
    with pytest.raises(InputFileError) as ei:
        stepnf.open(path)
    assert o.err == f"stepnf: error: {ei.value}\n"


@pytest.mark.parametrize("edit", [
    ("analysis", "methodz", ["nf"]),                # a misspelt key
    ("analysis", "retained_modes", 0),              # out of range
    ("model", "k_maxx", 4),                         # a [model] key the solver does not declare
    ("output", "plot", "yes"),                      # a wrong type
])
def test_bad_key_raises_the_cli_message(edit, tmp_path, capsys, monkeypatch):
    """str(exc) is what `stepnf run` prints after "stepnf: error: ", for the file; the dict's names <scene>."""
    monkeypatch.chdir(tmp_path)
    table, key, value = edit
    data = tomllib.loads(VK)
    data[table][key] = value
    s = tmp_path / "bad.toml"
    s.write_text(VK.replace(f"[{table}]\n", f"[{table}]\n{key} = {json.dumps(value)}\n", 1))
    o = run_cli(["run", s, "-q"], capsys)
    assert o.code == 2
    with pytest.raises(SceneError) as ei:
        stepnf.run(s)
    assert o.err == f"stepnf: error: {ei.value}\n"
    with pytest.raises(SceneError) as ed:
        stepnf.run(data)
    assert str(ed.value) == str(ei.value).replace(str(s), "<scene>", 1)


def test_not_a_scene_and_empty_output(tmp_path):
    with pytest.raises(TypeError, match="takes a scene file"):
        stepnf.run(42)  # type: ignore[arg-type]
    with pytest.raises(SceneError, match="output must name a folder"):
        stepnf.run(POLYNOMIAL, output=" ")


def test_program_keys_refused_without_permission(tmp_path, capsys, monkeypatch):
    """A program the scene names (code_aster's command) is refused as by the command line without
    --allow-programs (the same message); allow_programs=True lets it run (it fails: exit 7)."""
    pytest.importorskip("stepnf_code_aster")
    from stepnf.errors import SolverRunError

    monkeypatch.delenv("STEPNF_ALLOW_PROGRAMS", raising=False)
    monkeypatch.chdir(tmp_path)
    evil = tmp_path / "evil.sh"
    evil.write_text('#!/bin/sh\ntouch "$(dirname "$0")/MARKER"\nexit 7\n')
    evil.chmod(0o755)
    s = tmp_path / "s.toml"
    s.write_text('[model]\nsolver = "code_aster"\ncommand = "./evil.sh ${export}"\n'
                 '[model.geometry]\nshape = "spherical_cap"\na = 0.15\nR = 1.5\nh = 0.003\nn_core = 2\nn_ring = 1\n'
                 '[model.material]\nE = 2.0e11\nnu = 0.3\nrho = 7800.0\n'
                 '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\nretained_modes = 4\n')
    o = run_cli(["run", s, "-q", "--no-hdf5"], capsys)
    assert o.code == 2
    with pytest.raises(SceneError) as ei:
        stepnf.run(s)
    assert o.err == f"stepnf: error: {ei.value}\n" and "[model.command]" in str(ei.value)
    monkeypatch.setenv("STEPNF_ALLOW_PROGRAMS", "1")
    with pytest.raises(SceneError):  # an explicit False wins over the environment
        stepnf.run(s, allow_programs=False)
    assert not (tmp_path / "MARKER").exists()
    monkeypatch.delenv("STEPNF_ALLOW_PROGRAMS")
    with pytest.raises(SolverRunError, match="exited with code 7"):
        stepnf.run(s, allow_programs=True)
    assert (tmp_path / "MARKER").exists()


def test_import_stepnf_stays_light():
    """run, open and RunView are exported (open not in __all__: `from stepnf import *` keeps the built-in
    open), and `import stepnf` still imports no numpy."""
    code = ("import sys, stepnf; assert 'numpy' not in sys.modules; "
            "assert {'run', 'RunView'} <= set(stepnf.__all__) and 'open' not in stepnf.__all__; "
            "ns = {}; exec('from stepnf import *', ns); assert 'open' not in ns; "
            "assert callable(stepnf.run) and callable(stepnf.open); print('ok')")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert p.stdout.strip() == "ok", p.stderr


def test_figures(vk, tmp_path, monkeypatch):
    """plot_backbone draws on the caller's axes (the run's orders 3..N; a stored run's points), plot_modes
    returns a figure or None (a modal model has no dof coordinates)."""
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    monkeypatch.chdir(tmp_path)
    view = stepnf.run(vk, output=True)
    fig, ax = plt.subplots()
    assert view.plot_backbone(ax=ax) is ax
    assert [line.get_label() for line in ax.get_lines()][:2] == ["order 3", "order 5"]
    back = stepnf.open(view.hdf5_path)
    ax2 = back.plot_backbone(view.modes[1].index)
    x, y = ax2.get_lines()[0].get_data()
    assert list(x) == list(view.modes[1].backbone.amplitude) and list(y) == list(view.modes[1].backbone.frequency_ratio)
    with pytest.raises(ValueError, match="has no backbone"):
        view.plot_backbone(999)
    assert view.plot_modes() is None
    plt.close("all")
