"""The one path of a force evaluation (stepnf.step.forces): every field evaluated once and checked once,
cut into chunks by one policy that reads the adapter's declared limits."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import stepnf.external.adapter as external_module
import stepnf.plugin.adapter as adapter_module
from stepnf.dpim.polarisation import PolarisationStats, probe_forces
from stepnf.errors import AdapterError, NumericalError, SolverRunError
from stepnf.external.adapter import ExternalSolverAdapter
from stepnf.external.process import RunRecord
from stepnf.plugin.adapter import SolverAdapter, checked_forces
from stepnf.runtime.counters import Counters
from stepnf.step import procedure
from stepnf.step.forces import BATCH_FIELDS, SINGLE_FIELDS, ForceEvaluator, batch_size, solver_run_size

N = 3
DIAG = np.array([1.0, 2.0, 3.0])


def exact(U: np.ndarray) -> np.ndarray:
    """f(u) = diag(1, 2, 3) u + u**3: exact in double precision for the fields below (sums of products)."""
    return U * DIAG + U ** 3


class Counting(SolverAdapter):
    """An in-process adapter that counts every field it is asked for."""

    def __init__(self):
        self.fields: list[bytes] = []

    @property
    def n_dofs(self):
        return N

    def _internal_force(self, u):
        self.fields.append(u.tobytes())
        return exact(u[None, :])[0]


class CountingExternal(ExternalSolverAdapter):
    """An external adapter whose 'program' is this process: records the fields of every run."""

    name = "counting"

    def __init__(self, limit: int | None = None, **kw):
        super().__init__(**kw)
        self.max_fields_per_run = limit
        self.batches: list[int] = []

    @property
    def n_dofs(self):
        return N

    def mass_matrix(self):
        return sp.identity(N, format="csr")

    def stiffness_matrix(self):
        return sp.diags(DIAG, format="csr")

    def write_force_job(self, workdir: Path, U: np.ndarray):
        np.save(workdir / "fields.npy", U)
        return ["counting"]

    def run(self, argv, workdir: Path, *, log_name: str = "solver.log") -> RunRecord:
        (workdir / log_name).write_text("ran\n")
        rec = RunRecord(tuple(argv), workdir, workdir / log_name, 0.0)
        self.runs.append(rec)
        return rec

    def read_forces(self, workdir: Path, m: int):
        U = np.load(workdir / "fields.npy")
        self.batches.append(len(U))
        return exact(U)


@pytest.fixture
def checks(monkeypatch):
    """Every call of the one check, with the number of fields it checked."""
    seen: list[int] = []
    real = adapter_module.checked_forces

    def spy(F, m, adapter, **kw):
        seen.append(m)
        return real(F, m, adapter, **kw)

    monkeypatch.setattr(adapter_module, "checked_forces", spy)
    monkeypatch.setattr(external_module, "checked_forces", spy)
    return seen


def fields(m: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((m, N))


def test_one_chunking_policy_reads_the_adapters_declarations():
    assert batch_size(Counting()) == SINGLE_FIELDS == 64
    assert batch_size(CountingExternal()) == BATCH_FIELDS == 1024  # prefers_batches
    # one external run's share: even over the parallel runs, capped by max_fields_per_run, at least 1
    assert [solver_run_size(5, 1, None), solver_run_size(5, 2, None), solver_run_size(5, 1, 2),
            solver_run_size(7, 3, 2), solver_run_size(0, 4, None)] == [5, 3, 2, 2, 1]
    ev = ForceEvaluator(exact, N, Counters(), batch_size=3)
    assert ev.blocks(7) == [(0, 4), (4, 7)] and ev.blocks(0) == []  # even blocks: a pair +-v stays together


def test_in_process_fields_evaluated_once_and_checked_once_per_chunk(checks):
    ad, c = Counting(), Counters()
    ev = ForceEvaluator.for_adapter(ad, N, c)
    assert ev.checked and ev.batch_size == 64
    U = fields(150)
    F = ev(U)
    np.testing.assert_array_equal(F, exact(U))  # same operations, same bits
    assert len(ad.fields) == 150 and len(set(ad.fields)) == 150  # each field once
    assert checks == [64, 64, 22]  # one check per chunk the adapter returned, nowhere else
    assert (c.force_evaluations, c.solver_runs) == (150, 3)
    # the polarisation does not check an adapter's forces again
    stats = PolarisationStats()
    probe_forces(ev, fields(10, seed=1), stats)
    assert checks == [64, 64, 22, 10] and stats.force_evaluations == 10

    class Trusted:  # a checked force function: what it returns is not looked at again
        checked = True

        def __call__(self, X):
            return X * np.nan

    assert np.isnan(probe_forces(Trusted(), np.ones((2, N)), PolarisationStats())).all()


def test_external_fields_run_once_in_runs_of_the_declared_limit(tmp_path, checks):
    ad, c = CountingExternal(limit=4, workdir=tmp_path, keep="never"), Counters()
    ev = ForceEvaluator.for_adapter(ad, N, c)
    U = fields(10)
    np.testing.assert_array_equal(ev(U), exact(U))
    assert ad.batches == [4, 4, 2]  # cut once, by max_fields_per_run (the evaluator's chunk holds all 10)
    # the check where each run's forces are read (keeps the work folder on failure), then the public one
    assert checks == [4, 4, 2, 10]
    ev(U[:5])
    assert ad.batches == [4, 4, 2]  # nothing run again: the adapter's cache of finished runs


def test_bare_force_function_is_still_checked():
    ev = ForceEvaluator(lambda X: np.zeros((len(X), N + 1)), N, Counters())
    assert not ev.checked
    with pytest.raises(NumericalError, match=r"the solver returned forces of shape \(2, 4\) for \(2, 3\)"):
        ev(np.ones((2, N)))
    with pytest.raises(NumericalError, match="polarisation: the internal forces contain NaN or inf"):
        probe_forces(lambda X: X * np.nan, np.ones((2, N)), PolarisationStats())


def test_the_one_check_keeps_both_wordings():
    ad = Counting()
    with pytest.raises(AdapterError, match=r"^Counting returned forces of shape \(2, 2\), expected \(2, 3\)$"):
        checked_forces(np.zeros((2, 2)), 2, ad)
    with pytest.raises(AdapterError, match=r"^Counting returned NaN or inf internal forces for field\(s\) \[1\]"):
        checked_forces(np.array([[0.0, 0, 0], [0, np.inf, 0]]), 2, ad)
    assert checked_forces(np.zeros(3), 1, ad, what="internal force").shape == (1, 3)  # one field may be (n,)

    def fail(msg):
        return SolverRunError(msg)

    with pytest.raises(SolverRunError, match=r"^Counting: read forces of shape \(1, 2\), expected \(1, 3\)$"):
        checked_forces(np.zeros((1, 2)), 1, ad, what="forces", read_from="X (x)", fail=fail)
    with pytest.raises(SolverRunError, match=r"^X \(x\): NaN or inf internal forces for field\(s\) \[0\]"):
        checked_forces(np.full((1, 3), np.nan), 1, ad, what="forces", read_from="X (x)", fail=fail)


def test_the_stages_import_path_still_holds():
    assert procedure.ForceEvaluator is ForceEvaluator
