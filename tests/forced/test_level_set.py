"""The level set's topology (stepnf.forced.frc): an isola beyond the peak, and a level set that comes back
without closing, on a hand-made 2-dof manifold whose forcing term f1(rho) is designed for them.

Manifold: ``X_1(rho) = rho e0 + h(rho) e1 / 10``, ``h = beta rho^3 + gamma rho^5 - delta rho^7``, no frequency
change (``c = 0``), ``M = I``, master ``e0``; load ``F = e0 + 10 e1`` so ``f1 = rho + h``; modal damping
xi = 0.01 on e0 so ``2 D = 0.02 Omega_d^2 rho^2``. Then ``Omega_d f1 - 2 D ~ rho (1 - x (1 + 1/4 + 1/9) +
x^2 (1/4 + 1/9 + 1/36) - x^3 / 36 - 0.02 rho)``, ``x = rho^2``: roots near rho = 1, 2, 3 (the peak, then an
isola between about 2 and 3); without the rho^7 term the level set comes back near 1.6 and stays.
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.dpim.parametrisation import DPIMResult
from stepnf.forced.damping import Damping
from stepnf.forced.frc import forced_responses
from stepnf.forced.spec import DampingSpec

E0, E1 = np.eye(2)
BETA, GAMMA, DELTA = -(1 + 1 / 4 + 1 / 9), 1 / 4 + 1 / 9 + 1 / 36, 1 / 36


def level(delta: float):
    Y = {(1, 1): E0.copy(), (3, 1): BETA * E1 / 10, (5, 1): GAMMA * E1 / 10, (7, 1): -delta * E1 / 10}
    res = DPIMResult(omega=1.0, phi=E0.copy(), M=np.eye(2), order=7, Y=Y, c=np.zeros(3))
    d = Damping(DampingSpec(modal=0.01), np.eye(2), None, [(E0, 1.0)])
    return forced_responses(res, d, [({"load": 1.0}, E0 + 10 * E1)], (0.1, 10.0), valid_to=10.0)[0]


def test_an_isola_is_its_own_segments():
    fr = level(DELTA)
    assert fr.isolas == 1 and fr.flags == []
    assert fr.segment_isola[0] is False and all(fr.segment_isola[1:]) and len(fr.segment_isola) >= 2
    main, isola = fr.segment == 0, fr.segment > 0
    assert fr.rho[main].max() == fr.peak["rho"] < fr.rho[isola].min()
    # the isola's rho spans the interval between the two further roots (near 2 and 3; the -0.02 rho term moves
    # them by a few percent)
    assert fr.rho[isola].min() == pytest.approx(2.0, rel=0.05) and fr.rho[isola].max() == pytest.approx(3.0, rel=0.05)
    assert fr.stable[isola].any() and not fr.stable[isola].all()  # an isola has a stable and an unstable side
    assert np.all((fr.Omega >= 0.1 - 1e-12) & (fr.Omega <= 10.0 + 1e-12))
    js = fr.to_json()
    assert js["isolas"] == 1 and len(js["segment"]) == len(js["Omega"])


def test_a_level_set_that_comes_back_is_flagged():
    fr = level(0.0)
    assert fr.isolas == 0 and len(fr.flags) == 1 and "steady states again from rho" in fr.flags[0]
    assert set(fr.segment) == {0} and fr.to_json()["flags"] == fr.flags
