"""The energy-conserving step's Newton stages without a tangent (issue 31, item 5): the secant stage, Newton-Krylov
by directional differences of the forces, step halving, and the message when none converges.

The model: a von Karman string of 20 segments (transverse w and axial u at 20 inner nodes, fixed ends;
segment energy kw (dw)^2 / 2 + ku (du + (dw)^2 / 2)^2 / 2, ku / kw = 1e4): the membrane-bending coupling
of a slender structure in 40 dofs. At W = 0.2 (the largest transverse displacement) the tangent differs
from K along many directions and the modified Newton of Anderson depth 5 does not converge; before the
new stages EnergyConserving raised "Newton did not converge" at the first step (checked on the code before).
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.errors import NumericalError
from stepnf.verify.command import newton_hint
from stepnf.verify.integrate import HALVINGS, EnergyConserving, cubic_potential

N, KU, KW = 20, 1e4, 1.0


def string_forces(X: np.ndarray) -> np.ndarray:
    """Internal forces (m, 2N) of the fields X (m, 2N): w at the inner nodes, then u."""
    X = np.atleast_2d(X)
    w = np.pad(X[:, :N], ((0, 0), (1, 1)))
    u = np.pad(X[:, N:], ((0, 0), (1, 1)))
    dw, du = np.diff(w, axis=1), np.diff(u, axis=1)
    s = KU * (du + 0.5 * dw * dw)  # axial force of each segment
    g = KW * dw + s * dw
    return np.hstack([g[:, :-1] - g[:, 1:], s[:, :-1] - s[:, 1:]])


@pytest.fixture(scope="module")
def string():
    n = 2 * N
    e = 1e-6
    K = (string_forces(e * np.eye(n)) - string_forces(-e * np.eye(n))).T / (2 * e)  # exact: f is cubic
    lam, V = np.linalg.eigh(0.5 * (K + K.T))
    phi, w1 = V[:, 0], float(np.sqrt(lam[0]))
    return K, np.eye(n), phi, w1


def run(string, jacobian: str, W: float = 0.2, steps: int = 40):
    K, M, phi, w1 = string
    integ = EnergyConserving(M, K, string_forces, jacobian=jacobian, tol=1e-10)
    x0 = W * phi / np.abs(phi).max()
    return integ.run(x0, np.zeros(len(phi)), 2 * np.pi / w1 / 40, steps, watch=phi,
                     potential=cubic_potential(string_forces))


def test_secant_and_krylov_converge_where_modified_newton_does_not(string):
    """W = 0.2: "auto" goes to the secant stage (deep Anderson memory on K) at every step, "differences"
    uses Newton-Krylov at every step; both solve each step's equations to 1e-10 of the state, so over 40
    steps the watched coordinate agrees to 1e-8 (measured 6e-11), and the energy is conserved to the
    Newton tolerance (Simpson's rule is exact for cubic forces; measured drift 4e-10 and 5e-15)."""
    auto, krylov = run(string, "auto"), run(string, "differences")
    assert auto.secant_steps == 40 and auto.krylov_steps == 0 and auto.halved_steps == 0
    assert krylov.krylov_steps == 40 and krylov.secant_steps == 0 and krylov.jacobian_products > 0
    scale = np.abs(auto.q).max()
    assert np.abs(auto.q - krylov.q).max() < 1e-8 * scale
    assert auto.energy_drift < 1e-9 and krylov.energy_drift < 1e-9
    # at a small amplitude the modified Newton converges alone: nothing else is tried (the numbers it had)
    small = run(string, "auto", W=0.05)
    assert small.secant_steps == small.krylov_steps == small.halved_steps == 0


def test_krylov_and_halving_at_a_larger_amplitude(string):
    """W = 0.4: the secant stage fails on some steps, where "auto" goes on to Newton-Krylov, and halves the
    steps neither converges (w_max dt ~ 200: the fast axial modes are far from resolved). Each (half)
    step conserves the energy to the Newton tolerance, halved or not (measured drift <= 3e-11; bound
    1e-9). Which steps are halved changes the discrete trajectory: "differences" halves other steps than
    "auto" and ends 9% away, "modified" (K only: no Newton-Krylov) 25% away after 40 steps (measured):
    why stepnf verify notes halved steps under its table and names --steps-per-period."""
    for jacobian, krylov in (("auto", True), ("modified", False)):
        tr = run(string, jacobian, W=0.4)
        assert tr.secant_steps > 0 and tr.halved_steps > 0 and (tr.krylov_steps > 0) == krylov, jacobian
        assert tr.energy_drift < 1e-9 and np.all(np.isfinite(tr.q)), jacobian


def test_halving_and_the_message_naming_the_keys(string):
    """A step that no Newton converges is halved HALVINGS times, then the error says what was tried and
    names the keys (the hint of stepnf verify), never a traceback of scipy."""
    K, M, phi, w1 = string
    calls = {"n": 0}

    def broken(X):  # finite at the initial state, then NaN: no Newton can converge
        calls["n"] += 1
        return string_forces(X) if calls["n"] == 1 else np.full(np.atleast_2d(X).shape, np.nan)

    hint = newton_hint("modified", None, 1e-6)
    assert "--steps-per-period 284 (now 71)" in hint and "--tangent differences" in hint
    integ = EnergyConserving(M, K, broken, jacobian="auto", tol=1e-10, hint=hint)
    with pytest.raises(NumericalError) as exc:
        integ.run(0.2 * phi, np.zeros(len(phi)), 0.1, 5, watch=phi, what="time integration")
    msg = str(exc.value)
    assert msg.startswith("time integration: Newton did not converge at t = 0.1 (step 1 of dt = 0.1; tried ")
    assert f"the step halved {HALVINGS} times" in msg and "Newton-Krylov" in msg and hint in msg
    assert newton_hint("auto", 200, 1e-6).endswith("--steps-per-period 800 (now 200)")
