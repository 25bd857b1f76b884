"""``stepnf verify`` on a model with rotation dofs (issue 32, item 1): W_max is measured on the translations.

The six-dof model of tests/helpers/shell_dofs.py: mode 0 is a Duffing oscillator whose shape has its
largest entry on a rotation (``rx = 8`` rad per unit modal amplitude) and its largest translation ``uz = 0.6``
(model length units), the force a cubic in mode 0's coordinate only, so the manifold is the flat
``x = q phi0`` and the orbit's state at rest is ``A phi0``: W_max = 0.6 A exactly (not 8 A, the rotation).
With ``[analysis] thickness = 0.1`` the default amplitudes' top is where W_max/h = 2: A = 2 x 0.1 / 0.6 = 1/3
(before, W_max counted the rotation: 8 A = 0.2, A = 0.025, an orbit 13 times too small).
"""
from __future__ import annotations

import numpy as np
import pytest

from helpers.shell_dofs import H, W_MAX, SixDofPlate, scene_text
from helpers.systems import use_solver
from stepnf.verify import command as verify
from stepnf.verify.deflection import DEFAULT_DEFLECTION


def test_wmax_and_default_cap_use_translations(tmp_path, monkeypatch):
    from stepnf.scene.parse import load_scene

    use_solver(monkeypatch, lambda name: SixDofPlate)
    path = tmp_path / "s.toml"
    path.write_text(scene_text().replace('[output]', '[analysis.backbone]\norder = 7\n[output]'))
    doc = verify.verify_scene(load_scene(path), fractions=(0.5, 1.0))
    (mode,) = doc["modes"]
    assert "W_max/h = 2" in mode["amplitudes_from"], mode["amplitudes_from"]
    top = DEFAULT_DEFLECTION * H / W_MAX  # 1/3: W_max/h = 2 on the translations (module docstring)
    A = [c["amplitude"] for c in mode["checks"]]
    # brentq to 1e-10 on the backbone's own W_max(A); the flat manifold gives it exactly
    assert A == pytest.approx([top / 2, top], rel=1e-8)
    for c in mode["checks"]:
        # the orbit's start by shooting (Newton to ~1e-12 of the state): A phi0, its largest translation 0.6 A
        assert c["max_displacement"] == pytest.approx(W_MAX * c["orbit_amplitude"], rel=1e-8)
        assert abs(c["relative_difference"]) < 1e-6  # DPIM order 7 of a Duffing at w_NL/w - 1 ~ 1.5%: ~1e-8
