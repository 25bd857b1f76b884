"""When a backbone is not to be trusted: the forces behind it, the shapes of two orders, hostile inputs.

References: the DPIM's own fields rebuilt on the phase grid (the shape criterion's Gram form), shooting
on the full model (what the validity limit promises), a model without nonlinearity (whose backbone is
flat: any curvature is round-off), and the command line's exit codes.
"""
from __future__ import annotations

import json
import subprocess
import sys

import h5py
import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.dpim.parametrisation import DPIM
from stepnf.verify.periodic import Shooting
from stepnf.pipeline.run import run_scene
from stepnf.report.mode_shapes import _spans_plane
from stepnf.scene.parse import load_scene
from helpers.scenes import polynomial_scene
from helpers.systems import batch_force, modes, two_dof


# ------------------------------------------------------------------ forces
def test_linear_model_backbone_is_not_established(tmp_path, capsys):
    """Without G and H the forces' nonlinear part is round-off, whose size grows as the probe shrinks, so
    T changes by several times itself between the STEP amplitudes (T_error >= 1): the backbone gets a
    step_accuracy flag and no amplitude is called valid (every row printed 'beyond validity')."""
    path = polynomial_scene(tmp_path, G_scale=0.0)
    block = run_scene(load_scene(path)).modes[0].backbone
    assert block["valid_up_to"] == 0.0 and block["valid_reason"] == "forces inaccurate"
    flag = [f for f in block["flags"] if f["kind"] == "step_accuracy"]
    assert len(flag) == 1 and flag[0]["value"] >= 1.0 and "not established" in flag[0]["message"]
    assert main(["run", str(path), "-q", "--no-plot"]) == 0
    block_text = capsys.readouterr().out.split("backbone [0")[1]
    assert "no validity range: the forces at the probe amplitude are not accurate" in block_text.splitlines()[0]
    rows = [x for x in block_text.splitlines() if x.startswith("  ") and x.strip()[0].isdigit()]
    assert rows and all(x.endswith("beyond validity") for x in rows)


def test_nonlinear_model_backbone_has_no_force_flag(tmp_path):
    block = run_scene(load_scene(polynomial_scene(tmp_path))).modes[0].backbone
    assert block["valid_reason"] != "forces inaccurate"
    assert not [f for f in block["flags"] if f["kind"] == "step_accuracy"]


# ------------------------------------------------------------------ shapes
def test_shape_difference_equals_the_fields_rebuilt(tmp_path):
    """``Backbone.shape_difference`` (Gram form) against x_N - x_{N-2} rebuilt field by field on the same
    phase grid: the same ratio of M-norms to 1e-9 (the rebuilt difference cancels x_N against x_{N-2}:
    its round-off is ~1e-16 |x| / |x_N - x_{N-2}| <= 1e-12 here, the ratio being 1e-4 to 5e-2)."""
    M, K, G, H = two_dof()
    w, V = modes(K, M)
    res = DPIM(batch_force(K, G, H), K, M).parametrise(V[:, 0], w[0], 9, probe=1.0)
    bb, low = res.backbone(), res.truncated(7)
    for rho in (0.5, 0.8, 1.2):
        X = np.array([res.displacement(t, rho) for t in bb.theta])
        D = X - np.array([low.displacement(t, rho) for t in bb.theta])
        norm = lambda Y: np.sqrt(np.max(np.einsum("ti,ij,tj->t", Y, M, Y)))  # noqa: E731
        assert norm(D) / norm(X) > 1e-4
        assert bb.shape_difference(rho) == pytest.approx(norm(D) / norm(X), rel=1e-9)


def test_validity_limit_bounds_the_error_against_shooting():
    """Orders 7 and 9 of the 2-dof system within tol = 1e-4 in frequency and sqrt(tol) = 1e-2 in shape:
    at the limit found, order 9 is within tol of the full model's frequency (shooting, exact to ~1e-12)
    and within 1e-2 of its W_max (dof 1, grid of 20001 phases)."""
    M, K, G, H = two_dof()
    w, V = modes(K, M)
    f = batch_force(K, G, H)
    bb = DPIM(f, K, M).parametrise(V[:, 0], w[0], 9, probe=1.0).backbone()
    A, why = bb.validity_limit(1e-4)
    assert why in ("orders differ", "shapes differ") and A > 0.1
    sh = Shooting(M, K, lambda x: f(x[None])[0], V[:, 0], w[0])
    orb = sh.at_amplitude(A)
    assert bb.omega_at(A)[0] == pytest.approx(orb.omega, rel=1e-4)
    sol = sh.integrate(orb.x0, orb.period, dense=True)
    ref = np.abs(sol.sol(np.linspace(0, orb.period, 20001))[1]).max()
    assert bb.w_max_at(A, [1])[0] == pytest.approx(ref, rel=1e-2)


def test_bad_tolerance_and_points_with_a_list_exit_2(tmp_path, capsys):
    for extra, key in (("tolerance = 1e-12\n", "tolerance"), ("amplitudes = [0.1]\npoints = 5\n", "points")):
        path = polynomial_scene(tmp_path, "order = 5\n" + extra)
        assert main(["run", str(path), "-q"]) == 2
        err = capsys.readouterr().err
        assert f"[analysis.backbone.{key}]" in err and "Traceback" not in err


def test_overflowing_series_says_so(tmp_path):
    block = run_scene(load_scene(polynomial_scene(tmp_path, "order = 25\namplitudes = [1e15]\n"))).modes[0].backbone
    assert block["omega"] == [None]
    assert any("overflows" in f["message"] for f in block["flags"] if f["kind"] == "backbone_unreached")


# ------------------------------------------------------------ command line
@pytest.mark.parametrize("args, text", [
    (["--amplitudes", "1e-300"], "--amplitudes must be numbers in [1e-15"),
    (["--periods", "1e6"], "--periods must be a number in [1, 1000]"),
])
def test_verify_bounds_exit_2(tmp_path, capsys, args, text):
    assert main(["verify", str(polynomial_scene(tmp_path)), "-q", *args]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err


@pytest.mark.parametrize("out", ["", "   "])
def test_blank_output_folder_exit_2(tmp_path, capsys, out):
    assert main(["run", str(polynomial_scene(tmp_path)), "-q", "--output", out]) == 2
    assert "--output must name a folder" in capsys.readouterr().err


def test_show_of_an_edited_backbone_block_exit_2(tmp_path, capsys):
    """A results file whose backbone block was edited by hand (a list cut short) is a message naming the
    file (exit 2: the file given to `show` is bad input, issue 29 finding 11), not an internal error."""
    path = polynomial_scene(tmp_path)
    assert main(["run", str(path), "-q", "--no-plot"]) == 0
    h5 = tmp_path / "out" / "s.h5"
    with h5py.File(h5, "r+") as f:
        key = next(k for k in f.attrs if isinstance(f.attrs[k], str) and f.attrs[k].lstrip().startswith("{"))
        doc = json.loads(f.attrs[key])
        doc["modes"][0]["backbone"]["omega_ratio"] = []
        f.attrs[key] = json.dumps(doc)
    capsys.readouterr()
    assert main(["show", str(h5)]) == 2
    err = capsys.readouterr().err
    assert "s.h5" in err and "malformed" in err and "internal error" not in err


def test_points_on_a_line_make_no_mode_figure():
    assert not _spans_plane(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]))
    assert not _spans_plane(np.array([[0.0, 0.0], [1.0, 1.0]]))
    assert _spans_plane(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))


def test_closed_stdout_is_quiet(tmp_path):
    """``stepnf run ... --json | head -c 10``: the reader leaves early; no PETSc crash banner, exit 0."""
    path = polynomial_scene(tmp_path, "order = 5\npoints = 5000\n")  # a JSON document of ~1 MB
    proc = subprocess.Popen([sys.executable, "-m", "stepnf", "run", str(path), "-q", "--json", "--no-plot"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path)
    head = proc.stdout.read(10)
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=300) == 0 and head.startswith(b"{")
    assert "PETSC ERROR" not in err and "Traceback" not in err and "MPI_ABORT" not in err


def test_verify_checks_the_scene_amplitudes_within_validity(tmp_path, capsys):
    """The scene's amplitudes are checked, those beyond the validity limit (0.33 here) left out and said so;
    at 1/30 of the limit order 5 and the shooting orbit agree to ~1e-12 (measured 1.1e-13 and 2.9e-12)."""
    path = polynomial_scene(tmp_path, "order = 5\namplitudes = [0.01, 0.02, 1e6]\n")
    assert main(["verify", str(path), "-q", "--json"]) == 0
    m = json.loads(capsys.readouterr().out)["modes"][0]
    assert m["amplitudes_from"] == "[analysis.backbone] amplitudes (1 beyond the validity limit left out)"
    assert [c["amplitude"] for c in m["checks"]] == [0.01, 0.02]
    assert all(abs(c["relative_difference"]) < 1e-6 for c in m["checks"])
