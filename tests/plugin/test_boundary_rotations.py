"""Boundary conditions on rotational dofs (issue 32, item 1): a shell clamps with ux uy uz rx ry rz (its
default) and simply supports with the translations; a rotation named for a solid is refused in one line.

References: exact index arithmetic of node-major dofs (6 per node for a shell), and the scene checks of a
calculix cap (no ccx run: the [model] keys are checked when the scene is read). Before this change a
rotation was refused by the key's list of choices (no word of rotations), and no adapter could take one.
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.errors import SceneError
from stepnf.keys.schema import Schema
from stepnf.plugin.boundary import BOUNDARY_KEY, boundary_conditions, fixed_dofs
from stepnf.plugin.dofs import dof_counts, node_vectors, rotation_mask, translation_mask

KEYS = Schema(BOUNDARY_KEY)
POINTS = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])


def conditions(*tables, rotations=False):
    return boundary_conditions(KEYS.check({"boundary": list(tables)}, file="s.toml")["boundary"], "s.toml",
                               rotations=rotations)


def test_shell_conditions_fix_rotations():
    clamp, support, given = conditions({"set": "EDGE"}, {"set": "MID", "dofs": ["ux", "uy", "uz"]},
                                       {"set": "END", "dofs": ["rz", "uz"]}, rotations=True)
    assert clamp.dofs == (0, 1, 2, 3, 4, 5) and support.dofs == (0, 1, 2) and given.dofs == (2, 5)
    sets = {"EDGE": np.array([0]), "MID": np.array([1]), "END": np.array([2])}
    fixed = fixed_dofs([clamp, support, given], POINTS, sets, "s.toml", dofs_per_node=6)
    assert fixed.tolist() == [0, 1, 2, 3, 4, 5, 6, 7, 8, 14, 17]  # node 0 clamped, node 1 supported, node 2 uz rz
    with pytest.raises(ValueError, match="direction rz, but the nodes have 3 dofs"):
        fixed_dofs([clamp], POINTS, sets, "s.toml")  # a solid's numbering cannot hold a rotation


def test_rotation_on_a_solid_is_refused_by_the_table():
    with pytest.raises(SceneError) as info:
        conditions({"set": "L", "dofs": ["uz", "ry"]})
    assert info.value.key == "model.boundary[0].dofs[1]"
    assert "'ry' is a rotation" in str(info.value) and "solid" in str(info.value)
    assert conditions({"set": "L"})[0].dofs == (0, 1, 2)  # a solid's default clamp: its translations


def test_rotation_on_a_solid_adapter_exits_2_in_one_line(tmp_path, capsys):
    scene = tmp_path / "plate.toml"
    scene.write_text('[model]\nsolver = "calculix"\n[model.geometry]\nshape = "spherical_cap"\na = 0.15\n'
                     'R = "inf"\nh = 0.003\n[model.material]\nE = 1.04e11\nnu = 0.3\nrho = 4400.0\n'
                     '[[model.boundary]]\nset = "edge"\ndofs = ["ux", "uy", "uz", "rx", "ry", "rz"]\n'
                     '[analysis]\nmaster_modes = [0]\nmethods = ["dnf"]\n')
    assert main(["run", str(scene), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert str(scene) in err and "[model.boundary[0].dofs[3]]" in err and "'rx' is a rotation" in err


def test_dof_masks_and_counts():
    D = np.tile(np.arange(6), 2)
    assert translation_mask(D).tolist() == [True] * 3 + [False] * 3 + [True] * 3 + [False] * 3
    assert rotation_mask(np.tile([0, 1, 2], 2)) is None and translation_mask(None) is None
    assert dof_counts(D, 12) == "12 dofs (6 translations, 6 rotations)" and dof_counts(None, 1200) == "1 200 dofs"
    X = np.repeat([[1.0, 0, 0], [0.0, 0, 0]], 6, axis=0)
    nodes, U = node_vectors(np.arange(12.0), X, D)
    assert nodes.tolist() == [[0, 0, 0], [1, 0, 0]] and U.tolist() == [[6, 7, 8], [0, 1, 2]]  # sorted nodes
    assert node_vectors(np.arange(12.0), X, D, rotations=True)[1].tolist() == [[9, 10, 11], [3, 4, 5]]
