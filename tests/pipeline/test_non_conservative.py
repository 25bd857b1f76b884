"""The ``non_conservative`` flag (issue 32, item 2): a master whose force is not the gradient of an energy.

The six-dof model of tests/helpers/shell_dofs.py (rotation dofs; mode 0 a Duffing oscillator) with a
quadratic force added, in modal coordinates ``q_s = phi_s^T M u``:

* non-conservative: ``c2 q0^2 M phi1`` alone (mode 1 driven by mode 0's square, mode 0 feels nothing of
  mode 1): ``g_1 = phi_1.G(phi_0, phi_0) = c2`` but ``phi_0.G(phi_0, phi_1) = 0``. With ``y = c2 phi_1 / w_1^2``
  the check's ``a_sym = c2^2 / w_1^2`` and ``a_dyn = 0``: relative asymmetry exactly 1.
* conservative: the same plus ``2 c2 q0 q1 M phi0``, the gradient of ``c2 q0^2 q1``: ``a_dyn = a_sym``
  (polarisation is exact for a quadratic force and the cubic, odd, cancels): asymmetry at round-off.

Before the check existed, neither run carried any flag of the kind (the kind did not exist).
"""
from __future__ import annotations

import numpy as np
import pytest

from helpers.shell_dofs import SixDofPlate, scene_text
from helpers.systems import use_solver
from stepnf.pipeline.conservative import NON_CONSERVATIVE, asymmetry_of, modal_condensation
from stepnf.step.procedure import MAX_ROTATION

C2 = 0.3


def model(conservative: bool):
    class Quadratic(SixDofPlate):
        def _internal_forces(self, U):
            F = super()._internal_forces(U)
            U = np.asarray(U, dtype=float)
            q0, q1 = U @ (self.m * self.Phi[:, 0]), U @ (self.m * self.Phi[:, 1])
            F = F + C2 * np.outer(q0 ** 2, self.m * self.Phi[:, 1])
            if conservative:
                F = F + 2 * C2 * np.outer(q0 * q1, self.m * self.Phi[:, 0])
            return F
    return Quadratic


def run(tmp_path, monkeypatch, conservative: bool):
    from stepnf.pipeline.run import run_scene
    from stepnf.scene.parse import load_scene

    use_solver(monkeypatch, lambda name: model(conservative))
    path = tmp_path / "s.toml"
    path.write_text(scene_text())
    return run_scene(load_scene(path))


def test_asymmetry_figure_exact_on_modal_forces():
    for conservative, expected in ((False, 1.0), (True, 0.0)):
        ad = model(conservative)()
        Phi, omega = ad.Phi, ad.omega
        q = 1e-2
        Gv = (ad.internal_forces(np.stack([q * Phi[:, 0], -q * Phi[:, 0]])).sum(0)) / (2 * q ** 2)
        y = modal_condensation(Gv, Phi, omega)  # every mode: K^-1 Gv exactly
        a_sym, a_dyn, rel = asymmetry_of(ad.internal_forces, Phi[:, 0], Gv, y, q, ad.dof_directions())
        assert a_sym == pytest.approx(C2 ** 2 / omega[1] ** 2, rel=1e-9)  # STEP of a quadratic: exact to round-off
        assert rel == pytest.approx(expected, abs=1e-8), conservative
        sent = np.array(ad.sent[2:])  # the check's eight fields: their rotations within STEP's bound
        assert len(sent) == 8 and np.abs(sent[:, ad.dof_directions() >= 3]).max() <= MAX_ROTATION * (1 + 1e-12)


@pytest.mark.parametrize("conservative", [False, True])
def test_flag_on_the_master(tmp_path, monkeypatch, conservative):
    res = run(tmp_path, monkeypatch, conservative)
    (mode,) = res.modes
    flags = [f for f in mode.flags if f["kind"] == "non_conservative"]
    if conservative:
        assert flags == []
        return
    (flag,) = flags
    assert flag["value"] == pytest.approx(1.0, abs=1e-6) and flag["value"] > NON_CONSERVATIVE
    assert "not the gradient of an energy" in flag["message"] and "master mode 0" in flag["message"]
