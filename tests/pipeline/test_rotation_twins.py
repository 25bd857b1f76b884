"""Degenerate pairs of a model with rotational dofs are oriented by their translations (issue 32, item 1).

Reference: tests/helpers/shell_dofs.py with modes 1 and 2 made degenerate (the same frequency 1.37, exact):
the run turns the pair so that its first mode is the M-projection on the pair of the position-only probe
field (:func:`stepnf.linalg.modal_analysis.probe_vector`) with its rotation entries set to zero, as a solid
model of the structure (translations only) is turned; before this change the probe's rotation entries
took part, and the first mode of the pair differed.
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.linalg.modal_analysis import probe_vector
from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import load_scene
from helpers.shell_dofs import SixDofPlate, scene_text
from helpers.systems import use_solver


class Twins(SixDofPlate):
    def __init__(self):
        super().__init__()
        self.omega[2] = self.omega[1]
        Mphi = self.m[:, None] * self.Phi
        self.K = Mphi @ np.diag(self.omega ** 2) @ Mphi.T
        self.K = (self.K + self.K.T) / 2


def test_twins_turn_by_the_translations(tmp_path, monkeypatch):
    use_solver(monkeypatch, lambda name: Twins)
    path = tmp_path / "s.toml"
    path.write_text(scene_text().replace("master_modes = [0]", "master_modes = [1]"))
    res = run_scene(load_scene(path))
    ad = Twins()
    D, M = ad.dof_directions(), ad.mass_matrix()
    probe = probe_vector(ad.dof_coordinates(), D, ad.n_dofs) * (D < 3)
    V = ad.Phi[:, [1, 2]]  # an M-orthonormal basis of the pair (exact by construction)
    c = V.T @ (M @ probe)
    expected = V @ c / np.linalg.norm(c)
    got = res.arrays["phi_masters"][:, 0]
    # the eigen-solver's pair is exact to ~1e-13 of its entries (K, M of size 24 in double precision)
    assert np.abs(got - expected).max() <= 1e-9 * np.abs(expected).max()
