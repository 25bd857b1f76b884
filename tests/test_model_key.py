"""The key of stored results (stepnf.model_key): what determines a result changes it, nothing else does."""
import shutil
from pathlib import Path

from stepnf.model_key import describe_change, digest, model_key, scene_key
from stepnf.scene import load_scene

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


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
