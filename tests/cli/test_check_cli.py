"""``stepnf check SCENE`` and the harness's ``from_config`` check.

The adapters here are small in-test classes (a chain of masses with cubic ground springs), resolved by
name through :func:`helpers.systems.use_solver`, as an installed plugin would be.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stepnf.cli.main import main
from stepnf.keys.schema import Key, Schema
from stepnf.testing.harness import CHECKS, Tolerances, check_from_config, run_checks
from helpers.chain import DuffingChain
from helpers.paths import EXAMPLES
from helpers.systems import use_solver

ANALYSIS = '[analysis]\nmaster_modes = [0]\nmethods = ["dnf"]\n'


class Chain(DuffingChain):
    """n unit masses, grounded by springs 2 u + c u^3 and coupled by unit springs: conservative (the
    harness tests' chain, with the key ``c`` and a characteristic length)."""

    model_keys = Schema(Key("n", "integer", "number of masses", default=6, lo=2, hi=1000),
                        Key("c", "number", "cubic ground stiffness", default=1.0, lo=0))

    def __init__(self, n: int = 6, c: float = 1.0):
        super().__init__(n, c0=c)

    def characteristic_length(self):
        return 1.0


class Twisted(Chain):
    """Plus 0.1 A u^3 with A antisymmetric: the linear checks pass, conservativeness fails."""

    def _internal_force(self, u):
        A = np.triu(np.ones((self.n, self.n)), 1)
        return super()._internal_force(u) + 0.1 * (A - A.T) @ u**3


class WrongDefault(Chain):
    """Documents c = 2 while its constructor applies c = 1."""

    model_keys = Schema(Key("n", "integer", "number of masses", default=6, lo=2),
                        Key("c", "number", "cubic ground stiffness", default=2.0, lo=0))


class Broken(Chain):
    def __init__(self, n: int = 6, c: float = 1.0):
        raise ZeroDivisionError("the mesher divided by zero")


SOLVERS = {"chain": Chain, "twisted": Twisted, "broken": Broken}


@pytest.fixture
def solvers(monkeypatch):
    from stepnf.errors import UnknownSolverError
    from stepnf.plugin.registry import get_solver as installed

    def get_solver(name):
        if name in SOLVERS:
            return SOLVERS[name]
        try:
            return installed(name)
        except UnknownSolverError:
            raise UnknownSolverError(name, {}) from None

    use_solver(monkeypatch, get_solver)


def scene(tmp_path: Path, solver: str, model: str = "n = 5\n") -> Path:
    path = tmp_path / f"{solver}.toml"
    path.write_text(f'[model]\nsolver = "{solver}"\n{model}' + ANALYSIS)
    return path


def lines_of(out: str) -> dict[str, str]:
    """``{check name: status}`` from the printed lines."""
    rows = [ln.split() for ln in out.splitlines() if ln.startswith("  ")]
    return {r[1]: r[0] for r in rows}


def test_polynomial_example_passes(capsys):
    assert main(["check", str(EXAMPLES / "polynomial.toml")]) == 0
    out = capsys.readouterr().out
    st = lines_of(out)
    assert list(st) == list(CHECKS) and "FAILED" not in st.values()
    assert "the adapter gives no dof coordinates" in out and out.rstrip().endswith("8 passed, 3 skipped, 0 failed")


def test_a_conservative_adapter_passes_every_check(solvers, tmp_path, capsys):
    assert main(["check", str(scene(tmp_path, "chain"))]) == 0
    st = lines_of(capsys.readouterr().out)
    assert st.pop("step_equals_intrusive") == "skipped" and set(st.values()) == {"passed"}


def test_a_failed_check_exits_3_and_says_which(solvers, tmp_path, capsys):
    assert main(["check", str(scene(tmp_path, "twisted"))]) == 3
    out = capsys.readouterr().out
    assert lines_of(out)["conservative_force"] == "FAILED" and "not conservative" in out
    assert "1 failed" in out


def test_bad_input_exits_2(solvers, tmp_path, capsys):
    assert main(["check", str(scene(tmp_path, "chain", "n = 1\n"))]) == 2  # n >= 2: a SceneError on model.n
    assert "[model.n]" in capsys.readouterr().err
    assert main(["check", str(scene(tmp_path, "nosuchsolver"))]) == 2
    assert main(["check", str(tmp_path / "missing.toml")]) == 2
    assert main(["check", str(EXAMPLES / "clamped_plate_vk.toml")]) == 2  # vonkarman: a modal model
    assert "modal model" in capsys.readouterr().err


def test_an_adapter_failing_to_build_is_a_message(solvers, tmp_path, capsys):
    assert main(["check", str(scene(tmp_path, "broken"))]) == 3
    err = capsys.readouterr().err
    assert "'broken' adapter" in err and "ZeroDivisionError: the mesher divided by zero" in err
    assert "Traceback" not in err


# ------------------------------------------------------------------ the from_config check
def test_from_config_passes_with_the_documented_defaults():
    check_from_config(Chain(), Tolerances())
    check_from_config(Chain(), Tolerances(), config={"n": 4})


def test_a_documented_default_the_constructor_does_not_apply_fails():
    res = {r.name: r for r in run_checks(WrongDefault, only=["from_config"])}
    assert res["from_config"].status == "failed"
    reason = res["from_config"].reason
    assert "documented defaults" in reason and "'c': 2.0" in reason and "internal force differs" in reason


def test_from_config_failures_and_skips():
    class Required(Chain):
        model_keys = Schema(Key("n", "integer", "number of masses", required=True, lo=2))

    class Crashing(Chain):
        @classmethod
        def from_config(cls, config, *, base_dir, scene_file=None):
            raise KeyError("mesh")

    res = {r.name: r for r in run_checks(Required, only=["from_config"])}
    assert res["from_config"].status == "skipped" and "required [model] keys ['n']" in res["from_config"].reason
    res = {r.name: r for r in run_checks(Required, only=["from_config"], config={"n": 3})}
    assert res["from_config"].status == "passed"
    res = {r.name: r for r in run_checks(Chain, only=["from_config"], config={"n": 1})}  # refused: given table
    assert res["from_config"].status == "failed" and "[model.n]" in res["from_config"].reason
    res = {r.name: r for r in run_checks(Crashing, only=["from_config"])}
    assert res["from_config"].status == "failed" and "raised KeyError" in res["from_config"].reason


def test_defaults_alone_refused_with_a_message_are_skipped():
    from stepnf.errors import SceneError

    class NeedsAGeometry(Chain):
        @classmethod
        def validate_config(cls, config, *, base_dir, scene_file=None):
            raise SceneError(scene_file, "model.geometry", "missing: give a geometry or a mesh")

    res = {r.name: r for r in run_checks(NeedsAGeometry, only=["from_config"])}
    assert res["from_config"].status == "skipped" and "the defaults alone make no model" in res["from_config"].reason


def test_an_adapter_raising_during_a_check_is_a_failed_check():
    class Raising(Chain):
        def _internal_force(self, u):
            raise RuntimeError("solver crashed")

    res = {r.name: r for r in run_checks(Raising)}
    assert res["zero_force"].status == "failed" and "RuntimeError: solver crashed" in res["zero_force"].reason
    assert res["symmetric_matrices"].status == "passed"
