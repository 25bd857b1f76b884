"""Gamma of the free circular plate (a = 0.15 m, h = 3 mm, the paper's material) from Kratos's DKT shells
through the whole pipeline (``solver = "kratos"``, the generated plate's default mesh, 11 766 dofs),
against the von Karman plate (:class:`stepnf.models.vonkarman.VonKarmanShell`, kappa = 0, the same DNF).

Measured (one thread, ~12 s): (2,0) 0.1579 against 0.1584 (-0.3 %), (0,1) 0.3328 against 0.3341
(-0.4 %), (3,0) 0.2158 against 0.2177 (-0.9 %); the issue's bound is 3 %. The shells' internal force is
not exactly cubic (co-rotational kinematics) nor conservative (test_kratos.py); this is where that meets
the paper's figure.
"""
from __future__ import annotations

import numpy as np
import pytest

from helpers.required import requires

from stepnf.models.vonkarman import VonKarmanShell
from stepnf.nf.evaluators import nf_modal
from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import load_scene

pytestmark = [requires("KratosMultiphysics", "stepnf_kratos"), pytest.mark.slow]

SCENE = """[model]
solver = "kratos"
element = "dkt"

[model.geometry]
shape = "spherical_cap"
a = 0.15
R = "inf"
h = 0.003

[model.material]
E = 1.04e11
nu = 0.3
rho = 4400.0

[analysis]
master_modes = ["(2,0)", "(0,1)", "(3,0)"]
methods = ["dnf"]
"""


def vonkarman_gamma(labels) -> dict:
    vk = VonKarmanShell(kappa=0.0, nu=0.3)
    om, all_labels, wmax = vk.omegas(), vk.labels(), vk.mode_maxima()
    out = {}
    for lab in labels:
        p = all_labels.index(lab)
        r = nf_modal(p, om, vk.quadratic_coefficients(p), vk.cubic_coefficient(p), np.arange(len(om)))
        out[lab] = r.T / wmax[p] ** 2
    return out


def test_free_plate_gamma_matches_von_karman(tmp_path):
    path = tmp_path / "plate_dkt.toml"
    path.write_text(SCENE)
    scene = load_scene(path)
    scene.output_dir = tmp_path
    res = run_scene(scene)
    modes = {tuple(m.label): m for m in res.modes}
    vk = vonkarman_gamma([(2, 0), (0, 1), (3, 0)])
    for lab, gamma in vk.items():
        assert modes[lab].methods["dnf"].gamma == pytest.approx(gamma, rel=0.03), lab
