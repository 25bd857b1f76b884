"""Regions and materials of the fenicsx solid (issue 11, item 3): ``[model.material]`` isotropic or
orthotropic (``axes``), ``[model.materials.<set>]`` per named cell set, ``S = C : E`` (Green-Lagrange E).

References independent of the FE model:

* the Euler-Bernoulli clamped-clamped beam of two materials (one per half), its frequency equation
  solved here (transfer of w, w', EI w'', EI w''' across the joint);
* the clamped rectangular plate of a specially orthotropic material, solved here by Ritz with Legendre
  polynomials: Kirchhoff (``D11 = E1 h^3 / (12 (1 - nu12 nu21))``, ``D22``, ``D12 = nu12 D22``,
  ``D66 = G12 h^3 / 12``) and the first-order shear (Mindlin) plate with the transverse shear moduli
  G13, G23. One quadratic brick through the thickness has a constant transverse shear strain, i.e. the
  Mindlin plate *without* a shear correction (kappa = 1): that is the plate model the 3D mesh can
  converge to, and the reference of the 3D frequencies.
"""
from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from numpy.polynomial import legendre
from scipy.linalg import eigh
from scipy.optimize import brentq

pytest.importorskip("dolfinx")
meshio = pytest.importorskip("meshio")

from stepnf.cli.main import main as cli_main  # noqa: E402
from stepnf.plugin.materials import material  # noqa: E402
from stepnf.linalg.modal_analysis import modal_analysis  # noqa: E402
from stepnf.pipeline.run import run_scene  # noqa: E402
from stepnf.scene.parse import load_scene  # noqa: E402
from stepnf.testing.harness import Tolerances, parametrize_with_checks  # noqa: E402
from stepnf_fenicsx import FenicsxAdapter, read_mesh  # noqa: E402
from stepnf_fenicsx.model import Material  # noqa: E402
from helpers.beam import B, HB, beam_mesh, boundary_toml  # noqa: E402
from helpers.paths import EXAMPLES  # noqa: E402

pytestmark = pytest.mark.fenicsx

EXAMPLE = EXAMPLES / "orthotropic_plate"
STEEL = {"E": 2.1e11, "nu": 0.3, "rho": 7800.0}
ALUMINIUM = {"E": 7.0e10, "nu": 0.3, "rho": 2700.0}
#: a unidirectional fibre ply, fibres along axis 1, nine distinct constants (that of the example)
PLY = {"E1": 1.3e11, "E2": 1.0e10, "E3": 8.0e9, "nu12": 0.28, "nu13": 0.32, "nu23": 0.45,
       "G12": 5.5e9, "G13": 4.5e9, "G23": 3.2e9, "rho": 1600.0}
#: material axis 1 along global y, axis 2 along -x: the ply turned by 90 degrees about z
TURNED = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
CLAMPED_ENDS = [{"set": "LEFT"}, {"set": "RIGHT"}]
HAVE_H5PY = importlib.util.find_spec("h5py") is not None  # meshio writes MED files with it
SHORT = 0.2  # the stubby beam: L / h = 20 (10 quadratic bricks), the long one L / h = 100 (40)


def as_orthotropic(E: float, nu: float, rho: float) -> dict[str, float]:
    """Isotropic constants written as engineering constants."""
    G = E / (2 * (1 + nu))
    return {"E1": E, "E2": E, "E3": E, "nu12": nu, "nu13": nu, "nu23": nu, "G12": G, "G13": G, "G23": G, "rho": rho}


def swap_axes_12(c: dict[str, float]) -> dict[str, float]:
    """The constants of the same material with its axes 1 and 2 exchanged (nu21 = nu12 E2 / E1)."""
    return {**c, "E1": c["E2"], "E2": c["E1"], "nu12": c["nu12"] * c["E2"] / c["E1"], "nu13": c["nu23"],
            "nu23": c["nu13"], "G13": c["G23"], "G23": c["G13"]}


def ortho(constants: dict) -> object:
    return material(constants, None, "model.material")


# ------------------------------------------------------------------ meshes with cell sets
def beam_files(folder: Path, length: float, nx: int) -> Path:
    """The beam [0, length] x [-B/2, B/2] x [-HB/2, HB/2], nx x 1 x 1 bricks, halves named A (x < L/2) and B:
    beam.msh (hexahedron27; Gmsh physical groups: A, B of volume cells, LEFT, RIGHT of end vertices),
    beam20.inp (C3D20; *ELSET A, B and EALL (every cell), *NSET LEFT, RIGHT), beam.inp (linear hexahedra,
    the same sets), beam.med (linear hexahedra; MED groups A, B of cells, LEFT, RIGHT of nodes)."""
    folder.mkdir(parents=True, exist_ok=True)
    pts, cells = beam_mesh((nx, 1, 1))
    pts *= [length, 1.0, 1.0]
    in_a = pts[cells[:, 26], 0] < length / 2  # the body centre tells the half
    sets = {"A": [np.flatnonzero(in_a)], "B": [np.flatnonzero(~in_a)], "EALL": [np.arange(nx)]}
    left, right = (np.flatnonzero(pts[:, 0] == x) for x in (0.0, length))
    tags = [np.where(in_a, 3, 4), np.full(len(left), 1), np.full(len(right), 2)]
    meshio.Mesh(pts, [("hexahedron27", cells), ("vertex", left[:, None]), ("vertex", right[:, None])],
                cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
                field_data={"LEFT": np.array([1, 0]), "RIGHT": np.array([2, 0]), "A": np.array([3, 3]),
                            "B": np.array([4, 3])}).write(folder / "beam.msh", file_format="gmsh22", binary=False)
    used = np.unique(cells[:, :20])  # the hexahedron20 file leaves out the face and body centres
    ends = {"LEFT": np.flatnonzero(np.isin(used, left)), "RIGHT": np.flatnonzero(np.isin(used, right))}
    meshio.Mesh(pts[used], [("hexahedron20", np.searchsorted(used, cells[:, :20]))], point_sets=ends,
                cell_sets=sets).write(folder / "beam20.inp")
    p1, c1 = beam_mesh((nx, 1, 1), linear=True)
    p1 *= [length, 1.0, 1.0]
    ends = {"LEFT": np.flatnonzero(p1[:, 0] == 0.0), "RIGHT": np.flatnonzero(p1[:, 0] == length)}
    meshio.Mesh(p1, [("hexahedron", c1)], point_sets=ends, cell_sets=sets).write(folder / "beam.inp")
    if HAVE_H5PY:
        med = meshio.Mesh(p1, [("hexahedron", c1)], point_data={"point_tags": np.where(
            p1[:, 0] == 0.0, -1, np.where(p1[:, 0] == length, -2, 0))}, cell_data={"cell_tags": [np.where(in_a, -3, -4)]})
        med.point_tags, med.cell_tags = {-1: ["LEFT"], -2: ["RIGHT"]}, {-3: ["A"], -4: ["B"]}
        med.write(folder / "beam.med")
    return folder


@pytest.fixture(scope="module")
def short(tmp_path_factory) -> Path:
    return beam_files(tmp_path_factory.mktemp("short"), SHORT, 10)


@pytest.fixture(scope="module")
def long_beam(tmp_path_factory) -> Path:
    return beam_files(tmp_path_factory.mktemp("long"), 1.0, 40)


def test_cell_sets_read_from_mesh_files(short):
    """Gmsh physical groups of volume cells, *ELSETs (linear and C3D20 cells), MED groups of cells: the same
    cells; a group of vertices (LEFT) is a node set, not a cell set; the same two-material model from each."""
    first, second = np.arange(5), np.arange(5, 10)
    omega = {}
    for name in ("beam.msh", "beam.inp", "beam20.inp", *(["beam.med"] if HAVE_H5PY else [])):
        msh = read_mesh(short / name)
        extra = [] if name.endswith((".msh", ".med")) else ["EALL"]
        assert sorted(msh.cell_sets) == ["A", "B", *extra], name
        assert np.array_equal(msh.cell_sets["A"], first) and np.array_equal(msh.cell_sets["B"], second), name
        assert {"LEFT", "RIGHT"} <= set(msh.node_sets)
        ad = FenicsxAdapter(msh, None, materials={"A": Material(**STEEL), "B": ortho(PLY)},
                            boundary=CLAMPED_ENDS)
        assert ad.describe()["materials"]["A"] == {"cells": 5, **STEEL}
        omega[name] = modal_analysis(ad.stiffness_matrix(), ad.mass_matrix(), 4).omega[:4]
    for name, w in omega.items():  # the same Q2 space on the same affine geometry: eigen-solver round-off
        assert w == pytest.approx(omega["beam.msh"], rel=1e-8), name


# ------------------------------------------------------------------ the same model, written otherwise
SCENE = """\
[model]
solver = "fenicsx"
mesh = "{mesh}"
{materials}
{boundary}
[analysis]
master_modes = [0]
methods = ["dnf"]
thickness = 0.01
transverse = "uz"
[output]
dir = "out"
plot = false
"""


def material_toml(default: dict | None = None, **named: dict) -> str:
    """``[model.material]`` and ``[model.materials.<set>]`` tables."""
    rows = []
    for head, table in ([("[model.material]", default)] if default else []) + \
            [(f"[model.materials.{k}]", v) for k, v in named.items()]:
        rows += [head] + [f"{k} = {json.dumps(v)}" for k, v in table.items()]
    return "\n".join(rows)


def write_scene(folder: Path, name: str, mesh: Path, materials: str, bcs=CLAMPED_ENDS) -> Path:
    path = folder / name
    path.write_text(SCENE.format(mesh=mesh.as_posix(), materials=materials, boundary=boundary_toml(bcs)))
    return path


def run(scene: Path) -> dict:
    return json.loads(run_scene(load_scene(scene), write=False).to_json())


def test_isotropic_written_as_orthotropic(short, tmp_path):
    """E1 = E2 = E3 = E, nu_ij = nu, G = E / (2 (1 + nu)): C differs from the isotropic one by round-off
    (its compliance is inverted: 2e-16), so does K (2e-16). Frequencies and T: measured 2e-12 and 6e-13 on
    this stubby beam (L/h = 20); 7.5e-11 on the first frequency of a slender one (L/h = 100), whose
    bending energy is a sum of terms 1e8 times larger (eps |phi|^T |K| |phi| / phi^T K phi = 2e-8):
    round-off of the forms amplified by the slenderness, hence 1e-10 on the stubby beam. The isotropic
    model keeps its lambda-mu forms (bit for bit as before the orthotropic ones existed)."""
    iso = run(write_scene(tmp_path, "iso.toml", short / "beam.msh", material_toml(STEEL)))
    orth = run(write_scene(tmp_path, "orth.toml", short / "beam.msh", material_toml(as_orthotropic(**STEEL))))
    assert orth["model"]["material"]["E1"] == STEEL["E"] and iso["model"]["material"] == STEEL
    assert orth["spectrum"]["omega"][:6] == pytest.approx(iso["spectrum"]["omega"][:6], rel=1e-10, abs=0)
    t_iso, t_orth = (r["modes"][0]["methods"]["dnf"]["T"] for r in (iso, orth))
    assert t_orth == pytest.approx(t_iso, rel=1e-10)
    C = ortho(as_orthotropic(**STEEL)).C
    assert np.abs(C - Material(**STEEL).C).max() <= 1e-15 * np.abs(C).max()


def test_turned_axes_equal_swapped_constants(short):
    """The ply with axes 1, 2 along y, -x is the ply with its constants 1 and 2 exchanged: K the same to round-off
    (measured 5e-18), M bit for bit, the frequencies to the eigen-solver's round-off (measured 1e-11);
    with the fibres along the beam its first frequency is 3.2 times higher."""
    msh = read_mesh(short / "beam.msh")
    turned = FenicsxAdapter(msh, ortho({**PLY, "axes": TURNED}), boundary=CLAMPED_ENDS)
    swapped = FenicsxAdapter(msh, ortho(swap_axes_12(PLY)), boundary=CLAMPED_ENDS)
    along_x = FenicsxAdapter(msh, ortho(PLY), boundary=CLAMPED_ENDS)
    for a, b in ((turned.stiffness_matrix(), swapped.stiffness_matrix()),
                 (turned.mass_matrix(), swapped.mass_matrix())):
        assert abs(a - b).max() <= 1e-14 * abs(b).max()
    w = [modal_analysis(x.stiffness_matrix(), x.mass_matrix(), 4).omega[:4] for x in (turned, swapped, along_x)]
    assert w[0] == pytest.approx(w[1], rel=1e-10)
    assert w[2][0] / w[0][0] > 3  # E1 / E2 = 13


def test_two_regions_of_one_material_are_the_one_material_model(short):
    """Both halves steel, through per-cell (DG0) lambda and mu: K, M and f equal the constant-steel ones
    (measured: bit for bit)."""
    msh = read_mesh(short / "beam.msh")
    one = FenicsxAdapter(msh, Material(**STEEL), boundary=CLAMPED_ENDS)
    two = FenicsxAdapter(msh, None, materials={"A": Material(**STEEL), "B": Material(**STEEL)},
                         boundary=CLAMPED_ENDS)
    for a, b in ((one.stiffness_matrix(), two.stiffness_matrix()), (one.mass_matrix(), two.mass_matrix())):
        assert abs(a - b).max() <= 1e-15 * abs(a).max()
    u = 1e-3 * np.random.default_rng(5).standard_normal(one.n_dofs)
    f1 = one.internal_force(u)
    assert np.abs(two.internal_force(u) - f1).max() <= 1e-15 * np.abs(f1).max()
    assert two.describe()["materials"] == {"A": {"cells": 5, **STEEL}, "B": {"cells": 5, **STEEL}}


def euler_bernoulli_two_materials(EI: tuple[float, float], mass: tuple[float, float], L: float) -> float:
    """First angular frequency of the clamped-clamped Euler-Bernoulli beam whose halves have the bending
    stiffnesses ``EI`` and masses per length ``mass``: each half ``w = a cos bx + b sin bx + c cosh bx +
    d sinh bx`` (``b^4 = m w^2 / EI``), clamped ends, w, w', EI w'', EI w''' continuous at the joint."""
    half = L / 2

    def rows(beta: float, ei: float, x: float) -> np.ndarray:  # w, w', EI w'', EI w''' of the 4 functions at x
        c, s, ch, sh = math.cos(beta * x), math.sin(beta * x), math.cosh(beta * x), math.sinh(beta * x)
        return np.array([[c, s, ch, sh], [-s, c, sh, ch], [-c, -s, ch, sh], [s, -c, sh, ch]]) \
            * np.array([1, beta, ei * beta**2, ei * beta**3])[:, None]

    def det(omega: float) -> float:
        b1, b2 = ((m * omega**2 / ei) ** 0.25 for ei, m in zip(EI, mass))
        A = np.zeros((8, 8))
        A[:2, :4] = rows(b1, EI[0], 0.0)[:2]  # clamped at x = 0 (half 1 from x = 0)
        A[2:6, :4] = rows(b1, EI[0], half)  # the joint: half 1 at its end = half 2 at its start
        A[2:6, 4:] = -rows(b2, EI[1], 0.0)
        A[6:, 4:] = rows(b2, EI[1], half)[:2]  # clamped at x = L
        return float(np.linalg.det(A / np.abs(A).max(axis=1, keepdims=True)))

    scale = 4.73**2 / L**2 * math.sqrt(min(EI) / max(mass))  # below the first root
    grid = np.linspace(0.5, 4.0, 701) * scale
    d = [det(w) for w in grid]
    k = next(i for i in range(len(grid) - 1) if d[i] * d[i + 1] < 0)
    return brentq(det, grid[k], grid[k + 1], xtol=1e-14 * grid[k], rtol=1e-15)


def test_two_materials_against_euler_bernoulli(long_beam):
    """Steel and aluminium halves (L/h = 100): the 3D first bending frequency over the Euler-Bernoulli one is
    that of the all-steel beam (+0.41%: the clamp holds the Poisson contraction, shear), measured +0.45%
    (steel alone: +0.41%; with a 4 times softer half of steel's density, +0.45% too): the joint adds 0.04%
    of 3D effects. The aluminium half lowers the frequency by 6%, so misplaced cells would show."""
    EI, m = STEEL["E"] * B * HB**3 / 12, STEEL["rho"] * B * HB  # one material: the classical 4.7300^2
    assert euler_bernoulli_two_materials((EI, EI), (m, m), 1.0) == pytest.approx(
        4.730040744862704**2 * math.sqrt(EI / m), rel=1e-12)
    msh = read_mesh(long_beam / "beam.msh")
    ratio, omega = {}, {}
    for key, (a, b) in {"steel": (STEEL, STEEL), "steel-aluminium": (STEEL, ALUMINIUM)}.items():
        ad = FenicsxAdapter(msh, None, materials={"A": Material(**a), "B": Material(**b)}, boundary=CLAMPED_ENDS)
        basis = modal_analysis(ad.stiffness_matrix(), ad.mass_matrix(), 2)
        phi = basis.phi[:, 0]
        assert np.abs(phi[ad.dof_directions() == 2]).max() > 10 * np.abs(phi[ad.dof_directions() == 1]).max()
        EI = tuple(c["E"] * B * HB**3 / 12 for c in (a, b))
        m = tuple(c["rho"] * B * HB for c in (a, b))
        omega[key] = basis.omega[0]
        ratio[key] = omega[key] / euler_bernoulli_two_materials(EI, m, 1.0) - 1
    assert ratio["steel"] == pytest.approx(0.0041, abs=5e-4)
    assert ratio["steel-aluminium"] == pytest.approx(ratio["steel"], abs=1e-3), ratio
    assert omega["steel-aluminium"] < 0.95 * omega["steel"]


def two_region_cantilever() -> FenicsxAdapter:
    """4 bricks, clamped at x = 0: steel, then the ply with its fibres at 45 degrees in the xy plane and axis 2
    along z (a full 6 x 6 C in global axes)."""
    with tempfile.TemporaryDirectory() as folder:
        msh = read_mesh(beam_files(Path(folder), SHORT, 4) / "beam.msh")
    tilted = ortho({**PLY, "axes": [[1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]})
    return FenicsxAdapter(msh, None, materials={"A": Material(**STEEL), "B": tilted}, boundary=[{"set": "LEFT"}])


# f stays an exact cubic with per-cell C: its slope is K, STEP recovers the intrusive G and H
@parametrize_with_checks(two_region_cantilever, Tolerances())
def test_two_region_orthotropic_conformance(check):
    check()


# ------------------------------------------------------------------ the orthotropic clamped plate (example)
def plate_inp(a: float, h: float, n: int) -> str:
    """The example's mesh as CalculiX input: the plate [-a/2, a/2]^2 x [-h/2, h/2], n x n x 1 C3D20 bricks whose
    corner nodes stand at x_i, y_j = (a/2) sin(pi t / 2), t = -1 + 2 i / n (finer towards the clamped edges),
    mid-side nodes at the midpoints; *ELSET EALL (every brick), *NSET EDGE (every node of the lateral faces)."""
    t = np.linspace(-1.0, 1.0, n + 1)
    g = np.empty(2 * n + 1)
    g[0::2] = a / 2 * np.sin(np.pi * t / 2)
    g[1::2] = (g[0:-1:2] + g[2::2]) / 2
    g = g.tolist()  # Python floats: their repr is the number under numpy 2 too (not "np.float64(...)")
    ids: dict[tuple[int, int, int], int] = {}
    rows = []
    for k, z in enumerate((-h / 2, 0.0, h / 2)):  # no face centre (odd i and j); the middle layer: corners only
        for j in range(2 * n + 1):
            for i in range(2 * n + 1):
                if not ((k == 1 and (i % 2 or j % 2)) or (k != 1 and i % 2 and j % 2)):
                    ids[i, j, k] = len(ids) + 1
                    rows.append(f"{len(ids)}, {g[i]!r}, {g[j]!r}, {z!r}")
    corners = [(0, 0, 0), (2, 0, 0), (2, 2, 0), (0, 2, 0)]
    local = [*corners, *[(i, j, 2) for i, j, _ in corners], (1, 0, 0), (2, 1, 0), (1, 2, 0), (0, 1, 0),
             (1, 0, 2), (2, 1, 2), (1, 2, 2), (0, 1, 2), *[(i, j, 1) for i, j, _ in corners]]
    out = ["** A square plate clamped on its four edges (model units: m), the mesh of plate_fenicsx.toml.",
           f"** [-{a / 2!r}, {a / 2!r}]^2 x [-{h / 2!r}, {h / 2!r}]: side {a!r}, thickness {h!r}; {n} x {n} x 1 "
           "C3D20 bricks,", f"** corner nodes at (a/2) sin(pi t/2), t = -1 + 2 i/{n}; mid-side nodes at the "
           "midpoints.", "** Written by plate_inp() of tests/test_fenicsx_materials.py, which checks this file.",
           "*NODE, NSET=NALL", *rows, "*ELEMENT, TYPE=C3D20, ELSET=EALL"]
    for e, (ei, ej) in enumerate(((ei, ej) for ej in range(n) for ei in range(n)), 1):
        c = [ids[2 * ei + i, 2 * ej + j, k] for i, j, k in local]
        out += [f"{e}, " + ", ".join(map(str, c[:15])) + ",", ", ".join(map(str, c[15:]))]
    edge = sorted(v for (i, j, _), v in ids.items() if i in (0, 2 * n) or j in (0, 2 * n))
    out += ["*NSET, NSET=EDGE"] + [", ".join(map(str, edge[i:i + 16])) for i in range(0, len(edge), 16)]
    return "\n".join(out) + "\n"


PLATE = {"a": 0.2, "h": 0.005, "n": 20}


def test_the_example_mesh_is_the_described_plate():
    """plate_mesh.inp is what plate_inp writes (coordinates to round-off: sin's last bit may vary)."""
    ours, shipped = (t.splitlines() for t in (plate_inp(**PLATE), (EXAMPLE / "plate_mesh.inp").read_text()))
    assert len(ours) == len(shipped)
    for x, y in zip(ours, shipped):
        numbers = [[float(v) for v in line.rstrip(",").split(",")] for line in (x, y)] if x[0].isdigit() else None
        assert x == y if numbers is None else np.allclose(*numbers, rtol=1e-14, atol=1e-17), (x, y)


def plate_frequencies(a: float, h: float, c: dict, *, shear: bool, n: int = 14, k: int = 6) -> np.ndarray:
    """The first ``k`` angular frequencies of the clamped a x a plate of the specially orthotropic material ``c``
    (axes 1, 2 along x, y), Ritz with the Legendre polynomials ``P_i`` times ``(1 - s^2)^2`` (Kirchhoff: w) or
    ``(1 - s^2)`` (Mindlin, kappa = 1, rotary inertia: w, psi_x, psi_y), i < n in each direction."""
    nu21 = c["nu12"] * c["E2"] / c["E1"]
    d = 1 - c["nu12"] * nu21
    D11, D22, D12, D66 = (np.array([c["E1"], c["E2"], c["nu12"] * c["E2"], c["G12"] * d]) / d) * h**3 / 12
    s, wq = legendre.leggauss(2 * n + 12)
    bubble = legendre.poly2leg(np.polynomial.polynomial.polypow([1.0, 0.0, -1.0], 1 if shear else 2))
    f = [legendre.legmul(np.eye(n)[i], bubble) for i in range(n)]
    J = 2.0 / a  # d/dx = J d/ds, dx = ds / J
    F = [np.array([legendre.legval(s, legendre.legder(fi, q) if q else fi) for fi in f]) * J**q for q in range(3)]

    def I(p: int, q: int) -> np.ndarray:  # int f_i^(p) f_j^(q) dx
        return (F[p] * wq / J) @ F[q].T

    X00, X11, X10, X22, X20 = I(0, 0), I(1, 1), I(1, 0), I(2, 2), I(2, 0)
    kr = np.kron
    if not shear:
        K = D11 * kr(X22, X00) + D22 * kr(X00, X22) + D12 * (kr(X20, X20.T) + kr(X20.T, X20)) \
            + 4 * D66 * kr(X11, X11)
        return np.sqrt(eigh(K, c["rho"] * h * kr(X00, X00), eigvals_only=True, subset_by_index=[0, k - 1]))
    s13, s23 = h * c["G13"], h * c["G23"]
    KWW = s13 * kr(X11, X00) + s23 * kr(X00, X11)
    KPP = D11 * kr(X11, X00) + D66 * kr(X00, X11) + s13 * kr(X00, X00)  # psi_x
    KSS = D22 * kr(X00, X11) + D66 * kr(X11, X00) + s23 * kr(X00, X00)  # psi_y
    KPS = D12 * kr(X10, X10.T) + D66 * kr(X10.T, X10)
    KPW, KSW = s13 * kr(X10.T, X00), s23 * kr(X00, X10.T)
    K = np.block([[KWW, KPW.T, KSW.T], [KPW, KPP, KPS], [KSW, KPS.T, KSS]])
    M0, Z = kr(X00, X00), np.zeros((n * n, n * n))
    rot = c["rho"] * h**3 / 12
    M = np.block([[c["rho"] * h * M0, Z, Z], [Z, rot * M0, Z], [Z, Z, rot * M0]])
    return np.sqrt(eigh(K, M, eigvals_only=True, subset_by_index=[0, k - 1]))


def test_plate_references():
    """The isotropic clamped square plate: Kirchhoff w a^2 sqrt(rho h / D) = 35.985, 73.394, 108.22, 131.58
    (Leissa); the Mindlin plate tends to it as h / a -> 0."""
    c = as_orthotropic(1.0, 0.3, 1.0)
    D = 1.0 / (12 * (1 - 0.3**2))
    kirchhoff = plate_frequencies(1.0, 1.0, c, shear=False, n=16) / math.sqrt(D)
    assert kirchhoff[[0, 1, 3, 4]] == pytest.approx([35.985, 73.394, 108.22, 131.58], rel=5e-5)
    thin = plate_frequencies(1.0, 1e-3, c, shear=True) / math.sqrt(D * 1e-3**3 / 1e-3)
    assert thin[0] == pytest.approx(kirchhoff[0], rel=1e-4)


def test_orthotropic_plate_example_against_plate_theory():
    """examples/orthotropic_plate (a/h = 40, the ply with fibres along x, 13 689 free dofs). Measured against
    the Mindlin plate (kappa = 1): +0.06%, +0.20% for the first two frequencies (mesh: 28 x 28 gives
    +0.03%, +0.10%); both ~3% below Kirchhoff (-3.4%, -2.9%): E1 / G13 = 29 makes this plate shear-soft."""
    scene = load_scene(EXAMPLE / "plate_fenicsx.toml")
    ad = FenicsxAdapter.from_config(scene.model, base_dir=scene.base_dir, scene_file=scene.file)
    assert ad.n_dofs == 13689 and ad.describe()["boundary"]["n_fixed"] == 3 * (41 * 41 * 3 - 39 * 39 * 3)
    omega = modal_analysis(ad.stiffness_matrix(), ad.mass_matrix(), 4).omega[:4]
    a, h = PLATE["a"], PLATE["h"]
    mindlin = plate_frequencies(a, h, PLY, shear=True, k=4)
    kirchhoff = plate_frequencies(a, h, PLY, shear=False, n=16, k=4)
    assert omega[:2] / mindlin[:2] - 1 == pytest.approx([6e-4, 2e-3], abs=1e-3)
    assert np.all(omega[:2] / kirchhoff[:2] - 1 < -0.02)


# ------------------------------------------------------------------ bad input
ISO_ORTHO = {**STEEL, "E1": 1.0e11}
NOT_POSITIVE = {**PLY, "nu12": 3.9}  # nu12^2 = 15.2 > E1 / E2 = 13
PARALLEL = {**PLY, "axes": [[1, 0, 0], [2, 0, 0]]}


@pytest.mark.parametrize("mesh, materials, key, words", [
    ("beam.msh", material_toml(STEEL, CORE=PLY), "model.materials.CORE", ["'CORE'", "'A'", "'B'", "beam.msh"]),
    ("beam.vtu", material_toml(STEEL, CORE=PLY), "model.materials.CORE", ["'CORE'", "no named cell sets"]),
    ("beam.inp", material_toml(None, A=STEEL, EALL=PLY), "model.materials.EALL", ["'A'", "'EALL'", "5 cells"]),
    ("beam.msh", material_toml(None, A=STEEL), "model.material", ["5 of the 10 cells", "['A']"]),
    ("beam.msh", "", "model.material", ["missing", "[model.materials.<set>]"]),
    ("beam.msh", material_toml(ISO_ORTHO), "model.material", ["not a mix", "'E1'"]),
    ("beam.msh", material_toml(STEEL, B=NOT_POSITIVE), "model.materials.B", ["not positive definite"]),
    ("beam.msh", material_toml(PARALLEL), "model.material.axes", ["parallel"]),
    ("beam.msh", material_toml({**STEEL, "axes": TURNED}), "model.material.axes", ["isotropic"]),
    ("beam.msh", material_toml({k: v for k, v in PLY.items() if k != "G23"}), "model.material.G23", ["missing"]),
    ("cap", material_toml(PLY), "model.material.E1", ["isotropic"]),
    ("cap", material_toml(STEEL, A=PLY), "model.materials", ["no cell sets"]),
])
def test_bad_materials_are_scene_errors(short, tmp_path, capsys, mesh, materials, key, words):
    """Exit code 2 from ``stepnf run``, the key and the reason named, nothing written."""
    if mesh == "cap":
        scene = tmp_path / "bad.toml"
        scene.write_text('[model]\nsolver = "fenicsx"\n[model.geometry]\na = 0.15\nR = "inf"\nh = 0.003\n'
                         f"n_core = 2\nn_ring = 1\n{materials}\n[analysis]\nmaster_modes = [0]\n")
    else:
        if mesh == "beam.vtu":
            m = read_mesh(short / "beam.msh")
            meshio.Mesh(m.points, [(m.cell_type, m.cells)]).write(tmp_path / "beam.vtu")
        scene = write_scene(tmp_path, "bad.toml", (tmp_path if mesh == "beam.vtu" else short) / mesh, materials)
    assert cli_main(["run", str(scene), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"[{key}]" in err and str(scene) in err, err
    for w in words:
        assert w in err, (w, err)
    assert not [p for p in tmp_path.rglob("*") if p.is_file() and p.name not in ("bad.toml", "beam.vtu")]


def test_the_keys_are_listed(capsys):
    assert cli_main(["solvers", "--keys", "fenicsx"]) == 0
    out = capsys.readouterr().out
    for key in ("model.materials ", "model.material.E1 ", "model.material.G23 ", "model.material.axes "):
        assert key in out, key


# ------------------------------------------------------------------ MPI
def test_mpi_regions_equal_the_serial_ones(short, tmp_path):
    """Steel and the ply turned 45 degrees, a half each, under ``mpirun -n 2``: every rank sets its cells
    from their rows in the file (dolfinx distributes and renumbers them). Measured: frequencies 1e-11,
    T 3e-11 (all steel: 43% higher, so a misplaced cell would show)."""
    from helpers.required import need
    from helpers.mpi import MPIRUN, mpirun_command

    if MPIRUN is None:
        need("mpirun")
    turned = {**PLY, "axes": [[1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]]}
    scene = write_scene(tmp_path, "regions.toml", short / "beam.inp", material_toml(None, A=STEEL, B=turned))
    serial = run(scene)
    cmd, env = mpirun_command(2)
    proc = subprocess.run(cmd + [sys.executable, "-m", "stepnf", "run", str(scene), "--json", "--quiet",
                                 "--no-hdf5"], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    par = json.loads(proc.stdout)
    assert par["model"]["mpi_processes"] == 2 and par["model"]["materials"] == serial["model"]["materials"]
    n = min(len(serial["spectrum"]["omega"]), len(par["spectrum"]["omega"]))
    assert n >= 4 and par["spectrum"]["omega"][:n] == pytest.approx(serial["spectrum"]["omega"][:n], rel=1e-9)
    t_serial, t_par = (r["modes"][0]["methods"]["dnf"]["T"] for r in (serial, par))
    assert t_par == pytest.approx(t_serial, rel=1e-8)
