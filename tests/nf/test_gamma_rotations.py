"""Gamma and W_max of a model with rotational dofs read the translations only (issue 32, item 1).

Reference: tests/helpers/shell_dofs.py, a six-dof-per-node model built from its modes: mode 0 is exactly
uz = 0.6 and rx = 8 rad at node 0 (its largest entry a rotation), an uncoupled Duffing mode of frequency 1
with T = 3 c / 8 = 0.15 exactly. So W_max = 0.6 (not 8), Gamma = T (h / 0.6)^2, and the transverse share
of its translational kinetic energy is 1 (uz is its only translation): the rotary inertia (0.64 of
phi^T M phi) is no displacement. Before this change the share was 0.36, so Gamma was flagged n/a.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.flags import gamma_unusable
from stepnf.nf.gamma import transverse_peak, transverse_share
from helpers.shell_dofs import H, ROT_MAX, T_EXACT, W_MAX, SixDofPlate, run_six_dof


def test_share_and_peak_of_a_mode_whose_largest_entry_is_a_rotation():
    ad = SixDofPlate()
    X, D, M, phi = ad.dof_coordinates(), ad.dof_directions(), ad.mass_matrix(), ad.phi0
    assert np.abs(phi).max() == pytest.approx(ROT_MAX, rel=1e-14) and ROT_MAX > 10 * W_MAX  # a rotation leads
    # exact by construction (one uz entry, one rx entry): only the last bits of the products differ
    assert transverse_peak(phi, X, D, "uz") == pytest.approx(W_MAX, rel=1e-14)
    assert transverse_peak(phi, X, D, (0.0, 0.0, 1.0)) == pytest.approx(W_MAX, rel=1e-14)  # a direction vector
    assert float(phi @ (M @ phi)) == pytest.approx(1.0, rel=1e-14)  # M-normalised, 0.64 of it rotary
    assert transverse_share(phi, M, X, D, "uz") == pytest.approx(1.0, rel=1e-14)
    assert transverse_share(phi, M, X, D, "ux") == pytest.approx(0.0, abs=1e-15)
    # a solid's share is unchanged: the same field with its rotations read as translations of other nodes
    solid = np.tile([0, 1, 2], 8)
    assert transverse_share(phi, sp.identity(24), X, solid, "uz") == pytest.approx(
        float(np.sum(phi[solid == 2] ** 2) / np.sum(phi ** 2)), rel=1e-14)


def test_gamma_of_the_run_uses_the_translations(tmp_path, monkeypatch):
    res, _ = run_six_dof(tmp_path, monkeypatch)
    (mode,) = res.modes
    r = mode.methods["dnf"]
    # an exact cubic force in double precision: T to ~1e-11 relative (the rotation bound keeps the cubic
    # force 6e-6 of the linear one at the STEP amplitude, so round-off costs ~1e-16 / 6e-6); 1e-8 leaves room
    assert r.T == pytest.approx(T_EXACT, rel=1e-8)
    assert r.gamma == pytest.approx(r.T * (H / W_MAX) ** 2, rel=1e-14)  # W_max: the uz 0.6, not the rx 8
    assert gamma_unusable(r) is None and not [f for f in r.flags if f["kind"] == "gamma_not_transverse"]
