"""The code_aster adapter without code_aster: rendered command files, and the whole file round trip
through a fake ``run_aster`` (a Python script that reads the .export, the MED input and writes
the outputs code_aster would write).
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.errors import SceneError, SolverRunError

ca = pytest.importorskip("stepnf_code_aster")
from helpers.code_aster import install_fake_run_aster  # noqa: E402

CodeAsterAdapter = ca.CodeAsterAdapter

MATERIAL = {"E": 1.04e11, "nu": 0.3, "rho": 4400.0}
CAP = {"shape": "spherical_cap", "a": 0.15, "R": 1.5, "h": 0.003, "n_core": 2, "n_ring": 1}


def make(tmp_path, **kw):
    cfg = {"geometry": CAP, "material": MATERIAL, "workdir": "runs", **kw}
    from stepnf.runtime.programs import allow_programs

    with allow_programs():  # command and templates name programs: the user allows them here
        return CodeAsterAdapter.from_config(cfg, base_dir=tmp_path, scene_file=tmp_path / "scene.toml")


# --------------------------------------------------------------- templates
@pytest.mark.parametrize("job", ["forces", "matrices"])
def test_rendered_command_files_are_valid_python(tmp_path, job):
    ad = make(tmp_path)
    wd = tmp_path / "wd"
    wd.mkdir()
    argv = ad.render_job(wd, job, n_fields=7)
    comm = (wd / f"{job}.comm").read_text()
    assert "${" not in comm and "$" not in comm  # every placeholder filled
    tree = ast.parse(comm)  # code_aster command files are Python
    calls = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    assert {"DEBUT", "LIRE_MAILLAGE", "AFFE_MODELE", "DEFI_MATERIAU", "AFFE_MATERIAU", "FIN"} <= calls
    if job == "forces":
        assert {"LIRE_RESU", "AFFE_CHAR_CINE", "STAT_NON_LINE", "CALC_CHAMP", "IMPR_RESU"} <= calls
        assert 'DEFORMATION="GROT_GDEP"' in comm and '"FORC_NODA"' in comm
        assert "JUSQU_A=7.0" in comm  # one time step per field
    else:
        assert "ASSEMBLAGE" in calls and '"RIGI_MECA"' in comm and '"MASS_MECA"' in comm
        assert str(wd / "matrices.npz") in comm
    # material constants written with 17 significant digits: they read back exactly
    m = re.search(r"ELAS=_F\(E=([^,]+), NU=([^,]+), RHO=([^)]+)\)", comm)
    assert [float(x) for x in m.groups()] == [MATERIAL["E"], MATERIAL["nu"], MATERIAL["rho"]]
    export = (wd / f"{job}.export").read_text()
    assert "$" not in export
    files = [line.split() for line in export.splitlines() if line.startswith("F ")]
    assert all(len(f) == 5 and f[3] in ("D", "R") for f in files)
    units = {f[1]: int(f[4]) for f in files}
    assert units["comm"] == 1 and units["mmed"] == 20 and units["mess"] == 6
    assert (units.get("rmed") == 80) == (job == "forces")
    assert argv == ["run_aster", str(wd / f"{job}.export")]


def test_calcul_force_route_renders_forces_calcul(tmp_path):
    """force_route = "calcul": the force job is CALCUL FORC_INTE_ELEM per field (forces_calcul.comm, written as
    forces.comm with the same .export); the matrices job does not change."""
    ad = make(tmp_path, force_route="calcul")
    assert ad.describe()["force_route"] == "calcul"
    wd = tmp_path / "wd"
    wd.mkdir()
    ad.render_job(wd, "forces", n_fields=4)
    comm = (wd / "forces.comm").read_text()
    tree = ast.parse(comm)
    calls = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    assert {"CALCUL", "EXTR_TABLE", "ASSE_VECTEUR", "CREA_RESU", "IMPR_RESU"} <= calls and "STAT_NON_LINE" not in calls
    assert "n_fields = 4" in comm and 'DEFORMATION="GROT_GDEP"' in comm and "$" not in comm
    assert "forces.rmed R 80" in (wd / "forces.export").read_text()
    assert ad.templates["forces_calcul.comm"].source.endswith("templates/forces_calcul.comm")


def test_user_templates_and_docker_command(tmp_path):
    (tmp_path / "tpl").mkdir()
    custom = ca.shipped_template("forces.comm").text.replace("ITER_GLOB_MAXI=${max_iterations}",
                                                             "ITER_GLOB_MAXI=${max_iterations}, RESI_GLOB_RELA=1e-8")
    (tmp_path / "tpl" / "forces.comm").write_text(custom)
    ad = make(tmp_path, templates="tpl",
              command="docker run --rm -v ${workdir}:${workdir} simvia/code_aster run_aster ${export}")
    wd = tmp_path / "wd"
    wd.mkdir()
    argv = ad.render_job(wd, "forces", 2)
    assert "RESI_GLOB_RELA=1e-8" in (wd / "forces.comm").read_text()
    assert argv[:5] == ["docker", "run", "--rm", "-v", f"{wd}:{wd}"] and argv[-1] == str(wd / "forces.export")
    assert ad.templates["matrices.comm"].source.startswith("stepnf_code_aster")  # not overridden


def test_unfilled_placeholder_in_user_template(tmp_path):
    (tmp_path / "tpl").mkdir()
    (tmp_path / "tpl" / "forces.comm").write_text("DEBUT()\nx = ${my_own_value}\nFIN()\n")
    ad = make(tmp_path, templates="tpl")
    from stepnf.external import TemplateError

    with pytest.raises(TemplateError, match="my_own_value"):
        ad.internal_force(np.zeros(ad.n_dofs))


# ---------------------------------------------------------- fake run_aster
@pytest.fixture
def fake_run_aster(tmp_path):
    return install_fake_run_aster(tmp_path)


@pytest.mark.parametrize("route", ["stat_non_line", "calcul"])
def test_round_trip_through_fake_run_aster(tmp_path, fake_run_aster, route):
    ad = make(tmp_path, command=f"{fake_run_aster} ${{export}}", keep="never", force_route=route)
    n = ad.n_dofs
    K_exact = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).toarray()
    K = ad.stiffness_matrix()
    np.testing.assert_array_equal(K.toarray(), K_exact)  # dof map undone, triangle mirrored
    np.testing.assert_array_equal(ad.mass_matrix().diagonal(), np.ones(n))
    U = np.random.default_rng(1).standard_normal((4, n)) * 1e-3
    F = ad.internal_forces(U)
    np.testing.assert_allclose(F, U @ K_exact + U**3, rtol=0, atol=1e-15)  # MED carries float64
    assert len(ad.runs) == 2  # one run for K and M, ONE run for the whole batch
    assert list((tmp_path / "runs").iterdir()) == []  # work folders removed


def test_solver_failure_quotes_log_and_keeps_folder(tmp_path, fake_run_aster):
    (tmp_path / "tpl").mkdir()
    (tmp_path / "tpl" / "forces.comm").write_text("# FAIL\nDEBUT()\nFIN()\n")
    ad = make(tmp_path, command=f"{fake_run_aster} ${{export}}", templates="tpl")
    with pytest.raises(SolverRunError, match="exited with code 4") as ei:
        ad.internal_forces(np.zeros((2, ad.n_dofs)))
    assert "MED2_4" in ei.value.log_tail
    assert (Path(ei.value.workdir) / "forces.comm").is_file()  # kept on error


def test_missing_step_in_output(tmp_path, fake_run_aster):
    (tmp_path / "tpl").mkdir()
    (tmp_path / "tpl" / "forces.comm").write_text("# DROP_LAST\nDEBUT()\nFIN()\n")
    ad = make(tmp_path, command=f"{fake_run_aster} ${{export}}", templates="tpl")
    with pytest.raises(SolverRunError, match="no step at time 3"):
        ad.internal_forces(np.arange(1.0, 4.0)[:, None] * np.full((3, ad.n_dofs), 1e-3))


def test_missing_run_aster(tmp_path):
    ad = make(tmp_path, command="no-such-run-aster-xyz ${export}")
    with pytest.raises(SolverRunError, match="no-such-run-aster-xyz"):
        ad.stiffness_matrix()


def test_shell_facts_and_user_med_mesh(tmp_path):
    ad = make(tmp_path)
    assert ad.characteristic_length() == 0.003
    assert ad.shell_scales().kappa == pytest.approx(0.15**4 / (1.5**2 * 0.003**2))
    phi = np.zeros(ad.n_dofs)
    phi[2::3] = 1.0
    assert ad.transverse_amplitude(phi) == pytest.approx(1.0, abs=1e-12)
    # a user's MED mesh: the code_aster test-suite file (64 nodes)
    fx = Path("/work/shared/fixtures/code_aster/zzzz395f_modal_basis.rmed")
    if fx.is_file():
        import shutil

        shutil.copy(fx, tmp_path / "part.med")
        user = CodeAsterAdapter.from_config({"mesh": "part.med", "material": MATERIAL}, base_dir=tmp_path)
        assert user.n_dofs == 3 * 64 and user.mesh_name == "mesh"
        wd = tmp_path / "wd"
        wd.mkdir()
        user._write_model(wd, np.zeros((2, user.n_dofs)))
        assert [s.time for s in ca.read_nodal_steps(wd / "model.med", "U")] == [0.0, 1.0, 2.0]
        assert len(ca.read_nodal_steps(wd / "model.med", "base_p__DEPL")) == 2  # the user's data kept


@pytest.mark.parametrize("cfg, key", [
    ({"geometry": CAP, "material": MATERIAL, "element": "hex27"}, "model.element"),
    ({"geometry": CAP, "material": {"E": 1.0, "nu": 0.3}}, "model.material.rho"),
    ({"geometry": CAP, "material": MATERIAL, "ncpus": 0}, "model.ncpus"),
    ({"geometry": CAP, "material": MATERIAL, "templates": "nowhere"}, "model.templates"),
    ({"geometry": CAP, "material": MATERIAL, "force_route": "newton"}, "model.force_route"),
    ({"mesh": "x.inp", "material": MATERIAL}, "model.mesh"),
    ({"material": MATERIAL}, "model"),
])
def test_scene_errors_name_the_key(tmp_path, cfg, key):
    with pytest.raises(SceneError) as ei:
        CodeAsterAdapter.from_config(cfg, base_dir=tmp_path, scene_file=tmp_path / "s.toml")
    assert ei.value.key == key


# ---------------------------------------------------------- boundary conditions (issue 11)
#: real code_aster files (../shared/fixtures/code_aster/README.md), as the test above finds them
FIXTURES = Path("/work/shared/fixtures/code_aster")

def test_clamped_edge_round_trip_restricts_to_the_free_dofs(tmp_path, fake_run_aster):
    """[[model.boundary]] set = "edge" on a generated cap: the fake solver's K (whole mesh) and forces
    come back restricted to the free dofs, exactly (the same K with the fixed rows/columns removed)."""
    ad = make(tmp_path, command=f"{fake_run_aster} ${{export}}", keep="never",
              boundary=[{"set": "edge"}])
    fd = ad.free_dof_map()
    n_full = 3 * len(ad.points)
    edge = ad.node_sets["edge"]
    assert fd.n_full == n_full and sorted(fd.fixed.tolist()) == sorted((3 * edge[:, None] + np.arange(3)).ravel())
    assert ad.n_dofs == n_full - 3 * len(edge) and len(ad.dof_coordinates()) == ad.n_dofs
    K_full = sp.diags([-np.ones(n_full - 1), 2 * np.ones(n_full), -np.ones(n_full - 1)], [-1, 0, 1]).toarray()
    K_free = K_full[np.ix_(fd.free, fd.free)]
    np.testing.assert_array_equal(ad.stiffness_matrix().toarray(), K_free)
    U = np.random.default_rng(2).standard_normal((3, ad.n_dofs)) * 1e-3
    # the solver sees the expanded field (zeros on the edge), the adapter returns the free rows
    expected = (fd.expand(U) @ K_full + fd.expand(U) ** 3)[:, fd.free]
    np.testing.assert_allclose(ad.internal_forces(U), expected, rtol=0, atol=1e-15)
    assert ad.describe()["boundary"]["n_fixed"] == 3 * len(edge)


def test_med_groups_are_node_sets():
    """MED groups of the real code_aster fixtures: node groups and cell groups (their nodes)."""
    path = FIXTURES / "zzzz395f_modal_basis.rmed"
    if not path.is_file():
        pytest.skip("code_aster fixtures not present")
    groups = ca.med.read_groups(path)
    X = ca.med.read_mesh_nodes(path)
    assert len(groups["Group_Of_All_Nodes"]) == len(X) == 64
    # the faces z = 0 (S_inf) and z = 3 (S_f) of the 3 x 3 x 3 block: 16 nodes each
    assert len(groups["S_inf"]) == 16 and np.all(X[groups["S_inf"], 2] == 0.0)
    assert len(groups["S_f"]) == 16 and np.all(X[groups["S_f"], 2] == 3.0)


def test_unknown_med_group_lists_the_groups(tmp_path):
    src = FIXTURES / "static_solid_cantilever_code_aster.rmed"
    if not src.is_file():
        pytest.skip("code_aster fixtures not present")
    mesh = tmp_path / "beam.med"
    mesh.write_bytes(src.read_bytes())
    with pytest.raises(SceneError) as info:
        CodeAsterAdapter.from_config({"mesh": "beam.med", "material": MATERIAL, "boundary": [{"set": "LEFT"}]},
                                     base_dir=tmp_path, scene_file=tmp_path / "s.toml")
    assert info.value.key == "model.boundary[0].set" and "['bc_nodes', 'elMyBeam_so']" in str(info.value)
