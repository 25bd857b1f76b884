"""STEP on forces that are not exact cubics: the cubic fit's O(q^2) truncation measured and extrapolated.

The forces are a random cubic system (tests/helpers/systems.py) plus known terms above the cubic, so the
cubic truncation ``G(phi, phi)``, ``h = phi^T H(phi, phi, phi)`` is known exactly and so is every term of
the series STEP's combinations carry (stepnf/step/truncation.py's docstring):

* trigonometric, entrywise: ``c (sin u - u + u^3/6) + c (1 - cos u - u^2/2)``:
  ``Gv(a) = G - c a^2 phi^4/24 + c a^4 phi^6/720 - ...``, ``Hv(a) = H + c a^2 phi^5/120 - c a^4 phi^7/5040``;
* quintic: ``c5 |u|^4 u``: ``Hv(a) = H + c5 a^2 |phi|^4 phi`` exactly, ``Gv`` exact;
* non-analytic: ``c u |u|^3`` (entrywise): ``Hv(a) = H + c a |phi|^3 phi``, a rate of 1, not the cubic fit's 2.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from helpers.systems import random_system
from stepnf.nf.evaluators import nf_modal
from stepnf.runtime.counters import Counters
from stepnf.step.procedure import ForceEvaluator, StepPolicy, targeted_steps

N = 6
C_TRIG = 0.3


def _system(extra):
    """``(K, Phi, forces, G(phi, phi) of every mode (n, m), h of every mode (m,), omega)``."""
    M, K, G, H = random_system(N, 3)
    lam, Phi = sla.eigh(K, M)

    def forces(U):
        U = np.atleast_2d(U)
        cubic = U @ K.T + np.einsum("abc,mb,mc->ma", G, U, U) + np.einsum("abcd,mb,mc,md->ma", H, U, U, U)
        return cubic + extra(U)

    Gex = np.einsum("abc,bp,cp->ap", G, Phi, Phi)
    hex_ = np.einsum("abcd,ap,bp,cp,dp->p", H, Phi, Phi, Phi, Phi)
    return K, Phi, forces, Gex, hex_, np.sqrt(lam)


def trig(U):
    return C_TRIG * (np.sin(U) - U + U ** 3 / 6) + C_TRIG * (1 - np.cos(U) - U ** 2 / 2)


def _step(K, phi, forces, peak):
    """Targeted STEP of ``phi`` at the amplitude whose largest entry is ``peak``; (result, counters, q)."""
    counters = Counters()
    q = peak / np.abs(phi).max()
    st = targeted_steps(ForceEvaluator(forces, N, counters), K, phi[:, None], np.array([q]), StepPolicy())[0]
    return st, counters, q


def _raw(forces, K, phi, q):
    """STEP's combinations at ``+-q phi`` alone (what every master kept before): ``(Gv, h)``."""
    fp, fm = forces(np.stack([q * phi, -q * phi]))
    return (fp + fm) / (2 * q * q), float(phi @ ((fp - fm - 2 * q * (K @ phi)) / (2 * q ** 3)))


def _kinds(st):
    return [f["kind"] for f in st.flags]


@pytest.mark.parametrize("p", [0, 3])
def test_trigonometric_force_rate_two_and_extrapolation_by_the_predicted_factor(p):
    K, Phi, forces, Gex, hex_, omega = _system(trig)
    phi = Phi[:, p]
    st, counters, q = _step(K, phi, forces, 0.5)
    # the two-amplitude check sees a change far above rounding: one more pair of fields, no more
    assert counters.force_evaluations == 6
    assert st.amplitudes == pytest.approx((q, q / 2, q / 4), rel=1e-15)
    # rate: d1/d2 = 4 (1 + 15/16 (B/A) a^2 + ...), |B/A| a^2 = (a phi)^2/30 (G) or /42 (h) <= 0.25/30:
    # log2 moves by <= 0.012 (measured 0.011 and 0.007 at p = 0)
    assert abs(st.rate_G - 2.0) < 0.03 and abs(st.rate_h - 2.0) < 0.03
    assert "step_extrapolated" in _kinds(st) and "step_unconverged" not in _kinds(st)
    G_raw, h_raw = _raw(forces, K, phi, q)
    # before: the raw fit's error is its leading a^2 term (to 1%: the next is (a phi)^2/30 of it)
    lead_G = -C_TRIG * q ** 2 * phi ** 4 / 24
    lead_h = C_TRIG * q ** 2 * phi @ phi ** 5 / 120
    assert np.linalg.norm(G_raw - Gex[:, p] - lead_G) < 0.01 * np.linalg.norm(lead_G)
    assert abs(h_raw - hex_[p] - lead_h) < 0.01 * abs(lead_h)
    # after: the kept values are the extrapolation from (q/2, q/4), whose error is -(1/4) (q/2)^4 X_4:
    # predicted to 1% (the a^6 term adds 1.25 (X_6/X_4) (q/2)^2 <= 0.14% of it; rounding is 1e-15 of G)
    pred_G = -(q ** 4 / 64) * C_TRIG * phi ** 6 / 720
    pred_h = -(q ** 4 / 64) * (-C_TRIG * phi @ phi ** 7 / 5040)
    assert np.linalg.norm(st.Gv - Gex[:, p] - pred_G) < 0.01 * np.linalg.norm(pred_G)
    assert abs(st.h - hex_[p] - pred_h) < 0.01 * abs(pred_h)
    # so the error fell by the predicted factor (q phi)^2 / 1920 (G), / 2688 (h): below 1.4e-4 here
    assert np.linalg.norm(st.Gv - Gex[:, p]) < 1.4e-4 * np.linalg.norm(G_raw - Gex[:, p])
    assert abs(st.h - hex_[p]) < 1.4e-4 * abs(h_raw - hex_[p])
    # T (normal form, modal sums over every mode) follows: its error is the one the predicted errors of G
    # and h give (T is linear in them to first order: to 5%), 1e-3 of the raw fit's (measured 1.8e-4 at p = 0:
    # G's and h's errors partly cancel in the raw T)
    def T(g, h):
        return nf_modal(p, omega, Phi.T @ g, h, np.arange(N)).T
    T_ex = T(Gex[:, p], hex_[p])
    dT_pred = T(Gex[:, p] + pred_G, hex_[p] + pred_h) - T_ex
    assert abs(T(st.Gv, st.h) - T_ex - dT_pred) < 0.05 * abs(dT_pred)
    assert abs(T(st.Gv, st.h) - T_ex) < 1e-3 * abs(T(G_raw, h_raw) - T_ex)
    # and the error reported (the difference to the check value: the leading term of the kept value's
    # truncation) is the true one to the next term's share, 0.3% measured (10% allowed)
    err_h = abs(st.h - hex_[p]) / abs(st.h)
    assert 0.9 * err_h <= st.error_h <= 1.1 * err_h


def test_quintic_force_removed_by_one_extrapolation():
    K, Phi, forces, Gex, hex_, _ = _system(lambda U: 0.05 * np.sum(U * U, axis=1, keepdims=True) ** 2 * U)
    phi = Phi[:, 1]
    st, counters, q = _step(K, phi, forces, 0.5)
    G_raw, h_raw = _raw(forces, K, phi, q)
    assert counters.force_evaluations == 6
    # h changes by exactly c5 a^2 |phi|^4 (1 - c^2): d1/d2 = 4 to rounding (1e-13 of the differences)
    assert abs(st.rate_h - 2.0) < 1e-6
    # G has no even term above the cubic: its changes are rounding, no rate, G kept as before bit for bit
    assert st.rate_G is None or abs(st.rate_G - 2.0) > 0.5
    assert np.array_equal(st.Gv, G_raw)
    # one extrapolation removes an exact a^2 term: what is left is rounding (the raw error is 1e-2 of h)
    assert abs(st.h - hex_[1]) < 1e-9 * abs(h_raw - hex_[1])
    assert "step_extrapolated" in _kinds(st) and "step_unconverged" not in _kinds(st)


def test_exact_cubic_unchanged_and_no_extra_run():
    K, Phi, forces, Gex, hex_, _ = _system(lambda U: 0.0 * U)
    counters = Counters()
    q = 0.5 / np.abs(Phi).max(axis=0)
    steps = targeted_steps(ForceEvaluator(forces, N, counters), K, Phi, q, StepPolicy())
    assert counters.force_evaluations == 4 * N  # the two amplitudes only
    for j, st in enumerate(steps):
        G_raw, h_raw = _raw(forces, K, Phi[:, j], q[j])
        assert np.array_equal(st.Gv, G_raw) and st.h == h_raw and st.q == q[j] and st.q_check == q[j] / 2
        assert st.amplitudes == () and st.rate_G is None and st.rate_h is None
        assert not st.flags


@pytest.mark.parametrize("extra, peak", [(lambda U: 0.3 * U * np.abs(U) ** 3, 0.5), (trig, 6.0)],
                         ids=["rate-one", "amplitude-too-large"])
def test_unconverged_fit_is_flagged(extra, peak):
    """``c u |u|^3``: the changes fall as q^1, not the cubic fit's q^2 (no extrapolation, flagged); the
    trigonometric force at six radians: the series does not converge at that amplitude."""
    K, Phi, forces, _, _, _ = _system(extra)
    st, counters, q = _step(K, Phi[:, 0], forces, peak)
    assert counters.force_evaluations == 6
    assert "step_unconverged" in _kinds(st)
    msg = next(f["message"] for f in st.flags if f["kind"] == "step_unconverged")
    assert "not converged" in msg and "relative_amplitude" in msg


def test_unconverged_fit_gets_one_flag_not_the_contradicting_amplitude_advice():
    """A master STEP ran at three amplitudes is flagged by step_unconverged alone ("a smaller relative_amplitude");
    the two-amplitude step_accuracy flag, whose hint asks for a larger one (rounding), no longer comes with it."""
    K, Phi, forces, _, _, _ = _system(trig)
    st, _, _ = _step(K, Phi[:, 0], forces, 6.0)
    assert "step_unconverged" in _kinds(st) and "step_accuracy" not in _kinds(st)


def _noise(U):
    """An amplitude-independent "rounding" the per-entry model (eps (|K| |u|)_i + eps |f_i|) does not foresee:
    1e-9 times a deterministic function of u that changes sign with its last digits (even and odd parts, so
    both STEP combinations carry it), like the Green-Lagrange strain's rounding at eps of 1 in a solid."""
    return 1e-9 * (np.sin(1e8 * U) + np.cos(1.3e8 * U))


def test_rounding_beyond_its_bound_scales_the_bound():
    """A force whose rounding does not fall with the amplitude: at a peak of 1e-4 its noise (1e-9 / q^2 in G)
    grows as the amplitude shrinks (a negative rate) and exceeds the per-entry bound (~eps of the
    forces) by orders: ``rounding_excess`` is that ratio (measured 5.5e9; G changes by 0.24), by which T's rounding bound
    (stepnf.nf.roundoff.dnf_roundoff) is then multiplied. An exact cubic keeps 1 (no third amplitude).

    Before: ``MasterStep`` had no ``rounding_excess`` and T's bound ignored the STEP's own evidence (issue 31:
    the paper's plate at 1e-6 h printed T = -4.78e9 with a bound of 0.94 T, actual error 1.00002 T).
    """
    K, Phi, forces, _, _, _ = _system(_noise)
    st, counters, q = _step(K, Phi[:, 0], forces, 1e-4)
    assert counters.force_evaluations == 6  # the third amplitude ran: the change is far above its bound
    assert st.rate_G is not None and st.rate_G < 0.0  # measured -1.86
    change = np.linalg.norm(st.Gv - st.Gv_check)  # noise ~1e-9 / q^2 against G ~ 1: measured 0.24
    assert st.rounding_excess > 1e3, (st.rounding_excess, change)
    clean = _system(lambda U: 0.0 * U)
    st0, _, _ = _step(clean[0], clean[1][:, 0], clean[2], 1e-4)
    assert st0.rounding_excess == 1.0  # an exact cubic: its changes are within the bound (no third amplitude)


def test_roundoff_bound_scales_with_the_excess():
    """dnf_roundoff's forces part is multiplied by ``excess``; the eigenvalue part is not (it does not come from
    the forces): exact arithmetic of the formula, so equality to a few ulps (1e-14)."""
    import scipy.sparse as sp
    from stepnf.nf.roundoff import dnf_roundoff

    K, Phi, _, Gex, hex_, omega = _system(lambda U: 0.0 * U)
    Ks, Ms = sp.csr_matrix(K), sp.csr_matrix(np.eye(N))
    rng = np.random.default_rng(1)
    y, z = rng.standard_normal(N), rng.standard_normal(N)
    args = (Phi[:, 0], 1e-3, omega[0], 0.7, Gex[:, 0], None, y, z, Ks, Ms, None)
    r1, p1 = dnf_roundoff(*args, slope=2.0)
    r5, p5 = dnf_roundoff(*args, slope=2.0, excess=5.0)
    forces_part = p1["dT"] - p1["dT_lambda"]
    assert p5["dT"] == pytest.approx(5.0 * forces_part + p1["dT_lambda"], rel=1e-14)
    assert r5 == pytest.approx(p5["dT"] / 0.7, rel=1e-14) and p5["excess"] == 5.0


def test_a_fit_that_does_not_converge_is_not_taken_for_rounding():
    """The trigonometric force at 6 rad: the cubic fit does not converge (rates 0.38 for G, 0.94 for h, below
    NOISE_RATE but positive: the changes still fall as the amplitude shrinks), a truncation, not rounding: no
    excess (before the rate had to be negative, 4.4e12 was counted here, review of issue 31), and
    ``step_unconverged`` says so."""
    K, Phi, forces, _, _, _ = _system(trig)
    st, _, _ = _step(K, Phi[:, 0], forces, 6.0)
    assert 0.0 < st.rate_G < 0.5 and st.rounding_excess == 1.0
    assert "step_unconverged" in _kinds(st)
