"""STEP recovers the quadratic and cubic stiffness of an exact cubic force to near round-off.

The references are the intrusive tensors of the ``polynomial`` adapter,
projected on the modes: ``g[p, j, k] = phi_p^T G(phi_j, phi_k)``,
``h[p, j, k, l] = phi_p^T H(phi_j, phi_k, phi_l)``.

Round-off budget: STEP divides force differences by ``q^2`` (G) and ``q^3`` (H)
after cancelling the linear part ``K q phi``. With the automatic amplitude
(largest entry of ``q phi`` = 0.5) and O(1..10) stiffness, the linear part is
at most ~10x the nonlinear one, so the recovered terms lose about one decade
to cancellation: ~1e-15 x 10 x (a few terms summed) ~ 1e-14 relative to the
largest coefficient. Measured worst cases are in the assertions' comments
(<= 4.5e-15); the asserted 1e-12 leaves a margin of >200x and still fails for
any wrong combination (those give O(1) errors).
"""
from __future__ import annotations

import numpy as np
import pytest

from stepnf.runtime.counters import Counters
from stepnf.linalg.modal_analysis import modal_analysis
from stepnf.step.procedure import (ForceEvaluator, StepPolicy, full_step, n_full_step_evaluations, step_amplitude,
                         targeted_step)
from stepnf_polynomial import PolynomialAdapter
from helpers.systems import random_system

RTOL_STEP = 1e-12


def _setup(n=8, seed=5, rigid=0):
    M, K, G, H = random_system(n, seed, rigid=rigid)
    adapter = PolynomialAdapter(M, K, G, H)
    basis = modal_analysis(adapter.stiffness_matrix(), adapter.mass_matrix())
    return adapter, basis


def _exact_tensors(adapter, Phi):
    G = np.einsum("ai,abc,bj,ck->ijk", Phi, adapter._G, Phi, Phi)
    H = np.einsum("ai,abcd,bj,ck,dl->ijkl", Phi, adapter._H, Phi, Phi, Phi)
    return G, H


def expected_full_evaluations(n: int) -> int:
    """2n singles (+-), 3 per pair (+-(j+k), j-k), 1 per triple (j+k+l): written out independently."""
    singles = 2 * n
    pairs = 3 * (n * (n - 1) // 2)
    triples = n * (n - 1) * (n - 2) // 6
    return singles + pairs + triples


@pytest.mark.parametrize("rigid", [0, 3])
def test_targeted_step_recovers_G_and_h(rigid):
    adapter, basis = _setup(rigid=rigid)
    K = adapter.stiffness_matrix()
    policy = StepPolicy()
    counters = Counters()
    forces = ForceEvaluator(adapter.internal_forces, adapter.n_dofs, counters)
    for p in range(basis.n_elastic):
        phi = basis.phi[:, p]
        q = step_amplitude(phi, policy, adapter.characteristic_length())
        assert np.max(np.abs(q * phi)) == pytest.approx(0.5, rel=1e-15)  # 0.5 x length (1 by default)
        res = targeted_step(forces, K, phi, q, policy, p=p)
        Gv = adapter.quadratic_force(phi, phi)
        h = float(phi @ adapter.cubic_force(phi, phi, phi))
        # measured max errors 7.9e-16 (G) and 4.5e-15 (h) relative
        np.testing.assert_allclose(res.Gv, Gv, rtol=0, atol=RTOL_STEP * np.abs(Gv).max())
        assert res.h == pytest.approx(h, rel=RTOL_STEP)
        # the amplitude check sees an exact cubic: estimates at round-off, nothing flagged
        assert res.error_G < 1e-12 and res.error_h < 1e-12 and res.flags == []
    assert counters.force_evaluations == 4 * basis.n_elastic  # two amplitudes x (+q, -q)
    # without the check: exactly two per master mode
    c2 = Counters()
    targeted_step(ForceEvaluator(adapter.internal_forces, adapter.n_dofs, c2), K, basis.phi[:, 0], 1.0,
                  StepPolicy(check=False), p=0)
    assert c2.force_evaluations == 2


def test_targeted_step_flags_non_cubic_force():
    """A quintic term makes STEP amplitude-dependent: the check sees it, a third amplitude measures its rate
    (2) and the extrapolation removes it (issue 32; before, the raw h was kept and flagged step_accuracy)."""
    adapter, basis = _setup()

    def forces_quintic(U):
        return adapter.internal_forces(U) + 0.5 * U**5

    K = adapter.stiffness_matrix()
    phi = basis.phi[:, 0]
    policy = StepPolicy()
    res = targeted_step(ForceEvaluator(forces_quintic, adapter.n_dofs, Counters()), K, phi,
                        step_amplitude(phi, policy, None), policy, p=0)
    # the u^5 term contributes q^2 phi^5 ~ O(1e-1) relative to h at q phi <= 0.5: far above 1e-4; it is an
    # exact a^2 term of Hv(a), which one Richardson step removes to rounding (measured 6e-15)
    assert abs(res.rate_h - 2.0) < 1e-6
    _, h_exact = _exact_tensors(adapter, phi[:, None])
    assert abs(res.h - h_exact[0, 0, 0, 0]) < RTOL_STEP * abs(h_exact[0, 0, 0, 0])
    assert res.error_h < policy.tolerance
    assert [f["kind"] for f in res.flags] == ["step_extrapolated"]
    assert res.flags[0]["mode"] == 0


@pytest.mark.parametrize("n_ret, rigid", [(1, 0), (2, 0), (4, 0), (5, 2)])
def test_full_step_recovers_all_tensors(n_ret, rigid):
    adapter, basis = _setup(n=7, seed=9, rigid=rigid)
    K = adapter.stiffness_matrix()
    Phi = basis.phi[:, :n_ret]
    policy = StepPolicy()
    q = np.array([step_amplitude(Phi[:, j], policy, None) for j in range(n_ret)])
    counters = Counters()
    res = full_step(ForceEvaluator(adapter.internal_forces, adapter.n_dofs, counters), K, Phi, q, policy)
    g_ref, h_ref = _exact_tensors(adapter, Phi)
    # measured worst errors: 3.2e-15 (g) and 3.1e-15 (h) relative to the largest coefficient
    np.testing.assert_allclose(res.g, g_ref, rtol=0, atol=RTOL_STEP * np.abs(g_ref).max())
    np.testing.assert_allclose(res.h, h_ref, rtol=0, atol=RTOL_STEP * np.abs(h_ref).max())
    # symmetry in the lower indices comes out of the combinations, not imposed afterwards
    np.testing.assert_array_equal(res.g, np.transpose(res.g, (0, 2, 1)))
    assert res.error < 1e-12 and res.flags == []
    # 2n + 3n(n-1)/2 + n(n-1)(n-2)/6, plus 2n at the check amplitude
    assert n_full_step_evaluations(n_ret) == expected_full_evaluations(n_ret)
    assert counters.force_evaluations == expected_full_evaluations(n_ret) + 2 * n_ret
    c2 = Counters()
    full_step(ForceEvaluator(adapter.internal_forces, adapter.n_dofs, c2, batch_size=3), K, Phi, q,
              StepPolicy(check=False))
    assert c2.force_evaluations == expected_full_evaluations(n_ret)


def test_full_step_counts_formula_values():
    """The closed-form count for a few n, written out by hand (n = 1..4, 10)."""
    assert [n_full_step_evaluations(n) for n in (1, 2, 3, 4, 10)] == [2, 7, 16, 30, 275]


def test_full_step_matches_targeted_on_diagonal():
    """The two plans agree: g[:, p, p] and h[p, p, p, p] of the full plan equal the targeted results."""
    adapter, basis = _setup(n=6, seed=2)
    K = adapter.stiffness_matrix()
    Phi = basis.phi[:, :3]
    policy = StepPolicy()
    q = np.array([step_amplitude(Phi[:, j], policy, None) for j in range(3)])
    fs = full_step(ForceEvaluator(adapter.internal_forces, 6, Counters()), K, Phi, q, policy)
    for p in range(3):
        ts = targeted_step(ForceEvaluator(adapter.internal_forces, 6, Counters()), K, Phi[:, p], q[p], policy, p=p)
        np.testing.assert_allclose(fs.g[:, p, p], Phi.T @ ts.Gv, rtol=0, atol=RTOL_STEP * np.abs(ts.Gv).max())
        assert fs.h[p, p, p, p] == pytest.approx(ts.h, rel=RTOL_STEP)


def test_force_evaluator_writes_over_the_fields_chunk_by_chunk_and_checkpoints_the_fields(tmp_path):
    """``out=U``: each chunk's fields are read and fingerprinted before its forces replace them, so the
    forces equal those of a fresh array (the same function on the same rows: bit for bit) and a rerun from the
    checkpoint finds the chunks of the same fields."""
    from stepnf.step.checkpoint import Checkpoint

    rng = np.random.default_rng(4)
    U = rng.standard_normal((7, 5))
    f = lambda X: np.sin(X) * 2.0  # noqa: E731 - any per-row function
    ref = ForceEvaluator(f, 5, Counters(), batch_size=3)(U.copy())
    cp = Checkpoint(tmp_path / ".s.partial")
    work = U.copy()
    out = ForceEvaluator(f, 5, Counters(), batch_size=3, checkpoint=cp)(work, plan="p", out=work)
    assert out is work and np.array_equal(out, ref)
    again = Counters()
    reused = ForceEvaluator(f, 5, again, batch_size=3, checkpoint=cp)(U.copy(), plan="p")
    # every chunk found by its fields: one evaluation, the probe (the first reused field evaluated again
    # and compared with its stored forces, stepnf.step.checkpoint)
    assert np.array_equal(reused, ref) and again.force_evaluations == 1
    with pytest.raises(ValueError, match="out="):
        ForceEvaluator(f, 5, Counters())(U, out=np.empty((2, 5)))


def test_force_evaluator_refuses_forces_of_another_shape():
    """A forces callable (not an adapter, whose own checks come first) answering with another shape is a
    NumericalError naming both shapes, not a broadcasting traceback."""
    from stepnf.errors import NumericalError

    with pytest.raises(NumericalError, match=r"shape \(3, 4\) for \(3, 5\)"):
        ForceEvaluator(lambda X: np.zeros((3, 4)), 5, Counters())(np.ones((3, 5)))
