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
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers.hostile import assert_reported, run_cli, run_cli_process
from helpers.programs import ANALYSIS, MATERIAL, code_aster_scene, script
from stepnf.errors import SceneError

pytest.importorskip("stepnf_calculix")
pytest.importorskip("stepnf_code_aster")


def calculix_scene(folder: Path, extra: str = 'executable = "./evil.sh"\n') -> Path:
    """A one-brick CalculiX mesh scene in ``folder`` naming ``./evil.sh`` (beside it)."""
    from stepnf_calculix.deck import mesh_text

    from helpers.meshes import hex20_block

    p, c = hex20_block(1, 1, 1)
    ids = np.arange(1, len(p) + 1)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "part.inp").write_text(mesh_text(ids, p, [("C3D20", np.arange(1, len(c) + 1), ids[c])]))
    script(folder / "evil.sh")
    s = folder / "s.toml"
    s.write_text('[model]\nsolver = "calculix"\nmesh = "part.inp"\n' + extra + MATERIAL + ANALYSIS)
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
    from stepnf.plugin.registry import build_model
    from stepnf.scene.parse import load_scene

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
    ("workdir", 'w");__import__("os").system("touch PWNED");print("'),  # Python into np.savez("...") (review 1)
    ("workdir", "evil.comm D 1 x"),  # spaces split the .export's F lines: code_aster would read evil.comm
])
def test_code_aster_values_cannot_inject_code(tmp_path, monkeypatch, key, value):
    from stepnf_code_aster import CodeAsterAdapter
    from stepnf.geometry import spherical_cap

    monkeypatch.chdir(tmp_path)  # a relative workdir lands here (refused before any folder is made)
    mesh = spherical_cap(0.15, 1.5, 0.003, element="hex20", n_core=2, n_ring=1)
    with pytest.raises(ValueError, match=key):
        CodeAsterAdapter.from_volume_mesh(mesh, material={"E": 1.0, "nu": 0.3, "rho": 1.0},
                                          **{key: value.encode().decode("unicode_escape")})
    assert not (tmp_path / "PWNED").exists()


def test_code_aster_temporary_folder_with_a_space_is_refused(tmp_path, monkeypatch):
    """No workdir: the work folders go to the temporary folder (TMPDIR), whose path the .export file holds too."""
    from stepnf_code_aster import CodeAsterAdapter
    from stepnf.geometry import spherical_cap

    import tempfile

    spaced = tmp_path / "my temp"
    spaced.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(spaced))
    mesh = spherical_cap(0.15, 1.5, 0.003, element="hex20", n_core=2, n_ring=1)
    with pytest.raises(ValueError, match="TMPDIR") as ei:
        CodeAsterAdapter.from_volume_mesh(mesh, material={"E": 1.0, "nu": 0.3, "rho": 1.0})
    assert str(spaced) in str(ei.value) and "workdir" in str(ei.value)


def test_code_aster_workdir_with_a_space_names_the_key(tmp_path, elsewhere, capsys):
    s = code_aster_scene(tmp_path / "scene", 'workdir = "evil.comm D 1 x"\n')
    o = run_cli(["modes", s, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=[str(s), "[model.workdir]", "evil.comm D 1 x", "no space, quote"])


def test_code_aster_work_folder_checked_where_it_is_written(tmp_path):
    """The folder a job is rendered into is checked again (the .export file names its files)."""
    from stepnf.errors import SolverRunError
    from stepnf_code_aster import CodeAsterAdapter
    from stepnf.geometry import spherical_cap

    mesh = spherical_cap(0.15, 1.5, 0.003, element="hex20", n_core=2, n_ring=1)
    ad = CodeAsterAdapter.from_volume_mesh(mesh, material={"E": 1.0, "nu": 0.3, "rho": 1.0}, workdir=tmp_path)
    wd = tmp_path / 'x" D 1'
    wd.mkdir()
    with pytest.raises(SolverRunError, match="work folder"):
        ad.render_job(wd, "matrices")
    assert list(wd.iterdir()) == []  # nothing written


def test_code_aster_paths_are_python_literals_in_the_command_files(tmp_path, monkeypatch):
    """Second line of defence: with the folder check switched off, the payload of review item 1 stays a string
    in matrices.comm (the shipped templates hold repr()-rendered values, not "${...}")."""
    import ast

    import stepnf_code_aster.adapter as ca_adapter
    from stepnf_code_aster import CodeAsterAdapter
    from stepnf.geometry import spherical_cap

    monkeypatch.setattr(ca_adapter, "export_folder_problem", lambda folder: "")
    mesh = spherical_cap(0.15, 1.5, 0.003, element="hex20", n_core=2, n_ring=1)
    ad = CodeAsterAdapter.from_volume_mesh(mesh, material={"E": 1.0, "nu": 0.3, "rho": 1.0})
    wd = tmp_path / 'w");__import__("os").system("touch PWNED");print("'
    wd.mkdir()
    ad.render_job(wd, "matrices")
    tree = ast.parse((wd / "matrices.comm").read_text())
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    assert "__import__" not in names
    (savez,) = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "attr", "") == "savez"]
    assert savez.args[0].value == str(wd / "matrices.npz")


@pytest.mark.parametrize("name", ['it\'s "odd" \\ name\n', "plain", "caf\u00e9\u2028x"])
def test_python_string_literals_read_back(name):
    """The values written into code_aster's command files are Python string literals of exactly the value."""
    import ast

    from stepnf_code_aster.adapter import python_str

    text = python_str(name)
    assert ast.literal_eval(text) == name and "\n" not in text
    assert text.startswith('"') or '"' in name  # as the shipped templates were written (GROUP_MA="CORE")


def test_code_aster_default_command_written_out_needs_no_permission(tmp_path, elsewhere):
    """The documented default command, written out in a scene, names no program of the scene's (review 2)."""
    from stepnf.plugin.registry import build_model
    from stepnf.scene.parse import load_scene
    from stepnf_code_aster.adapter import DEFAULT_COMMAND

    s = code_aster_scene(tmp_path / "scene", f'command = "{DEFAULT_COMMAND}"\nversion = "stable"\n')
    model = build_model(load_scene(s))
    assert model.program_named_by is None and model.command.text == DEFAULT_COMMAND


def test_stepnf_check_on_a_code_aster_scene(tmp_path, elsewhere, capsys, monkeypatch):
    """`stepnf check` builds the model again with the documented defaults filled in (check_from_config),
    among them command = "run_aster ${export}": no permission is needed for it (review 2). run_aster is
    test_code_aster's fake (f = K u + u^3, M = I)."""
    from helpers.code_aster import FAKE_RUN_ASTER

    bindir = tmp_path / "bin"
    script(bindir / "run_aster", FAKE_RUN_ASTER.format(python=sys.executable))
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ['PATH']}")
    o = run_cli(["check", code_aster_scene(tmp_path / "scene", "")], capsys)
    assert "allow-programs" not in o.out + o.err, o.out + o.err
    assert ["passed", "from_config"] in [x.split() for x in o.out.splitlines()], o.out
    assert o.code == 0, o.out + o.err  # every check passed on the fake (f = K u + u^3 is conservative)


def test_code_aster_missing_hint_names_the_permission(tmp_path, elsewhere, capsys, monkeypatch):
    """The hint for a missing run_aster proposes a docker command: a command the scene names, so it says
    that this needs --allow-programs (review N9)."""
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    o = run_cli(["modes", code_aster_scene(tmp_path / "scene", ""), "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["'run_aster' not found", "docker run", "--allow-programs"])


@pytest.mark.parametrize("entry", [".", "", "scene"])
def test_default_program_ignores_relative_path_entries(tmp_path, elsewhere, capsys, monkeypatch, entry):
    """PATH holding ".", an empty entry (the current folder too) or a relative folder: a ccx found
    through it is not run, the absolute entries are searched (review N10)."""
    script(elsewhere / "ccx", '#!/bin/sh\ntouch "$(dirname "$0")/WRONG_MARKER"\nexit 7\n')
    script(elsewhere / "scene" / "ccx", '#!/bin/sh\ntouch "$(dirname "$0")/WRONG_MARKER"\nexit 7\n')
    bindir = tmp_path / "bin"
    script(bindir / "ccx")
    monkeypatch.setenv("PATH", os.pathsep.join([entry, str(bindir), "/usr/bin", "/bin"]))  # the script needs touch
    o = run_cli(["modes", calculix_scene(tmp_path / "scene", extra=""), "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["exited with code 7", str(bindir / "ccx")])
    assert (bindir / "MARKER").exists()
    assert not (elsewhere / "WRONG_MARKER").exists() and not (elsewhere / "scene" / "WRONG_MARKER").exists()


def test_only_a_relative_path_entry_finds_nothing(tmp_path, elsewhere, capsys, monkeypatch):
    script(elsewhere / "ccx", '#!/bin/sh\ntouch "$(dirname "$0")/WRONG_MARKER"\nexit 7\n')
    monkeypatch.setenv("PATH", ".")
    o = run_cli(["modes", calculix_scene(tmp_path / "scene", extra=""), "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["'ccx' not found"])
    assert not (elsewhere / "WRONG_MARKER").exists()


def test_program_notice_printed_once_before_every_parallel_run(tmp_path, monkeypatch):
    """parallel_runs > 1: the runs wait for the one notice of the program the scene named (review 10)."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    import stepnf.external.adapter as ext
    import stepnf.runtime.programs as programs
    from stepnf.external.process import RunRecord

    events: list[tuple[str, float]] = []
    lock = threading.Lock()

    def slow_announce(argv, why):
        with lock:
            events.append(("announce", time.monotonic()))
        time.sleep(0.3)  # a slow terminal: the notice is still being written
        with lock:
            events.append(("announced", time.monotonic()))

    def fake_run(argv, *, cwd, **kw):
        with lock:
            events.append(("run", time.monotonic()))
        return RunRecord(tuple(argv), Path(cwd), Path(cwd) / "log", 0.0)

    monkeypatch.setattr(programs, "announce", slow_announce)
    monkeypatch.setattr(ext, "run_command", fake_run)
    ad = ext.ExternalSolverAdapter(executable="/bin/true", parallel_runs=4)
    ad.program_named_by = "[model] executable of s.toml"
    with ThreadPoolExecutor(max_workers=4) as pool:
        list(pool.map(lambda i: ad.run(["x", str(i)], tmp_path), range(4)))
    kinds = [k for k, _ in events]
    assert kinds.count("announce") == 1 and kinds.count("run") == 4, kinds
    done = dict(events)["announced"]
    assert all(t >= done for k, t in events if k == "run"), kinds


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
    from stepnf.sweep.dask_sweep import load_sweep, run_case

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
    from stepnf.sweep.dask_sweep import load_sweep

    assert load_sweep(sw, allow_programs=True).scheduler == "tcp://127.0.0.1:9"
