"""Shells in the code_aster adapter (issue 32, item 4): ``element = "dkt"`` or ``"coque_3d"`` on a MED mid-surface.

code_aster is not installed here: the command files are held to its catalogue in
``test_code_aster_catalogue.py``; here the dof map (six dofs a node, ``ux uy uz rx ry rz``), the file round
trip through the fake ``run_aster`` (forces and moments, K and M over the rotational dofs) and the reading
of a real DKT result with rotations (``static_shell_cantilever_code_aster.rmed``, facts in
/work/shared/fixtures/code_aster/README.md) are checked.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from helpers.paths import REPO
from stepnf.errors import SceneError
from stepnf.plugin.adapter import DIRECTIONS
from stepnf.plugin.boundary import BoundaryCondition

ca = pytest.importorskip("stepnf_code_aster")
pytest.importorskip("h5py")
from helpers.code_aster import ISO, install_fake_run_aster, from_mesh, grouped_med, shell_plate_med  # noqa: E402
from stepnf_code_aster.med import read_mesh_nodes, read_nodal_steps  # noqa: E402
from stepnf_code_aster.shell import CodeAsterShellAdapter, forces_from_steps, read_cells  # noqa: E402

FIXTURES = REPO.parent / "shared" / "fixtures" / "code_aster"
if not FIXTURES.is_dir():  # the repository may live elsewhere: the shared folder of this machine
    FIXTURES = Path("/work/shared/fixtures/code_aster")
SHELL_RESULT = FIXTURES / "static_shell_cantilever_code_aster.rmed"
needs_fixture = pytest.mark.skipif(not SHELL_RESULT.is_file(), reason="code_aster fixtures not available")


def shell(tmp_path, element="dkt", kind="quad", **kw):
    path = shell_plate_med(tmp_path, "quad9" if element == "coque_3d" else kind)
    return from_mesh(tmp_path, path, material=ISO, element=element, thickness=0.003, **kw)


# ------------------------------------------------------------------ dofs
@pytest.mark.parametrize("kind", ["quad", "triangle"])
def test_dkt_dofs_are_six_a_node_in_node_order(tmp_path, kind):
    ad = shell(tmp_path, kind=kind)
    n = len(ad.points)
    assert isinstance(ad, CodeAsterShellAdapter) and n == 16 and ad.n_dofs == 6 * n
    np.testing.assert_array_equal(ad.dof_directions(), np.tile(np.arange(6), n))
    assert [DIRECTIONS[d] for d in ad.dof_directions()[:6]] == ["ux", "uy", "uz", "rx", "ry", "rz"]
    np.testing.assert_array_equal(ad.dof_coordinates(), np.repeat(ad.points, 6, axis=0))
    assert ad.characteristic_length() == 0.003  # the thickness, not the mesh's (zero) extent in z
    phi = np.arange(ad.n_dofs, dtype=float)
    np.testing.assert_array_equal(ad.nodal(phi), phi.reshape(n, 6))


def test_coque_3d_centre_nodes_carry_rotations_only(tmp_path):
    ad = shell(tmp_path, "coque_3d")  # 3 x 3 QUAD9 cells: 49 nodes, 9 of them centres
    n, dirs = len(ad.points), ad.dof_directions()
    assert n == 49 and ad.n_dofs == 6 * 40 + 3 * 9
    per_node = np.bincount(ad.dof_node, minlength=n)
    assert sorted(set(per_node)) == [3, 6] and np.sum(per_node == 3) == 9
    assert set(dirs[np.isin(ad.dof_node, np.flatnonzero(per_node == 3))]) == {3, 4, 5}


def test_clamp_fixes_rotations_and_simple_support_does_not(tmp_path):
    ad = shell(tmp_path)
    edge = [[-1e-9, -1.0, -1.0], [1e-9, 1.0, 1.0]]  # the 4 nodes at x = 0
    ad.apply_boundary([BoundaryCondition("model.boundary[0]", (0, 1, 2, 3, 4, 5), box=edge)])
    assert ad.n_dofs == 6 * 16 - 24 and ad.applied_conditions[0]["dofs"][3:] == ["DRX", "DRY", "DRZ"]
    (tmp_path / "b").mkdir()
    ss = shell(tmp_path / "b")
    ss.apply_boundary([BoundaryCondition("model.boundary[0]", (0, 1, 2), box=edge)])
    assert ss.n_dofs == 6 * 16 - 12 and set(ss.dof_directions()[ss.dof_coordinates()[:, 0] == 0]) == {3, 4, 5}


# ------------------------------------------------------------------ file round trip
@pytest.fixture
def fake_run_aster(tmp_path):
    return install_fake_run_aster(tmp_path)


def test_forces_moments_and_matrices_round_trip_through_fake_run_aster(tmp_path, fake_run_aster):
    """The fake run_aster answers a DKT job over DX..DRZ (f = K u + u**3, code_aster's own dof numbering):
    the imposed field is written with its rotations, forces and moments come back in the adapter's dof order."""
    ad = shell(tmp_path, command=f"{fake_run_aster} ${{export}}", keep="never")
    n = ad.n_dofs
    K_exact = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).toarray()
    np.testing.assert_array_equal(ad.stiffness_matrix().toarray(), K_exact)
    U = np.random.default_rng(3).standard_normal((3, n)) * 1e-3
    F = ad.internal_forces(U)
    np.testing.assert_allclose(F, U @ K_exact + U**3, rtol=0, atol=1e-15)  # MED carries float64
    assert np.abs(F[:, ad.dof_directions() >= 3]).min() > 0  # the moments are read, not dropped


def test_fixed_rotations_leave_the_exchanged_fields(tmp_path, fake_run_aster):
    ad = shell(tmp_path, command=f"{fake_run_aster} ${{export}}", keep="never")
    ad.apply_boundary([BoundaryCondition("model.boundary[0]", (3, 4, 5), set=None, box=[[-1, -1, -1], [1, 1, 1]])])
    assert ad.n_dofs == 3 * 16 and set(ad.dof_directions()) == {0, 1, 2}
    assert ad.stiffness_matrix().shape == (48, 48)
    assert ad.internal_forces(np.full((1, 48), 1e-3)).shape == (1, 48)


# ------------------------------------------------------------------ a real DKT result with rotations
@needs_fixture
def test_a_real_dkt_result_reads_forces_and_moments_in_equilibrium():
    """code_aster's own DKT cantilever under gravity: REAC_NODA (DX..DRZ) read through the shell dof map.
    The reactions' moments plus r x (their forces) balance the weight's moment about the origin (the weight,
    153 400.9 N by the README, acts at the area centroid: uniform thickness and density) to round-off, which
    only holds with the moments read on the right components."""
    ad = ca.CodeAsterAdapter.from_med(SHELL_RESULT, shell="dkt", thickness=0.01, material=ISO)
    assert ad.n_dofs == 6 * 403
    (st,) = read_nodal_steps(SHELL_RESULT, "result__REAC_NODA")
    F = forces_from_steps([dataclasses.replace(st, time=1.0)], ad.dof_node, ad.dof_code, 403, 1, Path("."))[0]
    R = ad.nodal(F)
    assert R[:, 2].sum() == pytest.approx(153_400.9, abs=0.05)  # the README's value and rounding
    X = read_mesh_nodes(SHELL_RESULT)
    quads = X[read_cells(SHELL_RESULT, ad.mesh_name)["QU4"]]
    area = np.linalg.norm(np.cross(quads[:, 1] - quads[:, 0], quads[:, 3] - quads[:, 0]), axis=1)  # rectangles
    centroid = (quads.mean(axis=1) * area[:, None]).sum(axis=0) / area.sum()
    moment = R[:, 3:].sum(axis=0) + np.cross(X, R[:, :3]).sum(axis=0)
    weight = np.cross(centroid, [0.0, 0.0, -R[:, 2].sum()])
    tol = 1e-9 * np.abs(weight).max()  # N m; measured 3e-10 N m (round-off of 1.5e5 N sums)
    np.testing.assert_allclose(moment + weight, 0.0, atol=tol)
    assert np.abs(R[:, 3:].sum(axis=0)).max() > 1e4 * tol  # the reaction moments (~26 N m) matter to that balance
    (d,) = read_nodal_steps(SHELL_RESULT, "result__DEPL")
    u = forces_from_steps([dataclasses.replace(d, time=1.0)], ad.dof_node, ad.dof_code, 403, 1, Path("."))[0]
    assert np.abs(u[ad.dof_directions() == 4]).max() == pytest.approx(4.598477e-3, rel=1e-6)  # tip slope DRY


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("cfg, key, mention", [
    ({"element": "dkt", "thickness": 0.003, "geometry": {"a": 0.15, "R": "inf", "h": 0.003}}, "model.element",
     "MED mesh of the mid-surface"),
    ({"element": "dkt", "mesh": "plate_quad.med"}, "model.thickness", "needs thickness"),
    ({"mesh": "plate_quad.med", "thickness": 0.003}, "model.thickness", "a shell's"),
    ({"element": "dkt", "mesh": "plate_quad.med", "thickness": -1.0}, "model.thickness", ""),
    ({"element": "dkt", "mesh": "solid.med", "thickness": 0.003}, "model", "takes a MED mesh of ['TR3', 'QU4']"),
    ({"element": "coque_3d", "mesh": "plate_quad.med", "thickness": 0.003}, "model", "['TR7', 'QU9']"),
    ({"element": "dkt", "mesh": "plate_quad.med", "thickness": 0.003, "force_route": "calcul"}, "model",
     "STAT_NON_LINE route only"),
    ({"element": "dkt", "mesh": "plate_quad.med", "thickness": 0.003,
      "material": {"E1": 1e11, "E2": 1e10, "E3": 1e10, "nu12": 0.3, "nu13": 0.3, "nu23": 0.3, "G12": 5e9, "G13": 5e9,
                   "G23": 4e9, "rho": 1500.0}}, "model.material", "one isotropic"),
])
def test_bad_shell_scenes_name_the_key(tmp_path, cfg, key, mention):
    shell_plate_med(tmp_path, "quad")
    grouped_med(tmp_path, {}, "solid.med")
    cfg = {"material": ISO, **cfg}
    with pytest.raises(SceneError) as ei:
        ca.CodeAsterAdapter.from_config(cfg, base_dir=tmp_path, scene_file=tmp_path / "s.toml")
    assert ei.value.key == key and mention in str(ei.value), str(ei.value)
    assert "s.toml" in str(ei.value)


def test_scene_boundary_on_a_shell_clamps_with_rotations_by_default(tmp_path):
    """``[[model.boundary]]`` on a shell: no ``dofs`` is a clamp (all six), translations alone a simple support,
    and a rotation may be named (on a solid it is refused: test_boundary_rotations in tests/plugin)."""
    edge = [[-1e-9, -1.0, -1.0], [1e-9, 1.0, 1.0]]  # the 4 nodes at x = 0
    clamped = shell(tmp_path, boundary=[{"box": edge}])
    assert clamped.n_dofs == 6 * 16 - 24
    (tmp_path / "b").mkdir()
    simple = shell(tmp_path / "b", boundary=[{"box": edge, "dofs": ["ux", "uy", "uz"]}])
    assert simple.n_dofs == 6 * 16 - 12
    (tmp_path / "c").mkdir()
    twist = shell(tmp_path / "c", boundary=[{"box": edge, "dofs": ["rx"]}])
    assert twist.n_dofs == 6 * 16 - 4 and twist.applied_conditions[0]["dofs"] == ["DRX"]
    c = ca.CodeAsterAdapter.validate_config({"element": "dkt", "mesh": "plate_quad.med", "thickness": 0.003,
                                             "material": ISO, "boundary": [{"box": edge, "dofs": ["ry"]}]},
                                            base_dir=tmp_path)
    assert c["shell"] == "dkt" and c["boundary"][0]["dofs"] == ["ry"]
