"""The backbone block of a master on a manifold of several modes (stepnf.dpim.manifold_report).

Reference: on a pair without resonance (helpers.systems.two_dof, w = 1 and 3.6) the branch that continues mode
0 is the single-mode backbone (tests/dpim/test_branches.py: 4e-16), so the block's frequencies and W_max / h at
its amplitudes are the single-mode DPIM's (stepnf.dpim.backbone) to round-off.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from stepnf.dpim.manifold_report import manifold_report
from stepnf.dpim.multimode.backbone import backbone_branches
from stepnf.dpim.multimode.manifold import parametrise_manifold
from stepnf.dpim.parametrisation import DPIM
from stepnf.keys.backbone import BackboneSpec
from helpers.systems import batch_force, modes, two_dof


@pytest.fixture(scope="module")
def pair():
    M, K, G, H = two_dof()
    f = batch_force(K, G, H)
    w, V = modes(K, M)
    man = parametrise_manifold(DPIM(f, K, M), [0, 1], V, w, 9, probe=1.0)
    single = DPIM(f, K, M).parametrise(V[:, 0], w[0], 9, probe=1.0).backbone()
    return man, backbone_branches(man, 0, 1.5, transverse=[1], h=0.1), single


def test_grid_block_equals_the_single_mode_backbone(pair):
    """The grid up to the validity limit: omega and W_max / h equal the single-mode series' (measured 1e-16,
    2e-16); the block is JSON (no NaN) with the keys of today's plus manifold, branch, coupled_branches."""
    man, branches, single = pair
    b = manifold_report(man, 0, branches, BackboneSpec(order=9, points=5), probe=1.0, resonance=0.05,
                        transverse=[1], h=0.1)
    json.dumps(b, allow_nan=False)
    assert {"order", "amplitude", "omega", "omega_ratio", "w_max_over_h", "valid_up_to", "valid_reason", "grid",
            "tolerance", "probe", "flags", "counts", "manifold", "branch", "coupled_branches"} == set(b)
    assert b["amplitude"][-1] == b["valid_up_to"] and b["grid"] and b["manifold"]["ratios"] is None
    for A, om, wh in zip(b["amplitude"], b["omega"], b["w_max_over_h"]):
        assert om == pytest.approx(single.omega_at(A)[0], rel=1e-12, abs=0)
        assert wh == pytest.approx(single.w_max(single.rho_at(A), [1], 0.1), rel=1e-10)


def test_w_over_h_targets(pair):
    """W_max / h targets: the amplitude where the branch reaches each (to 1e-12), one it never reaches is
    null with a backbone_unreached flag."""
    man, branches, single = pair
    b = manifold_report(man, 0, branches, BackboneSpec(order=9, w_over_h=(0.5, 1.0, 100.0)), probe=1.0,
                        transverse=[1], h=0.1)
    assert b["w_max_over_h"][:2] == pytest.approx([0.5, 1.0], rel=1e-12) and b["amplitude"][2] is None
    assert b["omega"][2] is None and any(f["kind"] == "backbone_unreached" for f in b["flags"])
    A = b["amplitude"][1]
    assert single.w_max(single.rho_at(A), [1], 0.1) == pytest.approx(1.0, rel=1e-10)
