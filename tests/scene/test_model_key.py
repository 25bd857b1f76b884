"""The key of stored results (stepnf.scene.model_key): what determines a result changes it, nothing else does."""
import shutil
from pathlib import Path

from stepnf.scene.model_key import describe_change, digest, model_key, scene_key
from stepnf.scene.parse import load_scene
from helpers.paths import EXAMPLES


def test_a_file_a_deck_includes_is_part_of_the_key(tmp_path):
    """The CalculiX deck example includes its mesh (*INCLUDE): editing the included file changes the key, and
    the change is named (no ccx is run: the key reads files, never runs the solver)."""
    for f in (EXAMPLES / "beam_ccx").iterdir():
        shutil.copy(f, tmp_path)
    before = model_key(load_scene(tmp_path / "beam_deck.toml"))
    assert [f["path"] for f in before["files"].values()] == [str(tmp_path / "beam_deck.inp"),
                                                              str(tmp_path / "beam_mesh.inp")]
    with open(tmp_path / "beam_mesh.inp", "a") as f:
        f.write("** edited\n")
    after = model_key(load_scene(tmp_path / "beam_deck.toml"))
    assert digest(after) != digest(before)
    assert describe_change(before, after) == f"{tmp_path / 'beam_mesh.inp'} changed"


def test_run_settings_and_output_keys_leave_the_key_alone(tmp_path):
    """A longer time-out or another output folder computes the same thing: the same key (a killed run whose
    time-out was raised still resumes); a material constant is another model."""
    for f in (EXAMPLES / "beam_ccx").iterdir():
        shutil.copy(f, tmp_path)
    scene = tmp_path / "beam_mesh.toml"
    text = scene.read_text()
    base = scene_key(load_scene(scene))
    scene.write_text(text.replace("[model]\n", "[model]\ntimeout = 7200.0\nkeep = \"always\"\n", 1)
                     .replace('dir = "results"', 'dir = "elsewhere"\nfields = false'))
    assert digest(scene_key(load_scene(scene))) == digest(base)
    scene.write_text(text.replace("E = 2.1e11", "E = 2.2e11"))
    assert "model.material.E 210000000000.0 -> 220000000000.0" in describe_change(base, scene_key(load_scene(scene)))


# ---------------------------------------------------------------- what is read (review items 6 and N4)
def mesh_scene(tmp_path, monkeypatch, extra=""):
    """A scene of an in-test adapter declaring ``mesh`` (a file), ``note`` (text) and ``label`` (any value)."""
    from stepnf.keys.schema import FromScene, Key, Schema
    from helpers.systems import use_solver

    class MeshModel(FromScene):
        model_keys = Schema(Key("mesh", "file", "a mesh"), Key("note", "text", "a note"), Key("label", "any", "x"))

    use_solver(monkeypatch, lambda name: MeshModel)
    (tmp_path / "s.toml").write_text(f'[model]\nsolver = "meshmodel"\nmesh = "m.xdmf"\n{extra}[analysis]\n'
                                     'master_modes = [0]\n[output]\ndir = "o"\n')
    return tmp_path / "s.toml"


def write_xdmf(path, shift=0.0):
    import meshio
    import numpy as np

    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0 + shift]])
    meshio.write(path, meshio.Mesh(pts, [("tetra", np.array([[0, 1, 2, 3]]))]))  # XDMF + HDF5 heavy data


def test_the_heavy_data_of_an_xdmf_mesh_is_part_of_the_key(tmp_path, monkeypatch):
    """FEniCSx reads any meshio format: an XDMF mesh keeps its points in the .h5 it names. Editing the .h5
    alone (the .xdmf unchanged, byte for byte) is another model, and the change names the .h5."""
    toml = mesh_scene(tmp_path, monkeypatch)
    write_xdmf(tmp_path / "m.xdmf")
    before = model_key(load_scene(toml))
    assert before["files"]["model.mesh.data[0]"]["path"] == str(tmp_path / "m.h5")
    xdmf = (tmp_path / "m.xdmf").read_bytes()
    write_xdmf(tmp_path / "m.xdmf", shift=0.5)
    assert (tmp_path / "m.xdmf").read_bytes() == xdmf
    after = model_key(load_scene(toml))
    assert digest(after) != digest(before)
    assert describe_change(before, after) == f"model.mesh.data[0] {tmp_path / 'm.h5'} changed"


def test_only_declared_files_are_read_and_never_a_system_file(tmp_path, monkeypatch):
    """A string that merely names a file (a note, a label) is a value, not an input read into the key; a
    declared file that is a link into /proc (a regular file there may be /proc/kcore) is not read."""
    from stepnf.scene import model_key as mk

    (tmp_path / "readme.txt").write_text("x")
    toml = mesh_scene(tmp_path, monkeypatch, extra='note = "readme.txt"\nlabel = "readme.txt"\n')
    write_xdmf(tmp_path / "m.xdmf")
    key = model_key(load_scene(toml))
    assert sorted(key["files"]) == ["model.mesh", "model.mesh.data[0]"]
    assert key["model"]["model.note"] == "readme.txt"  # still a value of the key
    (tmp_path / "m.h5").unlink()
    (tmp_path / "m.h5").symlink_to("/proc/self/status")
    read = []
    monkeypatch.setattr(mk, "file_sha256", lambda p, real=mk.file_sha256: read.append(str(p)) or real(p))
    key = model_key(load_scene(toml))
    assert key["files"]["model.mesh.data[0]"]["sha256"] == "not read: a system file (under /proc, /sys, /dev)"
    assert read == [str(tmp_path / "m.xdmf")]
    assert mk.input_sha256(Path("/dev/null")) == "not read: not a regular file or folder"
