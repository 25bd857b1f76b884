"""The MED reader/writer of the code_aster adapter, on real code_aster result files.

Fixture facts come from /work/shared/fixtures/code_aster/README.md (files written by
code_aster itself). Sums are compared to the README's rounding (0.1 N on ~1.5e5 N).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from helpers.paths import REPO

med = pytest.importorskip("stepnf_code_aster.med")

FIXTURES = REPO.parent / "shared" / "fixtures" / "code_aster"
if not FIXTURES.is_dir():  # the repository may live elsewhere: the shared folder of this machine
    FIXTURES = Path("/work/shared/fixtures/code_aster")
needs_fixtures = pytest.mark.skipif(not FIXTURES.is_dir(), reason="code_aster fixtures not available")


def _nonzero_nodes(values: np.ndarray, rel: float = 1e-8) -> np.ndarray:
    """Nodes whose reaction exceeds rel x the largest (code_aster leaves ~1e-12 relative noise elsewhere)."""
    a = np.abs(values).max(axis=1)
    return np.nonzero(a > rel * a.max())[0]


@needs_fixtures
def test_solid_cantilever_reactions():
    path = FIXTURES / "static_solid_cantilever_code_aster.rmed"
    assert med.list_fields(path)["result__REAC_NODA"] == ["DX", "DY", "DZ"]
    (st,) = med.read_nodal_steps(path, "result__REAC_NODA")
    assert st.values.shape == (930, 3) and len(st.nodes) == 930
    assert len(med.read_mesh_nodes(path)) == 930
    assert len(_nonzero_nodes(st.values)) == 30
    assert st.component("DZ").sum() == pytest.approx(149_109.4, abs=0.05)
    # equilibrium in x and y: the in-plane reactions cancel to round-off
    assert abs(st.component("DX").sum()) < 1e-6 * 149_109.4
    # a wrong (C-order) reshape would mix components and break the sum
    wrong = np.asarray(st.values).ravel(order="F").reshape(930, 3)[:, 2].sum()
    assert abs(wrong - 149_109.4) > 1e3


@needs_fixtures
def test_shell_cantilever_reactions_and_profile():
    path = FIXTURES / "static_shell_cantilever_code_aster.rmed"
    (st,) = med.read_nodal_steps(path, "result__REAC_NODA")
    assert st.components == ["DX", "DY", "DZ", "DRX", "DRY", "DRZ"]
    assert st.values.shape == (403, 6)
    clamped = _nonzero_nodes(st.values[:, :3])
    assert len(clamped) == 13
    assert st.component("DZ").sum() == pytest.approx(153_400.9, abs=0.05)
    # the file's profile lists exactly the clamped nodes
    np.testing.assert_array_equal(np.sort(med.read_profile(path, "PROFIL__00000001")), clamped)


@needs_fixtures
def test_eigen_cantilever_frequencies():
    path = FIXTURES / "eigen_solid_cantilever_code_aster.rmed"
    steps = med.read_nodal_steps(path, "modes___DEPL")
    assert len(steps) == 20
    freqs = [s.time for s in steps]
    assert freqs[0] == pytest.approx(14.2755, abs=5e-5)
    assert np.all(np.diff(freqs) >= 0)  # stored by increasing frequency
    assert all(s.values.shape == (930, 3) for s in steps)


@needs_fixtures
def test_zzzz395f_modal_basis():
    path = FIXTURES / "zzzz395f_modal_basis.rmed"
    steps = med.read_nodal_steps(path, "base_p__DEPL")
    assert len(steps) == 2
    assert [(s.ndt, s.nor) for s in steps] == [(1, 1), (2, 2)]
    assert all(s.values.shape == (64, 3) for s in steps)
    assert len(med.read_mesh_nodes(path, "mesh")) == 64
    assert all(np.abs(s.values).max() > 0 for s in steps)


@needs_fixtures
def test_errors_name_what_exists():
    path = FIXTURES / "zzzz395f_modal_basis.rmed"
    with pytest.raises(med.MedError, match="base_p__DEPL"):
        med.read_nodal_steps(path, "nope")
    with pytest.raises(med.MedError, match="has 2 step"):
        med.read_nodal_field(path, "base_p__DEPL", step=5)


def test_med_and_calculix_result_errors_are_solver_failures(tmp_path):
    """MedError and CalculiX's ResultFormatError: SolverRunError (CLI exit 3), still ValueError."""
    from stepnf.cli.main import report_failure
    from stepnf.errors import SolverRunError

    ccx = pytest.importorskip("stepnf_calculix.results")
    bad = tmp_path / "bad.sti"
    bad.write_text("1 1 2.0\n1 2\n")
    with pytest.raises(ccx.ResultFormatError) as ccx_error:
        ccx.read_matrix(bad, 2)
    with pytest.raises(med.MedError) as med_error:
        med.read_mesh_nodes(tmp_path / "missing.med")
    for exc in (ccx_error.value, med_error.value):
        assert isinstance(exc, SolverRunError) and isinstance(exc, ValueError)
        assert report_failure(exc) == 3


def test_write_read_round_trip(tmp_path):
    """A mesh and a field written by stepnf read back exactly (and by meshio, an independent reader)."""
    from stepnf.geometry import spherical_cap

    mesh = spherical_cap(1.0, 3.0, 0.1, element="hex20", n_core=2, n_ring=1)
    n = mesh.n_points
    rng = np.random.default_rng(0)
    steps = [(0.0, np.zeros((n, 3))), (1.0, rng.standard_normal((n, 3))), (2.0, rng.standard_normal((n, 3)))]
    path = med.write_med(tmp_path / "m.med", mesh.points, mesh.cells, "hexahedron20",
                         fields={"U": (["DX", "DY", "DZ"], steps)})
    back = med.read_nodal_steps(path, "U")
    assert [s.time for s in back] == [0.0, 1.0, 2.0]
    for s, (_, v) in zip(back, steps):
        np.testing.assert_array_equal(s.values, v)  # float64 both ways: bit-exact
    np.testing.assert_array_equal(med.read_mesh_nodes(path), mesh.points)
    meshio = pytest.importorskip("meshio")
    m = meshio.read(path)
    np.testing.assert_array_equal(m.points, mesh.points)
    cells = m.cells_dict["hexahedron20"]
    # MED's orientation: the first face of a MED hexahedron is the last of VTK's
    np.testing.assert_array_equal(cells[:, med.MED_FROM_VTK["hexahedron20"]], mesh.cells)


def test_med_orientation_matches_code_aster_test_mesh():
    """In code_aster's own test mesh (zzzz395f) every HE8 has negative volume in VTK's convention.

    So MED's hexahedra are VTK's with the opposite orientation, which MED_FROM_VTK undoes.
    """
    import h5py

    path = FIXTURES / "zzzz395f_modal_basis.rmed"
    if not path.is_file():
        pytest.skip("fixture missing")
    with h5py.File(path, "r") as f:
        st = next(iter(f["ENS_MAA"]["mesh"].values()))
        c = np.asarray(st["MAI"]["HE8"]["NOD"]).reshape((-1, 8), order="F") - 1
    X = med.read_mesh_nodes(path, "mesh")

    def signed(cells):
        P = X[cells]
        return np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 3] - P[:, 0]), P[:, 4] - P[:, 0])

    assert np.all(signed(c) < 0)
    assert np.all(signed(c[:, med.MED_FROM_VTK["hexahedron"]]) > 0)
