"""Damping operators and ratios (stepnf.forced.damping) and the bad inputs of the forced-response API:
no damping, overdamped, a zero forcing level, a load that does not excite the master, a bad range."""
from __future__ import annotations

import json

import numpy as np
import pytest

from stepnf.dpim.parametrisation import DPIM
from stepnf.errors import NumericalError, SceneError
from stepnf.forced.damping import Damping, damped_frequency, damping_ratio
from stepnf.forced.frc import forced_responses
from stepnf.forced.spec import DampingSpec
from helpers.systems import batch_force, modes, two_dof


@pytest.fixture(scope="module")
def system():
    M, K, G, H = two_dof()
    w, V = modes(K, M)
    res = DPIM(batch_force(K, G, H), K, M).parametrise(V[:, 0], w[0], 7, probe=1.0)
    return M, K, w, V, res


def test_rayleigh_and_modal_operators(system):
    """Rayleigh: ``C v = alpha M v + beta K v``, ratio ``alpha/(2w) + beta w/2`` on every mode; modal: C damps
    the masters only (``V^T C V = diag(2 xi w)`` on them, 0 elsewhere). Exact algebra: round-off (1e-13)."""
    M, K, w, V, _ = system
    ray = Damping(DampingSpec(rayleigh=(0.02, 0.003)), M, K, [(V[:, 0], w[0])])
    modal_c = V.T @ ray(V.T).T
    xi = np.array([damping_ratio(ray.spec, wi) for wi in w])
    assert np.allclose(modal_c, np.diag(2 * xi * w), atol=1e-13)
    assert ray.ratio(0) == pytest.approx(0.02 / (2 * w[0]) + 0.003 * w[0] / 2, rel=1e-15)
    modal = Damping(DampingSpec(modal=(0.05,)), M, K, [(V[:, 0], w[0])])
    assert np.allclose(V.T @ (modal @ V.T).T, np.diag([2 * 0.05 * w[0], 0.0]), atol=1e-13)
    assert modal(V[:, 0]).shape == (2,)
    assert damped_frequency(2.0, 0.6) == pytest.approx(1.6, rel=1e-15)


@pytest.mark.parametrize("spec, key", [
    (DampingSpec(modal=0.0), "analysis.damping.modal"),
    (DampingSpec(rayleigh=(0.0, 0.0)), "analysis.damping.rayleigh"),
    (DampingSpec(), "analysis.damping"),
    (DampingSpec(modal=1.2), "analysis.damping.modal"),
    (DampingSpec(rayleigh=(-0.1, 0.01)), "analysis.damping.rayleigh"),
], ids=["modal-zero", "rayleigh-zero", "none", "modal-overdamped", "negative"])
def test_no_damping_or_overdamped_is_refused(system, spec, key):
    M, K, w, V, _ = system
    with pytest.raises(SceneError) as e:
        Damping(spec, M, K, [(V[:, 0], w[0])])
    assert e.value.key == key
    assert "\n" not in str(e.value)


def test_rayleigh_overdamped_mode_is_refused(system):
    """alpha large enough that the master's xi = alpha / (2 w) >= 1: refused when its FRC is asked."""
    M, K, w, V, res = system
    d = Damping(DampingSpec(rayleigh=(2.5 * w[0], 0.0)), M, K, [(V[:, 0], w[0])])
    with pytest.raises(SceneError, match="overdamped"):
        forced_responses(res, d, [({"kappa": 0.01}, 0.01)], (0.9, 1.2), valid_to=1.0)


def test_bad_forcing_levels_and_range(system):
    M, K, w, V, res = system
    d = Damping(DampingSpec(modal=0.01), M, K, [(V[:, 0], w[0])])
    with pytest.raises(SceneError) as e:
        forced_responses(res, d, [({"kappa": 0.0}, 0.0)], (0.9, 1.2), valid_to=1.0)
    assert e.value.key == "analysis.forcing.modal"
    ortho = M @ V[:, 1]  # excites mode 1 only: phi_0^T F = 0
    with pytest.raises(SceneError, match="does not excite the master") as e:
        forced_responses(res, d, [({"load": 1.0}, ortho)], (0.9, 1.2), valid_to=1.0)
    assert e.value.key == "analysis.forcing.load"
    with pytest.raises(SceneError) as e:
        forced_responses(res, d, [({"kappa": 0.01}, 0.01)], (1.2, 0.9), valid_to=1.0)
    assert e.value.key == "analysis.forcing.frequency_range"


def test_a_load_and_its_sign(system):
    """A load with a component on the master: f1(rho -> 0) = phi^T F, and -F gives the same curve (a phase
    of pi); ``modal_force`` keeps the sign given. Same arithmetic on a negated vector: identical to 1e-13."""
    M, K, w, V, res = system
    d = Damping(DampingSpec(modal=0.01), M, K, [(V[:, 0], w[0])])
    F = np.array([0.004, -0.002])
    a, b = forced_responses(res, d, [({"load": 1.0}, F), ({"load": -1.0}, -F)], (0.9, 1.2), valid_to=1.0)
    assert a.modal_force == pytest.approx(float(V[:, 0] @ F), rel=1e-15) == -b.modal_force
    assert np.allclose(a.Omega, b.Omega, rtol=1e-13) and np.allclose(a.amplitude, b.amplitude, rtol=1e-13)
    js = json.loads(json.dumps(a.to_json()))  # plain JSON types only
    assert js["load"] == 1.0 and len(js["Omega"]) == len(js["amplitude"]) == len(js["stable"])
    assert set(js["peak"]) == {"amplitude", "Omega", "rho", "valid"}


def test_unbounded_response_is_a_numerical_error(system):
    """A forcing so strong the order-7 series never balances it within 1e3 linear peaks: exit 3, naming
    the stage."""
    M, K, w, V, res = system
    d = Damping(DampingSpec(modal=1e-6), M, K, [(V[:, 0], w[0])])
    with pytest.raises(NumericalError, match="forced response of mode 4"):
        forced_responses(res, d, [({"kappa": 10.0}, 10.0)], (0.9, 1.2), valid_to=1.0, mode=4)


def test_a_level_that_overflows_the_series_is_a_numerical_error():
    """Duffing (w = 1, g = 0.4, order 15), a forcing level of 1e14: the linear peak at rho = 5e15, the series'
    rho^32 overflows from the scan's first point (a millionth of it): a NumericalError naming the stage (exit 3;
    the pipeline keeps the backbone and gives the master a reason), not an IndexError on the empty scan (an
    internal error, exit 1, before the fix)."""
    K1, M1, phi = np.array([[1.0]]), np.array([[1.0]]), np.array([1.0])
    res = DPIM(lambda U: U + 0.4 * U ** 3, K1, M1).parametrise(phi, 1.0, 15, probe=1.0)
    d = Damping(DampingSpec(modal=0.01), M1, K1, [(phi, 1.0)])
    with np.errstate(over="ignore", invalid="ignore"), pytest.raises(NumericalError, match="forced response of "
                                                                                             "mode 2.*overflows"):
        forced_responses(res, d, [({"kappa": 1e14}, 1e14)], (0.9, 1.2), valid_to=1.0, mode=2)
