"""The shifted factorisations a manifold keeps alive (issue 33's benchmark: a two-mode manifold of the 38k-dof
cap kept ~30 MUMPS factorisations of ~220 MB each by order 5, and the machine ran out of its 24 GB).

With ``max_live`` the least recently used factorisation is freed first: the same coefficients (the same
factorisation of the same matrix, made again), more factorisations made, never more than ``max_live`` alive.
"""
from __future__ import annotations

import numpy as np

from stepnf.dpim.multimode.manifold import parametrise_manifold
from stepnf.dpim.multimode.solves import ManifoldSolves
from stepnf.dpim.parametrisation import DPIM
from stepnf.dpim.solves import Solvers
from stepnf.runtime.counters import Counters
from helpers.systems import batch_force, modes, near_one_to_four


def test_least_recently_used_factorisations_are_freed():
    M, K, G, H = near_one_to_four()
    w, V = modes(K, M)
    released = []

    class Spy:  # a factorisation that records its release
        def __init__(self, s):
            self.s = s

        def solve(self, X):
            return np.linalg.solve((K - self.s * M).toarray() if hasattr(K, "toarray") else K - self.s * M, X)

        def release(self):
            released.append(self.s)

    solves = ManifoldSolves(K, M, V[:, [0, 4]], (0, 4), w[[0, 4]], Solvers(factory=lambda s, label: Spy(s)),
                            Counters(), max_live=1)
    B = np.ones((K.shape[0], 1), dtype=complex)
    for s in (0.3, 0.7, 0.3):
        solves.solve(s, (), B, "test")
    assert solves.shifts_factorised == [0.3, 0.7, 0.3]  # 0.3 made again after 0.7 pushed it out
    assert released == [0.3, 0.7]
    solves.release()
    assert released == [0.3, 0.7, 0.3]


def test_one_live_factorisation_gives_the_same_manifold():
    M, K, G, H = near_one_to_four()
    f = batch_force(K, G, H)
    w, V = modes(K, M)
    kept = parametrise_manifold(DPIM(f, K, M), [0, 4], V[:, [0, 4]], w[[0, 4]], 7, probe=1.0)
    lean = parametrise_manifold(DPIM(f, K, M), [0, 4], V[:, [0, 4]], w[[0, 4]], 7, probe=1.0, max_live=1)
    # the same matrix factorised again by the same (deterministic) LU: the same bits
    assert all(np.array_equal(kept.W[a], lean.W[a]) for a in kept.W)
    assert kept.f == lean.f
    made = lambda r: sum(c.get("factorizations", 0) for c in r.counts)  # noqa: E731
    assert made(lean) > made(kept)


def test_forces_in_several_calls_give_the_same_manifold(monkeypatch):
    """Probe fields above CALL_BYTES go in several calls of whole directions: the same values (each field's forces
    do not depend on the batch), more calls."""
    import stepnf.dpim.nonlinear_terms as nt
    M, K, G, H = near_one_to_four()
    f = batch_force(K, G, H)
    w, V = modes(K, M)
    one = parametrise_manifold(DPIM(f, K, M), [0, 4], V[:, [0, 4]], w[[0, 4]], 5, probe=1.0)
    monkeypatch.setattr(nt, "CALL_BYTES", 1)  # one direction per call
    many = parametrise_manifold(DPIM(f, K, M), [0, 4], V[:, [0, 4]], w[[0, 4]], 5, probe=1.0)
    assert all(np.array_equal(one.W[a], many.W[a]) for a in one.W) and one.f == many.f
    calls = lambda r: sum(c["force_calls"] for c in r.counts)  # noqa: E731
    evals = lambda r: sum(c.get("force_evaluations", 0) for c in r.counts)  # noqa: E731
    assert evals(one) == evals(many)
    assert calls(one) == 4 and calls(many) > calls(one)  # orders 2..5, one call each
