"""Hostile output: full disk, unusable output folders, concurrent runs, umask, format versions.

Every file stepnf writes goes through :mod:`stepnf.io.atomic` (built in memory, written to a
temporary file in the target folder, fsync, ``os.replace``). Here: a full disk (a small tmpfs
mounted as the output folder; skipped where mounting is not allowed) ends with exit 3, a message
naming the file and "no space left on device", the computed results still printed, no
``.partial`` folder or temporary file left and the earlier results file byte-identical; an
output folder that is a file, read-only or not creatable is exit 2 on ``output.dir`` before any
computation; concurrent runs of one scene never corrupt the file; files get ``0666 & ~umask``;
readers refuse a newer ``format_version``.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

import stepnf.pipeline.model as pipeline
from helpers.hostile import assert_reported, run_cli, run_cli_process, snapshot
from stepnf.io import atomic
from stepnf.step.checkpoint import Checkpoint
from stepnf.cli.main import main
from stepnf.errors import OutputError, OutputWarning, StoreError
from stepnf.io.results import read_hdf5
from stepnf.sweep.dask_sweep import read_store, write_case
from stepnf_polynomial import save_system
from helpers.systems import random_system
from helpers.paths import REPO

NO_SPACE = "no space left on device"


def scene(tmp_path: Path, out: str | Path = "out", *, n: int = 6, extra: str = "") -> Path:
    M, K, G, H = random_system(n, seed=8)
    save_system(tmp_path / "s.npz", M, K, G, H)
    p = tmp_path / "s.toml"
    p.write_text(f'[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\n'
                 f'methods = ["nf", "dnf"]\n{extra}[output]\ndir = "{out}"\n')
    return p


@pytest.fixture(scope="module")
def small_curves():
    from stepnf.report.curves import CurveOptions, compute_curves

    return compute_curves(CurveOptions(kappas=(0.0, 1.0), modes=((2, 0),)))


def leftovers(folder: Path) -> list[str]:
    """Temporary files and checkpoint folders a run must not leave behind."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")
                  if p.name.endswith(".tmp") or p.name.endswith(".partial"))


# ------------------------------------------------------------------ tmpfs fixture
@pytest.fixture
def tmpfs(tmp_path):
    """``mount(size_kib, ro=False) -> folder``: a small tmpfs; skips where mounting is not allowed."""
    mounted: list[Path] = []

    def mount(size_kib: int, ro: bool = False) -> Path:
        if shutil.which("mount") is None:
            pytest.skip("no mount command")
        d = tmp_path / f"mnt{len(mounted)}"
        d.mkdir()
        opts = f"size={size_kib}k" + (",ro" if ro else "")
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(d)], capture_output=True, text=True)
        if r.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip() or r.returncode}")
        mounted.append(d)
        return d

    yield mount
    for d in reversed(mounted):
        if subprocess.run(["umount", str(d)], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", str(d)], capture_output=True)


def fill(folder: Path, keep: int) -> None:
    """Fill the file system of ``folder`` until only about ``keep`` bytes are free."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    block = b"\0" * 4096
    todo = max(free - keep, 0)
    fd = os.open(folder / "filler", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        while todo > 0:
            todo -= os.write(fd, block[:min(todo, len(block))])
        while keep == 0:
            os.write(fd, block)
    except OSError as exc:
        assert exc.errno == errno.ENOSPC
    finally:
        os.close(fd)
    st = os.statvfs(folder)
    assert st.f_bavail * st.f_frsize <= keep


# ------------------------------------------------------------------ full disk
@pytest.mark.parametrize("free_kib, checkpoint_fails", [(0, True), (8, False)],
                         ids=["checkpoints-and-results-fail", "only-results-fail"])
@pytest.mark.parametrize("json_out", [True, False], ids=["json", "table"])
def test_full_disk(tmp_path, tmpfs, free_kib, checkpoint_fails, json_out):
    out = tmpfs(96)
    s = scene(tmp_path, out)
    first = run_cli_process(["run", s, "-q", "--json"])
    assert first.code == 0, first.err
    h5 = out / "s.h5"
    assert h5.is_file()
    fill(out, free_kib * 1024)
    before = snapshot(out)

    o = run_cli_process(["run", s, "-q"] + (["--json"] if json_out else []))

    assert o.code != -11, "segmentation fault"
    assert_reported(o, codes=(3,), mentions=[str(h5), NO_SPACE])
    assert ("checkpointing disabled" in o.err) == checkpoint_fails, o.err
    assert o.err.count("checkpointing disabled") <= 1  # warned once, not for every chunk
    if json_out:  # the computed result is not lost
        doc = json.loads(o.out)
        assert doc["hdf5"] is None
        assert [m["index"] for m in doc["modes"]] == [0]
        ref = json.loads(first.out)
        for meth in ("nf", "dnf"):
            assert doc["modes"][0]["methods"][meth]["T"] == pytest.approx(ref["modes"][0]["methods"][meth]["T"],
                                                                         rel=1e-10)
    else:
        assert "hardening" in o.out or "softening" in o.out
        assert "nf" in o.out and "dnf" in o.out
    assert leftovers(out) == []
    assert snapshot(out) == before  # the earlier results file is byte-identical
    read_hdf5(h5)


def test_full_disk_sweep_store_keeps_the_previous_store(tmp_path, tmpfs):
    out = tmpfs(64)
    store = out / "demo.h5"
    info = {"name": "demo"}
    write_case(store, "a", {"status": "done", "params": {"x": 1}, "result": {"T": 1.0}}, info)
    fill(out, 0)
    before = snapshot(out)
    big = {"status": "done", "params": {"x": 2}, "result": {"blob": "x" * 200_000}}
    with pytest.raises(OutputError, match=f"sweep store {store}: {NO_SPACE}") as err:
        write_case(store, "b", big, info)
    assert err.value.errno == errno.ENOSPC and err.value.path == str(store)
    assert snapshot(out) == before and leftovers(out) == []
    assert list(read_store(store)) == ["a"]


def test_full_disk_curves_file(tmp_path, tmpfs, small_curves):
    from stepnf.report.curves import write_hdf5

    out = tmpfs(32)
    fill(out, 0)
    with pytest.raises(OutputError, match=NO_SPACE):
        write_hdf5(small_curves, out / "curves.h5")
    assert leftovers(out) == [] and not (out / "curves.h5").exists()


# ------------------------------------------------------------------ checkpoints never abort a run
def test_checkpoint_write_failure_warns_once_and_goes_on(tmp_path):
    (tmp_path / "blocker").write_text("a file where the checkpoint folder should be")
    cp = Checkpoint(tmp_path / "blocker" / ".s.partial")
    U = np.eye(3)
    with pytest.warns(OutputWarning) as warned:
        cp.store("plan", 0, U, U)
        cp.store("plan", 1, U, U)
    assert len(warned) == 1 and "checkpointing disabled" in str(warned[0].message) and cp.disabled
    assert cp.load("plan", 0, U) is None


def test_checkpoint_chunks_respect_the_umask_and_leave_no_tmp(tmp_path):
    old = os.umask(0o022)
    try:
        cp = Checkpoint(tmp_path / ".s.partial")
        U = np.arange(6.0).reshape(2, 3)
        cp.store("plan", 0, U, U * 2)
    finally:
        os.umask(old)
    files = list((tmp_path / ".s.partial").iterdir())
    assert [p.name for p in files] == ["plan_000000.npz"]
    assert stat.S_IMODE(files[0].stat().st_mode) == 0o644
    assert np.array_equal(cp.load("plan", 0, U), U * 2)


# ------------------------------------------------------------------ unusable output folders
def _no_solver(name):
    pytest.fail("the output folder must be checked before any computation")


def test_output_dir_is_a_file(tmp_path, capsys, monkeypatch):
    (tmp_path / "out").write_text("not a folder")
    s = scene(tmp_path, "out")
    monkeypatch.setattr(pipeline, "get_solver", _no_solver)  # the scene itself names an installed solver
    o = run_cli(["run", s, "-q", "--json"], capsys)
    assert_reported(o, codes=(2,), mentions=["output.dir", str(tmp_path / "out"), "not a folder"])
    assert o.out == ""


def test_output_dir_not_creatable(tmp_path, capsys, monkeypatch):
    (tmp_path / "f").write_text("a file")
    s = scene(tmp_path, "f/sub/out")
    monkeypatch.setattr(pipeline, "get_solver", _no_solver)  # the scene itself names an installed solver
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["output.dir", str(tmp_path / "f" / "sub" / "out")])
    # the --output override is checked the same way
    o = run_cli(["run", s, "-q", "--output", tmp_path / "f" / "x"], capsys)
    assert_reported(o, codes=(2,), mentions=["output.dir", str(tmp_path / "f" / "x")])


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores folder permissions (see the read-only mount test)")
def test_output_dir_read_only_permissions(tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    out.chmod(0o555)
    try:
        s = scene(tmp_path, "out")
        monkeypatch.setattr(pipeline, "get_solver", _no_solver)  # the scene itself names an installed solver
        o = run_cli(["run", s, "-q"], capsys)
        assert_reported(o, codes=(2,), mentions=["output.dir", str(out), "permission denied"])
    finally:
        out.chmod(0o755)


def test_output_dir_read_only_mount(tmp_path, tmpfs, capsys, monkeypatch):
    out = tmpfs(64, ro=True)
    s = scene(tmp_path, out)
    monkeypatch.setattr(pipeline, "get_solver", _no_solver)  # the scene itself names an installed solver
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["output.dir", str(out), "read-only file system"])
    # and one level below (a folder to create on a read-only file system)
    s = scene(tmp_path, out / "sub")
    o = run_cli(["run", s, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["output.dir", str(out / "sub")])


def test_sweep_store_folder_checked_before_dask_starts(tmp_path, capsys, monkeypatch):
    import dask.distributed

    def no_dask(*a, **k):
        pytest.fail("the store's folder must be checked before Dask starts")

    monkeypatch.setattr(dask.distributed, "LocalCluster", no_dask)
    monkeypatch.setattr(dask.distributed, "Client", no_dask)
    (tmp_path / "base.toml").write_text('[model]\nsolver = "polynomial"\nfile = "x.npz"\n'
                                        '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\n')
    (tmp_path / "results").write_text("a file, not a folder")
    (tmp_path / "x.npz").write_bytes(b"")  # exists (checked when the sweep is read), never loaded
    s = tmp_path / "sw.toml"
    s.write_text('[sweep]\nname = "st"\nbase = "base.toml"\n[sweep.vary]\n"analysis.retained_modes" = [2, 3]\n'
                 '[output]\ndir = "results"\n')
    o = run_cli(["sweep", s, "--quiet"], capsys)
    assert_reported(o, codes=(2,), mentions=["output.dir", str(tmp_path / "results")])


# ------------------------------------------------------------------ no two runs corrupt one output
def test_concurrent_runs_of_one_scene(tmp_path):
    s = scene(tmp_path, "out", n=12, extra='retained_modes = 8\ntensors = "full"\n')
    cmd = [sys.executable, "-m", "stepnf.cli.main", "run", str(s), "-q", "--json", "--compact"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(4)]
    outs = [p.communicate(timeout=300) for p in procs]
    docs = []
    for p, (out, err) in zip(procs, outs):
        assert p.returncode == 0, err
        assert "checkpointing disabled" not in err
        docs.append(json.loads(out))
    stored = read_hdf5(tmp_path / "out" / "s.h5")  # complete, readable, one of the runs
    for d in docs:
        for meth in ("nf", "dnf"):
            assert d["modes"][0]["methods"][meth]["T"] == pytest.approx(
                stored["modes"][0]["methods"][meth]["T"], rel=1e-10)
    assert leftovers(tmp_path / "out") == []


WRITER = """
import sys
from pathlib import Path
from stepnf.sweep.dask_sweep import write_case
store, tag = Path(sys.argv[1]), sys.argv[2]
for i in range(25):
    write_case(store, f"{tag}{i}", {"status": "done", "params": {"i": i}, "result": {"T": i}}, {"name": "c"})
"""


def test_two_writers_of_one_sweep_store_lose_no_case(tmp_path):
    store = tmp_path / "out" / "c.h5"
    procs = [subprocess.Popen([sys.executable, "-c", WRITER, str(store), tag], stderr=subprocess.PIPE, text=True)
             for tag in ("a", "b", "c")]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    assert sorted(read_store(store)) == sorted(f"{t}{i}" for t in "abc" for i in range(25))
    assert leftovers(tmp_path / "out") == []


# ------------------------------------------------------------------ umask
@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600)], ids=["022", "077"])
def test_new_files_follow_the_umask(tmp_path, capsys, small_curves, umask, mode):
    from stepnf.report.curves import write_hdf5

    s = scene(tmp_path, "out")
    curves = small_curves
    old = os.umask(umask)
    try:
        assert main(["run", str(s), "-q"]) == 0
        write_case(tmp_path / "out" / "store.h5", "a", {"status": "done", "params": {}}, {"name": "x"})
        write_hdf5(curves, tmp_path / "out" / "curves.h5")
    finally:
        os.umask(old)
    for name in ("s.h5", "store.h5", "curves.h5"):
        assert stat.S_IMODE((tmp_path / "out" / name).stat().st_mode) == mode, name


def test_replaced_file_keeps_its_mode(tmp_path, capsys):
    s = scene(tmp_path, "out")
    assert main(["run", str(s), "-q"]) == 0
    h5 = tmp_path / "out" / "s.h5"
    h5.chmod(0o640)
    old = os.umask(0o022)
    try:
        assert main(["run", str(s), "-q"]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE(h5.stat().st_mode) == 0o640


# ------------------------------------------------------------------ the atomic writer itself
def test_failed_replace_leaves_previous_file_and_no_tmp(tmp_path, monkeypatch):
    target = tmp_path / "f.bin"
    atomic.write_bytes(target, b"old")

    def boom(src, dst, **dir_fds):  # the writer renames relative to the folder's descriptor
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(atomic.os, "replace", boom)
    with pytest.raises(OutputError, match=r"cannot write the file .*f\.bin: input/output error \(EIO\)"):
        atomic.write_bytes(target, b"new")
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["f.bin"]


def test_write_through_a_symlink_is_refused(tmp_path):
    """Issue 29, finding 5: a link at the target was followed (its target replaced); now refused, both
    untouched (tests/hostile/test_hostile_links.py has the runs)."""
    real = tmp_path / "real"
    real.mkdir()
    (real / "r.h5").write_bytes(b"old")
    (tmp_path / "link.h5").symlink_to(real / "r.h5")
    with pytest.raises(OutputError, match="is a symbolic link"):
        atomic.write_bytes(tmp_path / "link.h5", b"new")
    assert (tmp_path / "link.h5").is_symlink() and (real / "r.h5").read_bytes() == b"old"


# ------------------------------------------------------------------ format and format_version
def _bump_version(path: Path, version: int = 99) -> None:
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = version


def test_every_file_is_versioned_and_newer_versions_are_refused(tmp_path, capsys, small_curves):
    from stepnf.report.curves import read_hdf5 as read_curves
    from stepnf.report.curves import write_hdf5 as write_curves

    s = scene(tmp_path, "out")
    assert main(["run", str(s), "-q"]) == 0
    run_file = tmp_path / "out" / "s.h5"
    store = tmp_path / "out" / "store.h5"
    write_case(store, "a", {"status": "done", "params": {"x": 1}}, {"name": "x"})
    curves_file = write_curves(small_curves, tmp_path / "out" / "curves.h5")
    for path, fmt in ((run_file, "stepnf-run"), (store, "stepnf-sweep"), (curves_file, "stepnf-curves")):
        with h5py.File(path, "r") as f:
            assert f.attrs["format"] == fmt and int(f.attrs["format_version"]) == 1, path
    read_hdf5(run_file), read_store(store), read_curves(curves_file)
    for path in (run_file, store, curves_file):
        _bump_version(path)
    with pytest.raises(StoreError, match="format_version 99, written by a newer stepnf"):
        read_hdf5(run_file)
    with pytest.raises(StoreError, match="format_version 99, written by a newer stepnf"):
        read_store(store)
    with pytest.raises(StoreError, match="format_version 99, written by a newer stepnf"):
        read_curves(curves_file)
    before = store.read_bytes()
    with pytest.raises(StoreError, match="newer stepnf"):  # never modified by an older stepnf
        write_case(store, "b", {"status": "done", "params": {"x": 2}}, {"name": "x"})
    assert store.read_bytes() == before


def test_unversioned_stores_of_earlier_stepnf_are_read_and_extended(tmp_path):
    old = REPO / "docs" / "fig4" / "table2.h5"
    if not old.is_file():
        pytest.skip("no stored sweep in docs/fig4")
    with h5py.File(old, "r") as f:
        assert "format_version" not in f.attrs  # a store of stepnf before format versions
    cases = read_store(old)
    assert cases
    copy = tmp_path / "table2.h5"
    shutil.copyfile(old, copy)
    write_case(copy, "extra", {"status": "done", "params": {"x": 1}}, {"name": "table2"})
    after = read_store(copy)
    assert set(after) == set(cases) | {"extra"}
    assert after[next(iter(cases))]["result"] == cases[next(iter(cases))]["result"]
    with h5py.File(copy, "r") as f:
        assert int(f.attrs["format_version"]) == 1


def test_legacy_curves_files_are_read(tmp_path, small_curves):
    from stepnf.report.curves import read_hdf5 as read_curves, write_hdf5 as write_curves

    path = write_curves(small_curves, tmp_path / "c.h5")
    with h5py.File(path, "r+") as f:  # as stepnf wrote them before format_version
        f.attrs["format"] = "stepnf-curves-1"
        del f.attrs["format_version"]
    assert set(read_curves(path)["modes"]) == {(2, 0)}


def test_repeated_writes_leave_only_the_file(tmp_path):
    for i in range(20):
        atomic.write_bytes(tmp_path / "x", str(i).encode())
    assert (tmp_path / "x").read_bytes() == b"19" and sorted(p.name for p in tmp_path.iterdir()) == ["x"]
