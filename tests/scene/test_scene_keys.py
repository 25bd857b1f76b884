"""One vocabulary for scene keys: every bundled adapter declares its [model] keys, checked when a scene
or a sweep is read (before any model is built or Dask starts), with one wording for an unknown key.

The references are the declared schemas themselves (``stepnf solvers --keys``) and the examples
shipped under examples/: every one of them must load.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from stepnf.pipeline import model as pipeline
from stepnf.cli.main import main
from stepnf.errors import SceneError
from stepnf.plugin.registry import installed_solvers
from stepnf.scene.parse import load_scene
from stepnf.sweep.dask_sweep import load_sweep
from helpers.paths import EXAMPLES

ANALYSIS = '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\n[analysis.step]\ncheck = false\n[output]\ndir = "out"\n'
CAP = '[model.geometry]\nshape = "spherical_cap"\na = 0.15\nR = 1.5\nh = 0.003\n'
MATERIAL = "[model.material]\nE = 1.04e11\nnu = 0.3\nrho = 4400.0\n"
#: A valid [model] of every bundled adapter, and a key of each of its tables to misspell (names of three
#: letters or more: difflib suggests the right one back).
MODELS = {
    "polynomial": ('solver = "polynomial"\nfile = "sys.npz"\n', ["file"]),
    "vonkarman": ('solver = "vonkarman"\nkappa = 25.0\nk_max = 4\n', ["kappa", "k_max"]),
    "fenicsx": ('solver = "fenicsx"\nelement = "hex27"\n' + CAP + MATERIAL,
                ["element", "geometry.n_core=4", "material.rho"]),
    "fenicsx_shell": ('solver = "fenicsx_shell"\npenalty = 10.0\n' + CAP.replace('shape = "spherical_cap"\n', "")
                      + MATERIAL, ["penalty", "geometry.n_rings=8", "material.rho"]),
    "calculix": ('solver = "calculix"\ntimeout = 60\n' + CAP + MATERIAL, ["timeout", "geometry.n_thick=1", "material.rho"]),
    "code_aster": ('solver = "code_aster"\nncpus = 1\n' + CAP + MATERIAL, ["ncpus", "geometry.n_ring=5", "material.rho"]),
}
#: How every unknown key reads (stepnf.keys.checks.check_unknown).
WORDING = re.compile(r"\[(?P<key>[\w.]+)\]: unknown key( \(did you mean '(?P<near>\w+)'\?\))?; "
                     r"allowed keys of \[(?P<table>[\w. ]+)\]: \[")


def misspelt(key: str) -> str:
    """``key`` with its last two letters swapped (``"kappa"`` -> ``"kapap"``)."""
    assert key[-1] != key[-2], f"swapping the end of {key!r} leaves it as it is"
    return key[:-2] + key[-1] + key[-2]


def scene_text(model: str, target: str) -> tuple[str, str]:
    """The scene with ``target`` (``"key"``, ``"table.key"`` or ``"table.key=value"`` to add it first)
    misspelt, and the dotted key the error must name."""
    path, _, value = target.partition("=")
    table, _, key = path.rpartition(".")
    header = f"[model.{table}]\n" if table else None
    lines = ["[model]"] + model.splitlines()
    if value:  # a key the valid scene leaves out: add it to its table first
        at = lines.index(header.strip())
        lines.insert(at + 1, f"{key} = {value}")
    start = lines.index(header.strip()) if header else 0
    for i in range(start + 1, len(lines)):
        if lines[i].startswith(f"{key} ="):
            lines[i] = misspelt(key) + lines[i][len(key):]
            break
    else:
        raise AssertionError(f"{target} not in the scene")
    return "\n".join(lines) + "\n" + ANALYSIS, f"model.{table + '.' if table else ''}{misspelt(key)}"


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "sys.npz").write_bytes(b"")  # exists: [model] is checked, nothing is loaded
    return tmp_path


def expect_unknown(exc: SceneError, key: str, intended: str, file: Path) -> None:
    """``exc`` (or the case error wrapping it) says, in the one wording, that ``key`` of ``file`` is
    unknown and suggests ``intended``."""
    text = str(exc)
    m = WORDING.search(text)
    assert m, text
    assert m.group("key") == key and m.group("near") == intended, text
    assert m.group("table") == key.rpartition(".")[0], text
    assert str(file) in text


def test_every_bundled_adapter_declares_its_keys():
    solvers = installed_solvers()
    assert set(MODELS) <= set(solvers)
    for name in MODELS:
        schema = solvers[name].cls.model_schema()
        assert schema is not None and len(schema.names) >= 1, name


@pytest.mark.parametrize("solver", list(MODELS))
def test_valid_scene_loads(folder, solver):
    model, _ = MODELS[solver]
    (folder / "s.toml").write_text("[model]\n" + model + ANALYSIS)
    scene = load_scene(folder / "s.toml")
    assert scene.solver == solver


@pytest.mark.parametrize("solver, target", [(s, t) for s, (_, ts) in MODELS.items() for t in ts])
def test_misspelt_model_key_fails_at_load(folder, solver, target, monkeypatch):
    text, key = scene_text(MODELS[solver][0], target)
    (folder / "s.toml").write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(folder / "s.toml")
    assert info.value.key == key
    expect_unknown(info.value, key, target.partition("=")[0].rpartition(".")[2], folder / "s.toml")

    def no_build(name):
        pytest.fail("the model was built before its keys were checked")

    monkeypatch.setattr(pipeline, "get_solver", no_build)
    assert main(["run", str(folder / "s.toml"), "-q"]) == 2
    assert not (folder / "out").exists()


@pytest.mark.parametrize("solver", list(MODELS))
def test_misspelt_key_in_a_sweeps_base_scene_fails_before_dask(folder, solver, monkeypatch):
    import dask.distributed

    def no_dask(*a, **k):
        pytest.fail("Dask started before the cases' keys were checked")

    monkeypatch.setattr(dask.distributed, "LocalCluster", no_dask)
    monkeypatch.setattr(dask.distributed, "Client", no_dask)
    model, targets = MODELS[solver]
    text, key = scene_text(model, targets[-1])
    (folder / "base.toml").write_text(text)
    sweep = folder / "sweep.toml"
    sweep.write_text('[sweep]\nbase = "base.toml"\n[sweep.vary]\n"analysis.retained_modes" = [2, 3]\n')
    with pytest.raises(SceneError) as info:
        load_sweep(sweep)
    assert info.value.key == "sweep.vary" and str(sweep) in str(info.value)
    # the base scene's own message, inside
    expect_unknown(info.value, key, targets[-1].partition("=")[0].rpartition(".")[2], folder / "base.toml")
    assert main(["sweep", str(sweep), "--quiet"]) == 2
    assert not (folder / "results").exists()


@pytest.mark.parametrize("place, key, intended", [
    ("[analysis]\nmaster_mode = [0]\n", "analysis.master_mode", "master_modes"),
    ("[analysis.step]\ncheck_ration = 2.0\n", "analysis.step.check_ration", "check_ratio"),
    ("[output]\ndirr = \"x\"\n", "output.dirr", "dir"),
])
def test_misspelt_scene_key_has_the_same_wording(folder, place, key, intended):
    table = place.splitlines()[0]
    text = "[model]\n" + MODELS["vonkarman"][0] + ANALYSIS
    text = text.replace(table + "\n", place, 1)
    (folder / "s.toml").write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(folder / "s.toml")
    assert info.value.key == key
    expect_unknown(info.value, key, intended, folder / "s.toml")


@pytest.mark.parametrize("key, intended", [("ordre", "order"), ("amplitude", "amplitudes"), ("w_over_H", "w_over_h"),
                                            ("tolerence", "tolerance"), ("point", "points")])
def test_misspelt_backbone_key_has_the_same_wording(folder, key, intended):
    """``[analysis.backbone]`` (stepnf.keys.backbone) is checked with the same vocabulary at load time."""
    table = f"[analysis.backbone]\n{key} = 7\n[output]"
    text = "[model]\n" + MODELS["polynomial"][0] + ANALYSIS.replace("[output]", table)
    (folder / "s.toml").write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(folder / "s.toml")
    assert info.value.key == f"analysis.backbone.{key}"
    expect_unknown(info.value, f"analysis.backbone.{key}", intended, folder / "s.toml")


def test_backbone_table_loads_with_defaults(folder):
    text = "[model]\n" + MODELS["polynomial"][0] + ANALYSIS.replace("[output]", "[analysis.backbone]\n[output]")
    (folder / "s.toml").write_text(text)
    spec = load_scene(folder / "s.toml").backbone
    assert (spec.order, spec.amplitudes, spec.w_over_h, spec.tolerance, spec.points) == (7, None, None, 1e-3, 40)
    (folder / "s.toml").write_text(text.replace("[analysis.backbone]\n", ""))
    assert load_scene(folder / "s.toml").backbone is None


def test_unknown_solver_fails_at_load(folder):
    (folder / "s.toml").write_text('[model]\nsolver = "abaqus"\n' + ANALYSIS)
    with pytest.raises(SceneError) as info:
        load_scene(folder / "s.toml")
    assert info.value.key == "model.solver" and "polynomial" in str(info.value)


@pytest.mark.parametrize("solver", list(MODELS))
def test_solvers_keys_lists_the_declared_keys(solver, capsys):
    assert main(["solvers", "--keys", solver]) == 0
    out = capsys.readouterr().out
    schema = installed_solvers()[solver].cls.model_schema()
    listed = [line.split()[0] for line in out.splitlines()[2:]]
    assert listed == ["model.solver"] + [row[0] for row in schema.rows()]
    assert main(["solvers", "--keys", "abaqus"]) == 2


def test_solvers_lists_every_capability(capsys):
    assert main(["solvers"]) == 0
    out = capsys.readouterr().out
    line = {ln.split()[0]: ln for ln in out.splitlines()}
    assert "tangent stiffness" in line["calculix"] and "tangent stiffness" in line["polynomial"]
    assert "collective" not in line["polynomial"]


# ------------------------------------------------------------------ every shipped example loads
# examples/plugin is a third-party distribution (its pyproject.toml, and a scene for its own solver,
# which is not installed here): tests/plugin/test_plugin.py loads and runs it in an environment of its own
OURS = [p for p in EXAMPLES.rglob("*.toml") if "plugin" not in p.relative_to(EXAMPLES).parts]
SCENES = sorted(p for p in OURS if "[sweep]" not in p.read_text())
SWEEPS = sorted(p for p in OURS if "[sweep]" in p.read_text())


def test_examples_are_all_found():
    assert len(SCENES) >= 6 and len(SWEEPS) >= 2


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.name)
def test_every_example_scene_loads(path):
    scene = load_scene(path)
    assert scene.solver in installed_solvers()


@pytest.mark.parametrize("path", SWEEPS, ids=lambda p: p.name)
def test_every_example_sweep_loads(path):
    sweep = load_sweep(path)
    assert sweep.cases and all(c.id for c in sweep.cases)
