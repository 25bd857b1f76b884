"""A run killed part-way resumes from its checkpoint without redoing solver work, with the same numbers."""
import pytest

import stepnf.pipeline as pipeline
from stepnf.errors import SolverRunError
from stepnf.scene import parse_scene
from stepnf.step import n_full_step_evaluations
from stepnf_polynomial import PolynomialAdapter, save_system
from systems import random_system, use_solver


class Crashing(PolynomialAdapter):
    """Fails once `budget` fields have been evaluated (a solver that dies mid-run)."""

    budget = 10**9
    seen = 0

    def _internal_forces(self, U):
        type(self).seen += len(U)
        if type(self).seen > type(self).budget:
            raise SolverRunError("solver killed (test)")
        return super()._internal_forces(U)


def scene_for(tmp_path):
    M, K, G, H = random_system(9, seed=21)
    save_system(tmp_path / "s.npz", M, K, G, H)
    data = {"model": {"solver": "crashing", "file": "s.npz"},
            "analysis": {"master_modes": [0, 1], "methods": ["nf", "dnf"], "retained_modes": 6,
                         "tensors": "full"},
            "output": {"dir": "out"}}
    return parse_scene(data, file=tmp_path / "s.toml", base_dir=tmp_path)


def test_killed_run_resumes(tmp_path, monkeypatch):
    use_solver(monkeypatch, lambda name: Crashing)
    n_full = n_full_step_evaluations(6) + 2 * 6
    # reference: an uninterrupted run
    Crashing.budget, Crashing.seen = 10**9, 0
    (tmp_path / "ref").mkdir()
    ref = pipeline.run_scene(scene_for(tmp_path / "ref"))
    total = ref.counts["force_evaluations"]
    assert total == n_full + 8  # full plan (+ check) and the targeted plan DNF needs (4 per master)
    # killed at 80 fields: the targeted plan (8 fields) and the first full-plan chunk (64) are on disk
    work = tmp_path / "work"
    work.mkdir()
    Crashing.budget, Crashing.seen = 80, 0
    with pytest.raises(SolverRunError):
        pipeline.run_scene(scene_for(work))
    partial = work / "out" / ".s.partial"
    assert partial.is_dir() and len(list(partial.glob("*.npz"))) == 2
    assert not (work / "out" / "s.h5").exists()
    Crashing.budget, Crashing.seen = 10**9, 0
    res = pipeline.run_scene(scene_for(work))
    assert res.counts["force_evaluations_reused"] == 72
    # + 1: the probe, the first reused field evaluated again to check the model did not change
    assert res.counts["force_evaluations"] == total - 72 + 1
    for a, b in zip(res.modes, ref.modes):
        for m in ("nf", "dnf"):
            assert a.methods[m].T == pytest.approx(b.methods[m].T, rel=1e-12)
    assert not partial.exists()  # removed once the results are written
    assert (work / "out" / "s.h5").exists()


def test_killed_backbone_resumes_from_its_stored_orders(tmp_path, monkeypatch):
    """Killed inside the DPIM of the first master (order 6), the rerun reuses DNF's targeted plan and the
    stored forces of orders 2..5 (the fields are checkpointed before their forces overwrite them in the
    same array: ForceEvaluator(out=U)) and gives the same backbone (the same forces: identical numbers)."""
    from stepnf.dpim_forcing import planned_evaluations

    use_solver(monkeypatch, lambda name: Crashing)

    def scene(folder):
        M, K, G, H = random_system(9, seed=21)
        save_system(folder / "s.npz", M, K, G, H)
        data = {"model": {"solver": "crashing", "file": "s.npz"},
                "analysis": {"master_modes": [0, 1], "methods": ["dnf"], "backbone": {"order": 7}},
                "output": {"dir": "out"}}
        return parse_scene(data, file=folder / "s.toml", base_dir=folder)

    Crashing.budget, Crashing.seen = 10**9, 0
    (tmp_path / "ref").mkdir()
    ref = pipeline.run_scene(scene(tmp_path / "ref"))
    plan = planned_evaluations(7)  # per order 2..7: [8, 16, 24, 40, 40, 48]
    assert ref.counts["force_evaluations"] == 8 + 2 * sum(plan)  # DNF's targeted plan, then two masters
    work = tmp_path / "work"
    work.mkdir()
    Crashing.budget, Crashing.seen = 8 + sum(plan[:4]) + 10, 0  # dies in order 6 of the first master
    with pytest.raises(SolverRunError):
        pipeline.run_scene(scene(work))
    Crashing.budget, Crashing.seen = 10**9, 0
    res = pipeline.run_scene(scene(work))
    assert res.counts["force_evaluations_reused"] == 8 + sum(plan[:4])
    for a, b in zip(res.modes, ref.modes):
        assert a.backbone["omega"] == b.backbone["omega"] and a.backbone["valid_up_to"] == b.backbone["valid_up_to"]


# ---------------------------------------------------------------- a checkpoint of another model (issue 29)
def write_scene(folder, G_scale=1.0):
    """The scene of ``scene_for`` as a TOML file (for the CLI), its system's G and H scaled by ``G_scale``."""
    M, K, G, H = random_system(9, seed=21)
    save_system(folder / "s.npz", M, K, G_scale * G, G_scale * H)
    (folder / "s.toml").write_text('[model]\nsolver = "crashing"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0, 1]\n'
                                   'methods = ["nf", "dnf"]\nretained_modes = 6\ntensors = "full"\n'
                                   '[output]\ndir = "out"\n')
    return folder / "s.toml"


def run_json(capsys, toml, *extra):
    """``stepnf run TOML --json``: (exit code, document or None, stderr with the warnings as the CLI prints
    them: pytest records warnings instead of letting Python print them)."""
    import json
    import warnings

    from stepnf.cli import main

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main(["run", str(toml), "--json", "--quiet", *extra])
    out, err = capsys.readouterr()
    err += "".join(f"stepnf: warning: {w.message}\n" for w in caught)
    return code, (json.loads(out) if code == 0 else None), err


def test_a_checkpoint_of_other_tensors_is_not_reused(tmp_path, monkeypatch, capsys):
    """Issue 29, finding 2: killed, the model file's nonlinear tensors changed, rerun: the stored forces (of
    the old tensors) are not reused, the rerun says so and gives what a fresh run of the new model gives."""
    use_solver(monkeypatch, lambda name: Crashing)
    (tmp_path / "ref").mkdir()
    (tmp_path / "old").mkdir()
    Crashing.budget, Crashing.seen = 10**9, 0
    code, fresh, _ = run_json(capsys, write_scene(tmp_path / "ref", G_scale=1.6))
    assert code == 0
    code, old, _ = run_json(capsys, write_scene(tmp_path / "old"))
    work = tmp_path / "work"
    work.mkdir()
    toml = write_scene(work)
    Crashing.budget, Crashing.seen = 80, 0
    assert run_json(capsys, toml)[0] == 3  # killed: two chunks (72 fields) of the old tensors are stored
    assert len(list((work / "out" / ".s.partial").glob("*.npz"))) == 2
    write_scene(work, G_scale=1.6)  # same M and K (same modes, same fields asked for), other G and H
    Crashing.budget, Crashing.seen = 10**9, 0
    code, doc, err = run_json(capsys, toml)
    assert code == 0, err
    assert "was made for another model" in err and "s.npz" in err and "not reused" in err
    assert doc["counts"]["force_evaluations_reused"] == 0
    assert doc["counts"]["force_evaluations"] == fresh["counts"]["force_evaluations"]
    for a, b, c in zip(doc["modes"], fresh["modes"], old["modes"]):
        for m in ("nf", "dnf"):
            # the same arithmetic as the fresh run: equal to round-off; the old model's T is far away
            assert a["methods"][m]["T"] == pytest.approx(b["methods"][m]["T"], rel=1e-12)
            assert abs(c["methods"][m]["T"] - b["methods"][m]["T"]) > 1e-3 * abs(b["methods"][m]["T"])


def test_an_unchanged_rerun_still_resumes_and_says_nothing(tmp_path, monkeypatch, capsys):
    """The model key does not get in the way of a real resume: the same scene and file, the stored forces reused."""
    use_solver(monkeypatch, lambda name: Crashing)
    toml = write_scene(tmp_path)
    Crashing.budget, Crashing.seen = 80, 0
    assert run_json(capsys, toml)[0] == 3
    Crashing.budget, Crashing.seen = 10**9, 0
    code, doc, err = run_json(capsys, toml)
    assert code == 0, err
    assert doc["counts"]["force_evaluations_reused"] == 72 and "another model" not in err


def test_a_checkpoint_without_a_model_key_is_not_reused(tmp_path, monkeypatch, capsys):
    """Chunks written by an earlier stepnf (no model key beside them) cannot be trusted: recomputed, and said."""
    use_solver(monkeypatch, lambda name: Crashing)
    toml = write_scene(tmp_path)
    Crashing.budget, Crashing.seen = 80, 0
    assert run_json(capsys, toml)[0] == 3
    partial = tmp_path / "out" / ".s.partial"
    for f in partial.iterdir():
        if not f.name.endswith(".npz"):
            f.unlink()  # what an earlier stepnf left: the chunks alone
    Crashing.budget, Crashing.seen = 10**9, 0
    code, doc, err = run_json(capsys, toml)
    assert code == 0, err
    assert doc["counts"]["force_evaluations_reused"] == 0
    assert "without a model key" in err and "not reused" in err


class Upgraded(Crashing):
    """The same scene and files, other forces: what the scene cannot show (an adapter upgrade, an included file)."""

    factor = 1.0

    def _internal_forces(self, U):
        F = super()._internal_forces(U)
        return F + (type(self).factor - 1.0) * (F - U @ self._K.T)  # the nonlinear part scaled


def test_a_checkpoint_whose_forces_the_solver_no_longer_gives_is_not_reused(tmp_path, monkeypatch, capsys):
    """The probe: on the first reuse one stored field is evaluated again; forces that differ drop the checkpoint."""
    use_solver(monkeypatch, lambda name: Upgraded)
    (tmp_path / "ref").mkdir()
    Upgraded.budget, Upgraded.seen, Upgraded.factor = 10**9, 0, 1.3
    code, fresh, _ = run_json(capsys, write_scene(tmp_path / "ref"))
    assert code == 0
    toml = write_scene(tmp_path)
    Upgraded.budget, Upgraded.seen, Upgraded.factor = 80, 0, 1.0
    assert run_json(capsys, toml)[0] == 3
    Upgraded.budget, Upgraded.seen, Upgraded.factor = 10**9, 0, 1.3
    code, doc, err = run_json(capsys, toml)
    assert code == 0, err
    assert "another model" in err and "not reused" in err
    assert doc["counts"]["force_evaluations_reused"] == 0
    for a, b in zip(doc["modes"], fresh["modes"]):
        for m in ("nf", "dnf"):
            assert a["methods"][m]["T"] == pytest.approx(b["methods"][m]["T"], rel=1e-12)
