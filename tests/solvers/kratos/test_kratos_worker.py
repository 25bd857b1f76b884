"""The Kratos worker's data paths (issue 32, item 6 "Speed"), with real Kratos runs.

* K and M come back as canonical CSR sharing ONE pattern (both are assembled into the same Kratos matrix:
  its pattern is read and renumbered once, and pickled once).
* Kratos's equation numbers are read back without a loop over the dofs (the static scheme's ``Update``
  trick, :meth:`stepnf_kratos.worker.ShellModel._equations`): a shuffled node numbering gives the same
  matrices and forces, permuted, bit for bit (the same element routines on the same numbers; only the
  assembly order of a node's contributions could differ, and it does not: the element order is kept).
* The worker's per-phase clock: setting a state (DISPLACEMENT, ROTATION, node positions, through
  ``VariableUtils`` on all nodes at once) costs a small part of the C++ assembly of the right-hand side.
  Measured (CPU seconds, one thread, a cap of 4 038 dofs, 1 280 DKT elements): "set" ~1 % of "rhs"; a
  Python loop over the nodes (about 6 us per node for its 9 values) would be ~15 % (bench/kratos.py).
"""
from __future__ import annotations

import pickle

import numpy as np
import pytest

from helpers.required import requires

pytestmark = requires("KratosMultiphysics", "stepnf_kratos")

kratos = pytest.importorskip("stepnf_kratos")
from stepnf_kratos.client import KratosWorker  # noqa: E402
from stepnf_kratos.shellmesh import KRATOS_ELEMENT  # noqa: E402

MATERIAL = {"E": 1.04e11, "nu": 0.3, "rho": 4400.0, "h": 0.003}


def build(worker: KratosWorker, points: np.ndarray, cells: np.ndarray, element: str = "dkt") -> int:
    return worker.call("build", {"points": points, "cells": cells, "element": KRATOS_ELEMENT[element],
                                 "properties": [MATERIAL], "cell_property": np.zeros(len(cells), np.int64),
                                 "folder": str(worker.folder)})


@pytest.fixture(scope="module")
def cap():
    return kratos.cap_surface(0.15, 1.5, "dkt", n_core=6, n_ring=3, core=0.5)


def test_matrices_share_one_canonical_pattern(cap):
    """K and M: canonical CSR (sorted, no duplicates), the same index arrays (one object after unpickling:
    pickle keeps the sharing), and one pickle of both smaller than two separate ones by the pattern's size."""
    with KratosWorker() as w:
        n = build(w, cap.points, cap.cells)
        K, M = w.call("matrices")
    assert K.shape == M.shape == (n, n)
    assert K.has_canonical_format and M.has_canonical_format
    assert M.indices is K.indices and M.indptr is K.indptr
    both, apart = len(pickle.dumps((K, M))), len(pickle.dumps(K)) + len(pickle.dumps(M))
    assert apart - both >= K.indices.nbytes


def test_shuffled_node_numbering_gives_the_same_model(cap):
    """Nodes renumbered by a random permutation: K, M and the forces of a field are the permuted ones, bit
    for bit (Kratos's equation numbers read back right whatever its dof order)."""
    perm = np.random.default_rng(3).permutation(len(cap.points))
    dof = (6 * perm[:, None] + np.arange(6)).ravel()  # new dof j is old dof dof[j]
    u = 1e-3 * np.random.default_rng(4).standard_normal(6 * len(cap.points))
    with KratosWorker() as a, KratosWorker() as b:
        build(a, cap.points, cap.cells)
        build(b, cap.points[perm], np.argsort(perm)[cap.cells])
        (Ka, Ma), (Kb, Mb) = a.call("matrices"), b.call("matrices")
        fa, fb = a.call("forces", u[None]), b.call("forces", u[dof][None])
    for X, Y in ((Ka, Kb), (Ma, Mb)):
        assert (X[dof][:, dof] != Y).nnz == 0
    assert np.abs(fa).max() > 0 and np.array_equal(fa[0][dof], fb[0])


def test_worker_clock_has_every_phase():
    """The worker's clock has every phase of the reset recipe (bench/kratos.py reads it; the share of
    "set" in the assembly's cost is a speed figure, measured there, not asserted in a unit test)."""
    c = kratos.cap_surface(0.15, 1.5, "dkt", n_core=8, n_ring=3, core=0.5)
    with KratosWorker(threads=1) as w:
        n = build(w, c.points, c.cells)
        w.call("forces", 1e-4 * np.random.default_rng(5).standard_normal((4, n)))
        clock = w.call("timings")
    assert {"build", "reset", "set", "frames", "rhs", "copy"} <= set(clock)
    assert all(t[1] >= 0 for t in clock.values()), clock
