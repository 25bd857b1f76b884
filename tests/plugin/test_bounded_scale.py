"""The one scaling rule of every field stepnf sends (:func:`stepnf.plugin.dofs.bounded_scale`): the largest
translation at most the target length, the largest rotation at most :data:`~stepnf.plugin.dofs.MAX_ROTATION`
radians; STEP's amplitude, the raised amplitude of a slender DNF and the conservation check all use it."""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.plugin.dofs import MAX_ROTATION, bounded_scale, rotation_mask, translation_mask
from stepnf.pipeline.slender_dnf import MAX_EXTENT, MAX_FACTOR, raise_factor
from stepnf.step.procedure import StepPolicy, step_amplitude

D = np.array([0, 1, 2, 3, 4, 5] * 2)  # two shell nodes
TR, ROT = translation_mask(D), rotation_mask(D)


def field(move: float, turn: float) -> np.ndarray:
    """A field whose largest translation is ``move`` (model units) and largest rotation ``turn`` (rad)."""
    phi = np.zeros(len(D))
    phi[[2, 6]] = move, -0.5 * move
    phi[[3, 11]] = 0.25 * turn, -turn
    return phi


def test_the_smaller_bound_governs():
    # exact: 0.5 / 2 and 0.03 / 0.12 are the quotients of the two bounds, both 0.25 (binary fractions)
    assert bounded_scale(field(2.0, 0.06), 0.5, TR, ROT) == 0.25  # translations govern (rotation 0.03 / 0.06)
    assert bounded_scale(field(2.0, 0.6), 0.5, TR, ROT) == MAX_ROTATION / 0.6  # the rotation governs
    assert bounded_scale(field(0.0, 0.6), 0.5, TR, ROT) == MAX_ROTATION / 0.6  # a drilling mode: rotation alone
    assert bounded_scale(field(2.0, 0.6), 0.5, None, None) == 0.5 / 2.0  # no directions: every dof a length
    assert bounded_scale(np.zeros(len(D)), 0.5, TR, ROT) == np.inf  # nothing bounds a zero field


def test_step_amplitude_and_the_raise_are_the_rule():
    """STEP's amplitude and the slender DNF's raised amplitude bound the rotation by the same rule, so a raise
    never turns a shell beyond the bound STEP itself keeps."""
    phi = field(1.0, 40.0)
    q = step_amplitude(phi, StepPolicy(relative_amplitude=1.0), 0.1, TR, ROT)
    assert q == bounded_scale(phi, 0.1, TR, ROT) == MAX_ROTATION / 40.0
    q0 = q / 8  # a STEP at an eighth of the bound: the raise stops at the bound (8x), below MAX_FACTOR
    k = raise_factor(1.0, 1e-12, q0, phi, np.array([[0.0, 0, 0], [1e3, 0, 0]]), D)
    assert k == pytest.approx(8.0, rel=1e-14) and k < MAX_FACTOR
    assert k * q0 * 40.0 <= MAX_ROTATION * (1 + 1e-15)
    # without rotations the extent bound (MAX_EXTENT of the model's size, 1.0 here) governs
    X = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    assert raise_factor(1.0, 1e-12, 1e-3, np.ones(3), X) == pytest.approx(MAX_EXTENT / 1e-3, rel=1e-14)
