"""Bad input to the FEniCSx route: a clear error (file, key or stage, what was expected),
a non-zero exit code from ``stepnf.cli.main.main``, and the results of an earlier run left intact.

Geometry errors are caught when the scene's ``[model]`` table is read, mesh
defects (coincident nodes, tangled cells, unreadable files) when the mesh is
read (``stepnf.geometry.checks``, ``stepnf_fenicsx.adapter.read_mesh``).
"""
from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("dolfinx")
meshio = pytest.importorskip("meshio")

from stepnf.cli.main import main  # noqa: E402
from stepnf.geometry import spherical_cap  # noqa: E402

pytestmark = pytest.mark.fenicsx

MATERIAL = "[model.material]\nE = 1.04e11\nnu = 0.3\nrho = 4400.0\n"
ANALYSIS = '[analysis]\nmaster_modes = {masters}\nmethods = ["dnf", "nf"]\n[output]\ndir = "out"\nname = "run"\nplot = false\n'


def generated(a=0.15, R="1.5", h=0.003, masters='["(2,0)"]'):
    return (f'[model]\nsolver = "fenicsx"\n[model.geometry]\nshape = "spherical_cap"\na = {a}\nR = {R}\nh = {h}\n'
            f"n_core = 6\nn_ring = 2\n" + MATERIAL + ANALYSIS.format(masters=masters))


def from_mesh(mesh: str, masters='["(2,0)"]'):
    return (f'[model]\nsolver = "fenicsx"\nmesh = "{mesh}"\n[model.geometry]\na = 0.15\nR = 1.5\nh = 0.003\n'
            + MATERIAL + ANALYSIS.format(masters=masters))


@pytest.fixture
def workdir(tmp_path):
    """A folder holding the results of a successful run (``out/run.h5``) and a helper to run scenes."""
    good = tmp_path / "good.toml"
    good.write_text(generated())
    assert main(["run", str(good), "-q"]) == 0
    h5 = tmp_path / "out" / "run.h5"
    return tmp_path, h5, h5.read_bytes()


def run_bad(workdir, text: str, capsys, name="bad.toml") -> tuple[int, str]:
    tmp, h5, before = workdir
    p = tmp / name
    p.write_text(text)
    capsys.readouterr()
    rc = main(["run", str(p), "-q"])
    err = capsys.readouterr().err
    assert h5.read_bytes() == before, "the earlier run's results were touched"
    assert not (tmp / "out" / ".run.partial").exists() or rc == 0
    return rc, err


@pytest.mark.parametrize("h, text", [(-0.003, "must lie in [1e-12, 1e+12] (a length"), (0.0, "must lie in [1e-12, 1e+12] (a length")])
def test_non_positive_thickness(workdir, capsys, h, text):
    rc, err = run_bad(workdir, generated(h=h), capsys)
    assert rc == 2
    assert "bad.toml" in err and "model.geometry.h" in err and text in err


def test_radius_smaller_than_a(workdir, capsys):
    rc, err = run_bad(workdir, generated(R="0.1"), capsys)
    assert rc == 2
    assert "model.geometry.R" in err and "must be >= a = 0.15" in err and '"inf"' in err


def test_thickness_on_a_read_mesh_is_checked_too(workdir, capsys):
    tmp = workdir[0]
    cap = spherical_cap(0.15, 1.5, 0.003, n_core=6, n_ring=2)
    meshio.write(tmp / "cap.vtu", meshio.Mesh(cap.points, [("hexahedron27", cap.cells)]))
    rc, err = run_bad(workdir, from_mesh("cap.vtu").replace("h = 0.003", "h = -1.0"), capsys)
    assert rc == 2 and "model.geometry.h" in err


def test_mode_label_that_does_not_exist(workdir, capsys):
    """A label no mode carries: the error names the entry and lists the labels that were found."""
    rc, err = run_bad(workdir, generated(masters='["(2,0)", "(9,9)"]').replace(
        "[output]", "max_modes = 40\n[output]"), capsys)
    assert rc == 2
    assert "analysis.master_modes[1]" in err and "no mode is labelled '(9,9)'" in err
    assert "labels found:" in err and "'(2,0)'" in err


def test_malformed_label(workdir, capsys):
    """'(2,' is no (k, n) label: taken as a free-text label that no mode carries (max_modes keeps it short:
    without it the eigen-solve grows to 400 modes, ~10 s, before giving up)."""
    rc, err = run_bad(workdir, generated(masters='["(2,"]').replace("[output]", "max_modes = 40\n[output]"),
                      capsys)
    assert rc == 2 and "analysis.master_modes[0]" in err and "'(2,'" in err


def test_missing_mesh_file(workdir, capsys):
    rc, err = run_bad(workdir, from_mesh("nowhere.msh"), capsys)
    assert rc == 2 and "model.mesh" in err and "does not exist" in err


def test_unreadable_mesh_file(workdir, capsys):
    """meshio calls sys.exit(1) on a file it cannot identify: the adapter turns that into a SceneError."""
    (workdir[0] / "junk.msh").write_text("this is not a mesh\n")
    rc, err = run_bad(workdir, from_mesh("junk.msh"), capsys)
    assert rc == 2 and "model.mesh" in err and "cannot read" in err


def _cap_mesh():
    return spherical_cap(0.15, 1.5, 0.003, n_core=6, n_ring=2)


def test_duplicate_nodes(workdir, capsys):
    """A cap whose right half uses copies of the shared nodes (a seam split in two, 12 rigid motions).

    Before the mesh check this failed at the eigen-solve with a message about K not being positive
    semi-definite (or, on a dense-sized cap, exited 0 with '(2,0)' as elastic mode 1254).
    """
    tmp = workdir[0]
    cap = _cap_mesh()
    pts = np.vstack([cap.points, cap.points])
    cells = cap.cells.copy()
    right = cap.points[cap.cells].mean(axis=1)[:, 0] > 0
    cells[right] += len(cap.points)
    meshio.write(tmp / "dup.vtu", meshio.Mesh(pts, [("hexahedron27", cells)]))
    rc, err = run_bad(workdir, from_mesh("dup.vtu"), capsys)
    assert rc == 2 and "model.mesh" in err and "duplicate" in err


def test_tangled_element(workdir, capsys):
    """One face-centre node pushed through its hex27 (det J changes sign inside the cell).

    dolfinx integrates |det J|, so without the check this ran to exit 0 with w_bar(2,0) 5.56 instead
    of 5.42 and no flag. Mirrored node order (det J < 0 everywhere) stays valid: see the next test.
    """
    tmp = workdir[0]
    cap = _cap_mesh()
    pts = cap.points.copy()
    pts[cap.cells[0, 24], 2] += 3 * 0.003  # bottom-face centre pushed through the top face
    meshio.write(tmp / "tangled.vtu", meshio.Mesh(pts, [("hexahedron27", cap.cells)]))
    rc, err = run_bad(workdir, from_mesh("tangled.vtu"), capsys)
    assert rc == 2 and "model.mesh" in err and ("inverted" in err or "Jacobian" in err)


def test_mirrored_cells_give_the_same_results(tmp_path, capsys):
    """Cells with mirrored node order (det J < 0 everywhere) are a valid mesh: same w_bar and Gamma."""
    import json

    cap = _cap_mesh()
    # VTK hex27: swap the bottom and top layers (corners, edges, face centres 24 and 25)
    perm = [4, 5, 6, 7, 0, 1, 2, 3, 12, 13, 14, 15, 8, 9, 10, 11, 16, 17, 18, 19, 20, 21, 22, 23, 25, 24, 26]
    cells = cap.cells.copy()
    cells[:10] = cells[:10][:, perm]
    docs = []
    for name, c in (("plain.vtu", cap.cells), ("mirrored.vtu", cells)):
        meshio.write(tmp_path / name, meshio.Mesh(cap.points, [("hexahedron27", c)]))
        (tmp_path / f"{name}.toml").write_text(from_mesh(name))
        assert main(["run", str(tmp_path / f"{name}.toml"), "-q", "--json", "--no-hdf5"]) == 0
        docs.append(json.loads(capsys.readouterr().out))
    a, b = (d["modes"][0] for d in docs)
    # same matrices up to assembly order: measured agreement ~1e-12; 1e-8 is far below any mesh effect
    assert a["omega"] == pytest.approx(b["omega"], rel=1e-8)
    assert a["methods"]["dnf"]["gamma"] == pytest.approx(b["methods"]["dnf"]["gamma"], rel=1e-6)
