"""The STEP amplitude of a model with rotational dofs (issue 32, item 1): the target length is met by the
largest translation, and the largest rotation of every STEP field stays at most MAX_ROTATION radians.

Reference: tests/helpers/shell_dofs.py (mode 0: uz 0.6 and rx 8 rad at node 0, h = 0.1). The default
relative amplitude 0.5 asks for a translation of 0.05, i.e. q = 0.05 / 0.6 and a rotation of 0.67 rad,
far beyond the bound: q is then 0.03 / 8, the translation 0.6 q = 2.25e-3. Before this change the STEP
fields carried rotations of 0.67 rad (and 0.33 at the check amplitude).
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.pipeline.slender_dnf import raise_factor
from stepnf.step.procedure import MAX_ROTATION, StepPolicy, step_amplitude
from helpers.shell_dofs import H, ROT_MAX, W_MAX, SixDofPlate, run_six_dof


def masks(ad):
    D = ad.dof_directions()
    return D < 3, D >= 3


def test_amplitude_bounds_the_rotation():
    ad = SixDofPlate()
    tr, rot = masks(ad)
    phi = ad.phi0
    q = step_amplitude(phi, StepPolicy(), H, tr, rot)
    assert q == pytest.approx(MAX_ROTATION / ROT_MAX, rel=1e-14)  # the bound governs (exact arithmetic)
    # a smaller target: the translation governs, as for a solid (q = 1e-3 / 0.6, rotation 0.0133 rad)
    q2 = step_amplitude(phi, StepPolicy(amplitude=1e-3), H, tr, rot)
    assert q2 == pytest.approx(1e-3 / W_MAX, rel=1e-14) and q2 * ROT_MAX < MAX_ROTATION
    # a solid (no rotation mask): unchanged, the largest entry of the masked dofs meets the target
    assert step_amplitude(phi, StepPolicy(), H, tr) == pytest.approx(0.5 * H / W_MAX, rel=1e-14)


def test_raised_amplitude_keeps_the_rotation_bound():
    ad = SixDofPlate()
    phi, X, D = ad.phi0, ad.dof_coordinates(), ad.dof_directions()
    q = MAX_ROTATION / ROT_MAX / 4  # a STEP at a quarter of the bound: a raise may take it up to 4 x
    assert raise_factor(1.0, 1e-4, q, phi, X, D) == pytest.approx(4.0, rel=1e-12)
    # without directions every entry is a displacement: MAX_EXTENT (0.1 of the diagonal sqrt 2) / (q x 8)
    assert raise_factor(1.0, 1e-4, q, phi, X) == pytest.approx(0.1 * np.sqrt(2) / (q * ROT_MAX), rel=1e-12)


def test_step_fields_of_the_run(tmp_path, monkeypatch):
    _, ad = run_six_dof(tmp_path, monkeypatch)
    tr, rot = masks(ad)
    U = np.array(ad.sent)
    assert len(U) >= 4  # +-q phi and the check at +-q/2
    turn = np.abs(U[:, rot]).max(axis=1)
    assert turn.max() == pytest.approx(MAX_ROTATION, rel=1e-12)  # the largest field is at the bound
    assert np.all(turn <= MAX_ROTATION * (1 + 1e-12))
    assert np.abs(U[:, tr]).max() == pytest.approx(MAX_ROTATION / ROT_MAX * W_MAX, rel=1e-12)


def test_mode_of_rotations_only_takes_the_rotation_bound():
    """A mode with rotations but no translation (a shell's drilling mode) is no zero mode: q puts its largest
    rotation at MAX_ROTATION (before: 'cannot choose a STEP amplitude for a zero mode shape')."""
    ad = SixDofPlate()
    tr, rot = masks(ad)
    phi = np.where(rot, ad.phi0, 0.0)
    assert step_amplitude(phi, StepPolicy(), H, tr, rot) == pytest.approx(MAX_ROTATION / ROT_MAX, rel=1e-14)
