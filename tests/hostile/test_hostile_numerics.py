"""Hostile input, numerical stages: overflow, no stiffness, rigid-mode counts, soft modes, flags.

Each case runs ``stepnf run`` on a small polynomial system (no FE) and checks
the exit code, that no traceback reaches the user, that the message names the
key or stage, and that an earlier result file is untouched. The flag tests
check that a number the tool knows to be doubtful carries its flag once.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

import stepnf.pipeline.run as pipeline
from helpers.hostile import assert_reported, run_cli, snapshot
from stepnf.errors import ModelWarning
from stepnf.scene.parse import load_scene
from stepnf_polynomial import PolynomialAdapter, save_system
from helpers.systems import full_symmetrize, random_system, use_solver


def write_scene(tmp_path, name, M, K, G, H, analysis="", methods='["nf", "dnf", "md", "smd"]'):
    save_system(tmp_path / f"{name}.npz", M, K, G, H)
    p = tmp_path / f"{name}.toml"
    p.write_text(f'[model]\nsolver = "polynomial"\nfile = "{name}.npz"\n[analysis]\nmaster_modes = [0]\n'
                 f'methods = {methods}\n{analysis}\n[output]\ndir = "out"\nname = "run"\n')
    return p


@pytest.fixture
def earlier(tmp_path, capsys):
    """A good run's results in tmp_path/out (run.h5); returns the snapshot to compare with."""
    p = write_scene(tmp_path, "good", *random_system(6, seed=8))
    assert run_cli(["run", p, "-q"], capsys).code == 0
    return snapshot(tmp_path / "out")


def diagonal_system(omega, couplings):
    """M = I, K = diag(omega^2), G from a potential with G[s, 0, 0] = couplings[s] (and its symmetric images)."""
    n = len(omega)
    G = np.zeros((n, n, n))
    for s, c in couplings.items():
        G[s, 0, 0] = c
    G = 3 * full_symmetrize(G)  # G[s,0,0] = G[0,s,0] = G[0,0,s] = c
    H = np.zeros((n,) * 4)
    H[0, 0, 0, 0] = 1.0
    return np.eye(n), np.diag(np.asarray(omega) ** 2), G, H


@pytest.mark.parametrize("factor", [1e200, 1e250, 1e300])
def test_overflow_in_the_evaluators_is_a_numerical_error(tmp_path, capsys, earlier, factor):
    M, K, G, H = random_system(6, seed=8)
    p = write_scene(tmp_path, "big", M, K, G * factor, H)
    o = run_cli(["run", p, "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["evaluators", "overflow", "master 0"])
    assert snapshot(tmp_path / "out")["run.h5"] == earlier["run.h5"]  # a .partial folder may stay, for a resume


@pytest.mark.parametrize("scale", [0.0, -0.0])
def test_zero_stiffness_names_the_stiffness_not_a_master_mode(tmp_path, capsys, earlier, scale):
    M, K, G, H = random_system(6, seed=8)
    p = write_scene(tmp_path, "zero", M, scale * K, G, H)
    o = run_cli(["run", p, "-q"], capsys)
    assert_reported(o, codes=(3,), mentions=["no elastic mode", "stiffness matrix K", str(p)])
    assert "master_modes" not in o.err
    assert snapshot(tmp_path / "out")["run.h5"] == earlier["run.h5"]  # a .partial folder may stay, for a resume


@pytest.mark.parametrize("count", [6, 7, 1000])
def test_more_rigid_modes_than_dofs_names_the_key(tmp_path, capsys, earlier, count):
    p = write_scene(tmp_path, "rig", *random_system(6, seed=8), analysis=f"rigid_modes = {count}")
    o = run_cli(["run", p, "-q"], capsys)
    assert_reported(o, codes=(2,), mentions=["analysis.rigid_modes", "allowed 0..5", str(p)])
    assert snapshot(tmp_path / "out")["run.h5"] == earlier["run.h5"]  # a .partial folder may stay, for a resume


def test_a_given_rigid_count_below_the_dofs_is_honoured(tmp_path, capsys):
    """rigid_modes = 5 of 6 dofs (2 true rigid modes): the user's count stands, one elastic mode is left."""
    M, K, G, H = random_system(6, seed=3, rigid=2)
    p = write_scene(tmp_path, "r5", M, K, G, H, analysis="rigid_modes = 5", methods='["nf"]')
    o = run_cli(["run", p, "-q", "--json"], capsys)
    assert o.code == 0, o.err
    doc = json.loads(o.out)
    assert doc["spectrum"]["n_rigid"] == 5 and len(doc["spectrum"]["omega"]) == 1


def test_soft_elastic_modes_below_the_rigid_tolerance_stay_elastic(tmp_path, capsys):
    """Eigenvalues 1e-10 and 2e-10 (of lambda_max = 25) lie below rigid_tolerance x lambda_max (2.5e-10), but
    K has no null vector there (issue 31: the tolerance only names candidates): both stay elastic modes,
    no mode is set aside and nothing warns of soft modes counted rigid (was: both counted rigid, a warning)."""
    w = np.sqrt([1e-10, 2e-10, 1.0, 2.3, 3.1, 25.0])
    p = write_scene(tmp_path, "soft", *diagonal_system(w, {3: 0.1}))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ModelWarning)
        o = run_cli(["run", p, "-q", "--json"], capsys)
    assert o.code == 0 and "Traceback" not in o.err, o.err
    doc = json.loads(o.out)
    assert doc["spectrum"]["n_rigid"] == 0 and not [f for f in doc["flags"] if f["kind"] == "soft_modes_counted_rigid"]
    # K = diag(w^2) is exact: mode 0 is the first eigenvalue to the last bit
    assert doc["modes"][0]["omega"] == pytest.approx(1e-5, rel=1e-12)
    # the user who says how many rigid modes there are keeps that count
    p2 = write_scene(tmp_path, "soft2", *diagonal_system(w, {3: 0.1}), analysis="rigid_modes = 1")
    o2 = run_cli(["run", p2, "-q", "--json"], capsys)
    assert o2.code == 0, o2.err
    assert json.loads(o2.out)["modes"][0]["omega"] == pytest.approx(np.sqrt(2e-10), rel=1e-12)


def test_dnf_names_a_degenerate_pair_at_twice_the_frequency_once(tmp_path, capsys):
    """A pair at 2.02 w_p, both members coupled: one 1:2 flag naming both modes (was: the same flag twice)."""
    w = np.array([1.0, 2.02, 2.02, 3.3, 4.1, 5.7])
    p = write_scene(tmp_path, "pair", *diagonal_system(w, {1: 0.3, 2: 0.2}), methods='["dnf"]')
    o = run_cli(["run", p, "-q", "--json"], capsys)
    assert o.code == 0, o.err
    flags = json.loads(o.out)["modes"][0]["methods"]["dnf"]["flags"]
    res = [f for f in flags if f["kind"] == "internal_resonance_1_2"]
    assert len(res) == 1, flags
    assert res[0]["modes"] == [1, 2] and res[0]["ratio"] == pytest.approx(2.02, rel=1e-12)
    assert "modes 1, 2" in res[0]["message"]


def test_exact_resonance_gives_one_dnf_flag_with_the_mode(tmp_path, capsys):
    """K - 4 w^2 M singular: DNF's own flag takes the mode the 1:2 check found, no second flag."""
    w = np.array([1.0, 2.0, 3.3, 4.1, 5.7, 6.6])
    p = write_scene(tmp_path, "exact", *diagonal_system(w, {1: 0.3}), methods='["dnf"]')
    o = run_cli(["run", p, "-q", "--json"], capsys)
    assert o.code == 0, o.err
    dnf = json.loads(o.out)["modes"][0]["methods"]["dnf"]
    res = [f for f in dnf["flags"] if f["kind"] == "internal_resonance_1_2"]
    assert len(res) == 1 and res[0]["mode"] == 1 and "singular" in res[0]["message"]
    assert dnf["T"] == "-inf"


def modal_truncation_scene(tmp_path, tensors):
    # G(phi_0, phi_0) lies on mode 7 (1.0) and barely on mode 1 (0.01): the 3 retained modes miss it
    w = np.array([1.0, 1.5, 2.7, 3.1, 4.3, 5.2, 6.1, 7.9])
    return write_scene(tmp_path, f"trunc_{tensors}", *diagonal_system(w, {1: 0.01, 7: 1.0}),
                       analysis=f'retained_modes = 3\ntensors = "{tensors}"', methods='["nf"]')


def test_full_step_route_carries_the_modal_truncation_flag(tmp_path):
    """Both STEP routes measure the same captured share of G(phi_p, phi_p) and flag it.

    The share is 0.01^2 / (0.01^2 + 1^2) = 1e-4. The routes compute it from
    different force evaluations (two fields, or the full plan's +-v_0 pair):
    exact for a cubic model up to round-off of ~1e-15, and CG on M = I is
    exact: 1e-10 leaves ample margin.
    """
    frac = {}
    for tensors in ("targeted", "full"):
        res = pipeline.run_scene(load_scene(modal_truncation_scene(tmp_path, tensors)), write=False)
        nf = res.modes[0].methods["nf"]
        assert [f["kind"] for f in nf.flags].count("modal_truncation") == 1, (tensors, nf.flags)
        frac[tensors] = nf.extra["captured_fraction"]
    assert frac["targeted"] == pytest.approx(0.01**2 / (0.01**2 + 1.0), rel=1e-10)
    assert frac["full"] == pytest.approx(frac["targeted"], rel=1e-10)


class Exploding(PolynomialAdapter):
    """An adapter with a bug: stepnf must say so (exit 1), not print a traceback unless --debug."""

    def _internal_forces(self, U):
        raise RuntimeError("adapter bug on purpose")


def test_an_unexpected_error_is_one_line_and_debug_shows_the_traceback(tmp_path, capsys, monkeypatch):
    p = write_scene(tmp_path, "bug", *random_system(6, seed=8))
    use_solver(monkeypatch, lambda name: Exploding)
    o = run_cli(["run", p, "-q"], capsys)
    assert o.code == 1 and "Traceback" not in o.err
    assert "internal error" in o.err and "adapter bug on purpose" in o.err and "--debug" in o.err
    o = run_cli(["run", p, "-q", "--debug"], capsys)
    assert o.code == 1 and "Traceback" in o.err and "adapter bug on purpose" in o.err


def test_an_os_error_is_exit_3_naming_the_file(tmp_path, capsys, monkeypatch):
    p = write_scene(tmp_path, "os", *random_system(6, seed=8))

    def refuse(*a, **k):
        raise PermissionError(13, "Permission denied", str(tmp_path / "somewhere.npz"))

    use_solver(monkeypatch, refuse)
    assert_reported(run_cli(["run", p, "-q"], capsys), codes=(3,), mentions=["Permission denied", "somewhere.npz"])


@pytest.mark.slow
@pytest.mark.fenicsx
def test_quiet_means_quiet_even_when_forms_are_compiled(tmp_path):
    """``-q`` with an empty form cache: the C compiler's INFO lines never reach stderr."""
    pytest.importorskip("dolfinx")
    scene = tmp_path / "ss.toml"
    scene.write_text('[model]\nsolver = "fenicsx_shell"\n[model.geometry]\na = 0.15\nR = 1.5\nh = 0.003\n'
                     'n_rings = 3\n[model.material]\nE = 1.04e11\nnu = 0.3\nrho = 4400.0\n'
                     '[analysis]\nmaster_modes = [0]\nmethods = ["dnf"]\n[output]\ndir = "out"\n')
    env = {"STEPNF_CACHE_DIR": str(tmp_path / "cache")}

    r = subprocess.run([sys.executable, "-m", "stepnf.cli.main", "run", str(scene), "-q"], capture_output=True,
                       text=True, env={**os.environ, **env}, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    assert any((tmp_path / "cache").rglob("*.so")), "the forms were not compiled in the fresh cache"
    assert r.stderr == "", r.stderr[:2000]


@pytest.mark.parametrize("args, code, mention", [
    (["curves", "--n-kappa", "0"], 2, "n_kappa"),
    (["curves", "--n-kappa", "-3"], 2, "n_kappa"),
    (["curves", "--n-kappa", "100000000"], 2, "n_kappa"),
    (["curves", "--kappa-max", "nan"], 2, "kappa_max"),
    (["curves", "--kappa-max", "-5"], 2, "kappa_max"),
    (["curves", "--kappa-max", "inf"], 2, "kappa_max"),
    (["curves", "--nu", "0.7"], 2, "nu"),
    (["curves", "--nu", "nan"], 2, "nu"),
    (["curves", "--modes", "(x)"], 2, "(x)"),
    (["curves", "--modes", "(99,99)"], 2, "(99, 99)"),
    (["curves", "--resonance-tol", "-1"], 2, "resonance_tol"),
    (["curves", "--gap-tol", "2"], 2, "gap_tol"),
    (["curves", "--omega-max", "nan"], 2, "omega_max"),
    (["curves", "--omega-max", "-1"], 2, "omega_max"),
    (["curves", "--n-kappa", "two"], 2, "invalid int value"),
    (["fig4", "nonexistent.h5"], 2, "nonexistent.h5"),
    (["run", "nonexistent.toml"], 2, "nonexistent.toml"),
    (["sweep", "nonexistent.toml"], 2, "nonexistent.toml"),
    (["run"], 2, "scene"),
    (["sweep", "nonexistent.toml", "--workers", "-1"], 2, "--workers"),
    (["sweep", "nonexistent.toml", "--workers", "0"], 2, "--workers"),
    (["sweep", "nonexistent.toml", "--workers", "100000"], 2, "--workers"),
    (["frobnicate"], 2, "invalid choice"),
])
def test_bad_command_line_arguments(tmp_path, capsys, monkeypatch, args, code, mention):
    """Out-of-range or malformed options: exit 2 naming the option, before any computation."""
    monkeypatch.chdir(tmp_path)
    extra = ["--out", str(tmp_path / "c"), "--no-plot"] if args[0] == "curves" else []
    o = run_cli(args + extra, capsys)
    assert_reported(o, codes=(code,), mentions=[mention])
    assert not (tmp_path / "c").exists()  # nothing written


def test_fig4_of_a_file_that_is_not_a_sweep_store(tmp_path, capsys):
    p = write_scene(tmp_path, "good", *random_system(6, seed=8))
    assert run_cli(["run", p, "-q"], capsys).code == 0
    for bad in (tmp_path / "out" / "run.h5", tmp_path / "good.npz", tmp_path / "good.toml"):
        o = run_cli(["fig4", bad, "--out", tmp_path / "f"], capsys)
        assert_reported(o, codes=(2, 3), mentions=[bad.name])


def test_a_stage_that_fails_is_not_reported_done(tmp_path, capsys):
    """Progress on stderr: the failing stage says "stopped", never "done", before the error message."""
    M, K, G, H = random_system(6, seed=8)
    p = write_scene(tmp_path, "big2", M, K, G * 1e200, H)
    o = run_cli(["run", p], capsys)
    assert_reported(o, codes=(3,), mentions=["overflow"])
    assert "normal form and modal derivatives: stopped in" in o.err
    assert "normal form and modal derivatives: done" not in o.err
