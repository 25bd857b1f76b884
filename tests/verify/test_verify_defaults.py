"""``stepnf verify`` with its default amplitudes on a cantilever strip (issue 31): the top amplitude capped
where the orbit's state at rest deflects two thicknesses (stepnf/verify/deflection.py).

Before the cap the defaults ran up to the backbone's validity limit, which a cantilever's nearly linear
first mode puts at tens of thicknesses. This strip, measured before: A = 0.0768, 0.154, 0.230 (the limit,
"shapes differ"), W_max/h = 10, 20, 30; the first orbit computed, the other two "Newton did not converge"
at steps 3 and 1 (modified Newton, secant, Newton-Krylov and three halvings tried), exit 3, 213 s.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from helpers.cantilever import H, write_mesh_scene, write_strip_deck
from helpers.required import requires
from helpers.scenes import run_verify
from stepnf.verify.deflection import DEFAULT_DEFLECTION, cap_amplitudes


@pytest.mark.fenicsx
@pytest.mark.slow
@requires("dolfinx")
def test_default_amplitudes_verify_a_cantilever(tmp_path, capsys):
    """L/h = 100, C3D20 20 x 1 x 1 read as Q2 bricks by FEniCSx (1080 dofs), DPIM order 7, first bending mode:
    three orbits at 1/3, 2/3 and 1 of the amplitude where W_max/h = 2, all computed (exit 0), the source
    said, and the backbone within 1e-4 of them (the integration's accuracy at the default rtol, 1e-6, and
    the order-7 series far inside its validity range; as tests/verify/test_verify_cantilever.py)."""
    deck = write_strip_deck(tmp_path, 100, "hex20", nx=20)
    scene = write_mesh_scene(deck, masters=(0,), analysis="\n[analysis.backbone]\norder = 7\n")
    code, out, err = run_verify(capsys, scene, "--json", "--quiet")
    assert code == 0, err
    (mode,) = json.loads(out)["modes"]
    assert not mode.get("failed"), mode.get("failed")
    assert mode["amplitudes_from"].startswith(f"W_max/h = {DEFAULT_DEFLECTION:g} at A = "), mode["amplitudes_from"]
    assert "validity limit" in mode["amplitudes_from"]  # what it was capped from
    checks = mode["checks"]
    tips = [c["max_displacement"] / H for c in checks]
    assert tips == pytest.approx([2 / 3, 4 / 3, 2.0], rel=1e-3)  # W_max/h grows like A here (linear to 1e-3)
    for c in checks:
        assert abs(c["relative_difference"]) < 1e-4, c


class _Line:
    """A stand-in backbone: the state at rest is A times a field whose largest entry is 1 (W_max = A)."""

    def __init__(self):
        self.res = self

    def rho_at(self, A):
        return A

    def displacement(self, theta, rho):
        return rho * np.array([0.25, -1.0, 0.5])


@pytest.mark.parametrize("h,amps,expected,capped", [
    (None, [1.0, 2.0, 3.0], [1.0, 2.0, 3.0], False),   # no thickness: the validity limit alone, as before
    (2.0, [1.0, 2.0, 3.0], [1.0, 2.0, 3.0], False),    # top W_max/h = 1.5 <= 2: unchanged (the plates' case)
    (1.0, [1.0, 2.0, 3.0], [2 / 3, 4 / 3, 2.0], True),  # top W_max/h = 3: scaled to 2 thicknesses
])
def test_cap_scales_only_beyond_two_thicknesses(h, amps, expected, capped):
    got, src = cap_amplitudes(_Line(), amps, "validity limit A = 3", h)
    assert got == pytest.approx(expected, rel=1e-9)
    assert src.startswith("W_max/h = 2 at A = 2 ") == capped and "validity limit A = 3" in src, src
