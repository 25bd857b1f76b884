"""The backbone stage's masters on manifolds of several modes (``[analysis.backbone] manifolds``, issue 33).

References: the full model's periodic orbits (stepnf.verify.periodic.Shooting, DOP853 at rtol 1e-12, as
tests/dpim/test_branches.py), the single-mode path of the same scene without ``manifolds`` (the same JSON),
the stored HDF5 arrays read back, and the scene keys' messages through the command line (exit 2).
"""
from __future__ import annotations

import json
import shutil
from itertools import product
from pathlib import Path

import h5py
import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.pipeline.run import run_scene
from stepnf.report.branches_plot import plot_branches
from stepnf.scene.parse import load_scene
from stepnf.verify.periodic import Shooting
from helpers.systems import batch_force, modes, near_one_to_four

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "near_one_to_four.toml"


def scene(backbone: str, masters=(0,)) -> str:
    return (f'[model]\nsolver = "polynomial"\nfile = "near_one_to_four.npz"\n[analysis]\n'
            f'master_modes = {list(masters)}\nmethods = ["dnf"]\n[analysis.backbone]\n{backbone}[output]\ndir = "out"\n')


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("manifold")
    shutil.copy(EXAMPLE.with_suffix(".npz"), d / "near_one_to_four.npz")
    return d


@pytest.fixture(scope="module")
def example(folder):
    """The example scene (order 15, manifolds = [[0, 4]], amplitudes 0.5 .. 3) run in a copy of its folder."""
    shutil.copy(EXAMPLE, folder / "example.toml")
    return run_scene(load_scene(folder / "example.toml"))


def _write(folder: Path, name: str, text: str) -> Path:
    (folder / name).write_text(text)
    return folder / name


@pytest.mark.parametrize("backbone, key, says", [
    ("manifolds = [[0]]\n", "analysis.backbone.manifolds[0]", "a manifold holds 2 to 4 modes"),
    ("manifolds = [[0, 4], [4, 1]]\n", "analysis.backbone.manifolds[1][0]", "already in manifold 0"),
    ("manifolds = [[0, 0]]\n", "analysis.backbone.manifolds[0][1]", "already in this manifold"),
    ("manifolds = 4\n", "analysis.backbone.manifolds", 'expected "auto" or a non-empty list'),
    ('manifolds = "all"\n', "analysis.backbone.manifolds", 'expected "auto" or a non-empty list'),
    ("manifolds = [[0, 4.5]]\n", "analysis.backbone.manifolds[0][1]", "expected a mode index"),
    ("manifolds = [[0, true]]\n", "analysis.backbone.manifolds[0][1]", "expected a mode index"),
    ("resonance = 0.02\n", "analysis.backbone.resonance", "applies to manifolds of several modes"),
    ("manifolds = [[0, 4]]\nresonance = 2\n", "analysis.backbone.resonance", "relative distance of frequencies"),
    ("manifolds = [[0, 4]]\nratios = [[1, 4, 2]]\n", "analysis.backbone.ratios[0]", "one integer per mode"),
    ('manifolds = "auto"\nratios = [[1, 4]]\n', "analysis.backbone.ratios", "go with explicit manifolds"),
    ("manifolds = [[0, 9]]\n", "analysis.backbone.manifolds[0][1]", "mode 9 does not exist"),  # 5 modes
    ("manifolds = [[1, 4]]\n", "analysis.backbone.manifolds[0]", "holds no master mode"),
    ('manifolds = [[0, "(2,1)"]]\n', "analysis.backbone.manifolds[0][1]", "gives no labels"),
    ("order = 5\nmanifolds = [[0, 4]]\nratios = [[1, 3]]\n", "analysis.backbone.ratios[0]", "do not match"),
    # w2 / w0 = 2.3: near 3:7 only (1.4% off), beyond order 5's monomials
    ("order = 5\nmanifolds = [[0, 2]]\n", "analysis.backbone.manifolds[0]", "in no internal resonance"),
])
def test_scene_mistakes_exit_2(folder, capsys, backbone, key, says):
    """Every mistake is one line naming the key and what is allowed, exit 2 (the last five once the modes are
    known, before any parametrisation)."""
    path = _write(folder, "bad.toml", scene(backbone))
    assert main(["run", str(path), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"[{key}]" in err and says in err and "Traceback" not in err


def test_example_backbone_against_the_full_model(example):
    """Mode 0 on the manifold of modes 0 and 4 (order 15): its backbone frequency at A = 2 against the full
    model's periodic orbit within 1e-4 (issue 33; tests/dpim/test_branches.py measured 6.4e-7 on the same
    manifold), valid beyond A = 3 (measured 3.155 there) where the single-mode series stops at ~1.3; the
    orbit is started from the branch's point rebuilt from the stored arrays (x = W(z))."""
    [rec] = example.modes
    b = rec.backbone
    assert b["manifold"]["modes"] == [0, 4] and b["manifold"]["ratios"] == [1, 4] and b["order"] == 15
    assert b["manifold"]["chosen"] == "explicit" and b["manifold"]["resonant_monomials"] > 0
    assert b["valid_reason"] == "orders differ" and b["valid_up_to"] > 3.0
    assert b["amplitude"] == [0.5, 1.0, 1.5, 2.0, 2.5, 3.0] and b["branch"]["kind"] == "continues mode 0"
    assert all(b["branch"]["stable"][:10])
    with h5py.File(example.hdf5_path, "r") as f:
        a = {k: f["arrays"][k][()] for k in f["arrays"] if k.startswith("backbone_0_")}
    assert np.array_equal(a["backbone_0_omega"], b["omega"]) and list(a["backbone_0_manifold_masters"]) == [0, 4]
    M, K, G, H = near_one_to_four()
    f = batch_force(K, G, H)
    w, V = modes(K, M)
    A = 2.0
    i = int(np.argmin(np.abs(a["backbone_0_branch0_A"][:, 0] - A)))
    zeta = a["backbone_0_branch0_zeta_re"][i] + 1j * a["backbone_0_branch0_zeta_im"][i]
    z = np.concatenate([zeta, zeta.conj()])
    W = a["backbone_0_manifold_W_re"] + 1j * a["backbone_0_manifold_W_im"]
    x0 = (np.prod(z[None, :] ** a["backbone_0_manifold_index"], axis=1) @ W).real  # x = W(z), model dofs
    sh = Shooting(M, K, lambda x: f(x[None])[0], V[:, 0], w[0])
    ref = sh.at_amplitude(A, guess=(x0, 2 * np.pi / a["backbone_0_branch0_Omega"][i])).omega
    assert b["omega"][3] == pytest.approx(ref, rel=1e-4, abs=0)


def test_example_prints_and_draws(example, folder, capsys):
    """The table says which manifold; the figure of the branches is written."""
    from stepnf.report.table import format_table

    text = format_table(example)
    assert "on the manifold of modes [0, 4] (explicit" in text and "ratios 1:4" in text
    assert plot_branches(example, folder / "branches.png").stat().st_size > 1000


@pytest.fixture(scope="module")
def order7(folder):
    """Order 7, masters 0 and 1: without manifolds, and with manifolds = "auto" (resonance 0.02)."""
    plain = run_scene(load_scene(_write(folder, "plain.toml", scene("order = 7\n", (0, 1)))))
    auto = run_scene(load_scene(_write(folder, "auto.toml", scene(
        'order = 7\nmanifolds = "auto"\nresonance = 0.02\n', (0, 1)).replace('"out"', '"auto"'))))
    return plain, auto


def test_auto_chooses_the_one_to_four_pair(order7):
    """w4 / w0 = 3.954 is within 2% of 4 (1.15%): auto puts mode 4 with master 0 and says why; w3 / w0 = 3.1 is
    3.3% off 3 (out at 2%); master 1 has no flagged mode and keeps the single-mode backbone."""
    _, auto = order7
    b0, b1 = (m.backbone for m in auto.modes)
    assert b0["manifold"]["modes"] == [0, 4] and b0["manifold"]["chosen"] == "auto"
    assert "mode 4 near 4 x w of mode 0" in b0["manifold"]["why"] and b0["manifold"]["ratios"] == [1, 4]
    assert "manifold" not in b1


def test_masters_outside_manifolds_unchanged(order7):
    """Master 1 (in no manifold) gets the same block as in the run without manifolds, to the bit (the
    timings of its orders aside)."""
    plain, auto = order7

    def strip(block):
        out = json.loads(json.dumps(block))
        for c in out["counts"].values():
            c.pop("seconds")
        return out
    assert strip(plain.modes[1].backbone) == strip(auto.modes[1].backbone)
    assert "manifold" not in plain.modes[0].backbone
    arrays = []
    for res in (plain, auto):
        with h5py.File(res.hdf5_path, "r") as f:
            arrays.append({k: f["arrays"][k][()] for k in f["arrays"] if k.startswith("backbone_1_")})
    assert sorted(arrays[0]) == sorted(arrays[1]) and "backbone_1_Y" in arrays[0]
    assert all(np.array_equal(arrays[0][k], arrays[1][k], equal_nan=True) for k in arrays[0])


@pytest.fixture(scope="module")
def one_to_two(tmp_path_factory):
    """x1'' + x1 + 2 x1 x2 = 0, x2'' + 4 x2 + x1^2 = 0 (exact 1:2, tests/dpim/test_branches.py's one_to_two(1)),
    both modes masters on their manifold, order 7."""
    from stepnf_polynomial import save_system
    from helpers.systems import sym

    d = tmp_path_factory.mktemp("m12")
    save_system(d / "s.npz", np.eye(2), np.diag([1.0, 4.0]), sym((2, 2, 2), {(0, 0, 1): 1.0}),
                np.zeros((2, 2, 2, 2)))
    path = _write(d, "s.toml", scene("order = 7\nmanifolds = [[0, 1]]\namplitudes = [0.1, 0.3]\n", (0, 1))
                  .replace("near_one_to_four.npz", "s.npz"))
    return run_scene(load_scene(path))


def test_exact_one_to_two_coupled_branches(one_to_two):
    """Master 0 has no branch that continues its mode (exact 1:2): a flag, no amplitudes, and its two coupled
    branches (phase 0 and pi), each against the full model's orbit at the traced point nearest A = 0.4 within
    1e-4 (tests/dpim/test_branches.py measured 3.8e-6 and 8.3e-6 at order 7); master 1 continues its mode."""
    b0, b1 = (m.backbone for m in one_to_two.modes)
    assert b0["branch"] is None and b0["amplitude"] == [] and b0["valid_up_to"] == 0.0
    assert any(f["kind"] == "manifold_no_own_branch" for f in b0["flags"])
    assert [c["kind"] for c in b0["coupled_branches"]] == ["coupled", "coupled"]
    assert b1["branch"]["kind"] == "continues mode 1" and b1["manifold"]["stored_with"] == 0
    with h5py.File(one_to_two.hdf5_path, "r") as f:
        a = {k: f["arrays"][k][()] for k in f["arrays"] if k.startswith("backbone_")}
    assert "backbone_1_manifold_W_re" not in a  # the manifold is stored once, with master 0
    W = a["backbone_0_manifold_W_re"] + 1j * a["backbone_0_manifold_W_im"]
    K = np.diag([1.0, 4.0])
    G = np.zeros((2, 2, 2))
    G[0, 0, 1] = G[0, 1, 0] = G[1, 0, 0] = 1.0
    f = batch_force(K, G, np.zeros((2, 2, 2, 2)))
    sh = Shooting(np.eye(2), K, lambda x: f(x[None])[0], np.array([1.0, 0.0]), 1.0)
    shifts = []
    for i, c in enumerate(b0["coupled_branches"]):
        A0 = np.asarray(c["A"][0])
        n = int(np.argmin(np.abs(A0 - 0.4)))
        zeta = a[f"backbone_0_branch{i}_zeta_re"][n] + 1j * a[f"backbone_0_branch{i}_zeta_im"][n]
        z = np.concatenate([zeta, zeta.conj()])
        x0 = (np.prod(z[None, :] ** a["backbone_0_manifold_index"], axis=1) @ W).real
        ref = sh.at_amplitude(A0[n], guess=(x0, 2 * np.pi / c["Omega"][n])).omega
        assert c["Omega"][n] == pytest.approx(ref, rel=1e-4, abs=0)
        shifts.append(ref - 1.0)
    assert min(shifts) < -0.05 < 0.05 < max(shifts)  # one hardens, one softens, by more than 5%


def test_branches_figure_dashes_the_unstable_parts(one_to_two):
    """Master 1's own branch starts unstable (parametric resonance of mode 0, test_branches.py): dashed there."""
    from stepnf.report.branches_plot import draw_branches
    from stepnf.report.figures import pyplot

    fig, ax = pyplot().subplots()
    draw_branches(ax, one_to_two.modes[1])
    styles = {line.get_linestyle() for line in ax.get_lines()}
    assert "--" in styles and "-" in styles
    pyplot().close(fig)


def test_auto_merges_only_sets_with_a_common_ratio(folder):
    """resonance = 0.12: master 0 takes modes 3 (3.1 ~ 3 x 1) and 4 (3.954 ~ 4 x 1), master 1 (1.7) finds mode 3
    near 2 x its own (9%); (1, 1.7, 3.1, 3.954) have no common ratio vector of integers up to 4, so the sets are
    not merged and master 1 keeps the single-mode backbone (before the review of issue 33 "auto" built
    [0, 1, 3, 4] and both backbones failed, exit 3, "not resonant for the ratios")."""
    res = run_scene(load_scene(_write(folder, "auto12.toml", scene(
        'order = 5\nmanifolds = "auto"\nresonance = 0.12\n', (0, 1)).replace('"out"', '"auto12"'))))
    b0, b1 = (m.backbone for m in res.modes)
    assert b0["manifold"]["modes"] == [0, 3, 4] and b0["manifold"]["ratios"] == [1, 3, 4]
    assert "manifold" not in b1 and len(b1["amplitude"]) > 0
