"""Scenes of the kratos adapter: the [model] keys, a user's mid-surface mesh with named sets, and bad input
(each a one-line message naming the file and the key, exit 2)."""
from __future__ import annotations

import numpy as np
import pytest

from helpers.required import requires

from stepnf.cli.main import main
from stepnf.errors import SceneError
from stepnf.plugin.registry import get_solver

pytestmark = requires("KratosMultiphysics", "stepnf_kratos")

kratos = pytest.importorskip("stepnf_kratos")
meshio = pytest.importorskip("meshio")

MATERIAL = '[model.material]\nE = 1.04e11\nnu = 0.3\nrho = 4400.0\n'


def plate_file(path, kind: str = "triangle"):
    """A 0.2 x 0.1 m plate of 4 x 2 squares (triangles or quads) with the point set LEFT (x = 0) and the cell set
    HALF (cells with x < 0.1); written by meshio (an Abaqus .inp: *NSET, *ELSET)."""
    x, y = np.meshgrid(np.linspace(0, 0.2, 5), np.linspace(0, 0.1, 3), indexing="ij")
    P = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    i = np.arange(len(P)).reshape(5, 3)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    cells = np.column_stack([a, b, c, d]) if kind == "quad" else np.concatenate(
        [np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    half = np.flatnonzero(P[cells].mean(axis=1)[:, 0] < 0.1)
    meshio.write(path, meshio.Mesh(P, [(kind, cells)], point_sets={"LEFT": np.flatnonzero(P[:, 0] == 0)},
                                   cell_sets={"HALF": [half]}))
    return path


def scene(tmp_path, model: str):
    path = tmp_path / "scene.toml"
    path.write_text(f'[model]\nsolver = "kratos"\n{model}\n[analysis]\nmaster_modes = [0]\n')
    return path


def build(tmp_path, model: str):
    import tomllib

    path = scene(tmp_path, model)
    table = {k: v for k, v in tomllib.loads(path.read_text())["model"].items() if k != "solver"}
    return get_solver("kratos").from_config(table, base_dir=tmp_path, scene_file=path)


def test_registered_and_keys():
    cls = get_solver("kratos")
    assert cls is kratos.KratosAdapter and cls.prefers_batches
    assert {"element", "mesh", "thickness", "geometry", "material", "materials", "boundary"} <= set(cls.model_keys.names)


def test_mesh_with_sets_materials_and_rotation_clamp(tmp_path):
    """A user's triangles: the point set LEFT clamped (all six dofs), the cell set HALF its own material."""
    plate_file(tmp_path / "plate.inp")
    model = ('mesh = "plate.inp"\nthickness = 0.002\nelement = "dkt"\n' + MATERIAL
             + '[model.materials.HALF]\nE = 2.0e11\nnu = 0.3\nrho = 7800.0\n')
    ad = build(tmp_path, model + '[[model.boundary]]\nset = "LEFT"\ndofs = ["ux", "uy", "uz", "rx", "ry", "rz"]\n')
    with ad:
        assert ad.n_dofs == 6 * (15 - 3) and ad.describe()["n_cells"] == 16
        assert ad.characteristic_length() == 0.002
    with build(tmp_path, model) as free:
        M = free.mass_matrix()
        ux = free.dof_directions() == 0
        # a rigid translation along x carries the plate's mass: rho h area of each half (0.1 x 0.1 m)
        assert M[ux][:, ux].sum() == pytest.approx(0.002 * 0.01 * (7800.0 + 4400.0), rel=1e-12)


def test_generated_cap_is_the_solid_caps_mid_surface(tmp_path):
    """[model.geometry] as for the solid adapters; n_core, n_ring set the mesh size; quads for dkq."""
    ad = build(tmp_path, 'element = "dkq"\n[model.geometry]\nshape = "spherical_cap"\na = 0.15\nR = 1.5\nh = 0.003\n'
               'n_core = 4\nn_ring = 2\n' + MATERIAL)
    with ad:
        r = np.hypot(ad.points[:, 0], ad.points[:, 1])
        assert np.allclose(ad.points[:, 2], np.sqrt(1.5**2 - r**2) - 1.5, atol=1e-15)  # on the sphere
        assert ad.mesh.cell_type == "quad" and len(ad.mesh.cells) == 4 * (4 * 4 + 4 * 4 * 2)
        assert ad.shell_scales().kappa == pytest.approx(0.15**4 / (1.5**2 * 0.003**2))
        assert np.allclose(r[ad.mesh.node_sets["edge"]], 0.15)


@pytest.mark.parametrize("model, key, says", [
    ('mesh = "plate.inp"\n' + MATERIAL, "model.thickness", "need a thickness"),
    ('mesh = "solid.inp"\nthickness = 0.002\n' + MATERIAL, "model.mesh", "solid cells"),
    ('element = "mitc4"\nmesh = "plate.inp"\nthickness = 0.002\n' + MATERIAL, "model.element", "dkt"),
    ('element = "dkq"\nmesh = "plate.inp"\nthickness = 0.002\n' + MATERIAL, "model.mesh", "no quad cells"),
    ('mesh = "plate.inp"\nthickness = 0.002\n[model.material]\nE1 = 1e11\nE2 = 1e10\nE3 = 1e10\nnu12 = 0.3\n'
     'nu13 = 0.3\nnu23 = 0.3\nG12 = 5e9\nG13 = 5e9\nG23 = 4e9\nrho = 1600.0\n', "model.material", "isotropic"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, model, key, says):
    plate_file(tmp_path / "plate.inp")
    meshio.write(tmp_path / "solid.inp", meshio.Mesh(np.eye(4, 3), [("tetra", np.array([[0, 1, 2, 3]]))]))
    path = scene(tmp_path, model)
    capsys.readouterr()  # what meshio said while writing
    code = main(["modes", "--quiet", str(path)])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and str(path) in err and f"[{key}]" in err and says in err, err
    with pytest.raises(SceneError):
        build(tmp_path, model)


@pytest.mark.parametrize("kind, broken", [
    ("triangle", lambda P, c: c.__setitem__((0, 1), c[0, 0])),  # a node used twice
    ("triangle", lambda P, c: P.__setitem__(c[0, 2], (P[c[0, 0]] + P[c[0, 1]]) / 2)),  # three nodes on a line
    ("quad", lambda P, c: P.__setitem__(c[0, 3], P[c[0, 2]])),  # two corners at one point
])
def test_degenerate_cell_is_one_line_exit_2(tmp_path, capsys, kind, broken):
    """A collapsed cell of a user's mesh is a one-line message naming the file, the key and the cell (exit 2),
    not Kratos's NaN stiffness reported as a solver failure (exit 3, as before)."""
    plate_file(tmp_path / "plate.inp", kind)
    m = meshio.read(tmp_path / "plate.inp")
    P, cells = np.array(m.points), np.array(m.cells[0].data)
    broken(P, cells)
    meshio.write(tmp_path / "plate.inp", meshio.Mesh(P, [(kind, cells)]))
    element = "dkq" if kind == "quad" else "dkt"
    path = scene(tmp_path, f'element = "{element}"\nmesh = "plate.inp"\nthickness = 0.002\n' + MATERIAL)
    capsys.readouterr()
    code = main(["modes", "--quiet", str(path)])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "[model.mesh]" in err, err
    assert f"{kind} cell 0 " in err and "degenerate" in err, err


def test_conditions_that_fix_every_dof_are_one_line_exit_2(tmp_path, capsys):
    """A box around the whole plate clamping all six dofs leaves no dof: a scene error naming
    [model.boundary] (exit 2), not "the model has no dofs (K is 0 x 0)" from the solver's matrices (exit 3,
    as before)."""
    plate_file(tmp_path / "plate.inp")
    path = scene(tmp_path, 'mesh = "plate.inp"\nthickness = 0.002\n' + MATERIAL + '[[model.boundary]]\n'
                 'box = [[-1, -1, -1], [1, 1, 1]]\ndofs = ["ux", "uy", "uz", "rx", "ry", "rz"]\n')
    capsys.readouterr()
    code = main(["modes", "--quiet", str(path)])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "[model.boundary]" in err and "all 90 dofs" in err, err
