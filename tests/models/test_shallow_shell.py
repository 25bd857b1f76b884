"""Tests of the Marguerre shallow-shell FE adapter (``fenicsx_shell``) against the von Karman model.

The semi-analytical model (:mod:`stepnf.models.vonkarman`, converged to ~1e-7) and this FE model
discretise the same equations (paper Eq. 1, free edge, no in-plane inertia) independently, so
their frequencies and Gamma must agree up to the FE discretisation error (issue 5, "Done means").
"""
from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("dolfinx")

from stepnf.errors import SceneError  # noqa: E402
from stepnf.linalg.modal_analysis import modal_analysis, rigid_body_fields  # noqa: E402
from stepnf.models.vonkarman import VonKarmanShell  # noqa: E402
from stepnf.pipeline.run import run_scene  # noqa: E402
from stepnf.scene.parse import parse_scene  # noqa: E402
from stepnf.testing.harness import Tolerances, parametrize_with_checks  # noqa: E402
from stepnf_fenicsx.shallow_shell import ShallowShellAdapter  # noqa: E402
from stepnf_fenicsx.shallow_shell_config import parse_shell_model  # noqa: E402
from stepnf_fenicsx.shallow_shell_mesh import disk_triangle6, ring_radii, triangle6_area  # noqa: E402

pytestmark = pytest.mark.fenicsx

A, H = 0.15, 0.003
MAT = {"E": 1.04e11, "nu": 0.3, "rho": 4400.0}
SIX = ["(2,0)", "(3,0)", "(4,0)", "(0,1)", "(0,2)", "(2,1)"]
#: Kirchhoff free circular plate, nu = 0.3 (issue 5)
KIRCHHOFF = {(2, 0): 5.358, (0, 1): 9.003, (3, 0): 12.439}
#: resolution of the comparison runs: 8373 dofs, ~2 s per scene (so no test here is marked slow)
N_RINGS = 10


def radius_of(kappa: float) -> float:
    """R giving ``kappa = a^4 / (R^2 h^2)`` with a = 0.15, h = 0.003 (inf for the plate)."""
    return math.inf if kappa == 0 else A**2 / (H * math.sqrt(kappa))


def coarse_shell() -> ShallowShellAdapter:
    # strongly curved (kappa = 225: large quadratic terms), 3 rings: 1 017 dofs
    return ShallowShellAdapter(A, 0.5, H, **MAT, n_rings=3)


@pytest.fixture(scope="module")
def shell() -> ShallowShellAdapter:
    return coarse_shell()


# Default tolerances: f is an exact cubic assembled in double precision. The in-plane mass
# factor (1e-3) does not enter any check of the harness.
@parametrize_with_checks(coarse_shell, Tolerances())
def test_conformance(check):
    check()


def test_disk_mesh():
    P, C = disk_triangle6(A, 10)
    assert C.shape == (600, 6)  # 6 n^2 triangles for n rings of 6 i vertices
    # curved (quadratic) boundary: area error O(h^4) ~ 2.5e-7 measured at 10 rings; a polygonal
    # boundary would be ~1.6e-3 short
    assert triangle6_area(P, C) == pytest.approx(math.pi * A**2, rel=1e-6)
    r = np.hypot(P[:, 0], P[:, 1])
    assert r.max() == pytest.approx(A, rel=1e-14) and np.isclose(r, 0).sum() == 1
    with pytest.raises(ValueError, match="grading"):
        disk_triangle6(A, 4, grading=0.0)
    rho = ring_radii(8, 0.5)  # spacings shrink linearly towards the edge, last = 0.5 x mean
    d = np.diff(rho)
    assert rho[0] == 0 and rho[-1] == pytest.approx(1, rel=1e-15) and np.all(np.diff(d) < 0)
    assert d[-1] / d.mean() == pytest.approx(0.5, rel=1e-12)
    P, C = disk_triangle6(A, 8, grading=0.5)
    assert triangle6_area(P, C) == pytest.approx(math.pi * A**2, rel=1e-6)


def test_rigid_body_modes_are_exact(shell):
    # on mid-surface coordinates (x, y, z0) the six rigid motions of stepnf.linalg.modal_analysis are exact zero-energy
    # fields of the discrete Marguerre model (rotation about e_y: w = -x, u = z0, with z0 interpolated
    # in the displacement space); round-off ~1e-14 |K| a
    K, M = shell.stiffness_matrix(), shell.mass_matrix()
    Rb = rigid_body_fields(shell.dof_coordinates(), shell.dof_directions())
    assert np.abs(K @ Rb).max() <= 1e-11 * abs(K).max() * A
    basis = modal_analysis(K, M, 6, rigid_candidates=Rb)
    assert basis.rigid.shape[1] == 6 and basis.n_elastic >= 6
    # no further (spurious) low-energy mode: the penalty is large enough; (2,0) is the first, w_bar ~ 5.5
    assert shell.shell_scales().omega_bar(basis.omega[0]) > 5.0


def test_internal_force_is_the_cubic_of_the_intrusive_tensors(shell):
    rng = np.random.default_rng(3)
    K = shell.stiffness_matrix()
    u = H * rng.standard_normal(shell.n_dofs)
    f = shell.internal_force(u)
    G, Hc = shell.quadratic_force(u, u), shell.cubic_force(u, u, u)
    parts = [np.abs(K @ u).max(), np.abs(G).max(), np.abs(Hc).max()]
    assert min(parts) > 1e-4 * max(parts)  # each term matters, so the identity tests all three
    # round-off of assembled sums: 1e-12 of the largest term
    assert np.abs(f - (K @ u + G + Hc)).max() <= 1e-12 * max(parts)


def test_transverse_amplitude_between_nodes(shell):
    # w = x cos(t) + y sin(t) is interpolated exactly by P3 on the curved cells; its maximum a is reached
    # on the circle at angle t. t = 0: the mid-node of a curved boundary edge (ring 3 is odd, its vertices
    # are offset), where no P3 dof lies: the nodes alone give a (1 - 3.0e-3), the sampled field a to
    # round-off. t = atan(4/3): inside a cell edge; measured -2.9e-5 (the O(h^3) distance of the quadratic
    # edge from the circle), nodes alone -9.1e-4.
    X = shell.dof_coordinates()[2::3]
    for (c, s), tol in (((1.0, 0.0), 1e-12), ((0.6, 0.8), 1e-4)):
        phi = np.zeros(shell.n_dofs)
        phi[2::3] = c * X[:, 0] + s * X[:, 1]
        amp = shell.transverse_amplitude(phi)
        assert amp == pytest.approx(A, rel=tol)
        assert np.abs(phi).max() < A * (1 - 5e-4) <= amp


def test_inplane_inertia_switch(shell):
    # von Karman (default): in-plane kinetic energy scaled by INPLANE_MASS_FACTOR; true: full rho h
    from stepnf_fenicsx.shallow_shell import INPLANE_MASS_FACTOR

    full = ShallowShellAdapter(A, 0.5, H, **MAT, n_rings=3, inplane_inertia=True)
    d0, d1 = shell.mass_matrix().diagonal(), full.mass_matrix().diagonal()
    dirs = shell.dof_directions()
    assert np.allclose(d0[dirs == 2], d1[dirs == 2], rtol=1e-14)
    assert np.allclose(d0[dirs < 2], INPLANE_MASS_FACTOR * d1[dirs < 2], rtol=1e-12)
    # total transverse mass = rho h pi a^2 (w = 1 is interpolated exactly; curved edge: area error ~1e-5)
    one = (dirs == 2).astype(float)
    assert one @ (full.mass_matrix() @ one) == pytest.approx(MAT["rho"] * H * math.pi * A**2, rel=1e-4)
    assert full.describe()["inplane_mass_factor"] == 1.0


def test_scene_validation():
    good = {"geometry": {"a": A, "R": "inf", "h": H}, "material": dict(MAT)}
    p = parse_shell_model(good)
    assert p["R"] == math.inf and p["degree"] == 3 and p["quadrature_degree"] == 6 and not p["inplane_inertia"]
    bad = [
        ({"mesh": "x.msh"}, "model.mesh", "unknown key"),
        ({"degree": 4}, "model.degree", "expected one of"),
        ({"penalty": 1.0}, "model.penalty", r"\[2, 1000\]"),
        ({"inplane_inertia": "no"}, "model.inplane_inertia", "true or false"),
        ({"geometry": {"a": A, "R": 0.1, "h": H}}, "model.geometry.R", ">= a"),
        ({"geometry": {"a": A, "h": H}}, "model.geometry", "missing keys"),
        ({"geometry": {"a": A, "R": 1.0, "h": H, "n_rings": 1}}, "model.geometry.n_rings", r"\[2, 200\]"),
        ({"material": {"E": 1.0, "nu": 0.6, "rho": 1.0}}, "model.material.nu", "Poisson"),
    ]
    for change, key, msg in bad:
        cfg = {**good, **change}
        with pytest.raises(SceneError, match=msg) as err:
            parse_shell_model(cfg, "s.toml")
        assert err.value.key == key


def test_registered_entry_point():
    from stepnf.plugin.registry import get_solver

    assert get_solver("fenicsx_shell") is ShallowShellAdapter


def test_plate_frequencies():
    ad = ShallowShellAdapter(A, math.inf, H, **MAT, n_rings=N_RINGS)
    K, M = ad.stiffness_matrix(), ad.mass_matrix()
    basis = modal_analysis(K, M, 8, rigid_candidates=rigid_body_fields(ad.dof_coordinates(), ad.dof_directions()))
    assert basis.rigid.shape[1] == 6
    wbar = ad.shell_scales().omega_bar(basis.omega)
    labels = ad.mode_labels(basis.phi)
    assert labels[:5] == [(2, 0), (2, 0), (0, 1), (3, 0), (3, 0)]
    for lab, ref in KIRCHHOFF.items():
        # issue: 0.5%; measured +1e-6 (2,0), +2e-6 (0,1), +4e-6 (3,0) against the von Karman model's
        # 5.35833, 9.00314, 12.43899, so 1e-3 bounds the printed 4-digit references' rounding too
        assert wbar[labels.index(lab)] == pytest.approx(ref, rel=1e-3)


def _near_one_two(vk: VonKarmanShell, p: int, band: float = 0.05) -> list:
    """Modes s coupled to p by g^s_pp with w_s / w_p within ``band`` (relative) of 2."""
    om, g = vk.omegas(), vk.quadratic_coefficients(p)
    big = np.abs(g) > 1e-8 * max(np.abs(g).max(), 1e-300)
    return [vk.labels()[s] for s in np.nonzero(big & (np.abs(om / om[p] / 2 - 1) <= band))[0]]


def _gammas(result) -> dict:
    return {tuple(m.label): m for m in result.modes}


@pytest.mark.parametrize("kappa", [0.0, 10.0, 25.0])
def test_gamma_agrees_with_vonkarman(kappa):
    vk_scene = parse_scene({"model": {"solver": "vonkarman", "kappa": kappa, "nu": 0.3},
                            "analysis": {"master_modes": SIX, "methods": ["nf"]}})
    R = radius_of(kappa)
    fe_scene = parse_scene({"model": {"solver": "fenicsx_shell",
                                      "geometry": {"a": A, "R": "inf" if math.isinf(R) else R, "h": H,
                                                   "n_rings": N_RINGS},
                                      "material": dict(MAT)},
                            "analysis": {"master_modes": SIX, "methods": ["dnf"]}})
    vk_res, fe_res = run_scene(vk_scene, write=False), run_scene(fe_scene, write=False)
    assert fe_res.spectrum["n_rigid"] == 6
    assert fe_res.kappa == pytest.approx(kappa, rel=1e-12, abs=1e-12)
    vk = VonKarmanShell(kappa=kappa, nu=0.3)
    gv, gf = _gammas(vk_res), _gammas(fe_res)
    for lab in [(2, 0), (3, 0), (4, 0), (0, 1), (0, 2), (2, 1)]:
        a, b = gv[lab], gf[lab]
        # frequencies: P3 C0-IP on 10 rings, measured |error| <= 5e-5 (the (0,2), (2,1) modes)
        assert b.omega_bar == pytest.approx(a.omega, rel=2e-4)
        G_vk, G_fe = a.methods["nf"].gamma, b.methods["dnf"].gamma
        if _near_one_two(vk, vk.labels().index(lab)):
            # within 5% of a 1:2 resonance ((2,1) with (4,1) at kappa 10, 25; (4,0) with (0,2) at 25): the
            # small denominator w_s^2 - 4 w_p^2 amplifies the O(h^4) frequency errors; measured 1.9%, 1.0%, 0.01%
            assert G_fe == pytest.approx(G_vk, rel=0.05), (kappa, lab)
            # and the FE run's DNF says so (the in-plane mass factor keeps stepnf's coupling floor low enough)
            kinds = [f["kind"] for f in b.flags + b.methods["dnf"].flags]
            assert "internal_resonance_1_2" in kinds, (kappa, lab)
        else:
            # issue 5's 2%; measured <= 0.3% ((0,2) at kappa 25, where Gamma nearly cancels), else <= 0.02%
            assert G_fe == pytest.approx(G_vk, rel=0.02), (kappa, lab)


@pytest.mark.parametrize("degree, rings, rate", [(3, (4, 6, 8), 4.0), (2, (6, 9, 12), 2.0)])
def test_frequency_convergence_rate(degree, rings, rate):
    # C0 interior penalty with P_k: eigenvalue errors O(h^(2k-2)), i.e. h^4 for P3 and h^2 for P2, against
    # the von Karman model at kappa = 25 (converged to ~1e-7, far below the FE errors used: >= 3e-5).
    # Measured rates: P3 3.91, 4.03, 3.96; P2 1.98, 1.89, 1.85 for (4,0), (0,2), (2,1).
    vk = VonKarmanShell(kappa=25.0, nu=0.3)
    ref = dict(zip(vk.labels(), vk.omegas()))
    labs = [(4, 0), (0, 2), (2, 1)]
    errors = {lab: [] for lab in labs}
    for n in rings:
        ad = ShallowShellAdapter(A, radius_of(25.0), H, **MAT, n_rings=n, degree=degree)
        basis = modal_analysis(ad.stiffness_matrix(), ad.mass_matrix(), 14, dense_limit=0,  # sparse: faster
                               rigid_candidates=rigid_body_fields(ad.dof_coordinates(), ad.dof_directions()))
        wbar, found = ad.shell_scales().omega_bar(basis.omega), ad.mode_labels(basis.phi)
        for lab in labs:
            errors[lab].append(wbar[found.index(lab)] / ref[lab] - 1)
    for lab in labs:
        e = np.asarray(errors[lab])
        assert np.all(e > 0)  # the discrete bending energy is stiffer than the exact one at this penalty
        slope = np.polyfit(np.log(1.0 / np.asarray(rings)), np.log(e), 1)[0]
        assert slope == pytest.approx(rate, abs=0.4), (lab, errors[lab])
