"""Nothing runs that the user did not allow (issue 29, finding 4 and 11b).

A scene names a program through the calculix adapter's ``executable``, the code_aster adapter's
``command`` and ``templates`` (command files are Python, run by code_aster). Each is refused (exit 2,
naming the file, the key and how to allow it) unless the user allows it outside the scene
(``--allow-programs``, ``STEPNF_ALLOW_PROGRAMS=1``, ``allow_programs=True``); when allowed, the
full command is printed before it runs, and a relative path is the scene folder's. The "program" here
is a shell script that leaves a marker file: neither ccx nor code_aster is needed.
"""
from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

import numpy as np
import pytest

from hostile import assert_reported, run_cli, run_cli_process
from stepnf.errors import SceneError

pytest.importorskip("stepnf_calculix")
pytest.importorskip("stepnf_code_aster")

EVIL = '#!/bin/sh\ntouch "$(dirname "$0")/MARKER"\necho "evil ran: $*"\nexit 7\n'
MATERIAL = "[model.material]\nE = 2.0e11\nnu = 0.3\nrho = 7800.0\n"
ANALYSIS = '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\nretained_modes = 4\n[output]\ndir = "out"\nplot = false\n'
CAP = '[model.geometry]\nshape = "spherical_cap"\na = 0.15\nR = 1.5\nh = 0.003\nn_core = 2\nn_ring = 1\n'


def script(path: Path, text: str = EVIL) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return path


def calculix_scene(folder: Path, extra: str = 'executable = "./evil.sh"\n') -> Path:
    """A one-brick CalculiX mesh scene in ``folder`` naming ``./evil.sh`` (beside it)."""
    from stepnf_calculix.deck import mesh_text

    from test_hostile_meshes import hex20_block

    p, c = hex20_block(1, 1, 1)
    ids = np.arange(1, len(p) + 1)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "part.inp").write_text(mesh_text(ids, p, [("C3D20", np.arange(1, len(c) + 1), ids[c])]))
    script(folder / "evil.sh")
    s = folder / "s.toml"
    s.write_text('[model]\nsolver = "calculix"\nmesh = "part.inp"\n' + extra + MATERIAL + ANALYSIS)
    return s


def code_aster_scene(folder: Path, extra: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    script(folder / "evil.sh")
    s = folder / "s.toml"
    s.write_text('[model]\nsolver = "code_aster"\n' + extra + CAP + MATERIAL + ANALYSIS)
    return s


@pytest.fixture
def elsewhere(tmp_path, monkeypatch):
    """Run from a folder that is not the scene's (a relative program must still be the scene's)."""
    other = tmp_path / "elsewhere"
    other.mkdir()
    script(other / "evil.sh", '#!/bin/sh\ntouch "$(dirname "$0")/WRONG_MARKER"\nexit 7\n')  # the cwd's: never run
    monkeypatch.chdir(other)
    monkeypatch.delenv("STEPNF_ALLOW_PROGRAMS", raising=False)
    return other


# ------------------------------------------------------------------ calculix executable
@pytest.mark.parametrize("command", ["run", "modes", "check", "verify"])
def test_calculix_executable_refused_without_permission(tmp_path, elsewhere, capsys, command):
    s = calculix_scene(tmp_path / "scene")
    o = run_cli([command, s, "-q"] if command in ("run", "modes") else [command, s], capsys)
    assert_reported(o, codes=(2,), mentions=[str(s), "[model.executable]", "./evil.sh", "--allow-programs",
                                             "STEPNF_ALLOW_PROGRAMS=1"])
    assert not (tmp_path / "scene" / "MARKER").exists() and not (elsewhere / "WRONG_MARKER").exists()
    assert "running a program" not in o.err


@pytest.mark.parametrize("how", ["flag", "environment"])
def test_calculix_executable_runs_with_permission_from_the_scene_folder(tmp_path, elsewhere, capsys, monkeypatch,
                                                                        how):
    s = calculix_scene(tmp_path / "scene")
    args = ["run", s, "-q"]
    if how == "flag":
        args.append("--allow-programs")
    else:
        monkeypatch.setenv("STEPNF_ALLOW_PROGRAMS", "1")
    o = run_cli(args, capsys)
    assert_reported(o, codes=(3,), mentions=["exited with code 7"])  # the script ran (and failed on purpose)
    assert (tmp_path / "scene" / "MARKER").exists()  # the scene folder's ./evil.sh
    assert not (elsewhere / "WRONG_MARKER").exists()  # not the current folder's
    exe = tmp_path / "scene" / "evil.sh"
    line = f"stepnf: running a program named by [model] executable of {s}: {exe} -i matrices"
    assert line in o.err.splitlines()
    assert o.err.index(line) < o.err.index("exited with code 7")  # printed before it ran


def test_environment_value_must_be_yes_or_no(tmp_path, elsewhere, capsys, monkeypatch):
    monkeypatch.setenv("STEPNF_ALLOW_PROGRAMS", "maybe")
    o = run_cli(["run", calculix_scene(tmp_path / "scene"), "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["STEPNF_ALLOW_PROGRAMS", "'maybe'"])
    assert not (tmp_path / "scene" / "MARKER").exists()


def test_default_program_needs_no_permission(tmp_path, elsewhere, capsys, monkeypatch):
    """No executable key: ccx found on PATH runs without the flag, and no line announces it."""
    bindir = tmp_path / "bin"
    script(bindir / "ccx")
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ['PATH']}")
    o = run_cli(["run", calculix_scene(tmp_path / "scene", extra=""), "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["exited with code 7"])
    assert (bindir / "MARKER").exists() and "running a program" not in o.err


def test_python_keyword(tmp_path, elsewhere):
    """load_scene(..., allow_programs=True): the decision travels with the scene to the model build."""
    from stepnf.registry import build_model
    from stepnf.scene import load_scene

    s = calculix_scene(tmp_path / "scene")
    with pytest.raises(SceneError) as ei:
        load_scene(s)
    assert ei.value.key == "model.executable"
    scene = load_scene(s, allow_programs=True)
    ad = build_model(scene)
    assert ad.executable == str(tmp_path / "scene" / "evil.sh")
    assert ad.program_named_by == f"[model] executable of {s}"
    with pytest.raises(SceneError):  # an explicit False wins over the environment
        os.environ["STEPNF_ALLOW_PROGRAMS"] = "1"
        try:
            load_scene(s, allow_programs=False)
        finally:
            del os.environ["STEPNF_ALLOW_PROGRAMS"]


# ------------------------------------------------------------------ code_aster command and templates
def test_code_aster_command_refused_then_run_from_the_scene_folder(tmp_path, elsewhere, capsys):
    s = code_aster_scene(tmp_path / "scene", 'command = "./evil.sh ${export}"\n')
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=[str(s), "[model.command]", "--allow-programs"])
    assert not (tmp_path / "scene" / "MARKER").exists()
    o = run_cli(["run", s, "-q", "--allow-programs"], capsys)
    assert_reported(o, codes=(3,), mentions=["exited with code 7"])
    assert (tmp_path / "scene" / "MARKER").exists() and not (elsewhere / "WRONG_MARKER").exists()
    exe = tmp_path / "scene" / "evil.sh"
    assert f"stepnf: running a program named by [model] command of {s}: {exe} " in o.err
    assert o.err.index("running a program") < o.err.index("exited with code 7")


def test_code_aster_templates_refused_then_run(tmp_path, elsewhere, capsys, monkeypatch):
    """templates: Python that code_aster runs. The default command (run_aster on PATH, faked) is not the
    scene's, yet the scene's command files are: refused without permission, announced with it."""
    bindir = tmp_path / "bin"
    script(bindir / "run_aster")
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ['PATH']}")
    (tmp_path / "scene" / "tpl").mkdir(parents=True)
    (tmp_path / "scene" / "tpl" / "matrices.comm").write_text("import os\nos.system('touch /tmp/pwned')\n")
    s = code_aster_scene(tmp_path / "scene", 'templates = "tpl"\n')
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=[str(s), "[model.templates]", "--allow-programs"])
    assert not (bindir / "MARKER").exists()
    o = run_cli(["run", s, "-q", "--allow-programs"], capsys)
    assert_reported(o, codes=(3,), mentions=["exited with code 7"])
    assert (bindir / "MARKER").exists()
    assert f"stepnf: running a program named by [model] templates of {s}: {bindir / 'run_aster'} " in o.err
    # without templates or command, the shipped templates and run_aster need no permission
    (bindir / "MARKER").unlink()
    o = run_cli(["run", code_aster_scene(tmp_path / "plain", ""), "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["exited with code 7"])
    assert (bindir / "MARKER").exists() and "running a program" not in o.err


@pytest.mark.parametrize("key, value", [
    ("mesh_name", 'x")\\nimport os\\nos.system("touch /tmp/pwned")\\n#'),  # Python into the command files
    ("version", "stable\\nF comm /tmp/evil.comm D 1"),  # a line into the .export file
])
def test_code_aster_values_cannot_inject_code(tmp_path, key, value):
    from stepnf_code_aster import CodeAsterAdapter
    from stepnf.geometry import spherical_cap

    mesh = spherical_cap(0.15, 1.5, 0.003, element="hex20", n_core=2, n_ring=1)
    with pytest.raises(ValueError, match=key):
        CodeAsterAdapter.from_volume_mesh(mesh, material={"E": 1.0, "nu": 0.3, "rho": 1.0},
                                          **{key: value.encode().decode("unicode_escape")})


# ------------------------------------------------------------------ sweeps
def _sweep(tmp_path: Path) -> Path:
    base = calculix_scene(tmp_path / "scene", extra="")
    sw = tmp_path / "sweep.toml"
    sw.write_text('[sweep]\nname = "p"\nbase = "scene/s.toml"\n[sweep.vary]\n"model.executable" = ["./evil.sh"]\n'
                  '[sweep.dask]\nn_workers = 1\n[output]\ndir = "out"\n')
    assert base.is_file()
    return sw


def test_sweep_case_naming_a_program_is_refused(tmp_path, elsewhere, capsys):
    sw = _sweep(tmp_path)
    o = run_cli(["sweep", sw, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=[str(sw), "[model.executable]", "--allow-programs"])
    assert not (tmp_path / "scene" / "MARKER").exists() and not (tmp_path / "out").exists()


def test_sweep_workers_take_the_decision_of_the_top_level(tmp_path, monkeypatch):
    """run_case (the Dask task) obeys the decision it is given, not the worker's environment."""
    from stepnf.errors import SolverRunError
    from stepnf.sweep import load_sweep, run_case

    sw = _sweep(tmp_path)
    monkeypatch.delenv("STEPNF_ALLOW_PROGRAMS", raising=False)
    sweep = load_sweep(sw, allow_programs=True)
    assert sweep.allow_programs is True
    (case,) = sweep.cases
    monkeypatch.setenv("STEPNF_ALLOW_PROGRAMS", "1")  # a worker whose environment would allow
    with pytest.raises(SceneError, match="--allow-programs"):
        run_case(case.data, case.file, case.base_dir, False)
    assert not (tmp_path / "scene" / "MARKER").exists()
    monkeypatch.setenv("STEPNF_ALLOW_PROGRAMS", "0")  # a worker whose environment would refuse
    with pytest.raises(SolverRunError, match="exited with code 7"):
        run_case(case.data, case.file, case.base_dir, True)
    assert (tmp_path / "scene" / "MARKER").exists()


def test_sweep_with_permission_runs_on_dask_workers(tmp_path):
    """The whole way: `stepnf sweep --allow-programs` in a fresh process, its Dask worker runs the case."""
    sw = _sweep(tmp_path)
    env = {"STEPNF_ALLOW_PROGRAMS": "0", "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    o = run_cli_process(["sweep", sw, "-q", "--allow-programs"], cwd=tmp_path / "scene", env=env, timeout=240)
    assert o.code == 4, o.err  # the one case failed (the script exits 7), stored as failed
    assert (tmp_path / "scene" / "MARKER").exists()


# ------------------------------------------------------------------ *INCLUDE quotes nothing (11b)
@pytest.mark.parametrize("key, deck, star", [
    ("deck", "*NODE\n1, 0, 0, 0\n*INCLUDE, INPUT={secret}\n", "*"),  # read as a keyword
    ("deck", "*NODE\n1, 0, 0, 0\n*INCLUDE, INPUT={secret}\n", ""),  # as a node line
    ("mesh", "*NODE\n1, 0, 0, 0\n*ELEMENT, TYPE=C3D8\n*INCLUDE, INPUT={secret}\n", ""),  # as an element line
    ("deck", "*NODE\n1, 0, 0, 0\n*NSET, NSET=A, GENERATE\n*INCLUDE, INPUT={secret}\n", ""),  # as a range
])
def test_include_error_does_not_quote_the_included_file(tmp_path, capsys, key, deck, star):
    secret = tmp_path / "private" / "shadow"
    secret.parent.mkdir()
    secret.write_text(star + "root:$6$SECRETHASH$xyz:19000:0:99999, OPT=hunter2:::\nalice:$6$OTHERHASH:19000\n")
    (tmp_path / "m.inp").write_text(deck.format(secret=secret))
    s = tmp_path / "s.toml"
    s.write_text(f'[model]\nsolver = "calculix"\n{key} = "m.inp"\n' + (MATERIAL if key == "mesh" else "") + ANALYSIS)
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=[str(tmp_path / "m.inp"), f"line 1 of {secret}", "not shown"])
    for leaked in ("SECRETHASH", "hunter2", "19000", "99999", "OTHERHASH", "alice"):
        assert leaked not in o.err, o.err


def test_error_on_the_top_file_still_quotes_it(tmp_path, capsys):
    (tmp_path / "m.inp").write_text("*NODE\n1, 0, 0, 0\n*ELEMENT, TYPE=C3D8\nxyz, 1\n")
    s = tmp_path / "s.toml"
    s.write_text('[model]\nsolver = "calculix"\ndeck = "m.inp"\n' + ANALYSIS)
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["line 4", "'xyz'"])


def test_sweep_file_naming_a_scheduler_is_refused(tmp_path, elsewhere, capsys):
    """Dask unpickles what the scheduler's cluster sends back: a received sweep file must not choose it."""
    calculix_scene(tmp_path / "scene", extra="")
    sw = tmp_path / "sweep.toml"
    sw.write_text('[sweep]\nname = "p"\nbase = "scene/s.toml"\n[sweep.vary]\n"analysis.retained_modes" = [3]\n'
                  '[sweep.dask]\nscheduler = "tcp://127.0.0.1:9"\n[output]\ndir = "out"\n')
    o = run_cli(["sweep", sw, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=[str(sw), "[sweep.dask.scheduler]", "--allow-programs", "--scheduler"])
    assert not (tmp_path / "out").exists()
    from stepnf.sweep import load_sweep

    assert load_sweep(sw, allow_programs=True).scheduler == "tcp://127.0.0.1:9"
