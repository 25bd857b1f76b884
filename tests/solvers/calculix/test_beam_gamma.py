"""A slender clamped-clamped beam brought three ways (issue 11): a user's mesh with node sets to fenicsx,
the same to calculix, and a complete CalculiX deck with its own *MATERIAL, *BOUNDARY and a static *STEP.

Reference (derived here, independent of every FE model): the von Karman beam with immovable ends,
``EI w'''' + rho A w_tt - N w'' = 0``, ``N = EA/(2L) int_0^L w'^2 dx`` (the axial inertia neglected:
the axial modes are ~L/h times faster than bending). One clamped-clamped mode ``w = a phi(x)``,
``phi = cosh bx - cos bx - s (sinh bx - sin bx)``, ``b L = 4.7300...``, gives the Duffing oscillator
``a'' + w^2 a + beta a^3 = 0`` with ``beta = EA/(2L) (int phi'^2)^2 / (rho A int phi^2)``, whose
backbone is ``w_NL = w (1 + 3 beta/(8 w^2) a^2)``. With ``w^2 = EI int phi''^2 / (rho A int phi^2)``,
``EA/EI = 12/h^2`` and ``W_max = a max|phi|``:

    Gamma = (9/4) I1^2 / (I2 max|phi|^2),  I1 = int_0^1 phi_xi^2, I2 = int_0^1 phi_xixi^2  (xi = x/L)

= 0.269735, free of E, rho, L, h and the width. No other mode changes it at this order: the beam
has no quadratic term once the axial field is condensed (its effect is the N above), and cubic
couplings to other modes do not enter T (docs/design.md). The 3D solid differs by transverse shear and
the restrained Poisson contraction at the clamps, O(h/L) and O((h/L)^2): within 1% at L/h = 100.
"""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import load_scene
from helpers.required import need
from helpers.paths import REPO

BEAM = REPO / "examples" / "beam_ccx"
L, B, H = 1.0, 0.02, 0.01  # the beam of examples/beam_ccx: length, width, thickness (m)
E, NU, RHO = 2.1e11, 0.3, 7800.0


def clamped_clamped_gamma() -> tuple[float, float]:
    """(Gamma, beta L) of the first mode of the clamped-clamped von Karman beam with immovable ends."""
    bl = brentq(lambda b: math.cos(b) * math.cosh(b) - 1.0, 4.5, 5.0)
    s = (math.cosh(bl) - math.cos(bl)) / (math.sinh(bl) - math.sin(bl))

    def d(x, k):  # k-th derivative of phi / bl^k
        c, ch, sn, sh = math.cos(bl * x), math.cosh(bl * x), math.sin(bl * x), math.sinh(bl * x)
        return [ch - c - s * (sh - sn), sh + sn - s * (ch - c), ch + c - s * (sh + sn)][k] * bl**k

    i1 = quad(lambda x: d(x, 1) ** 2, 0.0, 1.0, epsabs=0, epsrel=1e-13, limit=200)[0]
    i2 = quad(lambda x: d(x, 2) ** 2, 0.0, 1.0, epsabs=0, epsrel=1e-13, limit=200)[0]
    return 2.25 * i1**2 / (i2 * d(0.5, 0) ** 2), bl


def test_closed_form():
    gamma, bl = clamped_clamped_gamma()
    assert bl == pytest.approx(4.730040744862704, rel=1e-14)
    # the one-mode Galerkin of the classical literature: w_NL/w = 1 + 0.0225 (W/r)^2 with r^2 = h^2/12
    assert gamma == pytest.approx(0.2697, abs=5e-5)


def euler_bernoulli_omega() -> float:
    _, bl = clamped_clamped_gamma()
    return bl**2 * math.sqrt(E * B * H**3 / 12.0 / (RHO * B * H * L**4))


# ------------------------------------------------------------------ the fenicsx route: a Gmsh mesh
def write_hex27_beam(path: Path, nx: int = 40) -> None:
    """The beam as hexahedron27 cells (1 x 1 across) with the end faces as Gmsh physical groups
    LEFT (x = 0) and RIGHT (x = L) of quad9 facets, written in Gmsh 2.2 format."""
    import meshio

    from stepnf.geometry.cap import extruded_hex27

    gx, gy = np.linspace(0.0, L, 2 * nx + 1), np.linspace(0.0, B, 3)
    plan = np.array([(x, y) for x in gx for y in gy])
    node = lambda i, j: i * 3 + j  # noqa: E731
    quads = np.array([[node(2 * e, 0), node(2 * e + 2, 0), node(2 * e + 2, 2), node(2 * e, 2), node(2 * e + 1, 0),
                       node(2 * e + 2, 1), node(2 * e + 1, 2), node(2 * e, 1), node(2 * e + 1, 1)] for e in range(nx)])
    cells = extruded_hex27(quads, 1)
    points = np.array([(x, y, z) for x, y in plan for z in np.linspace(0.0, H, 3)])

    def end_face(i: int) -> np.ndarray:  # the quad9 facet x = gx[i]: 3 x 3 nodes (y, z)
        ids = np.array([[node(i, j) * 3 + k for k in range(3)] for j in range(3)])  # [j (y), k (z)]
        return ids[[0, 2, 2, 0, 1, 2, 1, 0, 1], [0, 0, 2, 2, 0, 1, 2, 1, 1]][None, :]

    blocks = [("hexahedron27", cells), ("quad9", end_face(0)), ("quad9", end_face(2 * nx))]
    tags = [np.full(len(cells), 3), np.array([1]), np.array([2])]
    meshio.write(path, meshio.Mesh(points, blocks, cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
                                   field_data={"LEFT": np.array([1, 2]), "RIGHT": np.array([2, 2]),
                                               "BEAM": np.array([3, 3])}),
                 file_format="gmsh22", binary=False)


def fenicsx_scene(folder: Path) -> Path:
    write_hex27_beam(folder / "beam.msh")
    text = (BEAM / "beam_mesh.toml").read_text()
    text = text.replace('solver = "calculix"', 'solver = "fenicsx"\nelement = "hex27"').replace(
        'mesh = "beam_mesh.inp"', 'mesh = "beam.msh"')
    (folder / "beam_fx.toml").write_text(text)
    return folder / "beam_fx.toml"


def dnf(result):
    (mode,) = result.modes
    return mode.omega, mode.methods["dnf"]


@pytest.fixture(scope="module")
def routes(tmp_path_factory):
    """DNF of the first bending mode by the three routes: {route: (omega, MethodResult)}."""
    pytest.importorskip("stepnf_fenicsx")
    need("ccx")
    folder = tmp_path_factory.mktemp("beam")
    for f in BEAM.iterdir():
        shutil.copy(f, folder / f.name)
    out = {}
    for route, scene in (("calculix mesh", folder / "beam_mesh.toml"), ("calculix deck", folder / "beam_deck.toml"),
                         ("fenicsx mesh", fenicsx_scene(folder))):
        sc = load_scene(scene)
        sc.write_hdf5 = False
        out[route] = dnf(run_scene(sc))
    return out


@pytest.mark.slow
@pytest.mark.fenicsx
def test_three_routes_against_the_closed_form(routes):
    gamma, _ = clamped_clamped_gamma()
    w_eb = euler_bernoulli_omega()
    for route, (omega, r) in routes.items():
        # frequency: 40 quadratic elements along, measured +0.68% (C3D20) against Euler-Bernoulli
        assert omega == pytest.approx(w_eb, rel=0.01), route
        assert r.gamma == pytest.approx(gamma, rel=0.01), (route, r.gamma)
    values = [r.gamma for _, r in routes.values()]
    assert max(values) / min(values) - 1 < 5e-3, values
    # the two CalculiX routes are the same ccx model: the same numbers (7 printed digits of the forces)
    (w1, r1), (w2, r2) = routes["calculix mesh"], routes["calculix deck"]
    assert w1 == pytest.approx(w2, rel=1e-10) and r1.T == pytest.approx(r2.T, rel=1e-8)


@pytest.mark.fenicsx
def test_a_beam_has_no_nk_labels(tmp_path):
    """A straight beam from a user's mesh (no axis, no a, R, h) gets no (k, n) labels; a label asked for
    is refused saying so, after the one eigen-solve and before any STEP."""
    pytest.importorskip("stepnf_fenicsx")
    from stepnf.errors import SceneError

    text = (REPO / "examples" / "beam" / "beam_fenicsx.toml").read_text().replace("master_modes = [0]",
                                                                                 'master_modes = ["(0,2)"]')
    text = text.replace('"../beam_ccx/beam_mesh.inp"', f'"{BEAM / "beam_mesh.inp"}"')
    (tmp_path / "beam.toml").write_text(text)
    sc = load_scene(tmp_path / "beam.toml")
    sc.write_hdf5 = False
    with pytest.raises(SceneError, match=r"gives no labels .*0-based mode index") as info:
        run_scene(sc)
    assert info.value.key == "analysis.master_modes[0]"
