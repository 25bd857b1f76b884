"""How far the eigen-solve must reach for manifolds (issue 33): ``manifolds = "auto"`` looks for partners among the
COMPUTED modes near h w_p, h <= min(N, 4), and explicit manifolds named by labels need those labels found.

Before this check, the 38k-dof cap with master (2,1) and ``manifolds = "auto"`` stopped its eigen-solve at
1.22 w_p (mode 14): "auto" found no 1:2 partner (there is one at 1.931 w_p) and said none exists.
"""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from stepnf.pipeline.modes import enough_modes, manifold_reach
from stepnf.scene.parse import parse_scene


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _scene(backbone: dict, masters=(0,)):
    data = {"model": {"solver": "polynomial", "file": "near_one_to_four.npz"},
            "analysis": {"master_modes": list(masters), "methods": ["dnf"], "backbone": backbone}}
    return parse_scene(data, file=None, base_dir=EXAMPLES)


class _Labels:
    """Labels of a made-up shell spectrum: mode i is "(i,0)"."""

    def of(self, basis):
        return [(i, 0) for i in range(basis.n_elastic)]


def _basis(omega):
    return SimpleNamespace(omega=np.asarray(omega, dtype=float), n_elastic=len(omega), complete=False)


def _state(scene):
    return SimpleNamespace(scene=scene, tol=SimpleNamespace(resonance=0.05))


def test_auto_asks_for_the_modes_up_to_four_times_the_master():
    # 1 + tol = 1.05: enough once a mode reaches 1.05 x min(N, 4) x w of the highest master (w_0 = 1 here)
    auto = _scene({"order": 7, "manifolds": "auto"})
    assert manifold_reach(auto) == 4.0
    enough = enough_modes(_state(auto), _Labels())
    assert not enough(_basis([1.0, 1.3, 2.0, 3.9]))
    assert enough(_basis([1.0, 1.3, 2.0, 3.9, 4.3]))
    # order 3 looks for 1:2 and 1:3 only
    assert manifold_reach(_scene({"order": 3, "manifolds": "auto"})) == 3.0


def test_without_auto_the_reach_is_unchanged():
    plain = _scene({"order": 7})
    assert manifold_reach(plain) == 1.0
    assert enough_modes(_state(plain), _Labels())(_basis([1.0, 1.3]))
    explicit = _scene({"order": 7, "manifolds": [[0, 1]]})
    assert manifold_reach(explicit) == 1.0


def test_explicit_labels_are_found_before_the_solve_stops():
    # the manifold names "(3,0)": mode 3 of this spectrum; a basis of three modes does not hold it yet
    scene = _scene({"order": 7, "manifolds": [["(0,0)", "(3,0)"]]}, masters=("(0,0)",))
    enough = enough_modes(_state(scene), _Labels())
    assert not enough(_basis([1.0, 1.3, 2.0]))
    assert enough(_basis([1.0, 1.3, 2.0, 3.0, 3.5]))
