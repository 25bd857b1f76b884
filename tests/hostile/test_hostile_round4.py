"""Hostile input, fourth round (issue 29, deliverable 7): the findings fixed, one test each.

Each test failed before its fix (checked by running it against the tree before the change).
"""
from __future__ import annotations

import json
import sys
import time
import warnings

import pytest

from helpers.hostile import assert_reported, run_cli
from stepnf.verify import command as verify
from stepnf.scene.model_key import describe_change
from stepnf.runtime.mpi_env import mpi_tmpdir_problem
from stepnf.sweep.store import stale_cases
from helpers.scenes import polynomial_scene


# ------------------------------------------------------------------ verify: validity limit 0
def test_default_amplitudes_of_a_backbone_without_validity_range_are_none():
    """A validity limit of 0 (the stage found no valid amplitude) is not "no limit": no amplitude is
    chosen, and why is said (before: the 10% frequency shift's amplitude, A ~ 1e7 on a linear model)."""
    amps, why = verify.default_amplitudes(None, (0.0, "forces inaccurate"))
    assert amps == [] and "no validity range" in why and "forces inaccurate" in why


def test_verify_of_a_linear_model_checks_nothing_and_says_why(tmp_path, capsys):
    """A model without nonlinearity: the backbone has no validity range (tests/dpim/test_backbone_trust), so
    verify checks no orbit and says so (before: three orbits at A = 2.2e7 .. 6.6e7, 'omega shifted by 10%')."""
    path = polynomial_scene(tmp_path, G_scale=0.0)
    o = run_cli(["verify", path], capsys)
    assert o.code == 0, o.err
    assert "no validity range" in o.out and "forces inaccurate" in o.out
    assert "e+07" not in o.out and "orbit 1 of" not in o.err
    o = run_cli(["verify", path, "--amplitudes", "0.01"], capsys)
    assert_reported(o, codes=(2,), mentions=["--amplitudes", "no validity range", "forces inaccurate"])


# ------------------------------------------------------------------ checkpoint: an edited model_key.json
@pytest.mark.parametrize("stored", ['{"key_version": 1, "files": {"x": 5}}',
                                    '{"key_version": 1, "model": {"a": 1}, "files": [1]}',
                                    '{"key_version": 1, "files": {"x": {"path": 3}}, "analysis": 7}'])
def test_edited_checkpoint_key_is_not_reused(tmp_path, capsys, stored):
    """A checkpoint's model_key.json edited into a key of another shape: the chunks are dropped with the
    usual warning and the run goes on (before: an internal error, exit 1, in describe_change)."""
    path = polynomial_scene(tmp_path)
    partial = tmp_path / "out" / ".s.partial"
    partial.mkdir(parents=True)
    (partial / "model_key.json").write_text(stored)
    (partial / "dnf_000000.npz").write_bytes(b"")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        o = run_cli(["run", path, "-q", "--no-plot"], capsys)
    assert o.code == 0, o.err
    assert any("not reused" in str(w.message) for w in caught)


def test_describe_change_of_a_damaged_key_says_so():
    new = {"key_version": 1, "solver": "polynomial", "files": {}, "model": {}}
    for old in ({"key_version": 1, "files": {"x": 5}}, {"key_version": 1, "files": [1], "model": {"a": 1}},
                {"key_version": 1, "model": [1, 2]}, {"key_version": 1, "files": {"k": {"path": None}}}):
        assert isinstance(describe_change(old, new), str)


# ------------------------------------------------------------------ sweep store: edited inputs of a case no longer in the sweep
@pytest.mark.parametrize("inputs", ['{"key_version": 1, "files": [1, 2]}', '{"key_version": 1, "files": {"a": 5}}'])
def test_store_case_with_damaged_inputs_is_stale(inputs):
    """A stored case no longer in the sweep whose recorded key was edited into another shape is stale
    (which model computed it cannot be told), not an internal error (before: exit 1, AttributeError)."""
    stale, gone = stale_cases({"ghost": {"key": "x", "inputs": inputs}}, {})
    assert not stale and "damaged" in gone["ghost"]


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_store_inputs_naming_a_device_or_fifo_are_not_read(tmp_path, special):
    """A recorded input path that is a device or a FIFO is not hashed (before: the sweep read /dev/zero
    for ever, or blocked opening the FIFO); such a path is no input file of a model, so it changed."""
    import os

    if special == "fifo":
        special = str(tmp_path / "fifo")
        os.mkfifo(special)
    inputs = json.dumps({"key_version": 1, "files": {"a": {"path": special, "sha256": "x"}}})
    t0 = time.perf_counter()
    stale, gone = stale_cases({"ghost": {"key": "x", "inputs": inputs}}, {})
    assert time.perf_counter() - t0 < 5 and special in gone["ghost"]


# ------------------------------------------------------------------ show: a validity limit edited to inf or < 0
@pytest.mark.parametrize("value", ["inf", -1.0, True])
def test_show_refuses_an_impossible_validity_limit(tmp_path, capsys, value):
    """stepnf stores a backbone's ``valid_up_to`` as null (not reached) or a number >= 0; an edited
    ``"inf"`` was shown as "valid up to A = inf" with every row valid, -1 as a limit (before: exit 0)."""
    import h5py

    path = polynomial_scene(tmp_path)
    assert run_cli(["run", path, "-q", "--no-plot"], capsys).code == 0
    h5 = tmp_path / "out" / "s.h5"
    with h5py.File(h5, "r+") as f:
        doc = json.loads(f.attrs["json"])
        doc["modes"][0]["backbone"]["valid_up_to"] = value
        f.attrs["json"] = json.dumps(doc)
    o = run_cli(["show", h5], capsys)
    assert_reported(o, codes=(2,), mentions=[str(h5), "valid_up_to"])
    assert "valid up to A = inf" not in o.out


# ------------------------------------------------------------------ MPI: a TMPDIR Open MPI cannot use
def _tmpdir(monkeypatch, path):
    for var in ("OMPI_MCA_orte_tmpdir_base", "TEMP", "TMP"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("TMPDIR", str(path))
    monkeypatch.delitem(sys.modules, "petsc4py.PETSc", raising=False)  # as if MPI were not started yet
    monkeypatch.delitem(sys.modules, "mpi4py.MPI", raising=False)


def test_tmpdir_with_a_bracket_is_a_problem(tmp_path, monkeypatch):
    """Open MPI 4 (Debian 12) aborts MPI_Init with ~50 lines and exit 1 ("Comm failure" in
    ess_singleton) when its session folder's path holds a '[' (checked by hand: TMPDIR=/tmp/t[x, a
    writable folder; ']', spaces, quotes, '$', control characters and 1159-character paths all start)."""
    folder = tmp_path / "t[x"
    folder.mkdir()
    _tmpdir(monkeypatch, folder)
    got = mpi_tmpdir_problem()
    assert got is not None and "'['" in got and f"TMPDIR={folder}" in got


def test_tmpdir_that_cannot_be_written_even_by_root_is_a_problem(monkeypatch):
    """/proc: os.access says writable to root, yet nothing can be created there (Open MPI aborted, exit 1)."""
    _tmpdir(monkeypatch, "/proc")
    got = mpi_tmpdir_problem()
    assert got is not None and "TMPDIR=/proc" in got


# ------------------------------------------------------------------ sweep --recompute-stale: what the warning says
def test_recompute_warning_names_each_case_under_its_own_count(tmp_path):
    """Only stale cases no longer in the sweep: the warning said "0 stored cases computed for another model
    (case ghost: ...) recomputed; 1 stale cases no longer in the sweep removed" (the removed case quoted
    as a recomputed one's reason)."""
    from types import SimpleNamespace

    from stepnf.errors import StaleWarning
    from stepnf.sweep.dask_sweep import _stale

    sweep = SimpleNamespace(store=tmp_path / "st.h5", file=tmp_path / "sweep.toml")
    with pytest.warns(StaleWarning) as rec:
        _stale(sweep, {}, {"ghost": "model.file /x changed"}, True)
    text = str(rec[0].message)
    assert "0 stored" not in text and "1 stale case no longer in the sweep removed (case ghost: model.file /x " \
        "changed)" in text
    with pytest.warns(StaleWarning) as rec:
        _stale(sweep, {"a": "A changed", "b": "B changed"}, {"ghost": "G changed"}, True)
    text = str(rec[0].message)
    assert "2 stored cases computed for another model recomputed (case a: A changed)" in text
    assert "1 stale case no longer in the sweep removed (case ghost: G changed)" in text


# ------------------------------------------------------------------ command line: argparse's own errors
def test_unrecognised_arguments_are_printed_inert(tmp_path, capsys):
    """``stepnf run *`` in a folder holding a file named with a terminal escape: argparse's "unrecognized
    arguments" echoed it raw (the window title set, the screen cleared); now as the other messages, escaped."""
    o = run_cli(["run", tmp_path / "s.toml", "\x1b]0;PWNED\x07", "\x9b2J"], capsys)
    assert o.code == 2 and "unrecognized arguments" in o.err
    assert "\x1b" not in o.err and "\x07" not in o.err and "\x9b" not in o.err and "\\x1b]0;PWNED\\x07" in o.err


# ------------------------------------------------------------------ code_aster: a command placeholder nobody fills
def test_code_aster_command_with_an_unknown_placeholder_is_input(tmp_path, capsys):
    """``command = "${nonexistent} x"`` (allowed): found when the model is built, exit 2 naming the scene
    and the placeholder (before: exit 3 "[model] command: placeholder(s) ... left unfilled", without the
    file, after the mesh was generated and written, when the first job was rendered)."""
    from helpers.programs import code_aster_scene

    s = code_aster_scene(tmp_path / "ca", 'command = "${nonexistent} x"\n')
    o = run_cli(["run", s, "-q", "--no-plot", "--allow-programs"], capsys)
    assert_reported(o, codes=(2,), mentions=[str(s), "command", "nonexistent"])


def test_verify_says_the_scene_amplitudes_were_all_left_out(tmp_path, capsys):
    """Every [analysis.backbone] amplitude beyond the validity limit (0.33 here): verify checks its default
    amplitudes instead and says why (before: only "amplitudes from validity limit ...", the scene's silently
    dropped)."""
    path = polynomial_scene(tmp_path, backbone="order = 5\namplitudes = [0.5, 0.9]\n")
    o = run_cli(["verify", path], capsys)
    assert o.code == 0, o.err
    assert "[analysis.backbone] amplitudes (2 beyond the validity limit left out)" in o.out


# ------------------------------------------------------------------ checkpoint: a chunk that is not a regular file
def test_checkpoint_chunk_that_is_a_fifo_is_not_read(tmp_path):
    """A FIFO (or any non-regular file, a link included) where a chunk belongs is recomputed, not opened
    (before: np.load blocked on the FIFO for ever, the run hung at its first reuse)."""
    import os
    import threading

    import numpy as np

    from stepnf.step.checkpoint import Checkpoint

    cp = Checkpoint(tmp_path / ".s.partial")
    cp.folder.mkdir()
    os.mkfifo(cp.folder / "dnf_000000.npz")
    (cp.folder / "dnf_000001.npz").symlink_to(tmp_path / "elsewhere.npz")
    got = {}
    t = threading.Thread(target=lambda: got.update(a=cp.load("dnf", 0, np.ones((2, 3))),
                                                   b=cp.load("dnf", 1, np.ones((2, 3)))), daemon=True)
    t.start()
    t.join(10)
    assert not t.is_alive() and got == {"a": None, "b": None}


# ------------------------------------------------------------------ verify: the header names the integrator chosen
def test_verify_header_names_the_implicit_integrator_when_every_orbit_failed(tmp_path, capsys, monkeypatch):
    """The model judged stiff (STIFF_RATIO lowered to 0 here: "auto" picks the implicit integrator for the
    2-dof system) and every orbit failing: the header still names the implicit integrator (before: it was
    read from the orbits that succeeded, none, and said "DOP853")."""
    from stepnf.verify import periodic
    from stepnf.errors import NumericalError
    from helpers.scenes import run_verify, write_two_dof_scene

    def fail(self, A, **kw):
        raise NumericalError("shooting: Newton did not converge in 25 iterations")
    monkeypatch.setattr(periodic, "STIFF_RATIO", 0.0)
    monkeypatch.setattr(periodic.Shooting, "at_amplitude", fail)
    code, out, err = run_verify(capsys, write_two_dof_scene(tmp_path), "--amplitudes", 0.2, "--quiet")
    header = out.splitlines()[0]
    assert code == 3 and "Traceback" not in err, err
    assert "implicit Gauss-Legendre" in header and "DOP853" not in header, header
    assert "no orbit: master mode 0" in out


# ------------------------------------------------------------------ sweep: a scheduler nobody answers at
def closed_port() -> int:
    """A loopback port nothing listens on (bound, then closed): a connection to it is refused at once."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("where", ["file", "option"])
def test_unreachable_scheduler_names_the_key_or_the_option(tmp_path, capsys, where):
    """An address Dask cannot reach: exit 3, naming the sweep file and ``[sweep.dask] scheduler`` (or
    ``--scheduler``) beside the address (before: Dask's "Timed out trying to connect to tcp://... after
    30 s" alone). Dask's connect timeout lowered to 2 s (distributed.comm.timeouts.connect) to keep it short."""
    import dask
    import distributed  # noqa: F401 - its defaults loaded first: leaving config.set would otherwise drop them

    from stepnf_polynomial.adapter import save_system
    from helpers.systems import two_dof

    save_system(tmp_path / "two_dof.npz", *two_dof())
    (tmp_path / "base.toml").write_text('[model]\nsolver = "polynomial"\nfile = "two_dof.npz"\n'
                                        '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\n')
    address = f"tcp://127.0.0.1:{closed_port()}"
    dask_table = f'[sweep.dask]\nscheduler = "{address}"\n' if where == "file" else ""
    s = tmp_path / "s.toml"
    s.write_text('[sweep]\nname = "st"\nbase = "base.toml"\n[sweep.vary]\n"analysis.retained_modes" = [2]\n'
                 f'{dask_table}[output]\ndir = "out"\n')
    args = ["sweep", s, "--quiet"] + (["--allow-programs"] if where == "file" else ["--scheduler", address])
    t0 = time.perf_counter()
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        o = run_cli(args, capsys)
    assert time.perf_counter() - t0 < 30
    key = "[sweep.dask] scheduler" if where == "file" else "--scheduler"
    assert_reported(o, codes=(3,), mentions=["s.toml", key, address])
