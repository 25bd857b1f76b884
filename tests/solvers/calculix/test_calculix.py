"""The CalculiX adapter, with real ccx runs on small meshes.

Precision model used by the tolerances below: ccx prints forces in the
``.dat`` file as ``%13.6E`` (7 significant digits), i.e. each printed force
carries a relative rounding error of at most 5e-7 of its own magnitude; K and
M come from ``.sti``/``.mas`` with 14 digits.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from helpers.meshes import block_mesh
from helpers.required import requires

from stepnf.errors import SceneError, SolverRunError
from stepnf.testing.harness import Tolerances, parametrize_with_checks

pytestmark = [
    pytest.mark.calculix,
    requires("ccx"),
]

ccx_mod = pytest.importorskip("stepnf_calculix")
CalculixAdapter = ccx_mod.CalculixAdapter

E, NU, RHO = 2.0e11, 0.3, 7800.0


class _Mesh:
    cell_type = "hexahedron20"

    def __init__(self, points, cells):
        self.points, self.cells = points, cells


def make_block_adapter(tmp_path=None, **kw) -> CalculixAdapter:
    pts, cells = block_mesh(2, 2, 1)
    kw.setdefault("material", {"E": E, "nu": NU, "rho": RHO})
    return CalculixAdapter.from_volume_mesh(_Mesh(pts, cells), **kw)


def _conformance_adapter():
    ad = make_block_adapter()
    ad.cache_size = 0  # the batch-versus-loop check must really run ccx for the loop
    return ad


# Tolerances justified by the 7 printed digits (5e-7 relative rounding per printed force):
# slope: (F(eps u) - F(-eps u)) / (2 eps) carries 2 x 5e-7 relative error -> 2e-6;
# batch: batch and separate runs may differ by one unit in the 7th digit -> 1e-6;
# symmetry: M and K are read from an upper triangle, so exactly symmetric (1e-12 leaves room for nothing else);
# zero force: ccx prints exact zeros for u = 0 (1e-10 as in the default).
CCX_TOL = Tolerances(symmetry=1e-12, zero_force=1e-10, slope=2e-6, batch=1e-6, step=1e-5)


@parametrize_with_checks(_conformance_adapter, CCX_TOL)
def test_conformance(check):
    check()


def test_batch_in_one_run_equals_separate_runs(tmp_path):
    """Each NLGEOM step prescribes the TOTAL displacement, so a step does not depend on the previous ones."""
    ad = make_block_adapter(workdir=tmp_path, keep="never")
    ad.cache_size = 0
    rng = np.random.default_rng(7)
    X = ad.dof_coordinates()
    # large, nonlinear fields (rotations of order 0.1 rad, strains of a few %): a path dependence would show
    U = 0.05 * np.stack([np.sin(3 * X[:, 0] + s) * rng.standard_normal(len(X)) for s in range(3)])
    F_batch = ad.internal_forces(U)
    assert len(ad.runs) == 1  # ONE ccx run for the whole batch
    F_rev = ad.internal_forces(U[::-1])[::-1]  # same fields, other order
    F_sep = np.stack([ad.internal_force(u) for u in U])
    assert len(ad.runs) == 5
    scale = np.abs(F_sep).max()
    # one unit in the 7th printed digit of the largest force, at most (5e-7 each side)
    assert np.abs(F_batch - F_sep).max() <= 1e-6 * scale
    assert np.abs(F_rev - F_sep).max() <= 1e-6 * scale
    # and the fields are really nonlinear: f(u) differs from K u by far more than the print precision
    KU = (ad.stiffness_matrix() @ U.T).T
    assert np.abs(F_sep - KU).max() > 1e-3 * scale
    assert list(tmp_path.iterdir()) == []  # work folders cleaned (keep = "never")


def test_step_recovers_cubic_terms_to_print_precision():
    """f is an exact cubic (SVK, NLGEOM): G and H from two amplitudes agree to the print precision."""
    ad = make_block_adapter()
    K = ad.stiffness_matrix()
    X = ad.dof_coordinates()
    phi = np.cos(np.pi * X[:, 0]) * (ad.dof_directions() == 2)  # a bending-like transverse field
    Kphi = K @ phi
    out = []
    for q in (0.1, 0.05):  # peak displacement = the plate's thickness and half of it
        fp, fm = ad.internal_forces(np.stack([q * phi, -q * phi]))
        G = (fp + fm) / (2 * q * q)
        h = phi @ (fp - fm - 2 * q * Kphi) / (2 * q**3)
        out.append((G, h))
    (G1, h1), (G2, h2) = out
    errG = np.abs(G1 - G2).max() / np.abs(G1).max()
    errh = abs(h1 - h2) / abs(h1)
    # forces 5e-7 relative; G cancels the linear part |K q phi| ~ |G q^2| at q ~ h, H likewise:
    # round-off ~ 5e-7 |f| / |G q^2| ~ 1e-6 at q = h/2; 2e-5 leaves a factor ~10
    assert errG < 2e-5, errG
    assert errh < 2e-5, errh
    assert h1 > 0  # stretching of a bending field hardens


def test_affine_patch_test_checks_node_order():
    """Uniform strain on distorted (affine) C3D20 blocks: zero force at interior nodes (exact patch test).

    A wrong VTK -> C3D20 node order would give negative Jacobians (ccx error) or fail the patch test.
    """
    A = np.array([[1.0, 0.2, 0.1], [-0.1, 0.9, 0.3], [0.05, -0.2, 1.1]])
    pts, cells = block_mesh(2, 2, 2, size=(1.0, 1.0, 1.0), A=A)
    ad = CalculixAdapter.from_volume_mesh(_Mesh(pts, cells), material={"E": E, "nu": NU, "rho": RHO})
    K = ad.stiffness_matrix()
    B = np.array([[1e-3, 2e-4, -3e-4], [5e-4, -1e-3, 1e-4], [0.0, 3e-4, 2e-3]])
    u = (pts @ B.T).ravel()
    f = (K @ u).reshape(-1, 3)
    ref = pts @ np.linalg.inv(A).T  # back on the unit cube
    inner = np.all((ref > 1e-9) & (ref < 1 - 1e-9), axis=1)
    assert inner.sum() >= 1
    # K has 14 digits; interior equilibrium holds up to round-off of the sums (~1e-12 |f|)
    assert np.abs(f[inner]).max() <= 1e-9 * np.abs(f).max()
    # the mass is rho times the volume det(A)
    M = ad.mass_matrix()
    mass = M[0::3][:, 0::3].sum()
    assert mass == pytest.approx(RHO * np.linalg.det(A), rel=1e-12)


def test_cap_scene_and_shell_facts(tmp_path):
    """A coarse cap from the same scene keys as the fenicsx adapter: mass, scales, transverse amplitude."""
    cfg = {"element": "hex20",
           "geometry": {"shape": "spherical_cap", "a": 0.15, "R": 1.5, "h": 0.003, "n_core": 2, "n_ring": 1},
           "material": {"E": 1.04e11, "nu": 0.3, "rho": 4400.0}, "keep": "never", "threads": 1}
    ad = CalculixAdapter.from_config(cfg, base_dir=tmp_path, scene_file=tmp_path / "s.toml")
    from stepnf.geometry import shell_volume, spherical_cap, volume

    M = ad.mass_matrix()
    mass = M[0::3][:, 0::3].sum()
    # same mesh integrated independently (VTK node order, Gauss order 4): checks the VTK -> C3D20 order
    # on curved elements; ccx integrates with 3x3x3 points, so only quadrature differences (~1e-9) remain
    mesh = spherical_cap(0.15, 1.5, 0.003, element="hex20", n_core=2, n_ring=1)
    assert mass == pytest.approx(4400.0 * volume(mesh.points, mesh.cells), rel=1e-7)
    # 8 quadratic arcs round the edge: the volume of the true cap is missed by < 0.1 %
    assert mass == pytest.approx(4400.0 * shell_volume(0.15, 1.5, 0.003), rel=1e-3)
    assert ad.characteristic_length() == 0.003
    sc = ad.shell_scales()
    assert sc.kappa == pytest.approx(0.15**4 / (1.5**2 * 0.003**2))
    n = ad.n_dofs
    phi = np.zeros(n)
    phi[2::3] = 1.0  # uniform uz: transverse component = cos(angle to the normal) <= 1, = 1 at the apex
    assert ad.transverse_amplitude(phi) == pytest.approx(1.0, abs=1e-12)
    K = ad.stiffness_matrix()
    # free edge: the six rigid motions are in the null space of K (14 printed digits)
    X = ad.points
    rot = np.cross([0.0, 0.0, 1.0], X).ravel()
    assert np.abs(K @ rot).max() <= 1e-8 * abs(K).max() * np.abs(X).max()
    d = ad.describe()
    assert d["n_nodes"] == n // 3 and d["elements"] == {"C3D20": 12}


def test_user_inp_mesh_and_template(tmp_path):
    """A user's .inp mesh (with lines stepnf ignores) and a user job template through scene keys."""
    from stepnf_calculix.deck import mesh_text

    pts, cells = block_mesh(2, 2, 1)
    ids = np.arange(1, len(pts) + 1) * 10  # non-consecutive node numbers
    text = "** user mesh\n*HEADING\nblock\n" + mesh_text(ids, pts, [("C3D20", np.arange(1, 5), ids[cells])])
    text += "*MATERIAL, NAME=STEEL\n*ELASTIC\n1., 0.3\n"
    (tmp_path / "part.inp").write_text(text)
    tpl = (ccx_mod.shipped_template("job.inp").text
           .replace("${E}, ${nu}", "${E}, 0.3").replace("** stepnf", "** my own"))
    (tmp_path / "my.inp").write_text(tpl)
    cfg = {"mesh": "part.inp", "template": "my.inp", "material": {"E": E, "rho": RHO}}
    ad = CalculixAdapter.from_config(cfg, base_dir=tmp_path, scene_file=tmp_path / "s.toml")
    ref = make_block_adapter()
    assert ad.n_dofs == ref.n_dofs
    K, K0 = ad.stiffness_matrix(), ref.stiffness_matrix()
    assert abs(K - K0).max() <= 1e-13 * abs(K0).max()  # same model, same 14 digits
    u = 1e-3 * np.sin(ad.dof_coordinates()[:, 0])
    assert np.allclose(ad.internal_force(u), ref.internal_force(u), rtol=0, atol=1e-6 * abs(K0).max() * 1e-3)


@pytest.mark.parametrize("cfg, key", [
    ({"geometry": {"a": 1.0, "R": 2.0, "h": 0.1}, "material": {"E": 1.0, "nu": 0.3, "rho": 1.0},
      "element": "hex27"}, "model.element"),
    ({"geometry": {"a": 1.0, "R": "flat", "h": 0.1}, "material": {"E": 1.0, "nu": 0.3, "rho": 1.0}},
     "model.geometry.R"),
    ({"geometry": {"a": 1.0, "R": "inf", "h": 0.1}, "material": {"E": 1.0, "nu": 0.3}}, "model.material.rho"),
    ({"geometry": {"a": 1.0, "R": "inf", "h": 0.1, "n_cor": 3},
      "material": {"E": 1.0, "nu": 0.3, "rho": 1.0}}, "model.geometry.n_cor"),
    ({"mesh": "nope.inp"}, "model.mesh"),
    ({"mesh": "mesh.inp", "keep": "sometimes"}, "model.keep"),
])
def test_scene_errors_name_the_key(tmp_path, cfg, key):
    (tmp_path / "mesh.inp").write_text("")  # exists: the other keys are checked (never read: a key fails first)
    with pytest.raises(SceneError) as ei:
        CalculixAdapter.from_config(cfg, base_dir=tmp_path, scene_file=tmp_path / "s.toml")
    assert ei.value.key == key


def test_ccx_error_is_reported_with_log(tmp_path):
    """A degenerate element makes ccx fail: the error quotes ccx's message and keeps the folder."""
    pts, cells = block_mesh(1, 1, 1)
    pts[cells[0, 6]] = pts[cells[0, 0]]  # collapse a corner: nonpositive Jacobian
    ad = CalculixAdapter.from_volume_mesh(_Mesh(pts, cells), material={"E": E, "nu": NU, "rho": RHO},
                                          workdir=tmp_path, keep="on_error")
    with pytest.raises(SolverRunError, match="(?s)exited with code.*jacobian") as ei:
        ad.stiffness_matrix()
    assert (tmp_path / ei.value.workdir).joinpath("matrices.inp").is_file()


def test_inf_radius_is_the_flat_plate(tmp_path):
    cfg = {"geometry": {"a": 0.15, "R": "inf", "h": 0.003, "n_core": 2, "n_ring": 1},
           "material": {"E": 1.04e11, "nu": 0.3, "rho": 4400.0}}
    ad = CalculixAdapter.from_config(cfg, base_dir=tmp_path)
    assert ad.shell_scales().kappa == 0.0
    assert math.isinf(ad.geometry["R"])
    assert np.ptp(ad.points[:, 2]) == pytest.approx(0.003)


def test_midsurface_sampler_reproduces_quadratics():
    """The hex20 mid-surface sampling interpolates exactly what a 20-node brick represents exactly.

    Serendipity elements reproduce complete quadratics; on straight-sided (plate) elements the map is
    affine, so W @ q(nodes) = q(sample positions) to round-off for any quadratic q.
    """
    from stepnf.geometry import spherical_cap
    from stepnf.geometry.midsurface import midsurface_sampler

    mesh = spherical_cap(1.0, float("inf"), 0.1, element="hex20", n_core=2, n_ring=1)
    W, X = midsurface_sampler(mesh.points, mesh.cells, mesh.midsurface)
    assert W.shape == (9 * mesh.n_cells, mesh.n_points)
    assert np.allclose(X[:, 2], 0.0, atol=1e-14)  # all on the plate's mid-plane

    def q(P):
        return 1.0 + P[:, 0] - 2 * P[:, 1] + 3 * P[:, 0] * P[:, 1] + P[:, 1] ** 2

    core = np.all(np.abs(X[:, :2]) <= 0.5 + 1e-12, axis=1)  # the square core: straight-sided elements
    err = np.abs(W @ q(mesh.points) - q(X))[core]
    assert err.max() < 1e-12


def test_tangent_stiffness_sharpens_the_cubic_terms():
    """Tangents at +-q phi (14 digits) give G and H; they reproduce the printed forces to print precision.

    For the exact cubic f: K_T(u) = K + 2 G(u,.) + 3 H(u,u,.), so f(u) = K u + G(u,u) + H(u,u,u) follows
    from two tangents alone; comparing it with ccx's printed f(u) checks the tangent independently.
    """
    ad = make_block_adapter()
    ad.cache_size = 0
    K = ad.stiffness_matrix()
    KT0 = ad.tangent_stiffness(np.zeros(ad.n_dofs))
    assert abs(KT0 - K).max() <= 1e-13 * abs(K).max()  # the tangent at u = 0 is K (both 14 digits)
    X = ad.dof_coordinates()
    phi = np.sin(3 * X[:, 0]) * (ad.dof_directions() == 2) + 0.2 * np.cos(2 * X[:, 1]) * (ad.dof_directions() == 0)
    q = 0.05
    Gv, h = ad.sharp_step(phi, q)
    fp, fm = ad.internal_forces(np.stack([q * phi, -q * phi]))
    # force route: 7 printed digits, so G to ~1e-6 and H to ~1e-5 relative here (see the precision model above)
    G_f = (fp + fm) / (2 * q * q)
    h_f = phi @ (fp - fm - 2 * q * (K @ phi)) / (2 * q**3)
    assert np.abs(Gv - G_f).max() <= 5e-6 * np.abs(Gv).max()
    assert abs(h - h_f) <= 1e-4 * abs(h)
    # f(q phi) predicted from the tangents alone equals the printed force to print precision (5e-7)
    Hv = (ad.tangent_stiffness(q * phi) + ad.tangent_stiffness(-q * phi) - 2 * K) @ phi / (6 * q * q)
    pred = q * (K @ phi) + q * q * Gv + q**3 * Hv
    assert np.abs(pred - fp).max() <= 2e-6 * np.abs(fp).max()


def test_parallel_ccx_runs_equal_one_run():
    """Two ccx processes on halves of a batch give exactly the forces of one run (same decks per field)."""
    one = make_block_adapter()
    two = make_block_adapter(parallel_runs=2)
    X = one.dof_coordinates()
    U = np.stack([1e-3 * (s + 1) * np.sin(X[:, 0] + s) for s in range(4)])
    F1, F2 = one.internal_forces(U), two.internal_forces(U)
    assert len(one.runs) == 1 and len(two.runs) == 2
    np.testing.assert_array_equal(F1, F2)


@pytest.mark.parametrize("edge", ["free", "clamped"])
def test_stepnf_check_passes_a_coarse_cap(tmp_path, capsys, edge):
    """Issue 29: ``stepnf check`` on a generated cap failed ``conservative_force`` (the rounding of the 7
    printed digits made the tangent look asymmetric by 1e-5 .. 1e-4 against the 1e-6 of exact forces);
    the adapter declares ``force_digits = 7`` and the check allows the rounding's bound on top."""
    from stepnf.cli.main import main

    scene = tmp_path / "cap.toml"
    held = '[[model.boundary]]\nset = "edge"\n' if edge == "clamped" else ""
    scene.write_text('[model]\nsolver = "calculix"\nkeep = "never"\nthreads = 1\n[model.geometry]\n'
                     'shape = "spherical_cap"\na = 0.15\nR = 1.5\nh = 0.003\nn_core = 2\nn_ring = 1\n'
                     '[model.material]\nE = 1.04e11\nnu = 0.3\nrho = 4400.0\n' + held +
                     '[analysis]\nmaster_modes = [0]\nmethods = ["dnf"]\n')
    code = main(["check", str(scene)])
    out, err = capsys.readouterr()
    assert code == 0, out + err
    assert "passed   conservative_force" in out
    assert CalculixAdapter.force_digits == 7  # the .dat file's %13.6E
