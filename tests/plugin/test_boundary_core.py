"""The solver-independent part of boundary conditions and of Gamma for any structure (issue 11).

References: exact index arithmetic (FreeDofs), hand-built nodal fields (transverse peaks), the
definition Gamma = T (h / max|phi . e|)^2 recomputed from the stored mode shape, and a spring
chain whose conditions leave a known number of rigid modes.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.plugin.adapter import SolverAdapter
from stepnf.plugin.boundary import (BOUNDARY_KEY, FreeDofs, boundary_conditions, box_tolerance, fixed_dofs,
                             select_nodes)
from stepnf.cli.main import main
from stepnf.errors import SceneError
from stepnf.nf.gamma import transverse_peak
from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import load_scene, parse_scene
from stepnf.keys.schema import Schema
from stepnf_polynomial import save_system
from helpers.systems import random_system, use_solver

KEYS = Schema(BOUNDARY_KEY)
POINTS = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 1, 0]])


def conditions(*tables):
    return boundary_conditions(KEYS.check({"boundary": list(tables)}, file="s.toml")["boundary"], "s.toml")


def test_conditions_select_sets_and_boxes():
    bcs = conditions({"set": "LEFT"}, {"box": [[1.5, -1, -1], [2.5, 0.5, 1]], "dofs": ["uz", "ux"]})
    assert bcs[0].dofs == (0, 1, 2) and bcs[1].dofs == (0, 2)
    fixed = fixed_dofs(bcs, POINTS, {"LEFT": np.array([0])}, "s.toml")
    assert fixed.tolist() == [0, 1, 2, 6, 8]  # node 0 clamped, node 2 (inside the box): ux, uz
    # a box whose faces pass through nodes: the round-off margin keeps them
    (only,) = conditions({"box": [[1.0, 0, 0], [1.0, 0, 0]]})
    assert select_nodes(only, POINTS + 1e-13, {}, "s.toml").tolist() == [1]
    assert box_tolerance(POINTS) == pytest.approx(1e-6 * math.sqrt(5.0))


@pytest.mark.parametrize("table, key, text", [
    ({"set": "L", "box": [[0, 0, 0], [1, 1, 1]]}, "model.boundary[0]", "exactly one of"),
    ({"dofs": ["ux"]}, "model.boundary[0]", "exactly one of"),
    ({"set": "L", "dofs": ["ux", "rx"]}, "model.boundary[0].dofs[1]", "expected one of ['ux', 'uy', 'uz']"),
    ({"set": "L", "dofs": ["ux", "ux"]}, "model.boundary[0].dofs", "without repeats"),
    ({"set": "L", "dofs": []}, "model.boundary[0].dofs", "non-empty"),
    ({"box": [[0, 0, 0], [1, 1]]}, "model.boundary[0].box", "two corners"),
    ({"box": [[1, 0, 0], [0, 1, 1]]}, "model.boundary[0].box", "first corner must be the lower"),
    ({"box": [[0, 0, 0], [1, 1, float("nan")]]}, "model.boundary[0].box[1][2]", "finite"),
    ({"set": "L", "colour": 1}, "model.boundary[0].colour", "unknown key"),
])
def test_bad_condition_tables(table, key, text):
    with pytest.raises(SceneError) as info:
        conditions(table)
    assert info.value.key == key and text in str(info.value)


def test_missing_set_lists_the_sets_and_empty_box_says_where_the_nodes_are():
    (bc,) = conditions({"set": "RIGHT"})
    with pytest.raises(SceneError, match=r"no node set 'RIGHT' in the mesh of beam.msh; it has \['LEFT', 'TOP'\]"):
        select_nodes(bc, POINTS, {"TOP": [3], "LEFT": [0]}, "s.toml", mesh="beam.msh")
    (bc,) = conditions({"box": [[5, 5, 5], [6, 6, 6]]})
    with pytest.raises(SceneError, match=r"holds no node of the mesh \(its nodes span \[0.0, 0.0, 0.0\] \.\. "
                                         r"\[2.0, 1.0, 0.0\]"):
        select_nodes(bc, POINTS, {}, "s.toml")


def test_free_dofs_maps():
    fd = FreeDofs(6, [4, 1, 4])
    assert fd.free.tolist() == [0, 2, 3, 5] and fd.n_free == 4 and fd.describe() == {"n_full": 6, "n_fixed": 2}
    u = np.arange(6.0) + 1
    assert fd.restrict(u).tolist() == [1, 3, 4, 6]
    assert fd.expand(fd.restrict(u)).tolist() == [1, 0, 3, 4, 0, 6]
    U = np.vstack([u, 2 * u])  # a batch along the last axis
    assert fd.expand(fd.restrict(U)).shape == (2, 6)
    A = sp.csr_matrix(np.arange(36.0).reshape(6, 6))
    assert np.array_equal(fd.restrict_matrix(A).toarray(), A.toarray()[np.ix_(fd.free, fd.free)])
    v = u[:3]
    assert FreeDofs(3).all_free and FreeDofs(3).restrict(v) is v  # nothing fixed: no copy
    with pytest.raises(ValueError):
        FreeDofs(3, [3])


def test_transverse_peak_by_name_and_direction():
    X = np.repeat(POINTS[:2], 3, axis=0)[[0, 2, 3, 4, 5]]  # node 0 has no uy dof (fixed)
    D = np.array([0, 2, 0, 1, 2])
    phi = np.array([0.1, -0.5, 0.3, 0.4, 0.2])
    assert transverse_peak(phi, X, D, "uz") == pytest.approx(0.5)
    assert transverse_peak(phi, X, D, "uy") == pytest.approx(0.4)
    e = (0.6, 0.8, 0.0)  # node 0: 0.06; node 1: 0.18 + 0.32
    assert transverse_peak(phi, X, D, e) == pytest.approx(0.5)
    assert transverse_peak(phi, X, np.zeros(5, int), "uz") is None


# ------------------------------------------------------------------ Gamma of any structure
def polynomial_scene(tmp_path, extra=""):
    M, K, G, H = random_system(6, seed=4)
    X = np.column_stack([np.arange(6.0), np.zeros(6), np.zeros(6)])  # six nodes, one uz dof each
    save_system(tmp_path / "s.npz", M, K, G, H, coordinates=X, directions=np.full(6, 2))
    p = tmp_path / "s.toml"
    p.write_text('[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0, 1]\n'
                 f'methods = ["dnf", "nf"]\nretained_modes = 6\n{extra}[output]\ndir = "out"\nhdf5 = false\n')
    return p


def test_gamma_of_any_structure(tmp_path):
    res = run_scene(load_scene(polynomial_scene(tmp_path, 'thickness = 0.25\ntransverse = "uz"\n')))
    phi = res.arrays["phi_masters"]
    for j, mode in enumerate(res.modes):
        w_max = float(np.abs(phi[:, j]).max())
        for r in mode.methods.values():
            # the definition, recomputed from the stored shape: only the last bits of a product differ
            assert r.gamma == pytest.approx(r.T * (0.25 / w_max) ** 2, rel=1e-14)
    assert res.model["gamma"].startswith("h = 0.25 (analysis.thickness)")
    assert "no_gamma" not in {f["kind"] for f in res.flags}


def test_without_thickness_gamma_is_null_and_said(tmp_path, capsys):
    res = run_scene(load_scene(polynomial_scene(tmp_path)))
    assert all(r.gamma is None for m in res.modes for r in m.methods.values())
    (flag,) = [f for f in res.flags if f["kind"] == "no_gamma"]
    assert "[analysis] thickness" in flag["message"]
    assert main(["run", str(polynomial_scene(tmp_path)), "-q"]) == 0
    assert "note: Gamma = T (h / W_max)^2 needs a thickness h" in capsys.readouterr().out


@pytest.mark.parametrize("value, text", [("uw", "expected one of"), ([0, 0, 0], "must not be zero"),
                                         ([1, 0], "direction vector"), (True, "expected one of")])
def test_bad_transverse(tmp_path, value, text):
    data = {"model": {"solver": "polynomial", "file": "x.npz"},
            "analysis": {"master_modes": [0], "methods": ["nf"], "transverse": value}}
    with pytest.raises(SceneError, match=text):
        parse_scene(data, check_model=False)


# ------------------------------------------------------------------ a mechanism left by the conditions
class SpringChain(SolverAdapter):
    """Unit masses on a line (uz dofs), springs between neighbours, a cubic spring at each: the nodes of
    ``fixed`` held. Holding one node of a chain leaves no rigid mode; conditions that hold nothing
    (``fixed = ()``, still reported through ``free_dof_map``) leave one."""

    def __init__(self, fixed=(0,), n=5):
        self.full = n
        self.fd = FreeDofs(n, fixed)
        K = sp.diags([-np.ones(n - 1), np.r_[1.0, 2 * np.ones(n - 2), 1.0], -np.ones(n - 1)], [-1, 0, 1])
        self.K, self.M = self.fd.restrict_matrix(K), self.fd.restrict_matrix(sp.identity(n))

    @property
    def n_dofs(self):
        return self.fd.n_free

    def mass_matrix(self):
        return self.M

    def stiffness_matrix(self):
        return self.K

    def _internal_force(self, u):
        return self.K @ u + u**3

    def free_dof_map(self):
        return self.fd

    def dof_coordinates(self):
        return np.column_stack([np.arange(self.full), np.zeros(self.full), np.zeros(self.full)])[self.fd.free]

    def dof_directions(self):
        return np.full(self.fd.n_free, 2)


def chain_scene(tmp_path, extra=""):
    p = tmp_path / "c.toml"
    p.write_text('[model]\nsolver = "chain"\n[analysis]\nmaster_modes = [0]\nmethods = ["dnf"]\n'
                 f'{extra}[output]\ndir = "out"\n')
    return p


def test_held_chain_runs_and_maps_back(tmp_path, monkeypatch):
    use_solver(monkeypatch, lambda name: SpringChain)
    res = run_scene(load_scene(chain_scene(tmp_path)))
    assert res.spectrum["n_rigid"] == 0
    assert res.arrays["free_dofs"].tolist() == [1, 2, 3, 4] and int(res.arrays["n_full_dofs"]) == 5


def test_conditions_leaving_a_mechanism_are_refused(tmp_path, monkeypatch, capsys):
    use_solver(monkeypatch, lambda name: type("Loose", (SpringChain,), {"__init__": lambda self: SpringChain.__init__(
        self, fixed=())}))
    assert main(["run", str(chain_scene(tmp_path)), "-q"]) == 2
    err = capsys.readouterr().err
    assert "[model.boundary]" in err and "leave one rigid-body mode" in err and "rigid_modes = 1" in err
    assert not (tmp_path / "out" / "c.h5").exists()
    # accepted when the count is the user's
    res = run_scene(load_scene(chain_scene(tmp_path, "rigid_modes = 1\n")))
    assert res.spectrum["n_rigid"] == 1
