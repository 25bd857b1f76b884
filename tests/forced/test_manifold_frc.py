"""Forced responses on manifolds of several modes (stepnf.forced.manifold_frc, stepnf.forced.manifold_system).

References: the linear oscillator's closed-form peak; the single-master FRC (stepnf.forced.frc, which keeps the
manifold's nonlinear damping terms); the full model's FRC by shooting continuation (stepnf.verify.forced_continuation
.full_frc, DOP853 rtol 1e-11); the Floquet multipliers of the full model's uncoupled response (its x1 = 0 is exact:
a damped Mathieu equation, DOP853 rtol 1e-12); the full model's period-doubled steady states by shooting (rtol
1e-12). System: the exact 1:2 pair of tests/dpim/test_branches.py, ``x1'' + x1 + 2 x1 x2 = 0``, ``x2'' + 4 x2 +
x1^2 = 0`` (M = I), modal damping xi = 0.01 on both modes, order 11 (orders 9 and 11 give peaks and folds equal to
1e-6: the truncation is far below the tolerances below, which come from the damping and forcing taken to first
order: projected on the manifold, stepnf.forced.manifold_projection).
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, root

from stepnf.dpim.multimode.manifold import parametrise_manifold
from stepnf.dpim.parametrisation import DPIM
from stepnf.errors import SceneError
from stepnf.forced.damping import Damping
from stepnf.forced.frc import FRC, forced_responses
from stepnf.forced.manifold_frc import manifold_damping, manifold_forced_responses
from stepnf.forced.manifold_projection import Projection
from stepnf.forced.manifold_system import ForcedSystem
from stepnf.forced.spec import DampingSpec
from stepnf.report.frc_table import frc_lines
from helpers.systems import batch_force, modes, sym, two_dof

XI = 0.01


@pytest.fixture(scope="module")
def pair():
    """The exact 1:2 pair: (M, K, forces, manifold of modes 0 and 1 at order 11, damping)."""
    K, M = np.diag([1.0, 4.0]), np.eye(2)
    f = batch_force(K, sym((2, 2, 2), {(0, 0, 1): 1.0}), np.zeros((2, 2, 2, 2)))
    man = parametrise_manifold(DPIM(f, K, M), [0, 1], np.eye(2), np.array([1.0, 2.0]), 11, probe=1.0)
    d = Damping(DampingSpec(modal=XI), M, K, [(np.eye(2)[0], 1.0), (np.eye(2)[1], 2.0)])
    return M, K, f, man, d


def curve(man, d, kappa, mode, rng=(0.85, 1.15)):
    return manifold_forced_responses(man, d, [({"kappa": kappa}, kappa)], rng, mode, master=mode)[0]


# ------------------------------------------------------------ (a) one mode
def test_one_mode_linear_limit_and_single_master_code():
    """two_dof's mode 0 on its one-mode manifold (order 11), xi = 0.01.

    Linear limit (kappa = 1e-7, A = 5e-6): the damped eigenvalue and the forcing ``g / (4 w_d)`` give the exact
    linear peak ``k / (2 xi sqrt(1 - xi^2) w^2)`` (stepnf.forced.manifold_system: no O(xi^2) left), at ``w_d``;
    what is left is the nonlinear ``O(A^2)`` bend of the peak, -0.17 A^2 = -4.2e-12 measured (the single-master code
    gives the same to 1e-15; before the projection the leading-order terms' +0.18 A^2 cancelled it to 4e-13); bound
    1e-9 (the projection's terms vanish at A = 0: the linear limit is the damped eigenvalue's, unchanged). With
    ``g / (4 w)`` (the undamped frequency) it would be low by xi^2 / 2 = 5e-5.

    Against the single-master code (stepnf.forced.frc) at kappa = 1e-3 and 5e-3 (peaks A = 0.05, 0.25): that code
    keeps the conservative manifold's nonlinear damping through its Gram matrices; here the damping and forcing
    projected on the manifold (stepnf.forced.manifold_projection) do the same, so the peaks agree to 6.9e-8 and
    1.43e-6 (2.8e-5 A^2 and 2.3e-5 A^2; not traced further), their
    frequencies to 1.4e-10 and 3.1e-8 (5e-7 A^2). Bounds: 5e-5 A^2 and 1e-6 A^2. At leading order only (before the
    projection) they differed by 0.18 A^2 (4.6e-4 and 1.12e-2) and 0.004 A^2 in Omega.
    """
    M, K, G, H = two_dof()
    f = batch_force(K, G, H)
    w, V = modes(K, M)
    man = parametrise_manifold(DPIM(f, K, M), [0], V[:, [0]], w[[0]], 11, probe=1.0)
    d = Damping(DampingSpec(modal=XI), M, K, [(V[:, 0], w[0])])
    lin = curve(man, d, 1e-7, 0, (0.8, 1.3))
    closed = 1e-7 / (2 * XI * np.sqrt(1 - XI ** 2) * w[0] ** 2)
    assert lin.peak["amplitude"] == pytest.approx(closed, rel=1e-9)
    assert lin.peak["Omega"] == pytest.approx(w[0] * np.sqrt(1 - XI ** 2), rel=1e-9)
    assert lin.stable.all() and not lin.folds and not lin.peak_outside_range
    res = DPIM(f, K, M).parametrise(V[:, 0], w[0], 11, probe=1.0)
    for kappa in (1e-3, 5e-3):
        mine = curve(man, d, kappa, 0, (0.8, 1.3))
        ref = forced_responses(res, d, [({"kappa": kappa}, kappa)], (0.8, 1.3))[0]
        A = ref.peak["amplitude"]
        assert mine.peak["amplitude"] == pytest.approx(A, rel=5e-5 * A ** 2)
        assert mine.peak["Omega"] == pytest.approx(ref.peak["Omega"], rel=1e-6 * A ** 2)


@pytest.mark.slow
def test_json_has_the_single_master_keys(pair):
    """The curve's JSON carries every key of stepnf.forced.frc.FRC.to_json (a one-piece curve), plus the manifold's
    modes, every mode's amplitudes and the branch points."""
    M, K, f, man, d = pair
    c = curve(man, d, 0.005, 0)
    single = FRC({"kappa": 0.005}, 1.0, np.zeros(2), np.zeros(2), np.zeros(2), None, np.ones(2, bool),
                 np.ones(2, bool), np.zeros(2, int), {}, [], None, XI, 1.0).to_json()
    js = c.to_json()
    assert set(single) <= set(js) and js["manifold"] == [0, 1]
    assert set(js["amplitudes"]) == {"0", "1"} and len(js["amplitudes"]["1"]) == len(js["Omega"])
    assert js["amplitudes"]["0"] == js["amplitude"]
    assert c.peak["stable"] and c.peak_stable == c.peak and "peak_stable" not in js  # (stable peak: said once)


# ------------------------------------------- (b) 1:2, forcing the lower mode
@pytest.mark.slow
@pytest.mark.parametrize("kappa", [0.008, 0.01])
def test_lower_mode_against_the_full_model(pair, kappa):
    """Forcing mode 0 (F = kappa M phi_0): the peak (A = 0.23 and 0.30, mode 1 at a third of it) and both folds
    against the full model's FRC (full_frc, shooting to rtol 1e-11). With the damping and forcing projected on the
    manifold (stepnf.forced.manifold_projection): peak A low by 0.147% and 0.104%, Omega 7.4e-5 and 6.6e-5
    high; folds' Omega 6.4e-6, 8e-7 and 1.1e-5, 9e-8; folds' A 0.33%, 1.2% and 0.22%, 1.5% (a fold's A is where
    dA/dOmega is infinite: its Omega is the sharp number). Orders 9 and 11 agree to 1e-6 (truncation), and the
    projection's order 5 leaves 6e-5 of the peak; the rest (0.1 .. 0.15%) was not traced further (terms of second
    order in the damping and forcing are the candidates). Bounds: A 0.4%, Omega 2e-4, folds' Omega 5e-5, folds' A
    2.5%. At leading order only (before the projection) the peak's A was low by 4.75% and 6.7%, its Omega 2.3e-3
    and 4.6e-3 off, the folds' Omega 6.8e-4, 2.1e-3 and 8.4e-4, 4.4e-3: the nonlinear damping and forcing terms
    are O(A) relative through the quadratic 1:2 coupling. Stability between the peaks (Omega = 0.99 .. 1.01, A ~
    0.1): unstable at 0.998 and 1.0 in both (kappa 0.008: the full model's largest multiplier 1.001, 1.0014),
    stable at 0.99 and 1.01."""
    from stepnf.verify.forced_continuation import full_frc

    M, K, f, man, d = pair
    c = curve(man, d, kappa, 0)
    phi = np.eye(2)[0]
    ref = full_frc(M, d(np.eye(2)), lambda x: f(x[None])[0], kappa * phi, phi, 1.0, (0.85, 1.15))
    A = ref.peak["amplitude"]
    assert c.peak["amplitude"] == pytest.approx(A, rel=4e-3)
    assert c.peak["Omega"] == pytest.approx(ref.peak["Omega"], rel=2e-4)
    assert len(c.folds) == len(ref.folds) == 2
    for mine, full in zip(sorted(c.folds, key=lambda x: x["Omega"]), sorted(ref.folds, key=lambda x: x["Omega"])):
        assert mine["Omega"] == pytest.approx(full["Omega"], rel=5e-5)
        assert mine["amplitude"] == pytest.approx(full["amplitude"], rel=0.025)
    assert c.peak["stable"] and c.peak["valid"]
    # between the two peaks the response loses its stability (a Hopf bifurcation: quasi-periodic motion, the
    # classical 1:2 picture): the ROM's stability at four points there is the full model's (Floquet multipliers)
    from stepnf.verify.forced_orbits import ForcedShooting

    sh = ForcedShooting(M, d(np.eye(2)), lambda x: f(x[None])[0], kappa * phi, phi=phi, rtol=1e-11)
    seen = set()
    for Om in (0.99, 0.9985, 1.0, 1.01):
        i = int(np.argmin(np.abs(c.Omega - Om) + 10 * (c.amplitude > 0.13)))
        z = np.concatenate([c.zeta[i], c.zeta[i].conj()])
        o = sh.orbit(c.Omega[i], np.concatenate([man.displacement(z), man.velocity(z)]))
        assert bool(c.stable[i]) == o.stable and c.amplitude[i] == pytest.approx(o.amplitude, rel=0.3 * o.amplitude)
        seen.add(o.stable)
    assert seen == {True, False}


# ------------------------------------------ (c) 1:2, forcing the higher mode
def floquet(C00: float, kappa: float, Om: float) -> float:
    """``trace + 1 + det`` of the monodromy of ``x1'' + C00 x1' + (1 + 2 x2(t)) x1 = 0``, ``x2`` the full model's
    exact uncoupled response to ``kappa cos(Om t)``: zero where a multiplier crosses -1 (period doubling)."""
    X = kappa / (4.0 - Om ** 2 + 2j * XI * 2.0 * Om)

    def rhs(t, y):
        s = 1 + 2 * (X * np.exp(1j * Om * t)).real
        return [y[1], -C00 * y[1] - s * y[0], y[3], -C00 * y[3] - s * y[2]]
    Y = solve_ivp(rhs, (0, 2 * np.pi / Om), [1, 0, 0, 1], method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
    mono = Y.reshape(2, 2).T
    return float(np.trace(mono) + 1 + np.linalg.det(mono))


def doubled_orbit(f, C, kappa: float, Om: float, y0: np.ndarray) -> np.ndarray:
    """The full model's steady state of period 4 pi / Om under ``kappa e_1 cos(Om t)`` by shooting from ``y0``:
    the amplitudes ``(max - min) / 2`` of x1 and x2."""
    T, F = 4 * np.pi / Om, np.array([0.0, kappa])

    def rhs(t, y):
        return np.concatenate([y[2:], -C @ y[2:] - f(y[None, :2])[0] + F * np.cos(Om * t)])

    def run(y, dense=False):
        return solve_ivp(rhs, (0, T), y, method="DOP853", rtol=1e-12, atol=1e-14, dense_output=dense)
    r = root(lambda y: run(y).y[:, -1] - y, y0, tol=1e-13)
    assert r.success and np.abs(run(r.x).y[:, -1] - r.x).max() < 1e-10
    x = run(r.x, True).sol(np.linspace(0, T, 4001))[:2]
    return (x.max(axis=1) - x.min(axis=1)) / 2


def saturated(man, d, kappa: float, c, Om: float) -> np.ndarray:
    """The steady state on the stable coupled branch of ``c`` at exactly ``Om`` (Newton from its nearest point):
    every mode's A."""
    from stepnf.dpim.multimode.measures import OrbitMeasure

    q = np.flatnonzero((c.segment == 1) & c.stable)
    i = q[np.argmin(np.abs(c.Omega[q] - Om))]
    s = ForcedSystem(man, [1, 2], 1, manifold_damping(man, d), np.array([0.0, kappa]),
                     Projection(man, d.K, d, [1, 2], 1).forced(np.array([0.0, kappa])))
    u = s.at_frequency(Om, s.point(c.zeta[i], c.Omega[i]))
    return OrbitMeasure(man, [1, 2]).amplitudes(s.zeta(u)), s.zeta(u)


@pytest.mark.slow
def test_higher_mode_pitchfork_and_saturation(pair):
    """Forcing mode 1 (F = kappa M phi_1, kappa = 0.01 and 0.02). The uncoupled response (mode 0 at rest: exact,
    the linear peak 2 |zeta_1| = kappa / (2 xi w1 w_d1) = 0.125 and 0.25) loses its stability at two pitchforks
    (branch points), where the coupled branch (Nayfeh & Mook's saturation) is born and which it joins.

    Pitchforks' Omega against the Floquet multipliers of the full model's uncoupled response (a multiplier at -1):
    measured 3.6e-8, 3.3e-7 (kappa 0.01), 2.1e-7, 8.5e-7 (0.02) with the projected damping and forcing
    (stepnf.forced.manifold_projection: the forcing's work through the quadratic terms of V, harmonic 2 of mode 0);
    at leading order only they were 4.9e-4, 4.5e-4, 9.9e-4, 8.9e-4. Bound 3e-6.

    Coupled branch against the full model's period-doubled steady states (shooting from the ROM's point) at Omega =
    1.98 and 2.02: A of mode 0 within 0.055% (measured 0.052, 0.055%, at leading order 0.63, 0.69%; bound 0.2%), of
    the saturated mode 1 within 2.4% (measured +2.1, -2.4%, at leading order 1.9 .. 5.1%; bound 3.5%).

    Saturation: at Omega = 2 the forced mode's A on the stable coupled branch is 0.0205 and 0.0224 (its order-2 value
    ``2 |lam_0 - i Omega / 2| / |c|`` does not depend on kappa at all; the orders above 2 add O(A_0^2) ~ 0.04: 9%
    measured (5.9% with the projected terms); the full model: 6%) while the uncoupled response doubles; bound 12%.
    """
    M, K, f, man, d = pair
    C = d(np.eye(2))
    sat = []
    for kappa in (0.01, 0.02):
        c = curve(man, d, kappa, 1, (0.85, 1.2))
        assert set(c.segment.tolist()) == {0, 1} and len(c.branch_points) == 2
        main = c.segment == 0
        assert np.abs(c.amplitudes[main, 0]).max() < 1e-15  # the uncoupled response: mode 0 at rest
        assert c.peak["amplitude"] == pytest.approx(kappa / (2 * XI * 2.0 * 2.0 * np.sqrt(1 - XI ** 2)), rel=1e-9)
        assert c.peak["segment"] == 0 and not c.peak["stable"]
        # the stable peak (what a sweep reaches): on the coupled branch (A1 = 0.068 and 0.135 at Omega = 2.057 and
        # 2.105), the largest stable A of the curve's points refined (the points are 1e-2 A apart at most), in the
        # JSON and under the level's line of the printed table; before the change there was no such key
        ps = c.peak_stable
        top = c.amplitude[c.stable].max()
        assert ps["stable"] and top <= ps["amplitude"] <= top * 1.01 and ps["amplitude"] < 0.6 * c.peak["amplitude"]
        assert ps["segment"] == 1 and c.to_json()["peak_stable"] == ps
        mode = SimpleNamespace(frc=[c.to_json()], index=1, label=None, omega=2.0)
        assert any(f"stable peak A = {ps['amplitude']:.4e}" in line for line in frc_lines(mode))
        for bp in c.branch_points:
            ref = brentq(lambda Om: floquet(C[0, 0], kappa, Om), 0.99 * bp["Omega"], 1.01 * bp["Omega"], xtol=1e-13)
            assert bp["Omega"] == pytest.approx(ref, rel=3e-6)
        between = main & (c.Omega > c.branch_points[0]["Omega"] + 1e-3) & (c.Omega < c.branch_points[1]["Omega"] - 1e-3)
        assert between.any() and not c.stable[between].any()  # parametric resonance: unstable between the pitchforks
        if kappa == 0.02:
            for Om in (1.98, 2.02):
                A, z = saturated(man, d, kappa, c, Om)
                zz = np.concatenate([z, z.conj()])
                full = doubled_orbit(f, C, kappa, Om, np.concatenate([man.displacement(zz), man.velocity(zz)]))
                assert A[0] == pytest.approx(full[0], rel=2e-3)
                assert A[1] == pytest.approx(full[1], rel=0.035)
        sat.append(saturated(man, d, kappa, c, 2.0)[0])
    assert sat[1][1] == pytest.approx(sat[0][1], rel=0.12)
    assert sat[1][0] > 1.3 * sat[0][0]  # mode 0 takes the extra energy


# ------------------------------------------------------------- (d) failures
def test_a_forcing_that_excites_no_resonant_mode_is_refused(pair):
    """A load on mode 1 only (k = 2) for master 0 (k = 1): nothing forced at the fundamental resonance of mode 0;
    a SceneError naming analysis.forcing.load. A frequency range without 0 < lo < hi: naming its key."""
    M, K, f, man, d = pair
    with pytest.raises(SceneError) as e:
        manifold_forced_responses(man, d, [({"load": 1.0}, np.array([0.0, 1.0]))], (0.9, 1.1), 0, master=0)
    assert e.value.key == "analysis.forcing.load" and "excites no mode" in e.value.message
    with pytest.raises(SceneError) as e:
        manifold_forced_responses(man, d, [({"kappa": 0.01}, 0.01)], (1.1, 0.9), 0, master=0)
    assert e.value.key == "analysis.forcing.frequency_range"
