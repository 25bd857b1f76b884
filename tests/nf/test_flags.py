"""Honest tables (issue 29, finding 9): one catalogue of flag kinds decides which numbers are n/a.

Three models where the single-mode reduction gives numbers that are not numbers of the structure:
an exact 1:2 internal resonance (NF and DNF divide by w_s^2 - 4 w_p^2 = 0), a degenerate pair coupled
by cubic terms (no single-mode invariant manifold: the DPIM refuses it), and a master that drives a
zero-frequency mode (the mean of the motion drifts: no periodic orbit). Each is built in modal
coordinates (``tests/helpers/systems.py``), so every coupling is known exactly; the table shows n/a with the
reason, the run exits 0 (a flagged number, as for the other n/a cases: README), and the JSON document
and the HDF5 file keep the numbers (infinite ones as "inf" strings, never ``Infinity``).
"""
from __future__ import annotations

import itertools
import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from stepnf.nf.coefficient import MethodResult
from stepnf.cli.main import main
from stepnf.flags import CATALOGUE, is_known, t_unusable
from stepnf.io.results import ModeResult, RunResult
from stepnf.pipeline.backbone import no_manifold
from stepnf.report.table import format_table
from stepnf_polynomial import save_system
from helpers.systems import modal_to_physical
from helpers.paths import REPO

ROOT = REPO


def sym(T: np.ndarray, idx: tuple, v: float) -> None:
    """Set every permutation of ``idx`` in the (fully symmetric) modal tensor ``T`` to ``v``."""
    for p in set(itertools.permutations(idx)):
        T[p] = v


def scene(d: Path, name: str, arrays, masters="[0]", extra="", backbone=False) -> Path:
    save_system(d / f"{name}.npz", *arrays)
    text = (f'[model]\nsolver = "polynomial"\nfile = "{name}.npz"\n[analysis]\nmaster_modes = {masters}\n'
            f'methods = ["nf", "dnf", "md", "smd"]\n{extra}'
            + ("[analysis.backbone]\norder = 5\n" if backbone else "") + '[output]\ndir = "out"\n')
    (d / f"{name}.toml").write_text(text)
    return d / f"{name}.toml"


def run(path: Path, capsys) -> tuple[int, str, dict]:
    code = main(["run", str(path), "-q", "--no-plot"])
    table = capsys.readouterr().out
    assert main(["run", str(path), "-q", "--no-plot", "--json"]) == code
    text = capsys.readouterr().out
    assert "Infinity" not in text and "NaN" not in text
    return code, table, json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in the JSON document"))


def rows(table: str) -> dict[str, list[str]]:
    """method -> the cells of its row (T, [Gamma,] behaviour, flags...)."""
    out = {}
    for line in table.splitlines():
        cells = line.split()
        for i, c in enumerate(cells[:7]):
            if c in ("nf", "dnf", "md", "smd"):
                out[c] = cells[i + 1:]
    return out


# ------------------------------------------------------------------ exact 1:2
def one_two(exact_matrices: bool):
    """Modes w = 1, 2 exactly, quadratic coupling g^1_00 = 1, cubic stiffening of both."""
    g = np.zeros((2, 2, 2))
    sym(g, (1, 0, 0), 1.0)
    h = np.zeros((2,) * 4)
    h[0, 0, 0, 0] = h[1, 1, 1, 1] = 1.0
    if exact_matrices:  # M = I, K = diag(1, 4): K - 4 w^2 M is exactly singular
        return np.eye(2), np.diag([1.0, 4.0]), g, h
    return modal_to_physical(np.array([1.0, 2.0]), g, h, seed=1)  # ratio 2 up to round-off: T ~ 1e14


@pytest.mark.parametrize("exact", [True, False], ids=["singular", "round-off"])
def test_exact_one_two_resonance_is_na(tmp_path, capsys, exact):
    code, table, doc = run(scene(tmp_path, "r12", one_two(exact)), capsys)
    assert code == 0  # a number known wrong is n/a in the table, the run itself succeeded (README)
    r = rows(table)
    for name in ("nf", "dnf"):
        assert r[name][:2] == ["n/a", "n/a"], table
        assert "softening" not in r[name] and "hardening" not in r[name]
        m = doc["modes"][0]["methods"][name]
        assert m["na"]["kind"] == "diverges" and re.search("1:2|twice its frequency", m["na"]["reason"])
        # round-off: the refined eigen-solve (issue 35, stepnf.linalg.refined_modes) may find w2 = 2 w1 to the bit
        assert m["behaviour"] == "diverges" if exact else m["behaviour"] in ("diverges", "hardening")
        if m["behaviour"] == "diverges":
            assert m["T"] in ("-inf", "inf")  # kept, as a string: JSON has no infinity
        else:
            assert abs(m["T"]) > 1e10  # kept: the round-off divergence (measured 1.4e14)
    assert re.search(r"n/a \[0 nf\]: .*(T is -?inf|round-off)", table)
    # MD and SMD have no 2 w_p denominator: their T stands (Table 1's rows by hand with g^1_00 = 1, h = 1,
    # w = 1, 2: MD 7/72, SMD (3 (1 - 2/4) + 1/4 - 3/4) / 8 = 1/8; STEP's round-off ~1e-10 relative)
    assert r["md"][1] == "hardening" and r["smd"][1] == "hardening"
    assert doc["modes"][0]["methods"]["md"]["T"] == pytest.approx(7 / 72, rel=1e-8)
    assert doc["modes"][0]["methods"]["smd"]["T"] == pytest.approx(1 / 8, rel=1e-8)
    with h5py.File(tmp_path / "out" / "r12.h5") as f:
        assert f["modes/mode_0/dnf"].attrs["na_kind"] == "diverges"
        assert "na_kind" not in f["modes/mode_0/md"].attrs
        json.loads(f["modes/mode_0/dnf"].attrs["flags"])  # valid JSON
    assert main(["show", str(tmp_path / "out" / "r12.h5")]) == 0
    assert rows(capsys.readouterr().out)["dnf"][:2] == ["n/a", "n/a"]


def test_exact_one_two_backbone_refused_not_fatal(tmp_path, capsys):
    """With a backbone asked the DPIM meets K - (2 w)^2 M singular: that master's block has no validity
    range, the run goes on (was: 'solver failure', exit 3)."""
    code, table, doc = run(scene(tmp_path, "r12", one_two(True), backbone=True), capsys)
    assert code == 0
    block = doc["modes"][0]["backbone"]
    assert block["valid_up_to"] == 0.0 and block["amplitude"] == []
    assert "no validity range: the parametrisation diverges" in table


# ------------------------------------------------------------------ degenerate twin
def twin(coupling: float):
    """Modes 0 and 1 at w = 1 (a degenerate pair), mode 2 at 3; cubic terms only. The pair's quartic
    potential is (x^2 + y^2)^2 / 4 (h_0000 = h_1111 = 1, h_0011 = 1/3), the same in every direction of the
    pair as for an axisymmetric structure, so whatever basis of the pair the eigen-solve returns, each
    direction has a single-mode manifold, until h_0001 = ``coupling`` breaks the symmetry."""
    g = np.zeros((3, 3, 3))
    h = np.zeros((3,) * 4)
    sym(h, (0, 0, 0, 0), 1.0)
    sym(h, (1, 1, 1, 1), 1.0)
    sym(h, (0, 0, 1, 1), 1.0 / 3.0)
    sym(h, (2, 2, 2, 2), 1.0)
    sym(h, (0, 0, 0, 1), coupling)
    return modal_to_physical(np.array([1.0, 1.0, 3.0]), g, h, seed=2)


@pytest.mark.parametrize("backbone", [False, True], ids=["T only", "with backbone"])
def test_degenerate_twin_with_cubic_coupling_is_na(tmp_path, capsys, backbone):
    code, table, doc = run(scene(tmp_path, "twin", twin(0.3), backbone=backbone), capsys)
    assert code == 0  # with a backbone: was exit 3 (the DPIM's refusal ended the run)
    r = rows(table)
    for name in ("nf", "dnf", "md", "smd"):
        assert r[name][:2] == ["n/a", "n/a"], table
        m = doc["modes"][0]["methods"][name]
        assert m["na"]["kind"] == "twin_driven" and "degenerate twin" in m["na"]["reason"]
        assert isinstance(m["T"], float)  # the number is kept
    assert "n/a [0 nf, dnf, md, smd]: mode 1, a degenerate twin of master mode 0" in table
    if backbone:
        block = doc["modes"][0]["backbone"]
        assert block["valid_up_to"] == 0.0 and block["valid_reason"].startswith("no single-mode manifold")
        assert "no validity range: no single-mode manifold" in table


def test_uncoupled_twin_keeps_its_numbers(tmp_path, capsys):
    """The same pair without the coupling: the reduction exists, T = 3 h / (8 w^2) = 3/8 for every method."""
    code, table, doc = run(scene(tmp_path, "twin", twin(0.0)), capsys)
    assert code == 0 and "n/a" not in table
    for name in ("nf", "dnf", "md", "smd"):
        assert doc["modes"][0]["methods"][name]["T"] == pytest.approx(3 / 8, rel=1e-8)  # STEP round-off ~1e-10


# ------------------------------------------------------------------ driven rigid mode
def rigid(drive: float):
    """A zero-frequency mode (counted rigid by its eigenvalue, not declared) and elastic modes at 1, 2.5;
    the master (elastic 0) drives the zero mode through g_r00 = ``drive``."""
    g = np.zeros((3, 3, 3))
    sym(g, (0, 1, 1), drive)
    sym(g, (2, 1, 1), 0.2)
    h = np.zeros((3,) * 4)
    sym(h, (1, 1, 1, 1), 1.0)
    sym(h, (2, 2, 2, 2), 1.0)
    return modal_to_physical(np.array([0.0, 1.0, 2.5]), g, h, seed=3)


@pytest.mark.parametrize("declared", [False, True], ids=["counted", "declared"])
def test_driven_rigid_mode_is_na_and_backbone_not_valid(tmp_path, capsys, declared):
    extra = "rigid_modes = 1\n" if declared else ""
    code, table, doc = run(scene(tmp_path, "rigid", rigid(0.5), extra=extra, backbone=True), capsys)
    assert code == 0
    r = rows(table)
    for name in ("nf", "dnf", "md", "smd"):
        assert r[name][:2] == ["n/a", "n/a"], table
        assert doc["modes"][0]["methods"][name]["na"]["kind"] == "rigid_mode_driven"
    assert ("declared by analysis.rigid_modes" if declared else "counted as rigid by its eigenvalue") in table
    block = doc["modes"][0]["backbone"]
    assert block["valid_up_to"] == 0.0 and block["valid_reason"].startswith("no periodic orbit")
    assert "valid up to" not in table and "no validity range: no periodic orbit" in table
    listed = [x for x in table.split("backbone [0")[1].splitlines() if x.startswith("  ") and x.strip()[0].isdigit()]
    assert listed and all(x.endswith("beyond validity") for x in listed)


def test_undriven_rigid_mode_keeps_its_numbers(tmp_path, capsys):
    """Forces that leave the zero mode alone (self-equilibrated, as for a true rigid-body motion): T stands."""
    code, table, doc = run(scene(tmp_path, "rigid", rigid(0.0), backbone=True), capsys)
    assert code == 0 and "rigid_mode_driven" not in table
    assert doc["modes"][0]["methods"]["dnf"]["na"] is None
    assert doc["modes"][0]["backbone"]["valid_up_to"] > 0


# ------------------------------------------------------------------ the catalogue
def emitted_kinds() -> set[str]:
    """Every flag kind a module of stepnf (or a bundled adapter) writes: ``new_flag("...", ...)`` calls,
    ``"kind": "..."`` literals and the f-string ``internal_resonance_1_{m}`` (as ``internal_resonance_1_3``), and
    ``kind=...`` keyword arguments (NoSingleModeManifold's kinds)."""
    kinds = set()
    for path in list((ROOT / "stepnf").rglob("*.py")) + list((ROOT / "solvers").rglob("*.py")):
        text = path.read_text()
        kinds |= set(re.findall(r"""["']kind["']\s*:\s*f?["']([A-Za-z0-9_{}]+)["']""", text))
        kinds |= set(re.findall(r"""\bkind=f?["']([A-Za-z0-9_{}]+)["']""", text))  # keyword arguments
        kinds |= set(re.findall(r"""\bnew_flag\(\s*f?["']([A-Za-z0-9_{}]+)["']""", text))  # stepnf.flags.new_flag
    return {re.sub(r"\{[^}]*\}", "3", k) for k in kinds} - {"stable"}  # (np.argsort's kind="stable")


def test_every_emitted_kind_is_in_the_catalogue():
    kinds = emitted_kinds()
    assert {"internal_resonance_1_2", "modal_truncation", "twin_driven", "rigid_mode_driven"} <= kinds
    assert not [k for k in kinds if not is_known(k)], sorted(kinds)


def test_catalogue_entries_are_complete():
    for k in CATALOGUE.values():
        assert k.printed in ("line", "note", "block", "column") and k.t_na in ("always", "never", "value")
        assert k.template and (k.backbone_reason or not k.backbone_invalid), k.name


@pytest.mark.parametrize("kind", sorted(k.name for k in CATALOGUE.values() if k.t_na == "always"))
def test_catalogue_decides_the_table(kind):
    """By construction: any flag whose kind the catalogue marks t_na = "always" makes the row n/a with its
    message; its backbone_invalid takes the validity range."""
    r = MethodResult("dnf", 0.25, (0.0,) * 6, flags=[{"kind": kind, "mode": None, "message": f"because {kind}"}])
    assert t_unusable(r) == (kind, f"because {kind}")
    mode = ModeResult(index=0, label=None, omega=1.0, rho=None, methods={"dnf": r})
    table = format_table(RunResult(scene={}, modes=[mode], counts={}, timings={}, spectrum={}))
    assert rows(table)["dnf"][:2] == ["n/a", "n/a"] and f"n/a [0 dnf]: because {kind}" in table
    block = no_manifold({"valid_up_to": 1.0, "valid_reason": "orders differ", "flags": []}, mode)
    assert (block["valid_up_to"] == 0.0) == CATALOGUE[kind].backbone_invalid


def test_infinite_values_never_reach_json_as_infinity():
    """A flag's value may be infinite (T_error of a T that vanishes at the check amplitude): the document
    stays strict JSON (was: ValueError from json.dumps(allow_nan=False), an internal error)."""
    r = MethodResult("dnf", 0.25, (0.0,) * 6, T_error=float("inf"),
                     flags=[{"kind": "step_accuracy", "value": float("inf"), "message": "m"}])
    run_ = RunResult(scene={}, modes=[ModeResult(0, None, 1.0, None, methods={"dnf": r})], counts={}, timings={},
                     spectrum={}, flags=[{"kind": "ill_conditioned", "value": float("inf"), "message": "x"}])
    doc = json.loads(run_.to_json())
    assert doc["modes"][0]["methods"]["dnf"]["flags"][0]["value"] == "inf"
    assert doc["modes"][0]["methods"]["dnf"]["na"]["kind"] == "step_accuracy"
