"""The inextensible-cantilever theory of tests/helpers/cantilever.py (issue 31, item 1), checked on its own:
against a direct integration of its one-dof equation and against the published Galerkin coefficients.
These tests guard the reference the cantilever benchmarks and tests compare stepnf's T with."""
from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid, quad, simpson, solve_bvp

from helpers import cantilever as cv
from helpers.required import need


def test_beta_l_roots():
    # the classical cantilever roots of cos x cosh x = -1 (e.g. Blevins, table 8-1: 1.87510407, 4.69409113)
    assert cv.beta_l(1) == pytest.approx(1.8751040687119611, rel=1e-14)
    assert cv.beta_l(2) == pytest.approx(4.6940911329741745, rel=1e-14)


@pytest.mark.parametrize("r", [1, 2])
def test_mode_shape_normalised_and_tip_is_two(r):
    # int phi^2 = 1 for this form of the mode, and then |phi(1)| = 2 exactly; quad is independent of the
    # Simpson grid the helper integrates on
    norm = quad(lambda s: cv.mode_shape(r, np.array([s]))[0][0] ** 2, 0, 1, epsabs=0, epsrel=1e-13)[0]
    assert norm == pytest.approx(1.0, rel=1e-12)
    assert abs(cv.mode_shape(r, np.array([1.0]))[0][0]) == pytest.approx(2.0, rel=1e-12)


@pytest.mark.parametrize("r, a_pub, b_pub", [(1, 40.44, 4.597), (2, 13418.0, 144.7)])
def test_galerkin_coefficients_match_published(r, a_pub, b_pub):
    # curvature (a) and inertia (b) coefficients of the one-mode inextensible cantilever as published to
    # 4 significant figures (Anderson, Nayfeh & Balachandran 1996; Malatkar & Nayfeh 2003): half a unit
    # of the last published digit
    w2, a, b = cv.galerkin_coefficients(r)
    assert w2 == pytest.approx(cv.beta_l(r) ** 4, rel=1e-14)
    assert a == pytest.approx(a_pub, abs=0.5 * 10 ** (math.floor(math.log10(a_pub)) - 3))
    assert b == pytest.approx(b_pub, abs=0.5 * 10 ** (math.floor(math.log10(b_pub)) - 3))


@pytest.mark.parametrize("r", [1, 2])
def test_frequency_correction_against_direct_integration(r):
    # w_NL/w = 1 + kappa A^2 + O(A^4): the O(A^4) term is removed by Richardson extrapolation of two
    # amplitudes A and 2A ((4 k(A) - k(2A))/3); what is left is O(A^4) relative (< 1e-5 at these A) plus
    # the ODE integration's error (rtol 1e-12 on a period, divided by A^2 ~ 1e-4 .. 1e-6)
    w2, a, b = cv.galerkin_coefficients(r)
    kappa = cv.frequency_correction(w2, a, b)
    A = 0.01 if r == 1 else 0.001  # tip deflection 2A = 2% (mode 1) and 0.2% (mode 2) of L

    def k(amp):
        return (cv.ode_frequency(w2, a, b, amp) / math.sqrt(w2) - 1.0) / amp**2

    extrapolated = (4.0 * k(A) - k(2 * A)) / 3.0
    assert extrapolated == pytest.approx(kappa, rel=2e-5)


def test_frequency_correction_pure_duffing_and_pure_inertia():
    # the two limits of the harmonic balance: Duffing 3a/(8w^2) (classical), and x'' + w^2 x + b (x^2 x''
    # + x x'^2) = 0, the Lagrangian (1 + b x^2) x'^2 / 2 - w^2 x^2 / 2, whose first-order shift is -b/4
    assert cv.frequency_correction(4.0, 1.0, 0.0) == pytest.approx(3.0 / 32.0, rel=1e-15)
    assert cv.frequency_correction(4.0, 0.0, 1.0) == pytest.approx(-0.25, rel=1e-15)
    A = 1e-2
    w_inertia = cv.ode_frequency(4.0, 0.0, 1.0, A)
    assert (w_inertia / 2.0 - 1.0) / A**2 == pytest.approx(-0.25, rel=1e-3)  # O(A^2) = 1e-4 left


def test_backbone_coefficients_and_gamma():
    # c_r = kappa_r / phi_r(1)^2 from the published coefficients: mode 1 hardening, mode 2 softening
    # (Crespo da Silva & Glynn 1978); the values follow from a, b above (4-5 digits of the published ones)
    c1, c2 = cv.backbone_coefficient(1), cv.backbone_coefficient(2)
    assert c1 == pytest.approx(0.0193835, rel=1e-5)
    assert c2 == pytest.approx(-6.45441, rel=1e-5)
    # from the published a, b: their rounding (half a unit of the last digit, da and db) propagated
    # through the cancellation 3a/(8w^2) - b/4 (16x for mode 1)
    for r, c, a_pub, da, b_pub, db in [(1, c1, 40.44, 0.005, 4.597, 0.0005), (2, c2, 13418.0, 0.5, 144.7, 0.05)]:
        w2 = cv.beta_l(r) ** 4
        kappa = 3 * a_pub / (8 * w2) - b_pub / 4
        assert c == pytest.approx(kappa / 4, abs=(3 * da / (8 * w2) + db / 4) / 4)
    assert cv.gamma_theory(2, 100) == pytest.approx(c2 * 1e-4, rel=1e-14)


def test_linear_frequency_and_t_scale():
    # the plate 300 x 30 x 1 mm, steel in N-mm-tonne: T of mode 2 "about -4" (issue 31, item 1)
    L, b, h, E, rho = 300.0, 30.0, 1.0, 210000.0, 7.85e-9
    assert cv.t_theory(2, rho, b * h, L) == pytest.approx(-4.0603, rel=1e-4)
    w1 = cv.linear_frequency(1, E, b * h**3 / 12, rho, b * h, L)
    assert w1 == pytest.approx(1.8751040687119611**2 * math.sqrt(E * h**2 / (12 * rho * L**4)), rel=1e-14)


def test_strip_meshes_have_the_volume_and_a_positive_orientation():
    L, b, h = cv.strip_size(100)
    for mesh in ("hex20", "tet10"):
        pts, cells = (cv.strip_hex20 if mesh == "hex20" else cv.strip_tet10)(100, 4)
        if mesh == "tet10":
            P = pts[cells[:, :4]]
            vol = np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), P[:, 3] - P[:, 0]) / 6
            assert (vol > 0).all() and vol.sum() == pytest.approx(L * b * h, rel=1e-12)
            mids = pts[cells[:, 4:]]
            ends = [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]
            for k, (p, q) in enumerate(ends):  # every C3D10 mid-node halfway along its edge
                np.testing.assert_allclose(mids[:, k], (pts[cells[:, p]] + pts[cells[:, q]]) / 2, atol=1e-15)
        else:
            assert pts[:, 0].max() == pytest.approx(L) and np.ptp(pts[:, 1]) == pytest.approx(b)
            assert np.ptp(pts[:, 2]) == pytest.approx(h)


@pytest.mark.parametrize("r, slenderness", [(1, 30), (2, 30), (2, 100)])
def test_axial_inertia_ratio_against_a_boundary_value_solve(r, slenderness):
    # the forced rod of axial_inertia_ratio solved independently as a BVP (scipy solve_bvp):
    # U'' = -(phi'^2)' - lam U, U(0) = 0, U'(1) = -phi'(1)^2, lam = mu Omega^2 = 4 w_r^2 (h/L)^2 / 12;
    # R = int U psi / int psi^2 (tolerance: solve_bvp's tol 1e-8 on R - 1 ~ 0.06, the helper's grid)
    lam = 4 * cv.beta_l(r) ** 4 / (12 * slenderness**2)

    def rhs(s, y):
        _, d1, d2 = cv.mode_shape(r, s)
        return np.vstack([y[1], -2 * d1 * d2 - lam * y[0]])

    def bc(ya, yb):
        return np.array([ya[0], yb[1] + cv.mode_shape(r, np.array([1.0]))[1][0] ** 2])

    s = np.linspace(0, 1, 401)
    sol = solve_bvp(rhs, bc, s, np.zeros((2, s.size)), tol=1e-8, max_nodes=200000)
    assert sol.success
    x = np.linspace(0, 1, 200001)
    psi = cumulative_trapezoid(cv.mode_shape(r, x)[1] ** 2, x, initial=0.0)  # O(dx^2) ~ 1e-10
    num, den = simpson(-sol.sol(x)[0] * psi, x=x), simpson(psi**2, x=x)
    assert cv.axial_inertia_ratio(r, slenderness) == pytest.approx(num / den, rel=1e-7)


def test_extensible_gamma_tends_to_the_inextensible_one():
    # the correction is O((h/L)^2): mode 2 +8.8% at L/h = 30, +0.74% at 100, < 1e-4 at 1000 (ratio of
    # the corrections 100 -> 1000 is 100 to within the O((h/L)^4) terms)
    rel = [cv.gamma_theory(2, s, extensible=True) / cv.gamma_theory(2, s) - 1 for s in (30, 100, 1000)]
    assert rel[0] == pytest.approx(0.0882, abs=5e-4) and rel[1] == pytest.approx(0.00742, abs=5e-5)
    assert rel[1] / rel[2] == pytest.approx(100, rel=0.01)


def _ccx_frequencies(folder, text: str) -> tuple[np.ndarray, list[np.ndarray]]:
    need("ccx")
    (folder / "freq.inp").write_text(text)
    subprocess.run(["ccx", "-i", "freq"], cwd=folder, capture_output=True, check=True, timeout=120)
    return cv.ccx_modes(folder / "freq.dat")


def test_plate_deck_gives_ccx_suite_frequencies(tmp_path):
    # CalculiX's own test/dloadlin20f.dat.ref for the 300 x 30 x 1 plate, 15 C3D20: 59.58324, 374.3339
    # rad/s (printed to 7 digits); the two first modes bend in z
    omega, shapes = _ccx_frequencies(tmp_path, cv.plate_deck_text(frequency=4))
    np.testing.assert_allclose(omega[:2], [59.58324, 374.3339], rtol=2e-6)  # both printed to 7 digits
    assert cv.bending_modes(shapes) == [0, 1]


@pytest.mark.parametrize("mesh", ["hex20", "tet10"])
def test_strip_frequencies_match_the_beam(tmp_path, mesh):
    # L/h = 300, nu = 0: Euler-Bernoulli within its O((beta h/L)^2) shear and rotary-inertia terms and
    # the mesh (measured +0.03/+0.07% hex20, -0.08/+0.07% tet10 at nx = 40: 0.2% allowed); the in-plane
    # mode (3 times mode 1's frequency, b = 3h) is not taken for a bending mode
    L, b, h = cv.strip_size(300)
    text = cv.deck_text(*(cv.strip_hex20 if mesh == "hex20" else cv.strip_tet10)(300, 40),
                        "C3D20" if mesh == "hex20" else "C3D10", frequency=4)
    omega, shapes = _ccx_frequencies(tmp_path, text)
    masters = cv.bending_modes(shapes)
    assert masters == [0, 2]
    theory = [cv.linear_frequency(r, cv.E, b * h**3 / 12, cv.RHO, b * h, L) for r in (1, 2)]
    np.testing.assert_allclose(omega[masters], theory, rtol=2e-3)
    assert omega[1] / omega[0] == pytest.approx(3.0, rel=2e-3)
