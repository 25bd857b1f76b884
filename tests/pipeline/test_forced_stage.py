"""The forced-response stage (issue 34, :mod:`stepnf.pipeline.forced`): scene -> curves -> JSON, HDF5, table, figure.

References: :func:`stepnf.forced.frc.forced_responses` called directly on the run's own parametrisation (the
stage must store exactly its numbers), and the linear peak ``k / (2 xi sqrt(1 - xi^2) w^2)`` of a forcing so
light that the cubic shift of the peak (``T A^2`` ~ 0.18 x (5e-5)^2 ~ 5e-10 relative here) is far below the
tolerance.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.forced.damping import Damping
from stepnf.forced.frc import forced_responses
from stepnf.forced.spec import DampingSpec
from stepnf.io.results import read_hdf5
from stepnf.pipeline.run import run_scene
from stepnf.report.frc_plot import draw_frc
from stepnf.report.table import format_table
from stepnf.scene.parse import load_scene
from stepnf_polynomial.adapter import save_system
from helpers.systems import two_dof

XI = 0.01
LEVELS = (1e-6, 0.005, 0.02)
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def scene(forcing: str, masters=(0,), backbone: str = "order = 9\n", damping: str = f"modal = {XI}\n") -> str:
    return (f'[model]\nsolver = "polynomial"\nfile = "two_dof.npz"\n[analysis]\nmaster_modes = {list(masters)}\n'
            f'methods = ["dnf"]\n[analysis.backbone]\n{backbone}[analysis.damping]\n{damping}'
            f'[analysis.forcing]\n{forcing}[output]\ndir = "out"\n')


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("forced")
    M, K, G, H = two_dof()  # omega = 1 and 3.6, hardening master 0 (T = +0.18)
    save_system(d / "two_dof.npz", M, K, G, H, coordinates=np.array([[0.0, 0, 0], [1.0, 0, 0]]),
                directions=np.array([2, 2]))
    return d


@pytest.fixture(scope="module")
def modal(folder):
    """Modal forcing, three levels (linear, moderate, past the folds), written."""
    path = folder / "modal.toml"
    path.write_text(scene(f"modal = {list(LEVELS)}\nfrequency_range = [0.8, 1.3]\n"))
    return load_scene(path), run_scene(load_scene(path))


def test_json_and_hdf5_hold_the_curves_of_forced_responses(modal):
    sc, res = modal
    rec = res.modes[0]
    bb = res.backbones[0]
    direct = forced_responses(bb, Damping(DampingSpec(modal=XI), bb.M, None, [(bb.phi, bb.omega)]),
                              [({"kappa": k}, k) for k in LEVELS], (0.8, 1.3), valid_to=rec.backbone["valid_up_to"])
    doc = json.loads(res.to_json())["modes"][0]
    stored = read_hdf5(res.hdf5_path)
    assert stored["modes"][0]["frc"] == doc["frc"]  # the HDF5 file's document is the JSON one
    with h5py.File(res.hdf5_path) as f:
        assert json.loads(f["modes/mode_0"].attrs["frc"]) == doc["frc"]
    assert [c["kappa"] for c in doc["frc"]] == list(LEVELS)
    for i, (c, d) in enumerate(zip(doc["frc"], direct)):
        assert {"kappa", "Omega", "amplitude", "stable", "peak", "folds"} <= set(c)
        # the stage's numbers are the function's (same parametrisation, same inputs): to round-off
        assert c["peak"]["amplitude"] == pytest.approx(d.peak["amplitude"], rel=1e-12)
        assert c["peak"]["Omega"] == pytest.approx(d.peak["Omega"], rel=1e-12)
        assert len(c["folds"]) == len(d.folds)
        arr = stored["arrays"]
        np.testing.assert_array_equal(arr[f"frc_0_{i}_Omega"], np.asarray(c["Omega"]))
        np.testing.assert_array_equal(arr[f"frc_0_{i}_amplitude"], np.asarray(c["amplitude"]))
        np.testing.assert_array_equal(arr[f"frc_0_{i}_stable"], np.asarray(c["stable"]))
        np.testing.assert_array_equal(arr[f"frc_0_{i}_valid"], np.asarray(c["valid"]))
    # the linear limit (module docstring): w = 1
    assert doc["frc"][0]["peak"]["amplitude"] == pytest.approx(LEVELS[0] / (2 * XI * np.sqrt(1 - XI ** 2)), rel=1e-6)
    # the strongest level jumps: two folds, an unstable middle branch
    assert len(doc["frc"][2]["folds"]) == 2 and not all(doc["frc"][2]["stable"])


def test_peak_table_under_the_backbone(modal):
    _, res = modal
    lines = format_table(res).splitlines()
    head = lines.index(f"forced responses [0 -], xi = {XI:.4g}:")
    assert lines[head - 1].startswith("  ") and any(ln.startswith("backbone [0 -]") for ln in lines[:head])
    assert lines[head + 1].split() == ["level", "peak", "A", "Omega/w_p", "W_max/h", "folds", "valid"]
    for k, c, line in zip(LEVELS, res.modes[0].frc, lines[head + 2:head + 5]):
        cells = line.split()
        assert cells[:2] == ["kappa", f"{k:.4g}"]
        assert float(cells[2]) == pytest.approx(c["peak"]["amplitude"], rel=1e-4)  # printed with 5 digits
        assert float(cells[3]) == pytest.approx(c["peak"]["Omega"] / res.modes[0].omega, abs=1e-6)
        assert cells[4:] == ["-", str(len(c["folds"])), "yes"]


def test_show_prints_the_same_table(modal, capsys):
    _, res = modal
    assert main(["show", res.hdf5_path]) == 0
    out = capsys.readouterr().out
    assert "forced responses [0 -], xi = 0.01:" in out and out.count("  kappa ") == 3


def test_figure_dashes_the_unstable_parts(modal, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _, res = modal
    fig, ax = plt.subplots()
    draw_frc(ax, res.modes[0], res.backbones[0])
    styles = {ln.get_linestyle() for ln in ax.get_lines()}
    labels = {ln.get_label() for ln in ax.get_lines()}
    plt.close(fig)
    assert "--" in styles and "-" in styles and "backbone" in labels
    folds = [ln for ln in ax.get_lines() if ln.get_marker() == "o"]
    assert len(folds) == 2  # the two folds of the strongest level


def test_load_on_a_box_equals_the_function_with_its_force(folder):
    """``load`` on the node at x = 1 (its uz dof, dof 1): F = a e_1; the stage's peak is the function's with that
    F, and at a light level the linear peak of the modal force phi^T F."""
    path = folder / "load.toml"
    path.write_text(scene('frequency_range = [0.8, 1.3]\nload = {box = [[0.5, -1, -1], [2, 1, 1]], dofs = ["uz"], '
                          'amplitude = [1e-6, 0.01]}\n'))
    res = run_scene(load_scene(path), write=False)
    bb = res.backbones[0]
    c = res.modes[0].frc
    assert [x["load"] for x in c] == [1e-6, 0.01] and c[0]["box"] == [[0.5, -1.0, -1.0], [2.0, 1.0, 1.0]]
    assert c[0]["dofs"] == ["uz"]
    F = np.array([0.0, 0.01])
    d = forced_responses(bb, Damping(DampingSpec(modal=XI), bb.M, None, [(bb.phi, bb.omega)]), [({"load": 0.01}, F)],
                         (0.8, 1.3), valid_to=res.modes[0].backbone["valid_up_to"])[0]
    assert c[1]["peak"]["amplitude"] == pytest.approx(d.peak["amplitude"], rel=1e-12)
    kappa = abs(bb.phi[1]) * 1e-6
    assert c[0]["peak"]["amplitude"] == pytest.approx(kappa / (2 * XI * np.sqrt(1 - XI ** 2)), rel=1e-6)


def test_masters_on_a_manifold_of_several_modes_get_curves(tmp_path):
    """Mode 0 on the manifold of modes 0 and 4 (near_one_to_four; mode 4 is no scene master, so modal damping leaves
    it undamped: xi = 0 there, nothing divides by it): its curve (stepnf.forced.manifold_frc), with mode 4's
    amplitude; master 1 its single-mode curve; the run goes on (exit 0). (Issue 34 on issue 33: before, master 0
    got no curve and the reason "its backbone is on a manifold of several modes (forced responses there: not
    yet)".) Light forcing (kappa = 1e-4, A ~ 5e-3): the linear peak kappa / (2 xi sqrt(1 - xi^2) w^2) to the
    cubic bend ~0.1 A^2 relative (< 1e-5)."""
    shutil.copy(EXAMPLES / "near_one_to_four.npz", tmp_path / "near_one_to_four.npz")
    path = tmp_path / "s.toml"
    path.write_text(scene("modal = [0.0001]\nfrequency_range = [0.9, 1.1]\n", masters=(0, 1),
                          backbone="order = 7\nmanifolds = [[0, 4]]\n").replace("two_dof", "near_one_to_four"))
    res = run_scene(load_scene(path), write=False)
    on, off = res.modes
    assert on.frc_reason is None and len(on.frc) == 1
    assert off.frc and off.frc_reason is None  # master 1: its single-mode backbone, its curve
    c = json.loads(res.to_json())["modes"][0]["frc"][0]
    assert c["manifold"] == [0, 4] and set(c["amplitudes"]) == {"0", "4"} and c["kappa"] == 0.0001
    assert all(c["stable"])  # (the undamped partner's eigenvalues on the axis count as stable: round-off)
    w = float(on.omega)
    assert c["peak"]["amplitude"] == pytest.approx(1e-4 / (2 * XI * np.sqrt(1 - XI ** 2) * w * w), rel=1e-5)
    assert "frc_0_0_amplitude_4" in res.arrays and len(res.arrays["frc_0_0_Omega"]) == len(c["Omega"])
    assert "forced responses [0 -], xi = 0.01:" in format_table(res)


def test_both_masters_of_a_one_to_two_manifold_through_the_command_line(tmp_path, capsys):
    """A near 1:2 pair (``x1'' + x1 + 2 x1 x2 + 0.1 x1^3 = 0``, ``x2'' + 1.97^2 x2 + x1^2 + 0.1 x2^3 = 0``) with
    ``manifolds = [[0, 1]]``, modal damping and forcing: ``stepnf run`` exits 0, both masters get one curve per
    level with both modes' amplitudes (JSON and HDF5), the table prints both, the figure is drawn. Forcing mode 1
    (the higher) its uncoupled response (mode 0 at rest: exact on the manifold) loses its stability at two branch
    points, where the coupled branch (a second segment) is born; its peak is the linear one, ``2 |zeta_1| = kappa /
    (2 xi w1 w_d1)`` (to the cubic bend ~0.1 A^2 ~ 2e-3 relative: bound 5e-3). Before issue 34 on manifolds: no
    curve for either master (the reason "forced responses there: not yet")."""
    from helpers.systems import sym

    w1 = 1.97
    save_system(tmp_path / "pair.npz", np.eye(2), np.diag([1.0, w1 * w1]), sym((2, 2, 2), {(0, 0, 1): 1.0}),
                sym((2, 2, 2, 2), {(0, 0, 0, 0): 0.1, (1, 1, 1, 1): 0.1}),
                coordinates=np.array([[0.0, 0, 0], [1.0, 0, 0]]), directions=np.array([2, 2]))
    path = tmp_path / "pair.toml"
    path.write_text(scene("modal = [0.01]\nfrequency_range = [0.85, 1.15]\n", masters=(0, 1),
                          backbone="order = 7\nmanifolds = [[0, 1]]\n").replace("two_dof", "pair")
                    .replace('dir = "out"\n', 'dir = "out"\nplot = true\n'))
    assert main(["run", str(path), "-q"]) == 0
    out = capsys.readouterr().out
    assert "forced responses [0 -], xi = 0.01:" in out and "forced responses [1 -], xi = 0.01:" in out
    assert "kappa 0.01: branch point(s) at Omega/w_p = " in out  # under master 1's line
    doc = read_hdf5(tmp_path / "out" / "pair.h5")
    low, high = (m["frc"][0] for m in doc["modes"][:2])
    for c in (low, high):
        assert c["manifold"] == [0, 1] and len(c["amplitudes"]["1"]) == len(c["Omega"]) and c["peak"]["valid"]
    assert len(low["folds"]) >= 2 and min(low["amplitudes"]["1"]) > 0  # mode 0 drives mode 1 through the 1:2
    assert len(high["branch_points"]) == 2 and sorted(set(high["segment"])) == [0, 1]
    assert max(high["amplitudes"]["0"][: high["segment"].index(1)]) < 1e-15
    assert high["peak"]["amplitude"] == pytest.approx(0.01 / (2 * XI * w1 * w1 * np.sqrt(1 - XI ** 2)), rel=5e-3)
    assert "frc_1_0_amplitude_0" in doc["arrays"] and "frc_0_0_amplitude_1" in doc["arrays"]
    assert (tmp_path / "out" / "pair_frc.png").is_file()


def test_example_scene(tmp_path, capsys):
    """examples/polynomial_frc.toml through the command line: the table, the figure, three curves whose peaks lie
    within the backbone's validity, the strongest with two folds (the jump the example's comment promises)."""
    shutil.copy(EXAMPLES / "system12.npz", tmp_path / "system12.npz")
    shutil.copy(EXAMPLES / "polynomial_frc.toml", tmp_path / "polynomial_frc.toml")
    assert main(["run", str(tmp_path / "polynomial_frc.toml"), "-q"]) == 0
    out = capsys.readouterr().out
    assert "forced responses [0 -], xi = 0.002:" in out
    assert (tmp_path / "results" / "polynomial_frc_frc.png").is_file()
    frc = read_hdf5(tmp_path / "results" / "polynomial_frc.h5")["modes"][0]["frc"]
    assert [c["kappa"] for c in frc] == [0.0002, 0.0004, 0.0006]
    assert all(c["peak"]["valid"] for c in frc) and [len(c["folds"]) for c in frc] == [0, 0, 2]


def test_w_max_over_h_where_the_backbone_measures_it(folder):
    """With a thickness and ``transverse = "uz"`` (both dofs are uz): W_max/h along each curve and at its peak, in
    the table and the arrays; at the light level the displacement is the linear mode's, W_max = A max|phi_uz|
    (the quadratic terms add ~g A ~ 5e-5 relative)."""
    path = folder / "wmax.toml"
    path.write_text(scene(f"modal = {list(LEVELS)}\nfrequency_range = [0.8, 1.3]\n").replace(
        'methods = ["dnf"]\n', 'methods = ["dnf"]\nthickness = 0.1\ntransverse = "uz"\n'))
    res = run_scene(load_scene(path), write=False)
    c = res.modes[0].frc[0]
    phi = res.backbones[0].phi
    assert c["peak"]["w_max_h"] == pytest.approx(c["peak"]["amplitude"] * np.max(np.abs(phi)) / 0.1, rel=1e-4)
    assert len(c["w_max_h"]) == len(c["Omega"]) and "frc_0_0_w_max_over_h" in res.arrays
    line = next(ln for ln in format_table(res).splitlines() if ln.startswith("  kappa 1e-06"))
    assert float(line.split()[4]) == pytest.approx(c["peak"]["w_max_h"], rel=1e-3)


def test_python_api_gives_the_curves(modal):
    """``stepnf.run`` and ``stepnf.open``: each master's ``frc`` as the JSON document's (the same run: the same
    numbers, bit for bit)."""
    import stepnf

    sc, res = modal
    expected = json.loads(res.to_json())["modes"][0]["frc"]
    for view in (stepnf.run(sc.file), stepnf.open(res.hdf5_path)):
        mode = view.modes[0]
        assert mode.frc_reason is None and [dict(c) for c in mode.frc] == expected


def test_failed_and_refused_backbones_give_reasons():
    """The backbone stage's own blocks for a DPIM that failed (a numerical error) and one it refused (a driven
    twin): no curve, each with its reason (:func:`stepnf.pipeline.forced.unusable`)."""
    from types import SimpleNamespace

    from stepnf.errors import NoSingleModeManifold, NumericalError
    from stepnf.keys.backbone import BackboneSpec
    from stepnf.pipeline.backbone import failed_backbone, refused_backbone
    from stepnf.pipeline.forced import unusable

    spec = BackboneSpec()
    failed = failed_backbone(spec, 1e-3, NumericalError("singular shift"))
    refused = refused_backbone(SimpleNamespace(index=0), spec, 1e-3, NoSingleModeManifold("twin 1 driven", mode=1))
    assert unusable(failed) == "its backbone failed"
    assert unusable(refused).startswith("no single-mode parametrisation (")
    assert unusable(None) == "no backbone"


def test_a_load_that_misses_one_master_keeps_its_backbone(tmp_path):
    """M = I, K = diag(1, 3.6^2) (two_dof's modal tensors, unmapped): mode 0 is e_0, so a load on dof 1 has
    phi_0^T F = 0 exactly and excites master 1 only. Master 0 keeps its backbone and gets no curve but the
    reason; master 1 gets its curve, whose light level peaks at the linear value (phi_1^T F = 1e-6). Before the
    fix the force's SceneError ended the run (exit 2) and discarded both backbones."""
    from helpers.systems import sym

    g = sym((2, 2, 2), {(0, 0, 0): 0.1, (1, 0, 0): 0.05, (1, 1, 0): 0.05})
    h = sym((2, 2, 2, 2), {(0, 0, 0, 0): 0.5, (1, 1, 0, 0): 0.2, (1, 1, 1, 1): 0.3})
    save_system(tmp_path / "two_dof.npz", np.eye(2), np.diag([1.0, 3.6 ** 2]), g, h,
                coordinates=np.array([[0.0, 0, 0], [1.0, 0, 0]]), directions=np.array([2, 2]))
    path = tmp_path / "s.toml"
    path.write_text(scene('frequency_range = [0.8, 1.3]\nload = {box = [[0.5, -1, -1], [2, 1, 1]], dofs = ["uz"], '
                          'amplitude = [1e-6]}\n', masters=(0, 1)))
    res = run_scene(load_scene(path), write=False)
    miss, hit = res.modes
    assert miss.backbone is not None and miss.backbone["valid_up_to"] > 0
    assert miss.frc == [] and "does not excite the master" in miss.frc_reason
    w1 = hit.omega
    assert hit.frc_reason is None and hit.frc[0]["peak"]["amplitude"] == pytest.approx(
        1e-6 / (2 * XI * np.sqrt(1 - XI ** 2) * w1 ** 2), rel=1e-6)  # the linear limit (module docstring)
    assert "forced responses [0 -]: n/a (not computed: " in format_table(res)


def test_a_peak_outside_the_range_is_said_and_pieces_are_drawn_apart(folder):
    """Range [0.8, 1.06] below the strongest level's peak (A = 0.89 at Omega = 1.136 w; its lower fold at 1.047 w):
    the curve leaves the range at 1.06 and comes back down the other branch to the fold (two pieces); the table
    says the peak is not on the curve, the figure draws the pieces as separate lines (none joins them at
    Omega = 1.06 w: before the fix one line did) and puts no peak marker outside the range."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = folder / "cut.toml"
    path.write_text(scene(f"modal = [{LEVELS[2]}]\nfrequency_range = [0.8, 1.06]\n"))
    res = run_scene(load_scene(path), write=False)
    c = res.modes[0].frc[0]
    assert c["peak_outside_range"] and set(c["segment"]) == {0, 1}
    assert "kappa 0.02: peak outside [analysis.forcing] frequency_range" in format_table(res)
    fig, ax = plt.subplots()
    draw_frc(ax, res.modes[0], res.backbones[0])
    curves = [ln for ln in ax.get_lines() if ln.get_marker() in ("None", "")
              and ln.get_label() not in ("backbone", "validity limit")]
    seg = np.asarray(c["segment"])
    plt.close(fig)
    assert len(curves) >= 2  # one per piece at least
    w = float(res.modes[0].omega)
    pieces = [set(zip(np.asarray(c["Omega"])[seg == s] / w, np.asarray(c["amplitude"])[seg == s])) for s in (0, 1)]
    for ln in curves:  # each drawn line lies within one piece: its points (Omega/w, A) are those of one segment
        pts = set(zip(np.asarray(ln.get_xdata()), np.asarray(ln.get_ydata())))
        assert any(pts <= p for p in pieces)
    assert not [ln for ln in ax.get_lines() if ln.get_marker() == "x"]
