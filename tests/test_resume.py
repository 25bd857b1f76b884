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
    assert res.counts["force_evaluations"] == total - 72
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
