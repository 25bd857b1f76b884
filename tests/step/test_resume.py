"""A run killed part-way resumes from its checkpoint without redoing solver work, with the same numbers."""
import pytest

import stepnf.pipeline.run as pipeline
from stepnf.errors import SolverRunError
from stepnf.scene.parse import parse_scene
from stepnf.step.procedure import n_full_step_evaluations
from stepnf_polynomial import PolynomialAdapter, save_system
from helpers.systems import random_system, use_solver


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
    from stepnf.dpim.nonlinear_terms import planned_evaluations

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

    from stepnf.cli.main import main

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
    toml, _ = killed_once(tmp_path, monkeypatch, capsys)
    code, doc, err = run_json(capsys, toml)
    assert code == 0, err
    assert doc["counts"]["force_evaluations_reused"] == 72 and "another model" not in err


def test_a_checkpoint_without_a_model_key_is_not_reused(tmp_path, monkeypatch, capsys):
    """Chunks written by an earlier stepnf (no model key beside them) cannot be trusted: recomputed, and said."""
    toml, partial = killed_once(tmp_path, monkeypatch, capsys)
    for f in partial.iterdir():
        if not f.name.endswith(".npz"):
            f.unlink()  # what an earlier stepnf left: the chunks alone
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


def test_a_reduced_chunk_of_another_width_is_recomputed(tmp_path, monkeypatch, capsys):
    """Review item 7: with 32 or more retained modes the first full-plan chunk (64 fields: +-v_0 .. +-v_31) asks
    for the same fields whatever retained_modes is, but keeps their projections on every retained mode (one
    column per mode, plus one). Killed with 34 modes and rerun with 33, the stored 35-column rows are not
    these projections: recomputed (was a broadcast ValueError, exit 1), numbers of a fresh run."""
    use_solver(monkeypatch, lambda name: Crashing)

    def scene(folder, retained):
        M, K, G, H = random_system(34, seed=3)
        save_system(folder / "s.npz", M, K, G, H)
        (folder / "s.toml").write_text(
            '[model]\nsolver = "crashing"\nfile = "s.npz"\n[analysis]\nmaster_modes = [0]\nmethods = ["nf"]\n'
            f'retained_modes = {retained}\ntensors = "full"\n[output]\ndir = "out"\n')
        return folder / "s.toml"

    (tmp_path / "ref").mkdir()
    Crashing.budget, Crashing.seen = 10**9, 0
    code, fresh, err = run_json(capsys, scene(tmp_path / "ref", 33))
    assert code == 0, err
    work = tmp_path / "work"
    work.mkdir()
    Crashing.budget, Crashing.seen = 70, 0
    assert run_json(capsys, scene(work, 34))[0] == 3  # killed: the first full-plan chunk (64 fields) stored
    assert len(list((work / "out" / ".s.partial").glob("full*.npz"))) == 1
    Crashing.budget, Crashing.seen = 10**9, 0
    code, doc, err = run_json(capsys, scene(work, 33))
    assert code == 0, err
    assert doc["counts"]["force_evaluations_reused"] == 0
    assert doc["counts"]["force_evaluations"] == fresh["counts"]["force_evaluations"]
    # the same fields and arithmetic as the fresh run: the same numbers to round-off
    assert doc["modes"][0]["methods"]["nf"]["T"] == pytest.approx(fresh["modes"][0]["methods"]["nf"]["T"], rel=1e-12)


# ---------------------------------------------------------------- the checkpoint folder is private (review item 5)
def killed_once(folder, monkeypatch, capsys):
    """A scene killed after 80 fields: its checkpoint (two chunks, 72 fields) is left in out/.s.partial."""
    use_solver(monkeypatch, lambda name: Crashing)
    toml = write_scene(folder)
    Crashing.budget, Crashing.seen = 80, 0
    assert run_json(capsys, toml)[0] == 3
    Crashing.budget, Crashing.seen = 10**9, 0
    return toml, folder / "out" / ".s.partial"


def forge(partial):
    """Another user's forces in the stored chunks: the results scaled, fingerprints and probe forces kept."""
    import numpy as np

    for f in partial.glob("*.npz"):
        with np.load(f) as z:
            arrays = dict(z)
        arrays["result"] = 1.5 * arrays["result"]
        with open(f, "wb") as out:
            np.savez(out, **arrays)


def test_the_checkpoint_folder_is_made_0700_whatever_the_umask(tmp_path, monkeypatch, capsys, umask000):
    """It holds forces a rerun trusts: no one else may write (or read) it, even under umask 000."""
    _, partial = killed_once(tmp_path, monkeypatch, capsys)
    assert partial.stat().st_mode & 0o777 == 0o700


@pytest.mark.parametrize("bits", [0o777, 0o770, 0o702], ids=["0777", "0770", "0702"])
def test_a_checkpoint_folder_writable_by_others_is_dropped(tmp_path, monkeypatch, capsys, bits):
    """Someone who could write into it may have put forged forces there (with a matching model key, and the
    probe forces of a real run): dropped with a warning naming it, the run gives a fresh run's numbers."""
    (tmp_path / "ref").mkdir()
    use_solver(monkeypatch, lambda name: Crashing)
    Crashing.budget, Crashing.seen = 10**9, 0
    code, fresh, _ = run_json(capsys, write_scene(tmp_path / "ref"))
    toml, partial = killed_once(tmp_path, monkeypatch, capsys)
    forge(partial)
    partial.chmod(bits)
    code, doc, err = run_json(capsys, toml)
    assert code == 0, err
    assert str(partial) in err and f"writable by others (mode {bits:04o})" in err and "not reused" in err
    assert doc["counts"]["force_evaluations_reused"] == 0
    for a, b in zip(doc["modes"], fresh["modes"]):
        for m in ("nf", "dnf"):
            assert a["methods"][m]["T"] == pytest.approx(b["methods"][m]["T"], rel=1e-12)  # same arithmetic
    assert not partial.exists()


def test_a_checkpoint_folder_of_another_user_is_not_used(tmp_path, monkeypatch, capsys):
    """A folder another user made where stepnf keeps its checkpoint is neither trusted nor removed: the run
    goes on without checkpoints, with one warning naming it and its owner."""
    import os

    (tmp_path / "ref").mkdir()
    use_solver(monkeypatch, lambda name: Crashing)
    Crashing.budget, Crashing.seen = 10**9, 0
    code, fresh, _ = run_json(capsys, write_scene(tmp_path / "ref"))
    toml, partial = killed_once(tmp_path, monkeypatch, capsys)
    forge(partial)
    owner = partial.stat().st_uid
    monkeypatch.setattr(os, "geteuid", lambda: owner + 1)  # the folder is now someone else's
    code, doc, err = run_json(capsys, toml)
    assert code == 0, err
    assert str(partial) in err and f"belongs to another user (uid {owner})" in err and "checkpoint" in err
    assert err.count("warning") == 1
    assert doc["counts"]["force_evaluations_reused"] == 0
    for a, b in zip(doc["modes"], fresh["modes"]):
        for m in ("nf", "dnf"):
            assert a["methods"][m]["T"] == pytest.approx(b["methods"][m]["T"], rel=1e-12)
    assert len(list(partial.glob("*.npz"))) == 2  # theirs: left alone


def test_the_checkpoint_keeps_its_key_as_the_one_canonical_json(tmp_path, monkeypatch, capsys):
    """Review N1: model_key.json is stepnf.scene.model_key.dumps of the key (one canonical JSON, no copy of it)."""
    import json

    from stepnf.step import checkpoint
    from stepnf.scene.model_key import dumps

    _, partial = killed_once(tmp_path, monkeypatch, capsys)
    text = (partial / checkpoint.KEY_FILE).read_text(encoding="utf-8")
    assert text == dumps(json.loads(text))
    assert not hasattr(checkpoint, "_canonical")
