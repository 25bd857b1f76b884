"""The cantilever strips' CalculiX decks as FEniCSx meshes (issue 31, item 1: bench/cantilever.py's fenicsx route).

The benchmark runs the SAME C3D10 and C3D20 decks by both routes; the fenicsx route reads them as meshes
(``tests/helpers/cantilever.py``, ``write_mesh_scene``: ``[model.material]`` and ``[[model.boundary]]
set = "CLAMP"``), so it relies on what is checked here: C3D10 read as P2 tetrahedra, the clamp held, and
the strip's masters 0 and 2 bending in the thickness direction (mode 1 bends in the width, b = 3h).
"""
from __future__ import annotations

import pytest

pytest.importorskip("dolfinx")  # a required tool on Debian 12 and 13: conftest fails the test when it is missing

from stepnf.pipeline.run import run_scene  # noqa: E402
from stepnf.scene.parse import load_scene  # noqa: E402
from helpers.cantilever import E, H, RHO, WIDTH_RATIO, linear_frequency, write_mesh_scene, write_strip_deck  # noqa: E402


@pytest.mark.fenicsx
def test_tet10_strip_deck_runs_as_a_p2_mesh_with_its_bending_masters(tmp_path):
    """L/h = 30, 10 x 3 x 2 boxes of C3D10 (the bench uses 40 along the length): masters 0 and 2 carry
    >= 99% of their kinetic energy in uz (measured 0.9996 and 0.997 on the converged hex20 strip: in-plane
    motion of a bending mode at L/h = 30 is ~(h/L)^2 small), mode 0's frequency within 3% of the
    Euler-Bernoulli cantilever (shear and rotary inertia: -0.06% at L/h = 30; a coarse tet10 mesh is
    stiffer by a few 0.1%), and the dof count that of P2 on the deck's 10-node tetrahedra: 3 x (nodes -
    clamped nodes)."""
    deck = write_strip_deck(tmp_path, 30, "tet10", nx=10)
    res = run_scene(load_scene(write_mesh_scene(deck, (0, 2))), write=False)
    nodes = (2 * 10 + 1) * (2 * 3 + 1) * (2 * 2 + 1)  # the half-cell grid of the Kuhn split: every grid node used
    clamped = (2 * 3 + 1) * (2 * 2 + 1)
    assert res.model["n_dofs"] == 3 * (nodes - clamped)
    assert res.model["degree"] == 2
    for m in res.modes:
        assert m.transverse_share > 0.99, (m.index, m.transverse_share)
    L, b, h = 30 * H, WIDTH_RATIO * H, H
    w1 = linear_frequency(1, E, b * h**3 / 12, RHO, b * h, L)
    assert abs(res.modes[0].omega / w1 - 1) < 0.03
