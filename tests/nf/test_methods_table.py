"""The declared vocabularies: the table of methods (:mod:`stepnf.methods`) and the flag constructor
(:func:`stepnf.flags.new_flag`).

Each Method declares what it needs; a small polynomial run (8 dofs, exact cubic forces, so STEP's
evaluation counts are those of its plan) shows that the run does what the table says: the full-order
linear algebra (``counts.linear_solves``) and the STEP plan (``counts.force_evaluations``).
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.errors import SceneError, allowed
from stepnf.flags import CATALOGUE, FlagKindError, new_flag
from stepnf.methods import FULL, MODAL, NAMES, TABLE, evaluators, method
from stepnf.plugin.modal_model import ModalModel
from stepnf.keys.checks import check_choice, describe_value
from stepnf.scene.parse import parse_scene
from stepnf.step.procedure import n_full_step_evaluations
from stepnf_polynomial import save_system
from helpers.systems import random_system, use_solver

#: The names the scene check allowed before the table existed (scene/parse.py's METHODS), in its order.
OLD_NAMES = ("nf", "dnf", "md", "smd", "md_modal", "smd_modal", "md_full", "smd_full")
N_DOFS = 8


def scene_dict(methods, **analysis) -> dict:
    return {"model": {"solver": "polynomial", "file": "s.npz"},
            "analysis": {"master_modes": [0], "methods": methods, **analysis}, "output": {"dir": "out"}}


def run_json(tmp_path: Path, capsys, methods, extra: str = "") -> dict:
    """``stepnf run --json`` of mode 0 of an 8-dof random cubic system with ``methods``."""
    if not (tmp_path / "s.npz").exists():
        save_system(tmp_path / "s.npz", *random_system(N_DOFS, seed=5))
    path = tmp_path / "s.toml"
    path.write_text('[model]\nsolver = "polynomial"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\n'
                    f"methods = {json.dumps(list(methods))}\nretained_modes = {N_DOFS}\n{extra}"
                    '[output]\ndir = "out"\nhdf5 = false\n')
    assert main(["run", str(path), "--json", "--quiet", "--no-plot"]) == 0
    return json.loads(capsys.readouterr().out)


# ------------------------------------------------------------------ the table
def test_the_table_is_closed_and_its_evaluators_import():
    assert NAMES == OLD_NAMES
    for m in TABLE.values():
        assert TABLE[m.modal].order == MODAL and TABLE[m.full].order == FULL, m.name
        for q in (FULL, MODAL):
            ev = m.resolve(q)
            assert ev.evaluator is not None and callable(ev.function()), (m.name, q)
            assert ev.order == (m.order or q)
        if m.evaluator is not None:  # an evaluator factorises exactly when it works on the whole mesh
            assert m.factorises == (m.order == FULL) and (m.step == "targeted") == (m.order == FULL), m.name
    assert evaluators(["md", "smd", "nf"], "full") == {"md": "md_full", "smd": "smd_full", "nf": "nf"}
    assert evaluators(["md", "dnf"], "modal") == {"md": "md_modal", "dnf": "dnf"}
    with pytest.raises(KeyError, match="unknown method 'nnf'"):
        method("nnf")


def test_importing_the_table_imports_nothing_heavy():
    code = "import sys, stepnf.methods; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


# ------------------------------------------------------------------ the scene check reads the table
@pytest.mark.parametrize("name", NAMES)
def test_every_method_of_the_table_is_accepted_by_the_scene(name):
    assert parse_scene(scene_dict([name]), check_model=False).methods == [name]


def test_an_unknown_method_gives_the_message_it_always_gave():
    """The messages of the scene check, built from the table, are those built from the old literal list."""
    with pytest.raises(SceneError) as exc:
        parse_scene(scene_dict(["nf", "nnf"]), check_model=False)
    with pytest.raises(SceneError) as old:
        check_choice(None, "analysis.methods[1]", "nnf", OLD_NAMES)
    assert str(exc.value) == str(old.value) and "expected one of ['nf', 'dnf', 'md', 'smd', 'md_modal', " in str(old.value)
    with pytest.raises(SceneError) as exc:
        parse_scene(scene_dict([]), check_model=False)
    assert str(exc.value) == str(SceneError(None, "analysis.methods", f"expected a non-empty list from "
                                            f"{allowed(OLD_NAMES)}, got {describe_value([])}"))


# ------------------------------------------------------------------ the run does what the table declares
def test_every_method_gives_a_result_of_its_declared_order(tmp_path, capsys):
    doc = run_json(tmp_path, capsys, NAMES)
    (mode,) = doc["modes"]
    assert list(mode["methods"]) == list(NAMES)
    assert doc["scene"]["evaluators"] == evaluators(NAMES, FULL)  # qm_order's default for a solver adapter
    for name, r in mode["methods"].items():
        assert isinstance(r["T"], float) and math.isfinite(r["T"]), name
        assert r["order"] == method(name).resolve(FULL).order, name
    # every mode retained: each modal sum equals its full-order variant to round-off (8 dofs: 1e-9 of T)
    for name in ("nf", "md_modal", "smd_modal"):
        full = mode["methods"][method(name).full]["T"]
        assert mode["methods"][name]["T"] == pytest.approx(full, rel=1e-9), name


@pytest.mark.parametrize("name", sorted(n for n, m in TABLE.items() if m.evaluator))
def test_declared_needs_match_the_run(tmp_path, capsys, name):
    """Linear solves: one per declared K^+ and shift (none for a modal sum); force evaluations: the full STEP
    plan asked for (``tensors = "full"``, every mode, with its check) plus the targeted STEP (2, and 2 for the
    amplitude check) only for a method that declares the targeted plan."""
    m = method(name)
    doc = run_json(tmp_path, capsys, [name], extra='tensors = "full"\n')
    counts = doc["counts"]
    assert counts["linear_solves"] == int(m.pinv) + len(m.shifts)
    assert (counts["linear_solves"] > 0) == m.factorises
    targeted = 4 if m.step == "targeted" else 0
    # the full plan over the 8 retained modes and its 2n check evaluations (tests/cli/test_cli.py), + targeted
    assert counts["force_evaluations"] == n_full_step_evaluations(N_DOFS) + 2 * N_DOFS + targeted


@pytest.mark.parametrize("qm_order", (FULL, MODAL))
def test_md_and_smd_follow_qm_order(tmp_path, capsys, qm_order):
    doc = run_json(tmp_path, capsys, ["md", "smd"], extra=f'qm_order = "{qm_order}"\n')
    assert doc["scene"]["evaluators"] == {"md": f"md_{qm_order}", "smd": f"smd_{qm_order}"}
    assert doc["counts"]["linear_solves"] == sum(int(method(f"{n}_{qm_order}").pinv)
                                                 + len(method(f"{n}_{qm_order}").shifts) for n in ("md", "smd"))


class TwoModes(ModalModel):
    """Two modes (w = 1, 3), g^s_00 = (0.4, 0.7), h^0_000 = 0.5: a model in modal coordinates."""

    def omegas(self):
        return np.array([1.0, 3.0])

    def labels(self):
        return [None, None]

    def quadratic_coefficients(self, p):
        return np.array([0.4, 0.7])

    def cubic_coefficient(self, p):
        return 0.5


def test_every_method_is_defined_on_a_modal_model(tmp_path, capsys, monkeypatch):
    """A full-order method is its modal variant over every mode ("all modes"): the same T."""
    use_solver(monkeypatch, lambda name: TwoModes)
    path = tmp_path / "s.toml"
    path.write_text('[model]\nsolver = "two"\n[analysis]\nmaster_modes = [0]\n'
                    f'methods = {json.dumps(list(NAMES))}\n[output]\ndir = "o"\nhdf5 = false\n')
    assert main(["run", str(path), "--json", "-q", "--no-plot"]) == 0
    (mode,) = json.loads(capsys.readouterr().out)["modes"]
    assert all(method(n).on_modal_model for n in NAMES)
    for name in NAMES:
        ev = method(name).resolve(MODAL)  # qm_order's default for a modal model
        r, variant = mode["methods"][name], mode["methods"][ev.modal]
        assert r["order"] == ("all modes" if ev.order == FULL else "modal"), name
        assert r["T"] == variant["T"], name  # the same sums over the same two modes: bit for bit


# ------------------------------------------------------------------ the flag constructor
def test_a_flag_of_an_unknown_kind_is_refused():
    with pytest.raises(FlagKindError, match="'step_acuracy' is not declared"):
        new_flag("step_acuracy", value=1.0, message="m")


def test_new_flag_builds_the_dict_the_literals_built():
    f = new_flag("step_accuracy", mode=None, value=0.5, message="m")
    assert f == {"kind": "step_accuracy", "mode": None, "value": 0.5, "message": "m"}
    assert list(f) == ["kind", "mode", "value", "message"]  # the JSON document keeps this key order
    assert new_flag("internal_resonance_1_5", mode=3)["kind"] == "internal_resonance_1_5"  # DPIM harmonics m >= 3
    for kind in CATALOGUE:
        assert new_flag(kind) == {"kind": kind}
