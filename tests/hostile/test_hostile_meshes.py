"""Hostile meshes: every malformed mesh ends as a message naming the file and the cell or node, exit 2.

Small valid meshes (linear hexahedra, linear tetrahedra, 20-node bricks) are
generated, broken in one way each, written with meshio (``.vtu``, ``.msh``,
Abaqus ``.inp``) or as a CalculiX ``.inp`` deck, and run through ``stepnf run``
(:mod:`hostile`). The checks live in one place, :func:`stepnf.geometry.checks.check_volume_mesh`,
called by the FEniCSx reader (meshio files) and the CalculiX reader (``.inp``):
the cases below run through both, and also straight through the checker.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from helpers.hostile import assert_reported, run_cli
from helpers.meshes import hex20_block
from stepnf.errors import MeshError, UnitsWarning
from stepnf.geometry.checks import check_volume_mesh, units_warning

meshio = pytest.importorskip("meshio")

MATERIAL = "[model.material]\nE = 2.0e11\nnu = 0.3\nrho = 7800.0\n"
ANALYSIS = '[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\nretained_modes = 4\n[output]\ndir = "out"\nplot = false\n'

# ------------------------------------------------------------------------------------------- generators
HEX_CORNERS = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)])
#: Kuhn split of the unit cube into 6 tetrahedra along the diagonal 0-6 (conforming between cubes)
KUHN = [(0, 1, 2, 6), (0, 2, 3, 6), (0, 3, 7, 6), (0, 7, 4, 6), (0, 4, 5, 6), (0, 5, 1, 6)]


def hex_block(nx=3, ny=3, nz=2, size=(0.3, 0.3, 0.02)):
    """Structured linear hexahedra (VTK order): points (N, 3), cells (E, 8)."""
    idx = np.arange((nx + 1) * (ny + 1) * (nz + 1)).reshape(nx + 1, ny + 1, nz + 1)
    g = np.stack(np.meshgrid(*[np.linspace(0, s, k + 1) for s, k in zip(size, (nx, ny, nz))], indexing="ij"), -1)
    pts = g.reshape(-1, 3)
    cells = [[idx[i + a, j + b, k + c] for a, b, c in HEX_CORNERS]
             for i in range(nx) for j in range(ny) for k in range(nz)]
    return pts, np.array(cells, dtype=np.int64)


def tet_block(**kw):
    pts, hexes = hex_block(**kw)
    tets = hexes[:, np.array(KUHN)].reshape(-1, 4)
    return pts, tets


# --------------------------------------------------------------------------------------------- defects
# each: (points, cells) -> (points, cells, things the message must name)
def nan_node(p, c):
    p = p.copy()
    p[c[1, 2], 1] = np.nan
    return p, c, [f"node {c[1, 2]}", "NaN"]


def inf_node(p, c):
    p = p.copy()
    p[c[0, 0], 2] = np.inf
    return p, c, [f"node {c[0, 0]}", "inf"]


def flat(p, c):
    p = p.copy()
    p[:, 2] = 0.0
    return p, c, ["flat", "plane"]


def nearly_flat(p, c):
    p = p.copy()
    p[:, 2] *= 1e-9
    return p, c, ["flat"]


def tilted_flat(p, c):
    p = p.copy()
    p[:, 2] = 0.3 * p[:, 0] - 0.2 * p[:, 1]  # every node in one tilted plane
    return p, c, ["flat"]


def dangling(p, c):
    c = c.copy()
    c[2, 1] = len(p) + 7
    return p, c, ["cell 2", f"node {len(p) + 7}", "does not exist"]


def node_twice(p, c):
    c = c.copy()
    c[3, 1] = c[3, 0]
    return p, c, ["cell 3", "twice"]


def degenerate_cell(p, c):
    """One more cell whose nodes all lie in the bottom plane: zero volume."""
    bottom = np.nonzero(p[:, 2] == 0)[0]
    extra = bottom[: c.shape[1]]
    return p, np.vstack([c, extra]), [f"cell {len(c)}", "degenerate"]


def duplicate_nodes(p, c):
    """The last cell uses copies of its nodes (a seam not merged)."""
    k = c.shape[1]
    p2 = np.vstack([p, p[c[-1]]])
    c2 = c.copy()
    c2[-1] = np.arange(len(p), len(p) + k)
    return p2, c2, ["coincident", "duplicate"]


def all_one_point(p, c):
    return np.zeros_like(p), c, ["one point"]


def inverted(p, c):
    """A node of cell 4 pushed through the opposite face (mirrored across it, beyond its neighbour)."""
    p = p.copy()
    e = min(4, len(c) - 1)
    v = c[e, 0]
    centre = p[c[e, :8]].mean(axis=0)
    p[v] = p[v] + 2.5 * (centre - p[v])
    return p, c, ["cell", "inverted"]


DEFECTS = [nan_node, inf_node, flat, nearly_flat, tilted_flat, dangling, node_twice, degenerate_cell,
           duplicate_nodes, all_one_point, inverted]
KINDS = {"hexahedron": hex_block, "tetra": tet_block}


# ------------------------------------------------------------------------------ the checker on its own
@pytest.mark.parametrize("kind", list(KINDS))
def test_valid_blocks_pass(kind):
    p, c = KINDS[kind]()
    check_volume_mesh(p, [(kind, c)], source="ok.vtu")
    # mirrored node order in some cells (det J < 0 there) is a valid mesh
    c = c.copy()
    c[::3] = c[::3][:, [1, 0, 2, 3] + list(range(4, c.shape[1]))] if kind == "tetra" else \
        c[::3][:, [4, 5, 6, 7, 0, 1, 2, 3]]
    check_volume_mesh(p, [(kind, c)], source="ok.vtu")


def test_valid_quadratic_cap_passes():
    from stepnf.geometry import spherical_cap
    from stepnf.geometry.tets import hex27_to_tetra

    cap = spherical_cap(0.15, 1.5, 0.003, n_core=4, n_ring=1)
    check_volume_mesh(cap.points, [("hexahedron27", cap.cells)], source="cap")
    tets = hex27_to_tetra(cap)
    check_volume_mesh(tets.points, [("tetra", tets.cells)], source="cap")
    cap20 = spherical_cap(0.15, 1.5, 0.003, n_core=4, n_ring=1, element="hex20")
    check_volume_mesh(cap20.points, [("hexahedron20", cap20.cells)], source="cap")


@pytest.mark.parametrize("defect", DEFECTS, ids=lambda f: f.__name__)
@pytest.mark.parametrize("kind", list(KINDS))
def test_checker_names_the_fault(kind, defect):
    p, c, mentions = defect(*KINDS[kind]())
    with pytest.raises(MeshError) as ei:
        check_volume_mesh(p, [(kind, c)], source="part.vtu")
    msg = str(ei.value)
    assert msg.startswith("part.vtu: ")
    assert any(m in msg for m in mentions), msg


def test_inverted_linear_hexahedron_is_tangled():
    p, c = hex_block()
    p = p.copy()
    top = c[4, 6]
    p[top, 2] = -0.05  # the top corner pushed below the bottom face
    with pytest.raises(MeshError, match=r"tangled|overlap|degenerate"):
        check_volume_mesh(p, [("hexahedron", c)], source="h.vtu")


@pytest.mark.parametrize("points, blocks, text", [
    (np.zeros((0, 3)), [("tetra", np.zeros((0, 4), dtype=int))], "no nodes"),
    (np.eye(3), [], "no volume cells"),
    (np.eye(3), [("tetra", np.zeros((0, 4), dtype=int))], "no volume cells"),
    (np.zeros((4, 2)), [("tetra", np.array([[0, 1, 2, 3]]))], "2D mesh"),
    (np.eye(4, 3), [("pyramid", np.array([[0, 1, 2, 3, 0]]))], "not supported"),
    (np.eye(4, 3), [("tetra", np.array([[0, 1, 2]]))], "has 4 nodes"),
    (np.eye(4, 3), [("tetra", np.array([[0.0, 1.0, 2.0, 3.0]]))], "non-integer"),
    (np.eye(4, 3), [("tetra", np.array([[0, 1, 2, -1]]))], "does not exist"),
])
def test_checker_structural_defects(points, blocks, text):
    with pytest.raises(MeshError, match=text):
        check_volume_mesh(points, blocks, source="m.msh")


# --------------------------------------------------------------------------- units (mm mesh, SI material)
def test_mm_mesh_with_si_material_warns():
    p, _ = hex_block(size=(300.0, 300.0, 2.0))  # drawn in mm
    with pytest.warns(UnitsWarning, match="1000x"):
        units_warning(p, {"E": 2e11, "nu": 0.3, "rho": 7800.0}, source="part.msh")


@pytest.mark.parametrize("size, material", [
    ((0.3, 0.3, 0.002), {"E": 2e11, "rho": 7800.0}),     # SI mesh, SI material
    ((300.0, 300.0, 2.0), {"E": 2e5, "rho": 7.8e-9}),    # mm mesh, mm-t-s material
    ((6.0, 0.5, 0.02), {"E": 2e11, "rho": 7800.0}),      # a 6 m blade 2 cm thick: SI, plausible
])
def test_consistent_units_do_not_warn(size, material):
    p, _ = hex_block(size=size)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitsWarning)
        assert units_warning(p, material) == ""


# ------------------------------------------------------------------------- through `stepnf run`: FEniCSx
def _fenicsx_scene(tmp_path, mesh_name):
    s = tmp_path / "scene.toml"
    s.write_text(f'[model]\nsolver = "fenicsx"\nmesh = "{mesh_name}"\n' + MATERIAL + ANALYSIS)
    return s


FORMATS = {"vtu": "vtu", "msh": "gmsh22", "inp": "abaqus"}


@pytest.mark.fenicsx
@pytest.mark.parametrize("fmt", list(FORMATS))
@pytest.mark.parametrize("defect", DEFECTS, ids=lambda f: f.__name__)
@pytest.mark.parametrize("kind", list(KINDS))
def test_fenicsx_reports_bad_meshes(tmp_path, capsys, kind, defect, fmt):
    pytest.importorskip("dolfinx")
    p, c, mentions = defect(*KINDS[kind]())
    name = f"part.{fmt}"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            meshio.write(tmp_path / name, meshio.Mesh(p, [(kind, c)]), file_format=FORMATS[fmt])
    except Exception as exc:  # noqa: BLE001 - meshio cannot even write some defects in some formats
        pytest.skip(f"meshio cannot write this defect as {fmt}: {exc}")
    o = run_cli(["run", _fenicsx_scene(tmp_path, name), "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=[name, "model.mesh"])
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").glob("*.h5"))


@pytest.mark.fenicsx
@pytest.mark.parametrize("case", ["no_cells", "surface_only", "mixed", "garbage", "truncated", "empty_file",
                                  "wedges"])
def test_fenicsx_unusable_files(tmp_path, capsys, case):
    pytest.importorskip("dolfinx")
    p, c = hex_block()
    name = "part.vtu"
    path = tmp_path / name
    if case == "no_cells":
        meshio.write(path, meshio.Mesh(p, []))
    elif case == "surface_only":
        meshio.write(path, meshio.Mesh(p, [("triangle", np.array([[0, 1, 2], [1, 2, 3]]))]))
    elif case == "mixed":
        pt, ct = tet_block()
        meshio.write(path, meshio.Mesh(pt, [("hexahedron", c), ("tetra", ct)]))
    elif case == "wedges":
        meshio.write(path, meshio.Mesh(p, [("wedge", c[:, :6])]))
    elif case in ("garbage", "truncated"):
        name = "part.msh"
        path = tmp_path / name
        meshio.write(path, meshio.Mesh(p, [("hexahedron", c)]), file_format="gmsh22", binary=False)
        text = path.read_text()
        path.write_text("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n12\n1 0 0 x y\n" if case == "garbage"
                        else text[: len(text) // 2])
    else:
        path.write_text("")
    o = run_cli(["run", _fenicsx_scene(tmp_path, name), "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=[name, "model.mesh"])


# ------------------------------------------------------------------------ through `stepnf run`: CalculiX
def _inp(tmp_path, p, c, name="part.inp"):
    """A CalculiX deck with the file's own (non-consecutive) node and element ids."""
    from stepnf_calculix.deck import mesh_text

    ids = np.arange(1, len(p) + 1) * 10
    conn = np.where((c >= 0) & (c < len(p)), ids[np.clip(c, 0, len(p) - 1)], c * 10 + 10)
    text = mesh_text(ids, p, [("C3D20", np.arange(1, len(c) + 1), conn)])
    (tmp_path / name).write_text(text.replace("nan", "NaN"))
    return ids


def _ccx_scene(tmp_path, mesh="part.inp"):
    s = tmp_path / "scene.toml"
    s.write_text(f'[model]\nsolver = "calculix"\nmesh = "{mesh}"\n' + MATERIAL + ANALYSIS)
    return s


@pytest.mark.calculix
@pytest.mark.parametrize("defect", DEFECTS, ids=lambda f: f.__name__)
def test_calculix_reports_bad_inp_meshes(tmp_path, capsys, defect):
    pytest.importorskip("stepnf_calculix")
    p, c, _ = defect(*hex20_block())
    _inp(tmp_path, p, c)
    o = run_cli(["run", _ccx_scene(tmp_path), "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["part.inp"])
    assert any(w in o.err for w in ("node", "cell", "element", "flat", "point")), o.err


@pytest.mark.calculix
@pytest.mark.parametrize("text, mentions", [
    ("*NODE\n1, 0, 0, 0\n", ["no elements"]),
    ("*ELEMENT, TYPE=C3D4\n1, 1, 2, 3, 4\n", ["no nodes"]),
    ("*NODE\n1, 0, 0, 0\n2, 1, 0, 0\n3, 0, 1, 0\n4, 0, 0, 1\n*ELEMENT, TYPE=C3D4\n1, 1, 2, 3, 9\n",
     ["element 1", "node 9"]),
    ("*NODE\n1, 0, 0, zero\n*ELEMENT, TYPE=C3D4\n1, 1, 2, 3, 4\n", ["line 2"]),
    ("*NODE\n1, 0, 0, 0\n*ELEMENT, TYPE=C3D4\n1, 1, 2, x, 4\n", ["line 4"]),
    ("*NODE\n1, 0, 0, 0\n*ELEMENT, TYPE=C3D20\n1, 1, 2, 3,\n", ["line 4", "truncated"]),
    ("*NODE\n1, 0, 0, 0\n*ELEMENT, TYPE=S8R\n1, 1, 2, 3, 4, 5, 6, 7, 8\n", ["line 3", "S8R", "not supported"]),
    ("*NODE\n1, 0, 0, 0\n*ELEMENT, TYPE=C3D4\n1, 1, 2\n", ["needs 4 nodes"]),
    ("*NODE\n1,\n", ["line 2"]),
    ("\x00\x01garbage\xff" * 10, ["no elements"]),
    ("*NODE\n1, 0, 0, 0\n2, 1, 0, 0\n3, 0, 1, 0\n4, 1, 1, 0\n*ELEMENT, TYPE=C3D4\n1, 1, 2, 3, 4\n", ["flat"]),
    ("*NODE\n1, 0, 0, 0\n2, 1, 0, 0\n3, 0, 1, 0\n4, 0, 0, 1\n5, 0.2, 0.2, 0.2\n*ELEMENT, TYPE=C3D4\n"
     "1, 1, 2, 3, 4\n2, 1, 2, 3, 5\n", ["element 1", "element 2", "overlap"]),
])
def test_calculix_malformed_inp_text(tmp_path, capsys, text, mentions):
    pytest.importorskip("stepnf_calculix")
    (tmp_path / "part.inp").write_text(text)
    o = run_cli(["run", _ccx_scene(tmp_path), "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["part.inp", *mentions])


@pytest.mark.calculix
def test_calculix_mm_mesh_with_si_material_warns(tmp_path):
    ccx = pytest.importorskip("stepnf_calculix")
    p, c = hex20_block(size=(300.0, 300.0, 2.0))
    _inp(tmp_path, p, c)
    with pytest.warns(UnitsWarning, match="millimetres"):
        ccx.CalculixAdapter.from_config({"mesh": "part.inp", "material": {"E": 2e11, "nu": 0.3, "rho": 7800.0}},
                                        base_dir=tmp_path, scene_file=tmp_path / "s.toml")
