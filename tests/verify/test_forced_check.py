"""The ROM's FRC side by side with the full model's (stepnf.verify.forced_check) on the forced Duffing oscillator
``x'' + 2 xi w x' + w^2 x + g x^3 = k cos(Omega t)`` with a jump (k = 0.016: folds 0.1% apart): by continuation
(peak and both folds) and by time integration (the peak)."""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.dpim.parametrisation import DPIM
from stepnf.forced.damping import Damping
from stepnf.forced.frc import forced_responses
from stepnf.forced.spec import DampingSpec
from stepnf.verify.forced_check import forced_rows

W, G, XI, KAPPA = 1.3, 0.4, 0.01, 0.016
RANGE = (0.97, 1.08)


def duffing_rom(kappa=KAPPA):
    K, M = np.array([[W ** 2]]), np.array([[1.0]])
    res = DPIM(lambda U: W ** 2 * U + G * U ** 3, K, M).parametrise(np.array([1.0]), W, 11, probe=1.0)
    damping = Damping(DampingSpec(modal=XI), M, K, [(np.array([1.0]), W)])
    (curve,) = forced_responses(res, damping, [({"kappa": kappa}, kappa)], RANGE)
    return res, curve, M, 2 * XI * W * M, K


def test_rows_by_continuation_peak_and_folds():
    """Peak and both folds paired with the full model's (A = 0.47): within the issue's floors (1% in A,
    0.1% in Omega) with a margin: 1e-3 in A and 2e-4 in Omega; measured peak 6e-7 in A and 4.8e-5 in Omega,
    folds 2e-5 in A and 2e-6 in Omega (the averaging's second order in xi and k, docs/design.md)."""
    res, curve, M, C, K = duffing_rom()
    assert len(curve.folds) == 2
    rows = forced_rows(res, curve, KAPPA * np.ones(1), M, C, K, lambda U: W ** 2 * U + G * U ** 3,
                       method="continuation", frequency_range=RANGE, tangent=lambda x: np.diag(W ** 2 + 3 * G * x ** 2))
    assert [r["what"] for r in rows] == ["peak", "fold", "fold"]
    for r in rows:
        assert r["full"] is not None and r["rom"] is not None
        assert abs(r["dA"]) < 1e-3 and abs(r["dOmega"]) < 2e-4, r


def test_rows_by_integration_at_the_peak():
    """The FE models' route: the steady state at the ROM's peak frequency from the ROM's state, k = 0.012 (no
    fold), within 1e-3 of the ROM's A (the scheme at 128 steps a period: 2.5e-4,
    tests/verify/test_forced_steady.py, plus the ROM's 1e-5; measured 3.6e-5); settled (Aitken's spread below
    1e-5 of A; measured 1.5e-6). At xi = 0.01 the transient, from the exact steady state to the scheme's,
    decays over ~1/(2 pi xi) = 16 periods, oscillating at the scheme's detuning: 30 periods of 64 steps leave
    Aitken's estimate 4% off, with a spread of 1e-2 that says so. On the k = 0.016 curve the folds are listed
    as not checked."""
    res, curve, M, C, K = duffing_rom(0.012)
    rows = forced_rows(res, curve, 0.012 * np.ones(1), M, C, K, lambda U: W ** 2 * U + G * U ** 3,
                       method="integration", periods=60, steps=128)
    (peak,) = rows
    assert peak["full"]["Omega"] == peak["rom"]["Omega"] and abs(peak["dA"]) < 1e-3, peak
    assert peak["spread"] < 1e-5
    res, curve, M, C, K = duffing_rom()
    rows = forced_rows(res, curve, KAPPA * np.ones(1), M, C, K, lambda U: W ** 2 * U + G * U ** 3,
                       method="integration", periods=5, steps=32)
    assert len(rows) == 3 and all(f["full"] is None and "time integration" in f["reason"] for f in rows[1:])


def test_unknown_method_is_refused():
    res, curve, M, C, K = duffing_rom()
    with pytest.raises(ValueError, match="continuation"):
        forced_rows(res, curve, KAPPA * np.ones(1), M, C, K, lambda U: U, method="harmonic balance")
