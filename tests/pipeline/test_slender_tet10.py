"""The tet10 cantilever strip at L/h = 1000 by FEniCSx (issue 31, item 1): run, each mode judged by its own rounding.

The strip of tests/helpers/cantilever.py (C3D10 read as P2 tetrahedra, 100 x 3 x 2 boxes of 6 tetrahedra, 21000
dofs, clamped at x = 0, nu = 0), masters 0 and 2 (the first two bending modes in z). Its lowest eigenvalue is
4e-15 of the largest: the run was refused as a whole (the global bound eps lambda_max / lambda_1 = 4e-2), and
before that the fundamental was taken for a mechanism. Each mode's own bound, ``eps |phi|^T |K| |phi| / lambda``
(stepnf.nf.roundoff.eigenvalue_roundoff), measured: mode 0: 2.7e-2 (refused: beyond 1%, T n/a), mode 2: 6.9e-4
(flagged, kept). Against the truth (measured, same mesh): mode 0's eigenvalue is 2.0e-3 off the Rayleigh
quotient of its own vector in long double, mode 2's 5.1e-5 (both within their bounds), and ccx's *FREQUENCY on
the same deck gives mode 2 at 3.300994 rad/s, ours 3.300946 (2.9e-5 in w^2).
"""
from __future__ import annotations

import pytest

from stepnf.flags import t_unusable
from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import load_scene
from helpers.cantilever import gamma_theory, strip_nx, write_mesh_scene, write_strip_deck
from helpers.required import requires


@pytest.mark.slow
@pytest.mark.fenicsx
@requires("dolfinx")
def test_tet10_strip_at_1000_runs_mode_2_within_3_percent(tmp_path):
    """Mode 2's Gamma against the theory with the axial-stiffness correction (the bench's reference): measured
    -0.67% at nx = 100 (-0.04% at nx = 200), error estimate 3e-10; 3% is the issue's target. Mode 0 is n/a
    (``unresolved_mode``: its own bound 2.7e-2 > 1%); the number kept in the JSON is +4.6% off at nx = 100
    (-0.4% at nx = 200). ~7 s here (21000 dofs). Before this change: exit 2 (a "mechanism"), or with
    rigid_modes = 0 exit 3 (ill-conditioned model), no T at all."""
    deck = write_strip_deck(tmp_path, 1000, "tet10", nx=strip_nx(1000))
    res = run_scene(load_scene(write_mesh_scene(deck)), write=False)
    assert [m.index for m in res.modes] == [0, 2]
    first, second = (m.methods["dnf"] for m in res.modes)
    assert t_unusable(second) is None, second.flags
    assert abs(second.gamma / gamma_theory(2, 1000, extensible=True) - 1) < 0.03, second.gamma
    why = t_unusable(first)
    assert why is not None and why[0] == "unresolved_mode", first.flags
    (ill,) = [f for f in res.flags if f["kind"] == "ill_conditioned"]
    assert ill["refused"] == [0] and 1e-2 < ill["bounds"][0] < 0.1 and 1e-6 < ill["bounds"][2] < 1e-2
