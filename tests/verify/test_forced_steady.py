"""Forced steady states by time integration (stepnf.verify.forced_steady, the FE models' reference) against
shooting (stepnf.verify.forced_orbits) on the forced Duffing oscillator, and Aitken's extrapolation."""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.verify.forced_orbits import ForcedShooting
from stepnf.verify.forced_steady import ForcedIntegration, steady_amplitude

W, XI, G, K = 1.3, 0.02, 0.4, 0.03
#: The peak of this Duffing's FRC (stepnf.verify.forced_continuation.full_frc over [0.95, 1.2] w, refined
#: by Brent on the arclength): Omega = 1.3213215916, A = 0.43713217.
PEAK = 1.3213215915682024


def test_aitken_is_exact_on_a_geometric_sequence():
    """``A_k = A + c r^k``: Aitken's estimate is ``A`` to round-off, and the spread of the last three is ~0."""
    k = np.arange(8)
    A, spread = steady_amplitude(0.7 + 0.05 * 0.8 ** k)
    assert A == pytest.approx(0.7, abs=1e-14) and spread < 1e-14


@pytest.mark.parametrize("steps,tol", [(64, 2e-3), (128, 6e-4)])
def test_duffing_peak_steady_state_against_shooting(steps, tol):
    """At the FRC's peak, started 2% off the steady state: 25 periods and Aitken's extrapolation give the
    shooting's amplitude within the midpoint rule's O((w dt)^2) error (its frequency error (w dt)^2 / 12 =
    1e-3 at 64 steps, 2.4e-4 at 128; measured 4.0e-4 and 2.5e-4 in A: at the peak the detuning enters at
    second order, the scheme's change of the effective forcing and damping at first); the last period alone
    is still 1.1e-3 off (the transient, exp(-xi w t) = 0.04 after 25 periods)."""
    f = lambda x: W ** 2 * x + G * x ** 3  # noqa: E731
    M, C = np.eye(1), 2 * XI * W * np.eye(1)
    sh = ForcedShooting(M, C, f, np.array([K]), tangent=lambda x: np.diag(W ** 2 + 3 * G * x ** 2), phi=np.array([1.0]))
    ref = sh.orbit(PEAK, np.array([0.0, 0.437 * PEAK]))  # the upper branch: in quadrature with the force
    assert ref.amplitude == pytest.approx(0.43713217, rel=1e-7)
    integ = ForcedIntegration(M, C, np.eye(1) * W ** 2, lambda U: W ** 2 * U + G * U ** 3, np.array([K]))
    run = integ.run(1.02 * ref.x0, 1.02 * ref.v0, PEAK, np.array([1.0]), periods=25, steps=steps)
    assert run.amplitude == pytest.approx(ref.amplitude, rel=tol)
    assert abs(run.amplitudes[-1] / ref.amplitude - 1) > abs(run.amplitude / ref.amplitude - 1)
    assert run.spread < 1e-4 * ref.amplitude
