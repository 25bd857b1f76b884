"""Field files of a model with rotational dofs (issue 32, item 1): each field's displacement vector holds the
translations, and a separate rotation vector field (``<name>_rotation``, radians) the rotations.

Reference: tests/helpers/shell_dofs.py, whose master mode is exactly uz = 0.6 and rx = 8 rad at node 0
(point 0 of its output mesh) and zero elsewhere; values go through the VTU file as float64 binary data,
so what is read back is what was written, bit for bit. Before this change the file had no rotation field.
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.io.fields import ROTATION_SUFFIX, DofPlacement, OutputMesh, dof_placement
from helpers.shell_dofs import NODES, ROT_MAX, W_MAX, SixDofPlate, run_six_dof

meshio = pytest.importorskip("meshio")


def test_placement_of_rotation_dofs():
    ad = SixDofPlate()
    mesh = OutputMesh(NODES.copy(), [("quad", np.array([[0, 1, 3, 2]]))])
    pl = dof_placement(mesh, ad.dof_coordinates(), ad.dof_directions(), ad.n_dofs)
    D = ad.dof_directions()
    assert pl.point[D >= 3].tolist() == [-1] * 12 and pl.point[D < 3].tolist() == np.repeat(range(4), 3).tolist()
    assert isinstance(pl.rotation, DofPlacement)
    assert pl.rotation.point[D >= 3].tolist() == np.repeat(range(4), 3).tolist()
    assert pl.rotation.direction[D >= 3].tolist() == [0, 1, 2] * 4 and pl.rotation.point[D < 3].max() == -1
    solid = dof_placement(mesh, np.repeat(NODES, 3, axis=0), np.tile([0, 1, 2], 4), 12)
    assert solid.rotation is None  # a solid's placement (and files) as before


def test_fields_file_holds_a_rotation_field(tmp_path, monkeypatch):
    res, ad = run_six_dof(tmp_path, monkeypatch)
    m = meshio.read(tmp_path / "out" / "s_fields.vtu")
    names = set(m.point_data)
    shape = [n for n in names if n.endswith("_phi")]
    assert len(shape) == 1, names
    disp, turn = m.point_data[shape[0]], m.point_data[shape[0] + ROTATION_SUFFIX]
    # the stored shape's sign: its largest entry (rx = +8) positive, so uz = +0.6
    expected_u, expected_r = np.zeros((4, 3)), np.zeros((4, 3))
    expected_u[0, 2], expected_r[0, 0] = W_MAX, ROT_MAX
    # exact by construction up to the eigen-solver's round-off (relative 1e-12 of the largest entry)
    assert np.abs(disp - expected_u).max() <= 1e-12 * ROT_MAX
    assert np.abs(turn - expected_r).max() <= 1e-12 * ROT_MAX
    # every field has its rotation twin, and nothing else was added
    plain = {n for n in names if not n.endswith(ROTATION_SUFFIX)}
    assert names == plain | {n + ROTATION_SUFFIX for n in plain} and len(plain) >= 3  # phi, dnf a_bar, w2_b_bar
