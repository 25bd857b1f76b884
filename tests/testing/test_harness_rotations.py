"""The conformance harness bounds the rotations of the fields it sends (issue 32, item 3).

Its random fields are scaled to 1% of the characteristic length, and two checks send ten times one
(``conservative_force``, ``step_equals_intrusive``). A length is no angle: for a shell in millimetres
(h = 3 mm, plate size 300 mm) the rotation entries of such a field were 1% of the length in radians,
0.03 to 3 rad, times ten. Rotations are bounded on their own as STEP bounds them
(:data:`stepnf.step.procedure.MAX_ROTATION`, 0.03 rad, where a co-rotational force's sin/cos are within
its tolerance of their cubic truncation): every field the harness sends rotates by at most that.
Before the bound, the six-dof model below with a 300 (mm) characteristic length received rotations of
30 rad (10 x 1% x 300 x the largest entry of the polynomial field), and 3 rad at 1% alone.
"""
from __future__ import annotations

import numpy as np
import pytest

from helpers.shell_dofs import SixDofPlate
from stepnf.plugin.dofs import rotation_mask, translation_mask
from stepnf.step.procedure import MAX_ROTATION
from stepnf.testing.base import random_fields
from stepnf.testing.harness import run_checks

#: a length in millimetres: a 300 mm plate's size as the characteristic length
LENGTH_MM = 300.0


class MillimetrePlate(SixDofPlate):
    def characteristic_length(self):
        return LENGTH_MM


@pytest.mark.parametrize("per_direction", [False, True])
def test_random_fields_bound_rotations_and_keep_translations(per_direction):
    ad = MillimetrePlate()
    U = random_fields(ad, 4, seed=7, per_direction=per_direction)
    rot, tra = rotation_mask(ad.dof_directions()), translation_mask(ad.dof_directions())
    # translations: as before, a largest entry of 1% of the length per field (exact up to rounding)
    np.testing.assert_allclose(np.abs(U[:, tra]).max(axis=1), 1e-2 * LENGTH_MM, rtol=1e-14)
    # rotations: a tenth of STEP's bound per field, so that ten times a field stays within it
    np.testing.assert_allclose(np.abs(U[:, rot]).max(axis=1), MAX_ROTATION / 10, rtol=1e-14)


def test_every_field_the_harness_sends_rotates_at_most_max_rotation():
    ad = MillimetrePlate()
    results = run_checks(lambda: ad)
    assert results  # the checks ran (the model is polynomial: they pass or skip)
    sent = np.array(ad.sent)
    rot = rotation_mask(ad.dof_directions())
    assert len(sent) > 10
    # conservative_force sends u + s v with u and v ten times a random field (each <= MAX_ROTATION) and
    # steps |s| <= 0.1: at most 1.1 MAX_ROTATION; before the bound, 30 rad (module docstring)
    assert np.abs(sent[:, rot]).max() <= 1.1 * MAX_ROTATION * (1 + 1e-12)
    assert np.abs(sent[:, rot]).max() >= MAX_ROTATION / 10  # rotations are probed, not dropped
