"""``stepnf verify`` on Kratos's DKT shells (issue 32's done-means): a free plate mode's DPIM backbone against
the full Kratos model's periodic orbits (time integration with Kratos's own forces) at two amplitudes.

The free circular plate of test_kratos_gamma.py (a = 0.15 m, h = 3 mm, the paper's material) on a coarse
mesh (n_core = 3, n_ring = 1, 582 dofs: the same check as the default mesh, in the time a test may take),
mode (2,0), DPIM order 7, at 1/4 and 1/2 of its validity limit (orders 5 and 7 within 1e-3 there, where
W_max/h = 1.01 on the translations, below the default cap of 2). W_max is measured on the translations:
counting the mode's rotations (radians) it was ~13 times larger (the default mesh: "13.3 h" at the limit).
Measured (one thread, 77 s): w_NL/w - 1 = 0.97 % and 3.8 % at W_max/h = 0.25 and 0.51, differences
-6.4e-5 and -3.5e-4, manifold distances 4e-4 and 8e-4; at the limit itself (14 % shift) -2.5e-3, of the
size of the limit's own tolerance (1e-3) plus the integration's error estimate there (6e-4 at rtol 1e-5).
Bound 1e-3, the issue's. The force is not the gradient of an energy for random fields (the harness's
conservative_force fails), but in the directions the backbone uses it is (stepnf.pipeline.conservative:
below 1e-5), and a force of the state alone keeps a family of symmetric periodic orbits.
"""
from __future__ import annotations

import time

import pytest

from helpers.required import requires

from stepnf.scene.parse import load_scene
from stepnf.verify import command as verify

pytestmark = [requires("KratosMultiphysics", "stepnf_kratos"), pytest.mark.slow]

SCENE = """[model]
solver = "kratos"
element = "dkt"

[model.geometry]
shape = "spherical_cap"
a = 0.15
R = "inf"
h = 0.003
n_core = 3
n_ring = 1

[model.material]
E = 1.04e11
nu = 0.3
rho = 4400.0

[analysis]
master_modes = ["(2,0)"]
methods = ["dnf"]
thickness = 0.003

[analysis.backbone]
order = 7
points = 4
"""


def test_dkt_plate_backbone_against_kratos_orbits(tmp_path):
    path = tmp_path / "plate_dkt.toml"
    path.write_text(SCENE)
    t0 = time.perf_counter()
    doc = verify.verify_scene(load_scene(path), periods=2, rtol=1e-5, fractions=(0.25, 0.5))
    seconds = time.perf_counter() - t0
    print(verify.format_report(doc), f"\n{seconds:.1f} s")
    assert doc["method"] == "integration"
    (mode,) = doc["modes"]
    assert tuple(mode["label"]) == (2, 0) and "failed" not in mode
    assert mode["amplitudes_from"].startswith("validity limit")  # W_max/h ~ 1 there: below the cap of 2
    checks = mode["checks"]
    assert len(checks) == 2
    # W_max on the translations (measured 0.25 and 0.51 h); counting the rotations (radians) it was ~13x that
    for c, top in zip(checks, (0.35, 0.7)):
        assert 0.1 < c["max_displacement"] / 0.003 < top, c
    for c in checks:
        assert abs(c["relative_difference"]) < 1e-3, c
        assert c["manifold_distance"] < 1e-2, c  # the orbit stays on the parametrised manifold
    assert checks[1]["omega_check_over_omega"] - 1 > 0.02  # hardening, visibly (measured 3.8 %)
