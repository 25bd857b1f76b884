"""Honest Gamma (issue 31, item 7): Gamma = T (h / W_max)^2 is n/a (flagged, the number kept) when the transverse
direction carries a small share of the mode's kinetic energy, and Gamma is printed with significant digits.

References: the shares of hand-built fields (exact: 1, 0, cos^2 of the angle to the direction, with M = I or
a lumped M), and examples/beam_ccx (width 2h, transverse = "uz"): its first mode bends in z (Gamma 0.2694,
tests/solvers/calculix/test_beam_gamma.py), its second bends sideways in y, where W_max is the uz of a mode
that has almost none (Gamma +296547 printed unflagged before this change).
"""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.cli.main import main
from stepnf.flags import gamma_unusable, t_unusable
from stepnf.io.results import ModeResult, RunResult
from stepnf.nf.coefficient import MethodResult
from stepnf.nf.gamma import GAMMA_SHARE_MIN, share_flag, transverse_share
from stepnf.report.table import format_table
from helpers.paths import REPO
from helpers.required import requires

# two nodes, dofs ux, uy, uz each (direction codes 0, 1, 2), one node at x = 0 and one at x = 1
X = np.repeat([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], 3, axis=0)
D = np.tile([0, 1, 2], 2)


def test_share_of_hand_built_fields():
    """Exact by construction: a field along e has share 1, across it 0; at 30 degrees to e, cos^2 30 = 0.75;
    a lumped M weighs the nodes (node 1 four times heavier: its uy alone gives 4 / 5 with e = uy)."""
    M = sp.identity(6, format="csr")
    uz, uy = np.array([0, 0, 1, 0, 0, 1.0]), np.array([0, 1, 0, 0, 1, 0.0])
    assert transverse_share(uz, M, X, D, "uz") == pytest.approx(1.0, abs=1e-15)
    assert transverse_share(uy, M, X, D, "uz") == pytest.approx(0.0, abs=1e-15)
    e = (0.0, np.sin(np.pi / 6), np.cos(np.pi / 6))  # a direction vector: per-node projection
    assert transverse_share(uz, M, X, D, e) == pytest.approx(0.75, rel=1e-14)
    assert transverse_share(uz, M, X, D, tuple(3 * c for c in e)) == pytest.approx(0.75, rel=1e-14)  # not unit
    lumped = sp.diags([1, 1, 1, 4, 4, 4.0])
    assert transverse_share(np.array([0, 1, 0, 0, 1, 1.0]), lumped, X, D, "uy") == pytest.approx(5 / 9, rel=1e-14)
    assert transverse_share(uz, M, X, None, "uz") is None  # no dof directions: no share, no flag
    assert share_flag(None) is None and share_flag(GAMMA_SHARE_MIN) is None
    assert share_flag(0.004)["kind"] == "gamma_not_transverse"


def table_of(gamma: float, flags=()) -> str:
    r = MethodResult("dnf", 0.25, (0.0,) * 6, flags=list(flags))
    r.gamma = gamma
    mode = ModeResult(index=0, label=None, omega=1.0, rho=None, methods={"dnf": r})
    return format_table(RunResult(scene={}, modes=[mode], counts={}, timings={}, spectrum={}))


def test_small_gamma_is_printed_with_its_digits():
    """A cantilever's Gamma ~1e-5 printed +0.0000 with four fixed decimals before; now four significant digits."""
    assert "+1.235e-05" in table_of(1.23456e-5) and "+0.0000" not in table_of(1.23456e-5)
    assert "+0.2694" in table_of(0.269363)
    assert "-2.965e+05" in table_of(-296547.0229)


def test_flag_makes_gamma_alone_na():
    """The catalogue's gamma_na: the Gamma cell n/a with a line saying why, T and the behaviour kept."""
    flag = share_flag(0.004)
    table = table_of(5.13, [flag])
    row = next(line.split() for line in table.splitlines() if " dnf " in f" {line} ")
    assert row[row.index("dnf") + 1:row.index("dnf") + 4] == ["+2.5000e-01", "n/a", "hardening"]
    assert "Gamma n/a [0 dnf]: the transverse direction carries 0.4% of the mode's kinetic energy" in table
    r = MethodResult("dnf", 0.25, (0.0,) * 6, flags=[flag])
    assert t_unusable(r) is None and gamma_unusable(r) == flag["message"]


@requires("ccx")
def test_beam_ccx_sideways_mode_gamma_is_na(tmp_path, capsys):
    """examples/beam_ccx with masters 0 and 1 (about 3 s of ccx): mode 1 bends sideways (uy), its uz share
    measured 1.2e-8, so its Gamma is n/a with a gamma_not_transverse flag (printed +296547.0229 before);
    the bending mode 0 (share 0.9999) keeps Gamma +0.2694. The JSON document keeps both numbers."""
    for f in (REPO / "examples" / "beam_ccx").iterdir():
        shutil.copy(f, tmp_path / f.name)
    scene = tmp_path / "beam_deck.toml"
    scene.write_text(scene.read_text().replace("master_modes = [0]", "master_modes = [0, 1]"))
    assert main(["run", str(scene), "-q", "--no-plot", "--no-hdf5", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    m0, m1 = doc["modes"]
    assert m0["transverse_share"] > 0.999 and m1["transverse_share"] < 1e-6  # measured 0.99990, 1.2e-8
    assert "gamma_not_transverse" not in [f["kind"] for f in m0["methods"]["dnf"]["flags"]]
    assert m0["methods"]["dnf"]["gamma"] == pytest.approx(0.2694, abs=5e-4)  # the clamped beam's (test_beam_gamma)
    kinds = [f["kind"] for f in m1["methods"]["dnf"]["flags"]]
    assert kinds.count("gamma_not_transverse") == 1
    assert m1["methods"]["dnf"]["gamma"] > 1e5  # the number is kept (measured 296547)
    assert main(["run", str(scene), "-q", "--no-plot", "--no-hdf5"]) == 0
    table = capsys.readouterr().out
    lines = table.splitlines()
    row = lines[next(i for i, line in enumerate(lines) if line.startswith("1 ")) + 1].split()  # mode 1's dnf
    assert row[0] == "dnf" and row[2] == "n/a" and "Gamma n/a [1 dnf]:" in table
    assert f"{m0['methods']['dnf']['gamma']:+.4g}" in table and "296547" not in table
