"""The energy-conserving integrator (stepnf.verify.integrate) against exact and independent periodic orbits.

* Duffing ``x'' + w^2 x + g x^3 = 0`` from rest at ``A``: exact period ``4 K(m) / W`` (complete
  elliptic integral); second order of the scheme measured as a rate, Richardson to 1e-8.
* A 2-dof system with quadratic and cubic terms (tests/helpers/systems.two_dof): the frequency of the
  shooting orbit (stepnf.verify.periodic, DOP853 rtol 1e-12) recovered by integrating from its initial state.
* Initial states from DPIM at order N (stepnf.verify.command.Chart): the orbit stays closer to the
  manifold as N grows.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ellipk

from stepnf.dpim.parametrisation import DPIM
from stepnf.errors import NumericalError
from stepnf.verify.integrate import EnergyConserving, cubic_potential, measure, romberg, steps_per_period
from stepnf.verify.periodic import Shooting
from stepnf.verify.command import by_integration, by_shooting
from helpers.systems import batch_force, modes, two_dof

W0 = 1.3


def duffing_exact(g, A):
    m = g * A * A / (2 * (W0 ** 2 + g * A * A))
    return np.pi * np.sqrt(W0 ** 2 + g * A * A) / (2 * ellipk(m))


def duffing(g, jacobian="auto"):
    f = lambda U: W0 ** 2 * U + g * U ** 3  # noqa: E731
    tan = lambda x: np.diag(W0 ** 2 + 3 * g * x ** 2)  # noqa: E731
    return f, EnergyConserving(np.eye(1), np.eye(1) * W0 ** 2, f, tangent=tan, jacobian=jacobian)


@pytest.mark.parametrize("g,A", [(0.4, 0.2), (0.4, 2.0), (-0.4, 1.5)])
@pytest.mark.parametrize("jacobian", ["auto", "tangent"])
def test_duffing_period(g, A, jacobian):
    """Richardson over dt, dt/2 reaches the exact frequency to 1e-8; the raw levels are second order.

    steps_per_period(1e-8) gives 681 steps per period on the coarse level; the extrapolated error is
    O(dt^4) plus the Hermite interpolation of the crossings (O(dt^4) too): measured 2.0e-9 (A = 0.2),
    5.2e-9 (A = 2, w_NL/w - 1 = 0.44), 9.5e-10 (softening): bound 1e-8, the requested accuracy. The
    raw levels' error ratio is 4 (second order) up to the next term's share, O(dt^2) ~ 1e-4 relative
    plus the O(dt^4) interpolation term: bound 1%. Energy: exact for a cubic f up to Newton's stopping
    (increment <= 1e-12 of the state) accumulated over ~2000 steps: measured <= 3.4e-12, bound 1e-10.
    """
    f, integ = duffing(g, jacobian)
    exact = duffing_exact(g, A)
    m = measure(integ, np.array([A]), np.array([0.0]), watch=np.array([1.0]), omega=exact, rtol=1e-8,
                level=0.0, potential=cubic_potential(f))
    assert abs(m.omega / exact - 1) < 1e-8
    e1, e2 = (d["omega"] / exact - 1 for d in m.levels)
    assert e1 / e2 == pytest.approx(4.0, rel=1e-2)
    assert abs(e2) <= m.omega_error * 1.01 + 1e-15  # the estimate bounds the finest raw level's error
    assert m.amplitude == pytest.approx(A, rel=1e-8)  # energy conserved: the turning points stay at +-A
    assert max(d["energy_drift"] for d in m.levels) < 1e-10
    if jacobian == "auto":
        assert all(d["tangent_steps"] == 0 for d in m.levels)  # modified Newton with K sufficed
        assert sum(d["newton_iterations"] for d in m.levels) <= 6 * sum(d["steps"] for d in m.levels)


def test_romberg_and_step_rule():
    """Romberg removes dt^2 and dt^4 exactly; the step rule inverts the linear scheme's error terms."""
    vals = [1 + 0.3 * h ** 2 - 0.7 * h ** 4 for h in (0.1, 0.05, 0.025)]
    assert romberg(vals)[0] == pytest.approx(1.0, abs=1e-14)  # round-off of O(1) sums
    assert romberg(vals[:2])[0] == pytest.approx(1 - 0.7 * 0.1 ** 4 * (1 / 16 * 4 - 1) / 3, abs=1e-14)
    x = 1.5 * 2 * np.pi / steps_per_period(1e-8)
    assert x ** 4 / 320 <= 1e-8 * 1.5 ** 4 * 1.01


def test_two_dof_against_shooting():
    """From the shooting orbit's initial state (exactly periodic) the integration gives its frequency.

    Shooting is exact to ~1e-12 (test_periodic). The integration at rtol = 1e-8 (Duffing: measured
    <= 5e-9): measured 4e-10 (A = 0.5), 1.6e-9 (A = 0.8, w_NL/w - 1 = 11%): bound 1e-8.
    """
    M, K, G, H = two_dof()
    f = batch_force(K, G, H)
    w, V = modes(K, M)
    sh = Shooting(M, K, lambda x: f(x[None])[0], V[:, 0], w[0])
    integ = EnergyConserving(M, K, f)
    for A in (0.5, 0.8):
        orb = sh.at_amplitude(A)
        m = measure(integ, orb.x0, np.zeros(2), watch=M @ V[:, 0], omega=orb.omega, rtol=1e-8)
        assert abs(m.omega / orb.omega - 1) < 1e-8, (A, m.omega / orb.omega - 1)
        assert m.amplitude == pytest.approx(A, rel=1e-7)  # turning points of a periodic orbit: O(dt^4) interpolation


def test_dpim_initial_states_stay_closer_as_order_grows():
    """Started on the order-N manifold at A = 0.5, the orbit's largest distance from it falls with N.

    The invariance defect is O(rho^(N+1)), so the distance falls by roughly A^2 per order step until
    the scheme's own O((w dt)^2) deviation (~1e-8 here at rtol 1e-8) is reached; measured
    3.4e-4 (N = 3), 6.6e-5 (5), 2.4e-5 (7), 1.3e-5 (9). The frequency from the order-9 state agrees
    with shooting to 1.5e-7 (measured; bound 1e-6): not the integration's error (1e-8, Duffing) but the
    quasi-periodic motion of a state ~1e-6 off the true manifold, which moves the crossings.
    """
    M, K, G, H = two_dof()
    f = batch_force(K, G, H)
    w, V = modes(K, M)
    res = DPIM(f, K, M).parametrise(V[:, 0], w[0], 11, probe=1.0)
    dist = []
    for N in (3, 5, 7, 9):
        chk = by_integration(res.truncated(N), K, M, f, 0.5, rtol=1e-8)
        dist.append(chk.distance)
    assert all(b < a for a, b in zip(dist, dist[1:])), dist
    assert dist[0] / dist[-1] > 10, dist
    ref = by_shooting(res, K, M, lambda x: f(x[None])[0], 0.5)
    assert ref.distance < dist[-1]  # the true periodic orbit lies closer still
    chk = by_integration(res.truncated(9), K, M, f, 0.5, rtol=1e-8)
    assert chk.omega_check == pytest.approx(ref.omega_check, rel=1e-6)


def test_divergence_is_a_numerical_error():
    """Softening Duffing beyond the separatrix (A^2 > w^2/|g|): the motion escapes; an error naming the run."""
    f, integ = duffing(-0.4, "modified")
    with pytest.raises(NumericalError, match="escape test"):
        integ.run(np.array([3.0]), np.array([0.0]), 0.01, 5000, watch=np.array([1.0]), what="escape test")
