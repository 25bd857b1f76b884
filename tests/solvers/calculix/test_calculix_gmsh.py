"""Issue 31, item 8: Gmsh meshes as users bring them to the calculix mesh route.

Gmsh's ``.inp`` export writes its physical surfaces as CPS6/CPS8 elements beside the C3D10/C3D20 volumes:
they are taken as node sets (usable in ``[[model.boundary]]``) and said, not refused ("element type 'CPS6'
is not supported" before); a Gmsh ``.msh`` is read too (refused by the ``mesh`` key's suffix before),
into the same model. The meshes are written here by Gmsh's own API.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.linalg as sla

from helpers.required import requires
from stepnf.errors import ModelWarning
from stepnf_calculix import CalculixAdapter

gmsh = pytest.importorskip("gmsh")  # a required tool (tests/required_tools.txt): conftest fails a missing one

pytestmark = requires("ccx")

E, NU, RHO = 2.1e11, 0.3, 7800.0
L, B, H = 0.2, 0.02, 0.01  # a cantilever strip, L/h = 20


def write_strip(folder, hexa: bool) -> None:
    """``strip.inp`` and ``strip.msh`` of the box [0, L] x [0, B] x [0, H] meshed by Gmsh: quadratic tetrahedra
    (``hexa`` False) or 20-node bricks (transfinite, recombined, incomplete second order), the physical volume
    SOLID and the physical surface CLAMP (the face x = 0)."""
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    try:
        gmsh.model.add("strip")
        v = gmsh.model.occ.addBox(0, 0, 0, L, B, H)
        gmsh.model.occ.synchronize()
        faces = [t for _, t in gmsh.model.getBoundary([(3, v)], oriented=False)]
        clamp = [t for t in faces if abs(gmsh.model.occ.getCenterOfMass(2, t)[0]) < 1e-12]
        gmsh.model.setPhysicalName(3, gmsh.model.addPhysicalGroup(3, [v]), "SOLID")
        gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, clamp), "CLAMP")
        if hexa:  # bricks of size H: 20 x 2 x 1
            for _, tag in gmsh.model.getEntities(1):
                box = gmsh.model.getBoundingBox(1, tag)
                gmsh.model.mesh.setTransfiniteCurve(tag, 1 + round(max(np.subtract(box[3:], box[:3])) / H))
            for t in faces:
                gmsh.model.mesh.setTransfiniteSurface(t)
                gmsh.model.mesh.setRecombine(2, t)
            gmsh.model.mesh.setTransfiniteVolume(v)
            gmsh.option.setNumber("Mesh.SecondOrderIncomplete", 1)
        else:
            gmsh.option.setNumber("Mesh.MeshSizeMax", H)
        gmsh.model.mesh.generate(3)
        gmsh.model.mesh.setOrder(2)
        gmsh.write(str(folder / "strip.inp"))
        gmsh.write(str(folder / "strip.msh"))
    finally:
        gmsh.finalize()


@pytest.fixture(scope="module", params=[False, True], ids=["tet10", "hex20"])
def strip(request, tmp_path_factory):
    folder = tmp_path_factory.mktemp("hex" if request.param else "tet")
    write_strip(folder, request.param)
    return folder, request.param


def build(folder, name: str) -> tuple[CalculixAdapter, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ad = CalculixAdapter.from_config({"mesh": name, "material": {"E": E, "nu": NU, "rho": RHO},
                                          "boundary": [{"set": "clamp"}]}, base_dir=folder)
    return ad, [str(w.message) for w in caught if issubclass(w.category, ModelWarning)]


def test_gmsh_inp_and_msh_give_the_same_clamped_model(strip):
    folder, hexa = strip
    solid, facet = ("C3D20", "CPS8") if hexa else ("C3D10", "CPS6")
    with build(folder, "strip.inp")[0] as inp, build(folder, "strip.msh")[0] as msh:
        _, said = build(folder, "strip.inp")
        assert len(said) == 1 and facet in said[0] and "[[model.boundary]]" in said[0], said
        assert [t for t, _, _ in inp.blocks] == [solid] and inp.facets_ignored and msh.facets_ignored
        assert f"{facet} facets" in inp.summary() and inp.describe()["facets_ignored"] == inp.facets_ignored
        # CLAMP, the facets of x = 0, holds every node there: the clamp removes 3 dofs of each
        at_root = np.count_nonzero(np.isclose(inp.points[:, 0], 0.0))
        assert inp.n_dofs == 3 * (len(inp.node_ids) - at_root) == msh.n_dofs
        # the same nodes, elements and node order: Gmsh writes coordinates to ~1e-16 in both files
        assert np.array_equal(inp.node_ids, msh.node_ids) and np.allclose(inp.points, msh.points, atol=1e-14)
        assert all(np.array_equal(a[2], b[2]) for a, b in zip(inp.blocks, msh.blocks))
        K, M = inp.stiffness_matrix().toarray(), inp.mass_matrix().toarray()
        K2, M2 = msh.stiffness_matrix().toarray(), msh.mass_matrix().toarray()
    # ccx prints K and M with 14 digits: the two routes' matrices agree to that
    assert np.abs(K - K2).max() <= 1e-12 * np.abs(K).max() and np.abs(M - M2).max() <= 1e-12 * np.abs(M).max()
    w2 = sla.eigh(K, M, eigvals_only=True, subset_by_index=[0, 0])[0]
    # first bending mode in z (the thin direction) of a cantilever: Euler-Bernoulli 1.8751^2 sqrt(EI / (rho A L^4));
    # at L/h = 20 shear and the clamp's Poisson constraint move it by < 1%, a coarse mesh by a few 0.1%: 3%
    eb = 1.87510407 ** 2 * np.sqrt(E * B * H ** 3 / 12 / (RHO * B * H * L ** 4))
    assert np.sqrt(w2) == pytest.approx(eb, rel=0.03)


def test_msh_without_volumes_is_refused(tmp_path):
    """A surface mesh is no solid: the one-line MeshError names the file and what it found."""
    import meshio

    from stepnf.errors import MeshError

    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    meshio.write_points_cells(tmp_path / "flat.msh", pts, [("triangle", np.array([[0, 1, 2]]))],
                              file_format="gmsh22", binary=False)
    with pytest.raises(MeshError, match=r"flat\.msh.*no volume cells CalculiX can use; found \['triangle'\]"):
        CalculixAdapter.from_config({"mesh": "flat.msh", "material": {"E": E, "nu": NU, "rho": RHO}},
                                    base_dir=tmp_path)
