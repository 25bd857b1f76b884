"""The DPIM's polarisation probes of a model with rotational dofs (issue 32, item 1): the probe length bounds
each probe field's largest translation, and its largest rotation stays at most MAX_ROTATION radians, as STEP's.

Reference: tests/helpers/shell_dofs.py (an uncoupled Duffing mode 0, uz 0.6 and rx 8 rad at node 0,
T = 0.15 exactly, h = 0.1: the probe length is 0.5 h = 0.05). Its probe fields are multiples of mode 0,
so before this change each one's largest entry, the rotation, was set to 0.05: 0.05 rad.
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.step.procedure import MAX_ROTATION
from helpers.shell_dofs import H, T_EXACT, run_six_dof


def test_backbone_probes_bound_the_rotation(tmp_path, monkeypatch):
    res, ad = run_six_dof(tmp_path, monkeypatch, "[analysis.backbone]\norder = 5\n")
    D = ad.dof_directions()
    U = np.array(ad.sent)
    turn, move = np.abs(U[:, D >= 3]).max(axis=1), np.abs(U[:, D < 3]).max(axis=1)
    assert len(U) > 4  # STEP's four fields and the DPIM's probes
    assert np.all(turn <= MAX_ROTATION * (1 + 1e-12)) and np.all(move <= 0.5 * H * (1 + 1e-12))
    # the backbone of an uncoupled Duffing mode: w_NL / w = 1 + T A^2 + O(A^4), so (ratio - 1) / A^2 at the
    # smallest amplitude of the grid is T to O(A^2): measured 7e-5 relative at A = 0.0145; 1e-3 leaves room
    bb = res.modes[0].backbone
    A, ratio = np.array(bb["amplitude"]), np.array(bb["omega_ratio"])
    i = int(np.argmin(np.where(A > 0, A, np.inf)))
    assert (ratio[i] - 1) / A[i] ** 2 == pytest.approx(T_EXACT, rel=1e-3)
