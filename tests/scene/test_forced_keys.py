"""The scene tables ``[analysis.damping]`` and ``[analysis.forcing]`` (issue 34, :mod:`stepnf.keys.forced`).

Every mistake is one line on stderr naming the file and the key, exit 2, through the command line: those the
scene's text shows when it is read, before any model is built; those the model decides (a load on a set the
mesh does not have, an overdamped master) in the run, before any parametrisation. The reference is the
issue's list of bad inputs (forcing without damping: an unbounded peak; a frequency range without the
resonance; a load on an unknown set) and the contract's keys.
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.pipeline import model as pipeline
from stepnf.scene.parse import load_scene
from stepnf_polynomial.adapter import save_system
from helpers.systems import two_dof

DAMPING = "[analysis.damping]\nmodal = 0.01\n"
FORCING = "[analysis.forcing]\nmodal = [0.01, 0.02]\nfrequency_range = [0.9, 1.2]\n"
BACKBONE = "[analysis.backbone]\norder = 5\n"


def scene(tables: str, masters=(0,), solver: str = 'solver = "polynomial"\nfile = "two_dof.npz"\n') -> str:
    return (f"[model]\n{solver}[analysis]\nmaster_modes = {list(masters)}\nmethods = [\"dnf\"]\n{tables}"
            "[output]\ndir = \"out\"\n")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("forced_keys")
    M, K, G, H = two_dof()
    # dof coordinates and directions (two nodes on the x axis, one uz dof each): a box can select them
    save_system(d / "two_dof.npz", M, K, G, H, coordinates=np.array([[0.0, 0, 0], [1.0, 0, 0]]),
                directions=np.array([2, 2]))
    return d


def run_bad(folder, capsys, text: str, name: str = "bad.toml") -> str:
    path = folder / name
    path.write_text(text)
    assert main(["run", str(path), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert str(path) in err, err
    return err


AT_LOAD = [
    # the three: forcing without damping, a range without the resonance (and a load on an unknown set, below)
    (BACKBONE + FORCING, "analysis.forcing", "unbounded peak"),
    (BACKBONE + DAMPING + FORCING.replace("[0.9, 1.2]", "[1.05, 1.3]"), "analysis.forcing.frequency_range",
     "does not contain the resonance"),
    (BACKBONE + DAMPING + FORCING.replace("[0.9, 1.2]", "[0.5, 0.95]"), "analysis.forcing.frequency_range",
     "does not contain the resonance"),
    (BACKBONE + DAMPING + FORCING.replace("[0.9, 1.2]", "[1.2, 0.9]"), "analysis.forcing.frequency_range",
     "lo must be below hi"),
    (BACKBONE + DAMPING + FORCING.replace("[0.9, 1.2]", "[0.0, 1.2]"), "analysis.forcing.frequency_range[0]",
     "must lie in (0, 10]"),
    (BACKBONE + DAMPING + FORCING.replace("[0.9, 1.2]", "[-0.5, 1.2]"), "analysis.forcing.frequency_range[0]",
     "must lie in (0, 10]"),
    (BACKBONE + DAMPING + FORCING.replace("[0.9, 1.2]", "0.9"), "analysis.forcing.frequency_range", "expected [lo, hi]"),
    (BACKBONE + DAMPING + FORCING.replace("frequency_range = [0.9, 1.2]\n", ""), "analysis.forcing.frequency_range",
     "missing"),
    # forcing needs the backbone's manifold; damping alone computes nothing
    (DAMPING + FORCING, "analysis.forcing", "add [analysis.backbone]"),
    (BACKBONE + DAMPING, "analysis.damping", "used by the forced responses only"),
    # damping: one of two forms, positive, one ratio per master
    (BACKBONE + "[analysis.damping]\nmodal = 0.01\nrayleigh = [0.1, 0.0]\n" + FORCING, "analysis.damping",
     "not both"),
    (BACKBONE + "[analysis.damping]\n" + FORCING, "analysis.damping", "give exactly one of"),
    (BACKBONE + "[analysis.damping]\nmodal = -0.01\n" + FORCING, "analysis.damping.modal", "must lie in (0, 1)"),
    (BACKBONE + "[analysis.damping]\nmodal = 0.0\n" + FORCING, "analysis.damping.modal", "must lie in (0, 1)"),
    (BACKBONE + "[analysis.damping]\nmodal = 1.5\n" + FORCING, "analysis.damping.modal", "must lie in (0, 1)"),
    (BACKBONE + "[analysis.damping]\nmodal = \"light\"\n" + FORCING, "analysis.damping.modal", "expected a damping ratio"),
    (BACKBONE + "[analysis.damping]\nmodal = [0.01, 0.02]\n" + FORCING, "analysis.damping.modal",
     "one damping ratio per master mode: 1 master"),
    (BACKBONE + "[analysis.damping]\nrayleigh = [-0.1, 0.01]\n" + FORCING, "analysis.damping.rayleigh[0]",
     "must lie in [0, 1e+15]"),
    (BACKBONE + "[analysis.damping]\nrayleigh = [0.0, 0.0]\n" + FORCING, "analysis.damping.rayleigh",
     "unbounded peak"),
    (BACKBONE + "[analysis.damping]\nrayleigh = 0.1\n" + FORCING, "analysis.damping.rayleigh", "expected [alpha, beta]"),
    (BACKBONE + "[analysis.damping]\nratio = 0.01\n" + FORCING, "analysis.damping.ratio", "unknown key"),
    # forcing: levels, one of modal and load, the load's set or box and dofs
    (BACKBONE + DAMPING + FORCING.replace("[0.01, 0.02]", "[]"), "analysis.forcing.modal", "non-empty list"),
    (BACKBONE + DAMPING + FORCING.replace("[0.01, 0.02]", "[0.01, 0.0]"), "analysis.forcing.modal[1]",
     "a forcing level of 0"),
    (BACKBONE + DAMPING + FORCING.replace("[0.01, 0.02]", "0.01"), "analysis.forcing.modal", "non-empty list"),
    (BACKBONE + DAMPING + FORCING.replace("[0.01, 0.02]", '["a"]'), "analysis.forcing.modal[0]", "a finite number"),
    (BACKBONE + DAMPING + FORCING + "point = 10\n", "analysis.forcing.point", "unknown key (did you mean 'points'?)"),
    (BACKBONE + DAMPING + FORCING + "points = 5\n", "analysis.forcing.points", "must lie in [20, 100000]"),
    (BACKBONE + DAMPING + "[analysis.forcing]\nfrequency_range = [0.9, 1.2]\n", "analysis.forcing",
     "give exactly one of modal"),
    (BACKBONE + DAMPING + FORCING + 'load = {set = "TIP", dofs = ["uz"], amplitude = [1.0]}\n', "analysis.forcing",
     "not both"),
    (BACKBONE + DAMPING + '[analysis.forcing]\nfrequency_range = [0.9, 1.2]\nload = {set = "TIP", box = [[0, 0, 0], '
     '[1, 1, 1]], dofs = ["uz"], amplitude = [1.0]}\n', "analysis.forcing.load", "exactly one of set"),
    (BACKBONE + DAMPING + '[analysis.forcing]\nfrequency_range = [0.9, 1.2]\nload = {dofs = ["uz"], amplitude = [1.0]}\n',
     "analysis.forcing.load", "exactly one of set"),
    (BACKBONE + DAMPING + '[analysis.forcing]\nfrequency_range = [0.9, 1.2]\nload = {set = "TIP", dofs = ["uw"], '
     'amplitude = [1.0]}\n', "analysis.forcing.load.dofs[0]", "expected one of ['ux', 'uy', 'uz', 'rx', 'ry', 'rz']"),
    (BACKBONE + DAMPING + '[analysis.forcing]\nfrequency_range = [0.9, 1.2]\nload = {set = "TIP", amplitude = [1.0]}\n',
     "analysis.forcing.load.dofs", "missing"),
    (BACKBONE + DAMPING + '[analysis.forcing]\nfrequency_range = [0.9, 1.2]\nload = {set = "TIP", dofs = ["uz"], '
     'amplitude = []}\n', "analysis.forcing.load.amplitude", "non-empty list"),
    (BACKBONE + DAMPING + '[analysis.forcing]\nfrequency_range = [0.9, 1.2]\nload = {set = "TIP", dofs = ["uz"], '
     'amplitude = [1.0], force = 2}\n', "analysis.forcing.load.force", "unknown key"),
    (BACKBONE + DAMPING + '[analysis.forcing]\nfrequency_range = [0.9, 1.2]\nload = {box = [[1, 0, 0], [0, 1, 1]], '
     'dofs = ["uz"], amplitude = [1.0]}\n', "analysis.forcing.load.box", "the first corner must be the lower one"),
    (BACKBONE + DAMPING + '[analysis.forcing]\nfrequency_range = [0.9, 1.2]\nload = "TIP"\n', "analysis.forcing.load",
     "expected a table"),
    # NaN, infinity, booleans, huge numbers, an empty range (the review's hostile inputs)
    (BACKBONE + "[analysis.damping]\nmodal = nan\n" + FORCING, "analysis.damping.modal", "got nan"),
    (BACKBONE + "[analysis.damping]\nmodal = true\n" + FORCING, "analysis.damping.modal", "(a boolean)"),
    (BACKBONE + "[analysis.damping]\nrayleigh = [inf, 0.0]\n" + FORCING, "analysis.damping.rayleigh[0]", "got inf"),
    (BACKBONE + "[analysis.damping]\nrayleigh = [0.0, 1e16]\n" + FORCING, "analysis.damping.rayleigh[1]",
     "must lie in [0, 1e+15]"),
    (BACKBONE + DAMPING + FORCING.replace("[0.01, 0.02]", "[true]"), "analysis.forcing.modal[0]", "(a boolean)"),
    (BACKBONE + DAMPING + FORCING.replace("[0.01, 0.02]", "[1e16]"), "analysis.forcing.modal[0]",
     "in [-1e+15, 1e+15]"),
    (BACKBONE + DAMPING + FORCING.replace("[0.9, 1.2]", "[1, 1]"), "analysis.forcing.frequency_range",
     "lo must be below hi"),
    (BACKBONE + DAMPING + FORCING + "points = 1000000000\n", "analysis.forcing.points", "must lie in [20, 100000]"),
]


@pytest.mark.parametrize("tables, key, says", AT_LOAD)
def test_scene_mistakes_exit_2_before_any_model(folder, capsys, monkeypatch, tables, key, says):
    """Each mistake: exit 2, one line naming the key and what is allowed, before the model is built."""
    def no_build(name):
        pytest.fail("the model was built before the forced-response keys were checked")

    monkeypatch.setattr(pipeline, "get_solver", no_build)
    err = run_bad(folder, capsys, scene(tables))
    assert f"[{key}]" in err and says in err, err


IN_THE_RUN = [
    # the polynomial model has no named node sets: a set is refused, with what works instead
    ('load = {set = "TIP", dofs = ["uz"], amplitude = [1.0]}\n', "analysis.forcing.load.set",
     "exposes no named node sets"),
    ('load = {box = [[5, 5, 5], [6, 6, 6]], dofs = ["uz"], amplitude = [1.0]}\n', "analysis.forcing.load.box",
     "holds no node of the mesh"),
    ('load = {box = [[0, 0, 0], [1, 0, 0]], dofs = ["ux"], amplitude = [1.0]}\n', "analysis.forcing.load.dofs",
     "no free dof ['ux']"),
]


@pytest.mark.parametrize("load, key, says", IN_THE_RUN)
def test_load_mistakes_exit_2_in_the_run(folder, capsys, load, key, says):
    tables = BACKBONE + DAMPING + "[analysis.forcing]\nfrequency_range = [0.9, 1.2]\n" + load
    err = run_bad(folder, capsys, scene(tables))
    assert f"[{key}]" in err and says in err, err


def test_overdamped_master_exit_2(folder, capsys, monkeypatch):
    """Rayleigh damping that overdamps the master (xi = alpha / (2 w) = 1.5 at w = 1) is known once the modes
    are: exit 2 naming the key, right after the modes (before STEP and the backbone)."""
    import stepnf.pipeline.run as run

    def no_step(*a, **k):
        pytest.fail("STEP ran before the damping of the masters was checked")

    monkeypatch.setattr(run, "step_stage", no_step)
    tables = BACKBONE + "[analysis.damping]\nrayleigh = [3.0, 0.0]\n" + FORCING
    err = run_bad(folder, capsys, scene(tables))
    assert "[analysis.damping.rayleigh]" in err and "overdamped" in err, err


def test_modal_model_refuses_forcing(folder, capsys):
    tables = BACKBONE + DAMPING + FORCING
    err = run_bad(folder, capsys, scene(tables, solver='solver = "vonkarman"\nkappa = 25.0\nk_max = 2\n'))
    assert "[analysis.forcing]" in err and "not computed" in err, err


def test_keys_load_into_the_scene(folder):
    path = folder / "good.toml"
    path.write_text(scene(BACKBONE + "[analysis.damping]\nrayleigh = [0.01, 0.001]\n[analysis.forcing]\n"
                          'frequency_range = [0.8, 1.25]\npoints = 100\nload = {box = [[0, 0, 0], [1, 0, 0]], '
                          'dofs = ["uz"], amplitude = [1.0, -2.0]}\n'))
    sc = load_scene(path)
    assert sc.damping.rayleigh == (0.01, 0.001) and sc.damping.modal is None
    f = sc.forcing
    assert f.modal is None and f.frequency_range == (0.8, 1.25) and f.points == 100
    assert f.load.box == ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)) and f.load.set is None
    assert f.load.dofs == ("uz",) and f.load.amplitude == (1.0, -2.0)
    path.write_text(scene(BACKBONE + "[analysis.damping]\nmodal = [0.01, 0.02]\n" + FORCING, masters=(0, 1)))
    sc = load_scene(path)
    assert sc.damping.modal == (0.01, 0.02) and sc.forcing.modal == (0.01, 0.02) and sc.forcing.points == 400
