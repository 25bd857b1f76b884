"""Received files that attack the user: links in the output folder, terminal control sequences in
a results file (issue 29, findings 5 and 6).

Links: stepnf never writes through a symbolic link. A link where an output goes (``NAME.h5``, the
checkpoint folder ``.NAME.partial``, the field files, figures) is refused before any computation
(exit 2 on ``output.dir``, naming the link); one that appears during the run is refused when the
file is written (exit 3, :class:`OutputError` naming it); in every case the link's target is
untouched. The user's output folder itself may be a link (their choice of where results go).

Printing: whatever comes from a file is shown with its control characters escaped
(:mod:`stepnf.runtime.printable`), never sent raw to the terminal.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import pytest

from helpers.hostile import assert_reported, run_cli
from stepnf.io import atomic
from stepnf.errors import OutputError, StoreError
from stepnf.runtime.printable import printable
from stepnf_polynomial import save_system
from helpers.systems import random_system

VICTIM = b"precious data of someone else\n"


def scene(d: Path, out: str = "out") -> Path:
    save_system(d / "s.npz", *random_system(6, seed=8))
    p = d / "s.toml"
    p.write_text(f'[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\n'
                 f'methods = ["nf", "dnf"]\n[output]\ndir = "{out}"\n')
    return p


def victim(d: Path) -> Path:
    v = d / "victim"
    v.write_bytes(VICTIM)
    return v


# ------------------------------------------------------------------ links (finding 5)
@pytest.mark.parametrize("name", ["s.h5", "s_fields.vtu", "s_modes.png"])
def test_linked_output_file_is_refused_and_its_target_untouched(tmp_path, capsys, name):
    s = scene(tmp_path)
    (tmp_path / "out").mkdir()
    v = victim(tmp_path)
    (tmp_path / "out" / name).symlink_to(Path("..") / "victim")
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, (2,), [str(tmp_path / "out" / name), "symbolic link", "output.dir"])
    assert v.read_bytes() == VICTIM and (tmp_path / "out" / name).is_symlink()


def test_linked_checkpoint_folder_receives_nothing(tmp_path, capsys):
    s = scene(tmp_path)
    (tmp_path / "out").mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (tmp_path / "out" / ".s.partial").symlink_to(elsewhere)
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, (2,), [".s.partial", "symbolic link"])
    assert list(elsewhere.iterdir()) == [] and (tmp_path / "out" / ".s.partial").is_symlink()


def test_writer_refuses_a_link_planted_after_the_check(tmp_path):
    """The atomic writer itself: a link at the target (planted during a run) is refused, exit 3."""
    v = victim(tmp_path)
    (tmp_path / "r.h5").symlink_to(v)
    with pytest.raises(OutputError, match=r"r\.h5 is a symbolic link .*never writes through"):
        atomic.write_bytes(tmp_path / "r.h5", b"new", what="results file")
    assert v.read_bytes() == VICTIM and sorted(p.name for p in tmp_path.iterdir()) == ["r.h5", "victim"]


def test_writer_refuses_a_linked_private_folder(tmp_path):
    """A checkpoint chunk (``private_folder``): the folder stepnf made for itself must be no link."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (tmp_path / ".s.partial").symlink_to(elsewhere)
    with pytest.raises(OutputError, match=r"\.s\.partial is a symbolic link"):
        atomic.write_bytes(tmp_path / ".s.partial" / "c.npz", b"chunk", what="checkpoint chunk",
                           private_folder=True)
    assert list(elsewhere.iterdir()) == []
    atomic.write_bytes(tmp_path / ".t.partial" / "c.npz", b"chunk", private_folder=True)  # made, not a link
    assert (tmp_path / ".t.partial" / "c.npz").read_bytes() == b"chunk"


def test_writer_makes_a_private_folder_0700_whatever_the_umask(tmp_path):
    """Review item 5: the checkpoint folder was created with the umask (0777 under umask 000)."""
    old = os.umask(0)
    try:
        atomic.write_bytes(tmp_path / ".s.partial" / "c.npz", b"chunk", private_folder=True)
    finally:
        os.umask(old)
    assert (tmp_path / ".s.partial").stat().st_mode & 0o777 == 0o700


@pytest.mark.parametrize("bits", [0o777, 0o775, 0o703], ids=["0777", "0775", "0703"])
def test_writer_refuses_a_private_folder_others_can_write(tmp_path, bits):
    """A private folder found writable by group or others (someone may have planted files) is not written."""
    (tmp_path / ".s.partial").mkdir()
    (tmp_path / ".s.partial").chmod(bits)
    with pytest.raises(OutputError, match=rf"\.s\.partial is writable by others \(mode {bits:04o}\)"):
        atomic.write_bytes(tmp_path / ".s.partial" / "c.npz", b"chunk", what="checkpoint chunk",
                           private_folder=True)
    assert list((tmp_path / ".s.partial").iterdir()) == []


def test_writer_refuses_a_private_folder_of_another_user(tmp_path, monkeypatch):
    (tmp_path / ".s.partial").mkdir(mode=0o700)
    owner = (tmp_path / ".s.partial").stat().st_uid
    monkeypatch.setattr(os, "geteuid", lambda: owner + 1)
    with pytest.raises(OutputError, match=rf"\.s\.partial belongs to another user \(uid {owner}\)"):
        atomic.write_bytes(tmp_path / ".s.partial" / "c.npz", b"chunk", private_folder=True)
    assert list((tmp_path / ".s.partial").iterdir()) == []


def test_linked_output_folder_is_the_users_choice(tmp_path, capsys):
    """The output folder itself may be a link (results on another disk): written into its target."""
    s = scene(tmp_path)
    (tmp_path / "disk").mkdir()
    (tmp_path / "out").symlink_to(tmp_path / "disk")
    assert run_cli(["run", s, "-q"], capsys).code == 0
    assert (tmp_path / "disk" / "s.h5").is_file()


# ------------------------------------------------------------------ printing (finding 6)
ESC_TITLE = "\x1b]0;pwned\x07"
ESC_CLEAR = "\x1b[2J\x1b[31m"


def test_printable_escapes_controls_and_keeps_text():
    assert printable("a\tb\nc") == "a\tb\nc"
    assert printable(ESC_TITLE) == "\\x1b]0;pwned\\x07"
    assert printable("x\r\x7f\x9b\u202e\udc80y") == "x\\x0d\\x7f\\x9b\\u202e\\udc80y"
    assert printable("Gamma = +0.42, (2,0), \u00e9\u00e8 \u03c9") == "Gamma = +0.42, (2,0), \u00e9\u00e8 \u03c9"


@pytest.fixture
def hostile_results(tmp_path, capsys) -> Path:
    """A results file whose adapter name, flag messages, label and run flags carry escape sequences."""
    s = scene(tmp_path)
    assert run_cli(["run", s, "-q", "--no-plot"], capsys).code == 0
    h5 = tmp_path / "out" / "s.h5"
    with h5py.File(h5, "r+") as f:
        doc = json.loads(f.attrs["json"])
        doc["model"]["adapter"] = f"Evil{ESC_TITLE}"
        doc["scene"]["solver"] = f"poly{ESC_CLEAR}"
        doc["modes"][0]["label"] = f"(2,0){ESC_CLEAR}"
        doc["modes"][0]["methods"]["nf"]["flags"] += [
            {"kind": "internal_resonance_1_2", "message": f"look{ESC_TITLE}\ud800 here"},
            {"kind": f"odd{ESC_CLEAR}", "message": "in the flags column"}]
        doc["flags"].append({"kind": "note", "message": f"note{ESC_CLEAR}"})
        f.attrs["json"] = json.dumps(doc)
    return h5


def test_show_prints_no_control_sequence(hostile_results, capsys):
    o = run_cli(["show", hostile_results], capsys)
    assert o.code == 0, o.err
    for ch in ("\x1b", "\x07", "\x9b"):
        assert ch not in o.out + o.err
    assert "Evil\\x1b]0;pwned\\x07" in o.out and "look\\x1b]0;pwned\\x07\\ud800 here" in o.out
    assert "poly\\x1b[2J" in o.out and "note\\x1b[2J" in o.out and "odd\\x1b[2J" in o.out


def test_error_messages_quoting_files_print_no_control_sequence(tmp_path, capsys):
    """The CLI's error printer escapes what it quotes: a scene's file name, a solver log's tail, a warning."""
    from stepnf.cli.main import _format_warning, report_failure
    from stepnf.errors import SolverRunError

    bad = tmp_path / f"s{ESC_CLEAR}.toml"
    bad.write_text('[model]\nsolver = "polynomial"\n[analysis]\nmaster_modes = [0]\nnope = 1\n')
    o = run_cli(["run", bad, "-q"], capsys)
    assert_reported(o, (2,), ["nope"])
    assert "\x1b" not in o.err and "s\\x1b[2J" in o.err
    assert report_failure(SolverRunError("ccx failed", log_tail=f"line 1\n{ESC_TITLE}line 2")) == 3
    err = capsys.readouterr().err
    assert "\x1b" not in err and "\x07" not in err and "\\x1b]0;pwned\\x07line 2" in err
    assert err.count("\n") == 4  # the message's own lines are kept
    line = _format_warning(f"mesh {ESC_TITLE}", UserWarning, "f.py", 1)
    assert "\x1b" not in line and line.endswith("\n")


def test_progress_lines_print_no_control_sequence(tmp_path, capsys):
    from stepnf.runtime.progress import Progress

    Progress(enabled=True).message(f"building the {ESC_TITLE} model")
    err = capsys.readouterr().err
    assert "\x1b" not in err and "\\x1b]0;pwned" in err


def test_dangling_link_is_refused_and_no_temporary_file_left(tmp_path):
    """The writer's temporary file is made in the target folder with O_EXCL and removed on refusal."""
    (tmp_path / "a").symlink_to(tmp_path / "nowhere")
    with pytest.raises(OutputError):
        atomic.write_bytes(tmp_path / "a", b"x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a"] and not os.path.exists(tmp_path / "nowhere")


def test_linked_outputs_of_sweep_and_curves_are_refused(tmp_path, capsys):
    """The other writers share the atomic writer: a sweep store and a curves file that are links."""
    from stepnf.sweep.dask_sweep import write_case

    v = victim(tmp_path)
    (tmp_path / "store.h5").symlink_to(v)
    with pytest.raises((OutputError, StoreError)):  # read first (not a store) or refused when written
        write_case(tmp_path / "store.h5", "a", {"status": "done", "params": {"x": 1}}, {"name": "x"})
    (tmp_path / "curves").mkdir()
    (tmp_path / "curves" / "curves.h5").symlink_to(Path("..") / "victim")
    o = run_cli(["curves", "--n-kappa", "2", "--kappa-max", "1", "--modes", "(2,0)", "--out",
                 tmp_path / "curves", "--no-plot", "-q"], capsys)
    assert_reported(o, (3,), [str(tmp_path / "curves" / "curves.h5"), "symbolic link"])
    assert v.read_bytes() == VICTIM
