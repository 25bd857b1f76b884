"""The FEniCSx form cache: where it goes (read-only images, non-root users) and a silent compiler."""
from __future__ import annotations

import os
import sys
import tempfile
import warnings
from pathlib import Path

import pytest

pytest.importorskip("dolfinx")

from stepnf.cli.main import main  # noqa: E402
from stepnf.errors import OutputError, OutputWarning  # noqa: E402
from stepnf_fenicsx import _compat, jitcache  # noqa: E402

pytestmark = pytest.mark.fenicsx

ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


@pytest.fixture
def env(monkeypatch, tmp_path):
    """No STEPNF_CACHE_DIR, not a source checkout, XDG and temp folders under tmp_path; fresh resolution."""
    monkeypatch.delenv("STEPNF_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(jitcache, "__file__", str(tmp_path / "site" / "pkg" / "stepnf_fenicsx" / "jitcache.py"))
    jitcache._resolve_cache.cache_clear()
    yield tmp_path
    jitcache._resolve_cache.cache_clear()


def unwritable(folder: Path) -> Path:
    """A path no file can be written into, also for root: below a regular file."""
    folder.parent.mkdir(parents=True, exist_ok=True)
    folder.write_text("not a folder")
    return folder


def test_stepnf_cache_dir_comes_first(env, monkeypatch):
    monkeypatch.setenv("STEPNF_CACHE_DIR", str(env / "mine"))
    assert _compat.cache_dir() == env / "mine" / "fenicsx"
    assert (env / "mine" / "fenicsx").is_dir()


def test_unusable_stepnf_cache_dir_is_an_error_naming_the_variable(env, monkeypatch, capsys):
    monkeypatch.setenv("STEPNF_CACHE_DIR", str(unwritable(env / "mine")))
    with pytest.raises(OutputError, match="STEPNF_CACHE_DIR=.*not a folder.*writable folder or unset it"):
        _compat.cache_dir()
    from stepnf.cli.main import report_failure  # one line on stderr, not a traceback

    try:
        _compat.cache_dir()
    except OutputError as exc:
        assert report_failure(exc) == 3
    err = capsys.readouterr().err
    assert err.startswith("stepnf: error: STEPNF_CACHE_DIR=") and err.count("\n") == 1


@pytest.mark.skipif(ROOT or not hasattr(os, "geteuid"), reason="root writes into a 0o555 folder")
def test_read_only_stepnf_cache_dir(env, monkeypatch):
    ro = env / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        monkeypatch.setenv("STEPNF_CACHE_DIR", str(ro))
        with pytest.raises(OutputError, match="STEPNF_CACHE_DIR"):
            _compat.cache_dir()
    finally:
        ro.chmod(0o755)


def test_source_checkout_uses_its_own_cache(monkeypatch):
    monkeypatch.delenv("STEPNF_CACHE_DIR", raising=False)
    jitcache._resolve_cache.cache_clear()
    repo = Path(_compat.__file__).resolve().parents[3]
    if not (repo / "stepnf").is_dir():
        pytest.skip("the adapter is installed, not run from a checkout")
    from stepnf.io.atomic import check_folder

    try:
        if check_folder(repo / ".cache" / "fenicsx"):  # a read-only checkout: as if installed
            assert _compat.cache_dir().parts[-2:] == ("stepnf", "fenicsx")
        else:
            assert _compat.cache_dir() == repo / ".cache" / "fenicsx"
    finally:
        jitcache._resolve_cache.cache_clear()


def test_installed_uses_the_xdg_cache_silently(env):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _compat.cache_dir() == env / "xdg" / "stepnf" / "fenicsx"


def test_installed_default_xdg_is_home_cache(env, monkeypatch):
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(env / "home"))
    assert _compat.cache_dir() == env / "home" / ".cache" / "stepnf" / "fenicsx"


def test_read_only_home_falls_back_to_temp_with_one_warning(env):
    xdg = unwritable(env / "xdg")
    expected = env / "tmp" / f"stepnf-{os.getuid()}" / "fenicsx"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert _compat.cache_dir() == expected
        assert _compat.cache_dir() == expected  # resolved once: no second warning
    assert [type(w.message) for w in caught] == [OutputWarning]
    text = str(caught[0].message)
    assert text.startswith(f"form cache: {xdg / 'stepnf' / 'fenicsx'} not writable") and text.endswith(f"using {expected}")


@pytest.mark.skipif(ROOT or not hasattr(os, "geteuid"), reason="root writes into a 0o555 folder")
def test_read_only_xdg_folder_falls_back_to_temp(env):
    ro = env / "xdg"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.warns(OutputWarning, match="not writable"):
            assert _compat.cache_dir().parent.name == f"stepnf-{os.getuid()}"
    finally:
        ro.chmod(0o755)


def test_nothing_writable_is_an_error(env, monkeypatch):
    unwritable(env / "xdg")
    monkeypatch.setattr(tempfile, "tempdir", str(unwritable(env / "tmp2")))
    with pytest.raises(OutputError, match="no writable folder for the FEniCSx form cache.*STEPNF_CACHE_DIR"):
        _compat.cache_dir()


def test_no_temporary_folder_at_all_is_an_error_naming_the_variable(env, monkeypatch):
    """tempfile.gettempdir() itself fails (FileNotFoundError) when no candidate folder is writable."""
    unwritable(env / "xdg")
    monkeypatch.setattr(tempfile, "tempdir", None)

    def none_writable():
        raise FileNotFoundError("No usable temporary directory found")

    monkeypatch.setattr(tempfile, "gettempdir", none_writable)
    with pytest.raises(OutputError, match="no writable temporary folder either; set STEPNF_CACHE_DIR"):
        _compat.cache_dir()


def test_quiet_jit_swallows_c_level_output_and_keeps_warnings(env, capfd):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with _compat.quiet_jit():
            os.write(1, b"gcc chatter on stdout\n")
            os.write(2, b"gcc chatter on stderr\n")
            print("python chatter")
            warnings.warn("kept", UserWarning)
    assert capfd.readouterr() == ("", "")
    assert [str(w.message) for w in caught] == ["kept"]
    print("after")  # the terminal is back
    assert capfd.readouterr().out == "after\n"


def test_quiet_jit_failure_carries_the_compiler_output(env, capfd):
    with pytest.raises(RuntimeError) as info:
        with _compat.quiet_jit():
            os.write(2, b"error: expected ';'\n")
            print("python side")
            raise RuntimeError("Failed just-in-time compilation")
    assert capfd.readouterr() == ("", "")
    if sys.version_info >= (3, 11):
        notes = "".join(info.value.__notes__)
        assert "error: expected ';'" in notes and "python side" in notes


SCENE = """
[model]
solver = "fenicsx"
element = "hex27"
geometry = { shape = "spherical_cap", a = 0.15, R = 0.5, h = 0.003, n_core = 2, n_ring = 1 }
material = { E = 1.04e11, nu = 0.3, rho = 4400.0 }
[analysis]
master_modes = [0]
methods = ["dnf"]
retained_modes = 4
[output]
dir = "out"
plot = false
"""


def test_first_compilation_prints_nothing_but_stepnf_lines(env, monkeypatch, capfd):
    cache = env / "empty-cache"
    monkeypatch.setenv("STEPNF_CACHE_DIR", str(cache))
    scene = env / "tiny.toml"
    scene.write_text(SCENE)
    assert main(["run", str(scene)]) == 0
    out, err = capfd.readouterr()
    assert list((cache / "fenicsx").glob("*.so")), "no compilation happened"
    assert not (env / "xdg").exists()  # elements too are compiled into the stepnf cache
    assert err and all(line.startswith("[stepnf] ") for line in err.splitlines()), err
    first = out.splitlines()
    assert first[0].startswith("stepnf: fenicsx"), out
    tail = first[next(i for i, line in enumerate(first) if line.startswith("results: ")):]
    assert all(Path(line.split(": ", 1)[-1]).exists() for line in tail), out  # "results: ...", then the other files
    for word in ("gcc", "build_ext", "cffi", "ffcx", "####", "warning"):
        assert word not in out.lower() + err.lower()


def test_read_only_install_compiles_into_temp_with_one_note(env, capfd):
    unwritable(env / "xdg")
    scene = env / "tiny.toml"
    scene.write_text(SCENE)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", OutputWarning)  # the filters of a plain run otherwise
        assert main(["run", str(scene), "--quiet"]) == 0
    out, err = capfd.readouterr()
    assert list((env / "tmp" / f"stepnf-{os.getuid()}" / "fenicsx").glob("*.so"))
    notes = [str(w.message) for w in caught] + [line for line in err.splitlines() if line]
    assert len(notes) == 1 and "form cache:" in notes[0] and "not writable" in notes[0], notes
    assert "py.warnings" not in err and "Traceback" not in err


# ------------------------------------------------------------------ permissions (issue 29, finding 7)
def mode(p: Path) -> int:
    return p.stat().st_mode & 0o777


def test_cache_folders_are_created_0700_whatever_the_umask(env, umask000, monkeypatch):
    """Under umask 000 the cache (compiled .so files the next run loads) was created world-writable."""
    cache = _compat.cache_dir()
    assert cache == env / "xdg" / "stepnf" / "fenicsx"
    assert mode(cache) == 0o700 and mode(cache.parent) == 0o700
    monkeypatch.setenv("STEPNF_CACHE_DIR", str(env / "mine"))
    jitcache._resolve_cache.cache_clear()
    assert mode(_compat.cache_dir()) == 0o700


def test_temporary_fallback_is_created_0700_whatever_the_umask(env, umask000):
    unwritable(env / "xdg")
    with pytest.warns(OutputWarning):
        cache = _compat.cache_dir()
    assert cache == env / "tmp" / f"stepnf-{os.getuid()}" / "fenicsx"
    assert mode(cache) == 0o700 and mode(cache.parent) == 0o700


@pytest.mark.parametrize("bits", [0o777, 0o770, 0o702], ids=["0777", "0770", "0702"])
def test_a_cache_writable_by_others_is_not_used(env, bits):
    """A group- or world-writable cache folder (or its parent) may hold someone else's .so: refused."""
    planted = env / "xdg" / "stepnf" / "fenicsx"
    planted.mkdir(parents=True)
    planted.chmod(bits)
    with pytest.warns(OutputWarning, match=r"writable by others .*not used"):
        cache = _compat.cache_dir()
    assert cache != planted and not str(cache).startswith(str(planted)) and mode(cache) == 0o700
    planted.chmod(0o700)
    planted.parent.chmod(bits)  # the parent: another user could swap the folder for theirs
    jitcache._resolve_cache.cache_clear()
    with pytest.warns(OutputWarning, match="writable by others"):
        assert _compat.cache_dir() != planted


def test_a_temporary_fallback_writable_by_others_is_not_used(env):
    unwritable(env / "xdg")
    shared = env / "tmp" / f"stepnf-{os.getuid()}"
    (shared / "fenicsx").mkdir(parents=True)
    shared.chmod(0o777)
    with pytest.warns(OutputWarning):
        cache = _compat.cache_dir()
    assert shared not in cache.parents and mode(cache) == 0o700 and mode(cache.parent) == 0o700


def test_stepnf_cache_dir_writable_by_others_is_an_error(env, monkeypatch):
    (env / "mine" / "fenicsx").mkdir(parents=True)
    (env / "mine" / "fenicsx").chmod(0o777)
    monkeypatch.setenv("STEPNF_CACHE_DIR", str(env / "mine"))
    with pytest.raises(OutputError, match=r"STEPNF_CACHE_DIR=.*writable by others \(mode 0777\)"):
        _compat.cache_dir()


def test_the_cache_and_the_checkpoint_share_one_private_folder_helper():
    """Review item 5: one definition of "the user's alone" (0700, owner, not writable by others), in stepnf.io.atomic."""
    from stepnf.io import atomic
    assert jitcache.private_folder is atomic.private_folder
    assert not hasattr(jitcache, "unsafe_reason") and not hasattr(jitcache, "_make_private")
