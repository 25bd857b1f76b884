"""``stepnf verify`` on a scene whose masters sit on a manifold of several modes (issue 33): until the full
model's orbits are started on the manifold, such a master is said to be NOT verified (text and JSON), not
left out of the document; a master outside the manifold is still checked.

System: examples/near_one_to_four.npz (mode 4 near 4 x mode 0), order 5, manifolds = [[0, 4]], masters 0 and
1, one orbit (--amplitudes 0.5, inside master 1's validity range).
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from helpers.scenes import run_verify

NPZ = Path(__file__).resolve().parents[2] / "examples" / "near_one_to_four.npz"


def _scene(d: Path) -> Path:
    shutil.copy(NPZ, d / "s.npz")
    path = d / "s.toml"
    path.write_text('[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0, 1]\n'
                    'methods = ["dnf"]\n[analysis.backbone]\norder = 5\nmanifolds = [[0, 4]]\n[output]\ndir = "out"\n')
    return path


def test_manifold_master_said_not_verified(tmp_path, capsys):
    code, out, err = run_verify(capsys, _scene(tmp_path), "--json", "--amplitudes", "0.5")
    doc = json.loads(out)
    modes = {m["index"]: m for m in doc["modes"]}
    assert sorted(modes) == [0, 1]
    assert modes[0]["checks"] == [] and "NOT VERIFIED" in modes[0]["not_verified"]
    assert "manifold of modes [0, 4]" in modes[0]["not_verified"] and "NOT VERIFIED" in err
    assert len(modes[1]["checks"]) == 1 and "not_verified" not in modes[1]
    code, out, err = run_verify(capsys, _scene(tmp_path), "--amplitudes", "0.5", "--quiet")
    assert "master mode 0 is on the manifold of modes [0, 4]: NOT VERIFIED" in out
    assert "amplitudes from --amplitudes" in out  # master 1's header, as before
