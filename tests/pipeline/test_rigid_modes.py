"""Rigid-body modes decided from the model through the whole run (issue 31, item 3): a polynomial model with no
zero eigenvalue has no rigid mode, however low its fundamental; one with true zero eigenvalues keeps them, and
the listing names the key that governs them.

Frequencies of a diagonal K with M = I are exact (``sqrt`` of the diagonal), hence the 1e-12 tolerances.
The tet10 strip at L/h = 600 (coarse: 6 boxes along the length, 1260 dofs, the dense path) is the issue's
FEniCSx case: its lowest three eigenvalues lie below rigid_tolerance x lambda_max.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from helpers.cantilever import E, NU, RHO, strip_tet10
from helpers.hostile import run_cli
from helpers.required import requires
from helpers.systems import random_system
from stepnf_polynomial import save_system


def write_scene(folder, name, K, M=None, rigid: str = ""):
    n = K.shape[0]
    G = np.zeros((n, n, n))
    H = np.zeros((n,) * 4)
    H[0, 0, 0, 0] = 1.0
    save_system(folder / f"{name}.npz", np.eye(n) if M is None else M, K, G, H)
    p = folder / f"{name}.toml"
    p.write_text(f'[model]\nsolver = "polynomial"\nfile = "{name}.npz"\n[analysis]\nmaster_modes = [0]\n'
                 f'methods = ["nf", "dnf"]\n{rigid}\n[output]\ndir = "out"\nname = "{name}"\n')
    return p


def test_a_fundamental_far_below_the_tolerance_is_mode_0(tmp_path, capsys):
    """K = diag(1, 1e12, 2e12): the fundamental is 5e-13 of the largest eigenvalue, below rigid_tolerance (1e-11),
    and K has no null vector: mode 0 at 1 rad/s (was: counted rigid, mode 0 at 1e6). Its own rounding bound is
    eps (``eps |phi|^T |K| |phi| / lambda`` of a diagonal K): no ill_conditioned flag (was: flagged from the
    global ratio, eps / 5e-13 = 4e-4, which said nothing of this mode)."""
    p = write_scene(tmp_path, "spread", np.diag([1.0, 1e12, 2e12]))
    o = run_cli(["run", p, "-q", "--json"], capsys)
    assert o.code == 0, o.err
    doc = json.loads(o.out)
    assert doc["spectrum"]["n_rigid"] == 0
    assert doc["modes"][0]["omega"] == pytest.approx(1.0, rel=1e-12)
    assert "ill_conditioned" not in {f["kind"] for f in doc["flags"]}


def test_diag_1_1e14_is_not_mode_0_at_1e7(tmp_path, capsys):
    """K = diag(1, 1e14): the fundamental is kept as mode 0 (was: exit 0, mode 0 at 1e7 rad/s with T = 0, the
    fundamental dropped as a rigid mode without a word). Its eigenvalue is exact (a diagonal K: its own rounding
    bound eps |phi|^T |K| |phi| / lambda is eps), so the run gives it, with T = 3 H / (8 w^2) = 0.375 (H_0000 = 1,
    G = 0; STEP of an exact cubic: round-off only); the refusal from the global ratio (eps / 1e-14 = 2%, exit 3)
    is gone: it said nothing of this mode."""
    p = write_scene(tmp_path, "diag", np.diag([1.0, 1e14]))
    o = run_cli(["run", p, "-q", "--json"], capsys)
    assert o.code == 0, o.err
    run = json.loads(o.out)
    assert run["modes"][0]["omega"] == pytest.approx(1.0, rel=1e-12)
    assert run["modes"][0]["methods"]["dnf"]["T"] == pytest.approx(0.375, rel=1e-10)
    assert "ill_conditioned" not in {f["kind"] for f in run["flags"]}
    o = run_cli(["modes", p, "-q", "--json"], capsys)
    assert o.code == 0, o.err
    doc = json.loads(o.out)
    assert doc["n_rigid"] == 0 and doc["modes"][0]["omega"] == pytest.approx(1.0, rel=1e-12)


def test_true_rigid_modes_stay_and_the_listing_names_the_key(tmp_path, capsys):
    """Two exact zero eigenvalues (K of rank n - 2): two rigid modes, and `stepnf modes` says which key governs
    them (was: the count alone)."""
    M, K, _, _ = random_system(8, seed=3, rigid=2)
    p = write_scene(tmp_path, "free", K, M)
    o = run_cli(["modes", p, "-q"], capsys)
    assert o.code == 0, o.err
    assert "rigid-body modes found: 2" in o.out and 'rigid_modes = "auto"' in o.out


@pytest.mark.fenicsx
@requires("dolfinx")
def test_tet10_strip_clamped_by_a_box_has_its_fundamental(tmp_path, capsys):
    """L/h = 600 tet10 strip clamped by a box (FEniCSx): no rigid mode, mode 0 bends in z at 1.470 rad/s (was:
    "3 rigid-body modes", `stepnf run` exit 2, and with rigid_modes = 3 mode 0 at 28.2 rad/s). Reference: the
    same coarse mesh's fundamental measured 1.47041; ccx on a 40-box mesh gives 1.4632 (the coarse mesh is
    0.5% stiff), so 2% tells the fundamental from any other mode (the next bending-in-z mode is at 9.5)."""
    import meshio

    pts, cells = strip_tet10(600, 6, 3, 2)
    meshio.write(tmp_path / "strip.vtu", meshio.Mesh(pts, [("tetra10", cells)]))
    p = tmp_path / "strip.toml"
    p.write_text(f'[model]\nsolver = "fenicsx"\nmesh = "strip.vtu"\n[model.material]\nE = {E!r}\nnu = {NU!r}\n'
                 f'rho = {RHO!r}\n[[model.boundary]]\nbox = [[0.0, -1.0, -1.0], [0.0, 1.0, 1.0]]\n[analysis]\n'
                 'master_modes = [0]\nmethods = ["dnf"]\n[output]\ndir = "out"\n')
    o = run_cli(["modes", p, "-q", "--json", "-n", "3"], capsys)
    assert o.code == 0, o.err
    doc = json.loads(o.out)
    assert doc["n_rigid"] == 0
    assert doc["modes"][0]["omega"] == pytest.approx(1.4632, rel=2e-2)
    assert doc["modes"][0]["energy"]["uz"] > 0.99
