"""``[analysis.forcing] load`` on a CalculiX model's named node sets (issue 34): the set's nodes found among the
free dofs, and a set the mesh does not have refused with the sets it has (exit 2), before any eigen-solve.

The reference is the mesh itself: a C3D20 beam along x with node sets LEFT (x = 0) and RIGHT (x = L), as
tests/solvers/calculix/test_calculix_boundary.py writes it.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from helpers.hostile import assert_reported, run_cli
from helpers.meshes import block_mesh
from helpers.required import requires

from stepnf.errors import SceneError
from stepnf.forced.spec import LoadSpec
from stepnf.pipeline.forced import load_dofs

pytestmark = [pytest.mark.calculix]
ccx_mod = pytest.importorskip("stepnf_calculix")
from stepnf_calculix.deck import mesh_text  # noqa: E402

MATERIAL = {"E": 2.1e11, "nu": 0.3, "rho": 7800.0}


def write_beam(folder, nx=4, size=(1.0, 0.02, 0.01)) -> np.ndarray:
    pts, cells = block_mesh(nx, 1, 1, size=size)
    ids = np.arange(1, len(pts) + 1)
    text = mesh_text(ids, pts, [("C3D20", np.arange(1, len(cells) + 1), cells + 1)])
    for name, x in (("LEFT", 0.0), ("RIGHT", size[0])):
        sel = ids[np.abs(pts[:, 0] - x) < 1e-12]
        text += f"*NSET, NSET={name}\n" + "".join(", ".join(map(str, sel[i:i + 16])) + "\n"
                                                   for i in range(0, len(sel), 16))
    (folder / "beam_mesh.inp").write_text(text)
    return pts


def test_a_set_selects_its_nodes_free_dofs(tmp_path):
    """RIGHT's uz dofs, LEFT clamped: one free dof per node of RIGHT, each at x = L along z; on LEFT none is free."""
    pts = write_beam(tmp_path)
    ad = ccx_mod.CalculixAdapter.from_config({"mesh": "beam_mesh.inp", "material": MATERIAL,
                                              "boundary": [{"set": "LEFT"}]}, base_dir=tmp_path)
    X, D = ad.dof_coordinates(), ad.dof_directions()
    model = SimpleNamespace(X=X, dirs=D, adapter=ad)
    scene = SimpleNamespace(file=tmp_path / "s.toml", solver="calculix")
    dofs = load_dofs(scene, model, LoadSpec(set="RIGHT", box=None, dofs=("uz",), amplitude=(1.0,)))
    right = np.abs(pts[:, 0] - 1.0) < 1e-12
    assert len(dofs) == right.sum() and np.all(D[dofs] == 2) and np.allclose(X[dofs, 0], 1.0)
    both = load_dofs(scene, model, LoadSpec(set="RIGHT", box=None, dofs=("uy", "uz"), amplitude=(1.0,)))
    assert len(both) == 2 * right.sum()
    with pytest.raises(SceneError) as info:  # LEFT is clamped: no free dof to load
        load_dofs(scene, model, LoadSpec(set="LEFT", box=None, dofs=("uz",), amplitude=(1.0,)))
    assert "[analysis.forcing.load.dofs]" in str(info.value) and "no free dof" in str(info.value)


@requires("ccx")
def test_an_unknown_set_lists_the_mesh_sets(tmp_path, capsys):
    write_beam(tmp_path)
    (tmp_path / "s.toml").write_text(
        '[model]\nsolver = "calculix"\nmesh = "beam_mesh.inp"\nkeep = "never"\n[[model.boundary]]\nset = "LEFT"\n'
        "[model.material]\nE = 2.1e11\nnu = 0.3\nrho = 7800.0\n"
        '[analysis]\nmaster_modes = [0]\nmethods = ["dnf"]\n[analysis.backbone]\norder = 5\n'
        "[analysis.damping]\nmodal = 0.01\n[analysis.forcing]\nfrequency_range = [0.9, 1.2]\n"
        'load = {set = "TIP", dofs = ["uz"], amplitude = [1.0]}\n[output]\ndir = "out"\n')
    o = run_cli(["run", tmp_path / "s.toml", "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["[analysis.forcing.load.set]", "no node set 'TIP'", "'LEFT'", "'RIGHT'"])
    assert len(o.err.strip().splitlines()) == 1
