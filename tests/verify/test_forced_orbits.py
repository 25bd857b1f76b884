"""Forced, damped steady states of the full model (stepnf.verify.forced_orbits, forced_continuation): the
independent reference of the FRC, against closed forms.

* Linear damped oscillator: the steady state ``X = k / (w^2 - Omega^2 + 2 i xi w Omega)`` exactly (to
  DOP853's ``rtol = 1e-11`` over one period).
* Forced Duffing ``x'' + 2 xi w x' + w^2 x + g x^3 = k cos(Omega t)``: the continuation's peak against the
  first-order harmonic balance (HB) closed form; their difference is HB's truncation, which must vanish as
  ``a^4`` at light forcing (a rate, not a point).
* Folds: the amplitude-fixed solve (Omega unknown) lands on the continuation's refined folds, where a
  Floquet multiplier is +1; the branch between the folds is unstable.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import fsolve

from stepnf.errors import NumericalError
from stepnf.verify.forced_continuation import full_frc, full_frc_peak
from stepnf.verify.forced_orbits import ForcedShooting, forced_orbit, forced_orbit_at_amplitude

W, XI, G = 1.3, 0.01, 0.4


def duffing(g=G):
    f = lambda x: W ** 2 * x + g * x ** 3  # noqa: E731
    tan = lambda x: np.diag(W ** 2 + 3 * g * x ** 2)  # noqa: E731
    return np.eye(1), 2 * XI * W * np.eye(1), f, tan


@pytest.mark.parametrize("Omega", [0.8, 1.3, 1.45])
@pytest.mark.parametrize("tangent", [True, False], ids=["tangent", "fd-jacobian"])
def test_linear_damped_oscillator_exact(Omega, tangent):
    """Linear: x(t) = Re(X e^{i Omega t}); the shooting's (x0, v0) and amplitude |X| to 1e-9 relative
    (DOP853 at rtol = 1e-11 over one period: measured 1e-12..1e-11; Newton converges in 1 step: linear)."""
    M, C, f, tan = duffing(0.0)
    k = 0.05
    orb = forced_orbit(M, C, f, np.array([k]), Omega, tangent=tan if tangent else None, phi=np.array([1.0]))
    X = k / (W ** 2 - Omega ** 2 + 2j * XI * W * Omega)
    assert orb.amplitude == pytest.approx(abs(X), rel=1e-9)
    assert np.allclose([orb.x0[0], orb.v0[0]], [X.real, -Omega * X.imag], rtol=0, atol=1e-9 * abs(X) * Omega)
    assert orb.residual < 1e-9 and orb.stable
    # Floquet multipliers of a linear oscillator: exp((-xi w +- i w_d) T), modulus exp(-xi w 2 pi / Omega)
    assert np.abs(orb.multipliers) == pytest.approx(np.exp(-XI * W * 2 * np.pi / Omega), rel=1e-7)


def hb_peak(k: float, g: float = G) -> tuple[float, float]:
    """First-order HB of the forced Duffing, ``x = a cos(Omega t - psi)``:
    ``a^2 [(w^2 - Omega^2 + 3 g a^2 / 4)^2 + (2 xi w Omega)^2] = k^2``; its peak (da/dOmega = 0) where
    ``w^2 - Omega^2 + 3 g a^2 / 4 = 2 xi^2 w^2``. Returned amplitude: ``a`` plus the third harmonic
    ``g a^3 / (4 (9 Omega^2 - w^2))`` (in phase at the extrema: ``A = (max - min) / 2 = a + a3``)."""
    def eqs(p):
        a, Om = p
        return [W ** 2 - Om ** 2 + 0.75 * g * a * a - 2 * XI ** 2 * W ** 2,
                a * a * ((2 * XI ** 2 * W ** 2) ** 2 + (2 * XI * W * Om) ** 2) - k * k]
    a0 = k / (2 * XI * W * W)
    a, Om = fsolve(eqs, [a0, np.sqrt(W ** 2 + 0.75 * g * a0 ** 2)], xtol=1e-13)  # 1e-13: far below the 1e-7 compared
    return a + g * a ** 3 / (4 * (9 * Om ** 2 - W ** 2)), Om


@pytest.mark.slow
def test_duffing_peak_against_harmonic_balance_rate():
    """The continuation's peak (A, Omega) against HB at k = 0.004, 0.008, 0.016 (a = 0.12 .. 0.48): HB's
    error is O(a^4) relative (the next harmonic's feedback on the fundamental), so the differences must
    fall as k^4 at fixed damping (a ~ k): slope of log(error) against log(k) within [3.4, 4.6]
    (measured 3.8..4.2 for both); the smallest level within 3e-7 (measured 1.5e-7, 1.1e-7)."""
    M, C, f, tan = duffing()
    ks = np.array([0.004, 0.008, 0.016])
    errA, errW = [], []
    for k in ks:
        A, Om = full_frc_peak(M, C, f, np.array([k]), np.array([1.0]), W, (0.97, 1.06), tangent=tan)
        a_hb, w_hb = hb_peak(k)
        errA.append(abs(A / a_hb - 1))
        errW.append(abs(Om / w_hb - 1))
    for err in (errA, errW):
        slope = np.polyfit(np.log(ks), np.log(err), 1)[0]
        assert 3.4 <= slope <= 4.6, (err, slope)
        assert err[0] < 3e-7, err


@pytest.mark.slow
def test_duffing_folds_amplitude_solve_and_stability():
    """k = 0.03 (a jump): two folds, the branch between them unstable, a Floquet multiplier +1 at each fold
    (to 1e-5: the fold is refined by Brent on Omega, whose flat extremum leaves ~1e-10 in Omega, ~1e-5 in
    the multiplier); the amplitude-fixed solve from the nearest continuation point lands on the fold's
    Omega (to 1e-9: both are converged shooting at rtol = 1e-11; measured 1e-14)."""
    M, C, f, tan = duffing()
    k = 0.03
    frc = full_frc(M, C, f, np.array([k]), np.array([1.0]), W, (0.9, 1.25), tangent=tan)
    assert len(frc.folds) == 2
    upper, lower = sorted(frc.folds, key=lambda p: -p["Omega"])
    assert upper["amplitude"] > lower["amplitude"]
    # the peak is on the stable upper branch, just before the upper fold (hardening)
    assert frc.peak["Omega"] < upper["Omega"] and frc.peak["amplitude"] > upper["amplitude"] and frc.peak["stable"]
    O, A, st = frc.Omega, frc.amplitude, frc.stable
    near = [int(np.argmin(np.hypot(O - p["Omega"], A - p["amplitude"]))) for p in (upper, lower)]
    iu, il = near
    assert iu + 2 < il  # along the curve: the upper fold first (Omega rising), then the lower one
    assert not st[iu + 1:il].any()  # between the folds (the points nearest to them left out): unstable
    assert st[:iu].all() and st[il + 1:].all()
    for fold, i in zip((upper, lower), near):
        o = forced_orbit_at_amplitude(M, C, f, np.array([k]), fold["amplitude"], np.array([1.0]),
                                      Omega0=frc.orbits[i].Omega, x0=frc.orbits[i].x0, v0=frc.orbits[i].v0,
                                      tangent=tan)
        assert o.Omega == pytest.approx(fold["Omega"], rel=1e-9)
        assert np.min(np.abs(o.multipliers - 1.0)) < 1e-5


def test_amplitude_solve_recovers_the_frequency():
    """An orbit at fixed Omega, then the amplitude-fixed solve at its amplitude from a guess 0.5% off in Omega:
    the same Omega (1e-9: converged shooting at rtol = 1e-11) and the same state."""
    M, C, f, tan = duffing()
    k, Om = 0.01, 1.33
    sh = ForcedShooting(M, C, f, np.array([k]), tangent=tan, phi=np.array([1.0]))
    ref = sh.orbit(Om)
    got = sh.orbit_at_amplitude(ref.amplitude, 1.005 * Om, ref.y0)
    assert got.Omega == pytest.approx(Om, rel=1e-9)
    assert got.amplitude == pytest.approx(ref.amplitude, rel=1e-9)
    assert np.allclose(got.y0, ref.y0, rtol=0, atol=1e-8 * ref.amplitude)


def test_range_without_the_peak_is_a_numerical_error():
    """A frequency range above the resonance: the largest amplitude is at the range's end; a NumericalError
    naming it, not a wrong peak."""
    M, C, f, tan = duffing()
    with pytest.raises(NumericalError, match="does not contain the peak"):
        full_frc(M, C, f, np.array([0.002]), np.array([1.0]), W, (1.1, 1.2), tangent=tan)
