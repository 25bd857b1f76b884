"""code_aster adapter: [model.material] orthotropic with axes and [model.materials.<group>] per MED cell group
(ELAS / ELAS_ORTH, AFFE_MATERIAU by GROUP_MA, AFFE_CARA_ELEM MASSIF ANGL_REP), checked on the rendered
command files and through a fake run_aster; code_aster itself is not needed."""
from __future__ import annotations

import ast
import hashlib
import math
import stat
import sys
from pathlib import Path

import numpy as np
import pytest

from stepnf.errors import SceneError
from stepnf.plugin.materials import rotation

ca = pytest.importorskip("stepnf_code_aster")
h5py = pytest.importorskip("h5py")
from stepnf_code_aster.materials import ALL_CELLS, nautical_angles  # noqa: E402
from helpers.code_aster import AXES, FAKE_RUN_ASTER, ISO, ORTHO, cap, from_mesh, grouped_med  # noqa: E402

CodeAsterAdapter = ca.CodeAsterAdapter
#: sha256 of today's (before [model.materials]) forces.comm and matrices.comm for the CAP with ISO,
#: workdir /WD, 7 fields: an isotropic single-material render must stay byte-identical.
GOLDEN = {"forces": "506d409196f9755246931c9573f43b4dfbe113637e80ecfdff79084ed30a8e4b",
          "matrices": "1077c0e13468c76782e4443e673408b5f6f9ac56e7cb19cee76ef5c58eda739d"}


def matrot(alpha: float, beta: float, gamma: float) -> np.ndarray:
    """code_aster's bibfor/utilitai/matrot.F90 (angles in radians): rows are the final axes."""
    ca_, sa, cb, sb, cg, sg = (math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta), math.cos(gamma),
                               math.sin(gamma))
    return np.array([[cb * ca_, cb * sa, -sb],
                     [sg * sb * ca_ - cg * sa, cg * ca_ + sg * sb * sa, sg * cb],
                     [sg * sa + cg * sb * ca_, cg * sb * sa - ca_ * sg, cg * cb]])


def render(ad, tmp_path, job):
    wd = tmp_path / f"wd_{job}"
    wd.mkdir(exist_ok=True)
    ad.render_job(wd, job, n_fields=3)
    comm = (wd / f"{job}.comm").read_text()
    assert "$" not in comm
    return comm, ast.parse(comm)


def calls(tree, name):
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == name]


def kwargs(call):
    return {k.arg: k.value for k in call.keywords}


def f_entries(node):
    """The ``_F(...)`` keyword dicts of a factor keyword (one ``_F`` or a tuple of them)."""
    items = node.elts if isinstance(node, ast.Tuple) else [node]
    return [{k: ast.literal_eval(v) if not isinstance(v, ast.Name) else v.id for k, v in kwargs(c).items()}
            for c in items]


# ------------------------------------------------------------------ renders
@pytest.mark.parametrize("job", ["forces", "matrices"])
def test_isotropic_render_is_byte_identical_to_before(tmp_path, job):
    ad = cap(tmp_path)
    text = ad.templates[f"{job}.comm"].render(ad._values(Path("/WD"), job, 7))
    assert hashlib.sha256(text.encode()).hexdigest() == GOLDEN[job]


def test_angles_rebuild_the_rotation():
    rng = np.random.default_rng(3)
    cases = [AXES, [[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 0, 0]], [[0, 1, 0], [-1, 0, 0]]]
    cases += [rng.standard_normal((2, 3)).tolist() for _ in range(50)]
    for axes in cases:
        Q = rotation(axes)
        angles = nautical_angles(Q)
        np.testing.assert_allclose(matrot(*np.radians(angles)), Q, rtol=0, atol=1e-12)
    assert nautical_angles(rotation([[0, 1, 0], [-1, 0, 0]])) == pytest.approx((90.0, 0.0, 0.0))


def test_groups_orthotropy_and_axes_rendered(tmp_path):
    n = len(cap(tmp_path).cells)
    path = grouped_med(tmp_path, {"CORE": slice(0, n // 2), "SKIN": slice(n // 2, n - 1)})
    ad = from_mesh(tmp_path, path, material=ISO,
                   materials={"CORE": {**ORTHO, "axes": AXES}, "SKIN": {"E": 7.1e10, "nu": 0.33, "rho": 2700.0}})
    assert ad.describe()["materials"]["CORE"]["E1"] == ORTHO["E1"]
    for job in ("forces", "matrices"):
        comm, tree = render(ad, tmp_path, job)
        mats = {}
        for assign in (n for n in ast.walk(tree) if isinstance(n, ast.Assign)):
            if isinstance(assign.value, ast.Call) and getattr(assign.value.func, "id", "") == "DEFI_MATERIAU":
                (kw, val), = kwargs(assign.value).items()
                mats[assign.targets[0].id] = (kw, f_entries(val)[0])
        # 17 significant digits: every constant reads back exactly
        assert mats["material"] == ("ELAS", {"E": ISO["E"], "NU": ISO["nu"], "RHO": ISO["rho"]})
        assert mats["material_1"] == ("ELAS_ORTH", {"E_L": ORTHO["E1"], "E_T": ORTHO["E2"], "E_N": ORTHO["E3"],
                                                    "NU_LT": ORTHO["nu12"], "NU_LN": ORTHO["nu13"],
                                                    "NU_TN": ORTHO["nu23"], "G_LT": ORTHO["G12"],
                                                    "G_LN": ORTHO["G13"], "G_TN": ORTHO["G23"], "RHO": ORTHO["rho"]})
        assert mats["material_2"] == ("ELAS", {"E": 7.1e10, "NU": 0.33, "RHO": 2700.0})
        (affe,) = calls(tree, "AFFE_MATERIAU")
        assert f_entries(kwargs(affe)["AFFE"]) == [  # the default first: later occurrences override it
            {"TOUT": "OUI", "MATER": "material"}, {"GROUP_MA": "CORE", "MATER": "material_1"},
            {"GROUP_MA": "SKIN", "MATER": "material_2"}]
        (cara,) = calls(tree, "AFFE_CARA_ELEM")
        massif = f_entries(kwargs(cara)["MASSIF"])
        assert [m["GROUP_MA"] for m in massif] == ["CORE", "SKIN"] and not calls(tree, "DEFI_GROUP")
        np.testing.assert_allclose(matrot(*np.radians(massif[0]["ANGL_REP"])), rotation(AXES), atol=1e-12)
        assert massif[1]["ANGL_REP"] == (0.0, 0.0, 0.0)
        (solver,) = calls(tree, "STAT_NON_LINE" if job == "forces" else "ASSEMBLAGE")
        assert kwargs(solver)["CARA_ELEM"].id == "cara"


def test_orthotropic_default_with_axes_on_a_mesh_without_groups(tmp_path):
    path = grouped_med(tmp_path, {})
    ad = from_mesh(tmp_path, path, material={**ORTHO, "axes": AXES})
    assert ad.material == {}
    comm, tree = render(ad, tmp_path, "forces")
    (group,) = calls(tree, "DEFI_GROUP")
    assert f_entries(kwargs(group)["CREA_GROUP_MA"]) == [{"NOM": ALL_CELLS, "TOUT": "OUI"}]
    (massif,) = f_entries(kwargs(calls(tree, "AFFE_CARA_ELEM")[0])["MASSIF"])
    assert massif["GROUP_MA"] == ALL_CELLS
    np.testing.assert_allclose(matrot(*np.radians(massif["ANGL_REP"])), rotation(AXES), atol=1e-12)
    assert f_entries(kwargs(calls(tree, "AFFE_MATERIAU")[0])["AFFE"]) == [{"TOUT": "OUI", "MATER": "material"}]


def test_orthotropic_without_axes_needs_no_cara_elem(tmp_path):
    ad = from_mesh(tmp_path, grouped_med(tmp_path, {}), material=ORTHO)
    comm, tree = render(ad, tmp_path, "matrices")
    assert not calls(tree, "AFFE_CARA_ELEM") and "CARA_ELEM" not in comm
    assert "ELAS_ORTH" in comm


def test_med_cell_groups(tmp_path):
    path = grouped_med(tmp_path, {"A": slice(0, 3), "B": slice(5, 7)})
    n, groups = ca.med.read_cell_groups(path)
    assert n == len(cap(tmp_path).cells)
    assert {k: v.tolist() for k, v in groups.items()} == {"A": [0, 1, 2], "B": [5, 6]}
    assert ca.med.read_cell_groups(grouped_med(tmp_path, {}, "plain.med"))[1] == {}


# ------------------------------------------------------------ fake run_aster
GROUP_CHECK = '''comm = files["comm"].read_text()
if 'GROUP_MA="CORE"' not in comm or 'GROUP_MA="SKIN"' not in comm or "ELAS_ORTH" not in comm:
    print("<F> group or material missing", flush=True)
    sys.exit(5)
'''


def test_round_trip_with_two_groups(tmp_path):
    exe = tmp_path / "bin" / "run_aster"
    exe.parent.mkdir()
    fake = FAKE_RUN_ASTER.replace('comm = files["comm"].read_text()\n', GROUP_CHECK, 1)
    assert fake != FAKE_RUN_ASTER
    exe.write_text(fake.format(python=sys.executable))
    exe.chmod(exe.stat().st_mode | stat.S_IEXEC)
    n = len(cap(tmp_path).cells)
    path = grouped_med(tmp_path, {"CORE": slice(0, n // 2), "SKIN": slice(n // 2, n)})
    ad = from_mesh(tmp_path, path, command=f"{exe} ${{export}}", keep="never",
                   materials={"CORE": {**ORTHO, "axes": AXES}, "SKIN": ISO})
    K = ad.stiffness_matrix()
    assert K.shape == (ad.n_dofs, ad.n_dofs) and ad.mass_matrix().diagonal().sum() == ad.n_dofs
    U = np.random.default_rng(2).standard_normal((2, ad.n_dofs)) * 1e-3
    np.testing.assert_allclose(ad.internal_forces(U), U @ K.toarray() + U**3, rtol=0, atol=1e-15)
    assert len(ad.runs) == 2


# ---------------------------------------------------------------- bad input
def test_bad_inputs_are_scene_errors_naming_the_key(tmp_path):
    n = len(cap(tmp_path).cells)
    path = grouped_med(tmp_path, {"CORE": slice(0, 4), "SKIN": slice(2, 8)})
    with pytest.raises(SceneError) as ei:
        from_mesh(tmp_path, path, material=ISO, materials={"WING": ISO})
    assert ei.value.key == "model.materials.WING" and "CORE" in str(ei.value) and "SKIN" in str(ei.value)
    assert str(ei.value.file) == str(tmp_path / "scene.toml")
    with pytest.raises(SceneError) as ei:
        from_mesh(tmp_path, path, material=ISO, materials={"CORE": ISO, "SKIN": ORTHO})
    assert ei.value.key == "model.materials.SKIN" and "both" in str(ei.value)
    with pytest.raises(SceneError) as ei:
        from_mesh(tmp_path, path, materials={"CORE": ISO})
    assert ei.value.key == "model.material" and f"of the {n} cells" in str(ei.value)
    with pytest.raises(SceneError) as ei:
        from_mesh(tmp_path, path, material={**ISO, "E1": 1.0})
    assert ei.value.key == "model.material"
    with pytest.raises(SceneError) as ei:
        cap(tmp_path, materials={"CORE": ISO})
    assert ei.value.key == "model.materials"


def test_user_templates_without_placeholders_refuse_regions(tmp_path):
    n = len(cap(tmp_path).cells)
    path = grouped_med(tmp_path, {"CORE": slice(0, n // 2)})
    shipped = Path(ca.__file__).parent / "templates"
    old = (shipped / "forces.comm").read_text().replace(
        "${materials}", "material = DEFI_MATERIAU(ELAS=_F(E=${E}, NU=${nu}, RHO=${rho}))\n\n"
        'fieldmat = AFFE_MATERIAU(MAILLAGE=mesh, AFFE=_F(TOUT="OUI", MATER=material))')
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "forces.comm").write_text(old.replace("${cara_elem}", ""))
    ok = from_mesh(tmp_path, path, material=ISO, templates="old")  # one isotropic material: ${E} still works
    comm, _ = render(ok, tmp_path, "forces")
    assert "ELAS=_F(E=104000000000, NU=0.29999999999999999, RHO=4400)" in comm
    with pytest.raises(SceneError, match=r"no \$\{materials\}") as ei:
        from_mesh(tmp_path, path, material=ISO, templates="old", materials={"CORE": ORTHO})
    assert ei.value.key == "model.materials"
    with pytest.raises(SceneError, match=r"no \$\{materials\}") as ei:
        from_mesh(tmp_path, path, material=ORTHO, templates="old")
    assert ei.value.key == "model.material"
    (tmp_path / "nocara").mkdir()
    (tmp_path / "nocara" / "matrices.comm").write_text(
        (shipped / "matrices.comm").read_text().replace("${cara_elem}", ""))
    from_mesh(tmp_path, path, material=ORTHO, templates="nocara")  # no axes: no CARA_ELEM needed
    with pytest.raises(SceneError, match=r"cara_elem") as ei:
        from_mesh(tmp_path, path, material={**ORTHO, "axes": AXES}, templates="nocara")
    assert ei.value.key == "model.material"
