"""Issue 31, item 8: the fenicsx route reads ``.inp`` meshes with stepnf's own reader (the calculix adapter's),
takes facet elements beside the solids as sets (and says so), and says the element order and dof count.

Before: meshio read them and failed on valid decks (``*ELSET ... GENERATE``: "[ 1 32]"-like messages; a
deck with shell elements: "could not convert string to float"), and a linear mesh ran as quadratic
elements without a word.
"""
from __future__ import annotations

import io
import warnings

import numpy as np
import pytest

pytest.importorskip("dolfinx")  # a required tool on Debian 12 and 13: conftest fails the test when it is missing

from stepnf.errors import ModelWarning  # noqa: E402
from stepnf.pipeline.model import open_model  # noqa: E402
from stepnf.runtime.progress import Progress  # noqa: E402
from stepnf.scene.parse import load_scene  # noqa: E402
from stepnf_fenicsx import FenicsxAdapter, Material, read_mesh  # noqa: E402
from helpers.meshes import block_mesh  # noqa: E402

STEEL = {"E": 2.1e11, "nu": 0.3, "rho": 7800.0}
NX = 4  # four C3D20 bricks along x: [0, 0.2] x [0, 0.02] x [0, 0.01]
SIZE = (0.2, 0.02, 0.01)


def deck(elset_lines: list[str], shells: bool = False, linear: bool = False) -> str:
    """A C3D20 (or, ``linear``, C3D8) strip with *NSET LEFT (x = 0) and an element set given by
    ``elset_lines``; ``shells``: S8 elements on the bottom face z = 0 (*ELSET SKIN) with a *SHELL SECTION, as
    a deck mixing shells and solids writes them."""
    pts, cells = block_mesh(NX, 1, 1, size=SIZE)
    if linear:
        cells = cells[:, :8]
        pts_used = np.unique(cells)
        renum = np.full(len(pts), -1)
        renum[pts_used] = np.arange(len(pts_used))
        pts, cells = pts[pts_used], renum[cells]
    lines = ["*HEADING", "a strip", "*NODE, NSET=NALL"]
    lines += [f"{i + 1}, {x!r}, {y!r}, {z!r}" for i, (x, y, z) in enumerate(pts)]
    lines.append(f"*ELEMENT, TYPE={'C3D8' if linear else 'C3D20'}, ELSET=EALL")
    for e, c in enumerate(cells, 1):  # 16 ids a line, the rest continued on the next (ccx's layout)
        ids = [e, *(c + 1)]
        lines += [", ".join(map(str, ids[:16])) + ("," if len(ids) > 16 else ""), *(
            [", ".join(map(str, ids[16:]))] if len(ids) > 16 else [])]
    if shells:
        bottom = [0, 1, 2, 3, 8, 9, 10, 11]  # the z = 0 face of a VTK/ccx hexahedron20: corners, mid-edges
        lines.append("*ELEMENT, TYPE=S8, ELSET=SKIN")
        lines += [", ".join(map(str, [100 + e, *(c[bottom] + 1)])) for e, c in enumerate(cells)]
        lines += ["*MATERIAL, NAME=STEEL", "*ELASTIC", "2.1e11, 0.3", "*DENSITY", "7800.",
                  "*SHELL SECTION, ELSET=SKIN, MATERIAL=STEEL", "0.001"]
    lines.append("*NSET, NSET=LEFT")
    lines.append(", ".join(str(i + 1) for i in np.flatnonzero(np.isclose(pts[:, 0], 0.0))))
    return "\n".join(lines + elset_lines) + "\n"


def test_elset_generate_reads_like_the_explicit_list(tmp_path):
    """``*ELSET, GENERATE`` (bricks 3 and 4) names the same cells as the explicit list; the adapter built on either
    file has the same K and M to the bit (one reader, one node and dof order)."""
    generated, listed = tmp_path / "generate.inp", tmp_path / "listed.inp"
    generated.write_text(deck(["*ELSET, ELSET=TIP, GENERATE", "3, 4"]))
    listed.write_text(deck(["*ELSET, ELSET=TIP", "3, 4"]))
    a, b = read_mesh(generated), read_mesh(listed)
    assert a.cell_type == "hexahedron27" and np.array_equal(a.cell_sets["TIP"], [2, 3])
    assert np.array_equal(a.points, b.points) and np.array_equal(a.cells, b.cells)
    assert np.array_equal(a.node_sets["LEFT"], b.node_sets["LEFT"])
    def model(name: str, **materials):
        return FenicsxAdapter.from_config({"mesh": name, "material": STEEL, "materials": materials,
                                           "boundary": [{"set": "left"}]}, base_dir=tmp_path)

    aluminium = {"E": 7.0e10, "nu": 0.33, "rho": 2700.0}
    ads = [model(f.name, tip=aluminium) for f in (generated, listed)]
    for get in ("stiffness_matrix", "mass_matrix"):
        A, B = (getattr(ad, get)() for ad in ads)
        assert A.shape == B.shape and (A != B).nnz == 0
    # the set's material is there: with no dof removed, sum(M) = 3 x the mass (a consistent mass matrix), and
    # half the strip in aluminium weighs (1 + 2700/7800)/2 of the steel strip (to round-off)
    steel, mixed = (FenicsxAdapter.from_config({"mesh": generated.name, "material": STEEL, "materials": m},
                                               base_dir=tmp_path) for m in ({}, {"TIP": aluminium}))
    ratio = mixed.mass_matrix().sum() / steel.mass_matrix().sum()
    assert ratio == pytest.approx((1 + 2700 / 7800) / 2, rel=1e-12)


def test_shell_elements_beside_solids_are_sets_and_said(tmp_path):
    """S8 shells on a face of the solid (and their *SHELL SECTION) are no part of the model: the cells are the
    bricks alone, SKIN names the nodes of the face (completed hex27 face centres included), and a warning says
    so."""
    mixed, plain = tmp_path / "mixed.inp", tmp_path / "plain.inp"
    mixed.write_text(deck([], shells=True))
    plain.write_text(deck([]))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = read_mesh(mixed)
    said = [str(w.message) for w in caught if issubclass(w.category, ModelWarning)]
    assert len(said) == 1 and "4 S8" in said[0] and "[[model.boundary]]" in said[0], said
    ref = read_mesh(plain)
    assert np.array_equal(m.points, ref.points) and np.array_equal(m.cells, ref.cells)
    skin = m.node_sets["SKIN"]
    assert np.allclose(m.points[skin, 2], 0.0)
    assert skin.size == np.count_nonzero(np.isclose(m.points[:, 2], 0.0))  # every node of z = 0: 9 x 3 of hex27
    assert m.info["facets_ignored"] == {"S8": 4}
    ad = FenicsxAdapter(m, Material(**STEEL), boundary=[{"set": "SKIN", "dofs": ["uz"]}])
    assert ad.n_dofs == 3 * len(m.points) - skin.size


def test_first_line_says_element_order_and_dofs(tmp_path):
    """A linear (C3D8) mesh runs with quadratic elements: the line printed once the model is built says so, with
    the dof count the model has."""
    (tmp_path / "hex8.inp").write_text(deck([], linear=True))
    scene = tmp_path / "s.toml"
    scene.write_text('[model]\nsolver = "fenicsx"\nmesh = "hex8.inp"\n[model.material]\nE = 2.1e11\nnu = 0.3\n'
                     'rho = 7800.0\n[[model.boundary]]\nset = "LEFT"\n[analysis]\nmaster_modes = [0]\n'
                     'methods = ["dnf"]\n')
    out = io.StringIO()
    with open_model(load_scene(scene), Progress(stream=out)) as ad:
        n = ad.n_dofs
    line = next(t for t in out.getvalue().splitlines() if "mesh:" in t)
    # 4 x 1 x 1 bricks promoted to Q2: 9 x 3 x 3 nodes, the 9 of x = 0 clamped
    assert n == 3 * (9 * 3 * 3 - 9) == 216
    assert line == ("[stepnf] mesh: 4 hex8 cells, order 2 elements (Q2, the hex8 mesh promoted to order 2), "
                    "216 free dofs"), line
