"""The evaluators stage's order of work (issue 14, memory and time): stepnf/pipeline/evaluate.py, prefetch.py.

On the FE cap (hex27, 3249 dofs, six masters, all four methods), the masters whose 2 w_p lies above what
the 16 computed modes solve get DNF's ``K - 4 w^2 M`` factorised in the context's slot. Checked here:

* the eigen-solver's factorisation is freed before the first of those factorisations (never two alive);
* the deflated solves of every master, run together in lockstep blocks, give the T of solving them
  master by master (prefetch switched off);
* every mode keeps its methods in the scene's order, and the counts are those of the one-by-one run.
"""
from __future__ import annotations

import pytest

from helpers.meshes import cap_model_toml
from stepnf.linalg.factorization import Factorization
from stepnf.pipeline.run import run_scene
from stepnf.scene.parse import load_scene
from stepnf.linalg.shifted import ShiftedFactorizer
from stepnf.pipeline import evaluate

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


def test_span_batch_solves_every_dnf_shift_by_deflation(runs, tmp_path, monkeypatch):
    """A large model's first eigen-solve reaches 2 w_p of every master (stepnf.pipeline.modes.dnf_span_batch,
    switched on here for this small cap): DNF's K - 4 w^2 M is then solved by deflation for every master, no
    factorisation but the eigen-solver's, and T is that of the run that factorised.

    Tolerance: the solves now differ (deflated CG to 1e-12 |b| on 31 modes against a factorisation, and CG
    on 16), by ~1e-11 relative; T of (2, 0) nearly cancels (its Gamma is 0.014 where its quadratic and
    cubic parts are each ~1), which multiplies that by ~1e3: measured 2.0e-8 for DNF, 1.4e-8 for MD and
    SMD, 7e-10 and less for the other modes; a wrong solve gives O(1)."""
    from stepnf.pipeline import modes

    (lock, _), _ = runs
    monkeypatch.setattr(modes, "DNF_SPAN_FROM", 0)
    span, events = run(tmp_path, monkeypatch, lockstep=True)
    assert span.counts["factorizations"] == 1 and not [e for e in events if e[0] == "refactor"], events
    assert span.counts["eigensolver_solves"] > lock.counts["eigensolver_solves"]  # the price: more modes
    for a, b in zip(span.modes, lock.modes):
        assert a.label == b.label
        for name in METHODS:
            assert a.methods[name].T == pytest.approx(b.methods[name].T, rel=1e-7, abs=0.0), (a.label, name)


def test_span_batch_size():
    """The first eigen-solve of dnf_span_batch: 2 sqrt(1.25) times the modes up to the highest master, plus
    four; only for large models with DNF and deflation, not with an adapter's eigen-solver that has no
    shifted solves to deflate with."""
    from types import SimpleNamespace

    from stepnf.pipeline.modes import DNF_SPAN_FROM, dnf_span_batch, first_batch

    def state(n=DNF_SPAN_FROM, masters=("(2,0)",) * 6, evaluators=("dnf", "md_full"), deflation=True,
              own_eigen=True, shifted=False):
        scene = SimpleNamespace(master_modes=list(masters), deflation=deflation)
        adapter = SimpleNamespace(provides_eigenmodes=not own_eigen, provides_shifted_solves=shifted)
        return SimpleNamespace(scene=scene, n=n, evaluators=set(evaluators), needs_modal=False, n_ret=10,
                               adapter=adapter)

    assert dnf_span_batch(state()) == 27 + 4 == first_batch(state())  # ceil(2.236 x 12) + 4
    assert dnf_span_batch(state(masters=[0, 5])) == 14 + 4 == first_batch(state(masters=[0, 5]))
    assert dnf_span_batch(state(own_eigen=False, shifted=True)) == 31  # SLEPc and MUMPS under MPI
    for other in (state(n=DNF_SPAN_FROM - 1), state(evaluators=("md_full", "smd_full")),
                  state(deflation=False), state(own_eigen=False)):
        assert dnf_span_batch(other) is None
    assert first_batch(state(n=1000)) == 16 and first_batch(state(n=1000, masters=[0, 5])) is None
