"""The evaluators stage's order of work (issue 14, memory and time): stepnf/stages/evaluate.py, prefetch.py.

On the FE cap (hex27, 3249 dofs, six masters, all four methods), the masters whose 2 w_p lies above what
the 16 computed modes solve get DNF's ``K - 4 w^2 M`` factorised in the context's slot. Checked here:

* the eigen-solver's factorisation is freed before the first of those factorisations (never two alive);
* the deflated solves of every master, run together in lockstep blocks, give the T of solving them
  master by master (prefetch switched off);
* every mode keeps its methods in the scene's order, and the counts are those of the one-by-one run.
"""
from __future__ import annotations

import pytest

from meshes import cap_model_toml
from stepnf.linalg import Factorization
from stepnf.pipeline import run_scene
from stepnf.scene import load_scene
from stepnf.shifted import ShiftedFactorizer
from stepnf.stages import evaluate

METHODS = ["dnf", "nf", "md", "smd"]
SCENE = cap_model_toml(6, 2) + f"""[analysis]
master_modes = ["(2,0)", "(3,0)", "(4,0)", "(0,1)", "(0,2)", "(2,1)"]
methods = {METHODS!r}
[output]
dir = "out"
"""

pytestmark = pytest.mark.fenicsx


def run(tmp_path, monkeypatch, *, lockstep: bool):
    pytest.importorskip("dolfinx")
    events: list[tuple[str, str]] = []
    release, refactor = Factorization.release, ShiftedFactorizer.refactor

    def logged_release(self):
        events.append(("release", self.label))
        return release(self)

    def logged_refactor(self, sigma, label=""):
        events.append(("refactor", label))
        return refactor(self, sigma, label)

    monkeypatch.setattr(Factorization, "release", logged_release)
    monkeypatch.setattr(ShiftedFactorizer, "refactor", logged_refactor)
    if not lockstep:
        monkeypatch.setattr(evaluate, "prefetch_deflated", lambda state, datas: None)
    (tmp_path / "cap.toml").write_text(SCENE)
    res = run_scene(load_scene(tmp_path / "cap.toml"), write=False)
    monkeypatch.undo()
    return res, events


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    try:
        lock = run(tmp_path_factory.mktemp("lock"), mp, lockstep=True)
        one = run(tmp_path_factory.mktemp("one"), mp, lockstep=False)
    finally:
        mp.undo()
    return lock, one


def test_eigen_factorisation_freed_before_the_slot_is_factorised(runs):
    (res, events), _ = runs
    slot = [i for i, (what, label) in enumerate(events) if what == "refactor" and "4 w^2" in label]
    assert slot, "no master needed K - 4 w^2 M on this mesh: the test checks nothing"
    eigen = [i for i, (what, label) in enumerate(events) if what == "release" and "eigen-solve" in label]
    assert eigen and eigen[0] < slot[0], events
    assert res.counts["factorizations"] == 1 + len(slot)  # the eigen-solve's and one per slot shift


def test_lockstep_solves_give_the_one_by_one_results(runs):
    """Both runs stop each CG at a residual of 1e-12 |b|; the deflated operators' condition numbers are a
    few tens at most (shifts up to lam_max / 1.25), so the solutions agree to ~1e-11 and T, a quotient of
    their products, to the same order: 1e-9 leaves a margin of 100 for the sums of the forms."""
    (lock, _), (one, _) = runs
    assert [m.label for m in lock.modes] == [m.label for m in one.modes]
    for a, b in zip(lock.modes, one.modes):
        assert list(a.methods) == METHODS == list(b.methods)
        for name in METHODS:
            assert a.methods[name].T == pytest.approx(b.methods[name].T, rel=1e-9, abs=0.0), (a.label, name)
            assert [f["kind"] for f in a.methods[name].flags] == [f["kind"] for f in b.methods[name].flags]
    for key in ("linear_solves", "factorizations", "eigensolver_solves", "force_evaluations"):
        assert lock.counts[key] == one.counts[key], key
