"""Full-order evaluators equal the modal sums with every mode; resonance flags and +-inf, never NaN.

On a system small enough to keep every mode, DNF (two linear solves) must
equal the NF modal sums (Table 1 with the corrected denominators), full-order
MD (bordered solve) the MD sums, full-order SMD (K^+ solve) the SMD sums:
they are the same quantities computed two ways. Tolerance 1e-10 relative
(the issue's figure): both sides are exact up to round-off amplified by the
conditioning of ``K - 4 w^2 M`` / ``K - w^2 M``. Measured worst cases on
the 30-dof systems (every elastic mode as master): DNF vs NF 1.3e-14 (no
rigid modes) and 1.7e-14 (six rigid modes); MD/SMD full vs modal 2.4e-12
(no rigid modes: the two lowest modes are 7.5e-4 apart, so MD's
1/(w_s^2 - w_p^2)^2 amplifies round-off ~1e6 times) and 5.2e-13 (rigid).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.runtime.counters import Counters
from stepnf.nf.evaluators import (FullOrderContext, Tolerances, dnf, md_full, md_modal, nf_modal, resonance_flags,
                               smd_full, smd_modal)
from stepnf.linalg.factorization import PseudoInverse
from stepnf.linalg.modal_analysis import modal_analysis
from helpers.systems import solver_backends, modal_to_physical, random_system

RTOL = 1e-10


def _context(K, M, R, backend="auto"):
    Ks, Ms = sp.csr_matrix(K), sp.csr_matrix(M)
    c = Counters()
    return FullOrderContext(Ks, Ms, PseudoInverse(Ks, Ms, R, counters=c, backend=backend), c, backend=backend)


_backends = solver_backends


def _modal_data(G, H, phi, Phi):
    Gv = np.einsum("abc,b,c->a", G, phi, phi, optimize=True)
    h = float(phi @ np.einsum("abcd,b,c,d->a", H, phi, phi, phi, optimize=True))
    return Gv, h, Phi.T @ Gv


@pytest.fixture(scope="module", params=[0, 6], ids=["free-of-rigid", "rigid6"])
def system30(request):
    M, K, G, H = random_system(30, 21, rigid=request.param)
    basis = modal_analysis(sp.csr_matrix(K), sp.csr_matrix(M))
    return request.param, M, K, G, H, basis


@pytest.mark.parametrize("backend", _backends())
def test_dnf_equals_nf_with_every_mode(system30, backend):
    rigid, M, K, G, H, basis = system30
    assert basis.rigid.shape[1] == rigid and basis.n_elastic == 30 - rigid and basis.complete
    ctx = _context(K, M, basis.rigid, backend)
    S = np.arange(basis.n_elastic)
    worst = 0.0
    for p in range(basis.n_elastic):
        phi = basis.phi[:, p]
        Gv, h, g = _modal_data(G, H, phi, basis.phi)
        nf = nf_modal(p, basis.omega, g, h, S)
        d, y = dnf(p, phi, basis.omega[p], Gv, h, ctx)
        assert math.isfinite(nf.T) and math.isfinite(d.T)
        worst = max(worst, abs(d.T - nf.T) / abs(nf.T))
        assert d.T == pytest.approx(nf.T, rel=RTOL), p
        # C4 + C5/3 is what enters T for NF (C1 = C2 = C3 = C6 = 0); DNF packs it as (A + h, w^2 B)
        assert 3 * d.C[3] + d.C[4] == pytest.approx(3 * nf.C[3] + nf.C[4], rel=RTOL)
        # y = K^+ Gv: M-orthogonal to the rigid modes, and K y = Gv (Gv self-equilibrated)
        if rigid:
            assert np.abs(basis.rigid.T @ (M @ y)).max() < 1e-12 * np.abs(y).max()
        np.testing.assert_allclose(K @ y, Gv, atol=1e-10 * np.abs(Gv).max())
    # two solves per master mode: K^+ (one factorisation, reused) and K - 4 w^2 M (one per mode)
    assert ctx.counters.linear_solves == 2 * basis.n_elastic
    assert ctx.counters.factorizations == 1 + basis.n_elastic
    assert worst < RTOL  # measured: 1.3e-14 (rigid 0), 1.7e-14 (rigid 6)


@pytest.mark.parametrize("backend", _backends())
def test_md_smd_full_equal_modal_with_every_mode(system30, backend):
    rigid, M, K, G, H, basis = system30
    ctx = _context(K, M, basis.rigid, backend)
    S = np.arange(basis.n_elastic)
    for p in range(0, basis.n_elastic, 3):
        phi = basis.phi[:, p]
        Gv, h, g = _modal_data(G, H, phi, basis.phi)
        pairs = [(smd_modal(p, basis.omega, g, h, S), smd_full(p, phi, basis.omega[p], Gv, h, ctx)),
                 (md_modal(p, basis.omega, g, h, S),
                  md_full(p, phi, basis.omega[p], Gv, h, ctx, basis.phi[:, basis.twins(p)], g=g))]
        for modal, full in pairs:
            assert full.method == modal.method
            scale = max(abs(c) for c in modal.C)
            # coefficients are sums of O(1) terms: compared relative to the largest one
            np.testing.assert_allclose(full.C, modal.C, rtol=0, atol=RTOL * scale, err_msg=f"{modal.method} {p}")
            assert full.T == pytest.approx(modal.T, rel=RTOL, abs=RTOL * scale / basis.omega[p] ** 2)


# ----------------------------------------------------------------- flags: 1:2 (NF) and 1:1 (MD)
def _two_dof(ratio, c=1.2, seed=1):
    """Modal 2-dof system w = (1, ratio), g^2_11 = c (mode 2 driven by mode 1 squared), mapped to u = P x."""
    g = np.zeros((2, 2, 2))
    g[0, 0, 0] = 0.3
    g[1, 0, 0] = g[0, 1, 0] = g[0, 0, 1] = c
    h = np.zeros((2, 2, 2, 2))
    h[0, 0, 0, 0] = 0.5
    return modal_to_physical(np.array([1.0, ratio]), g, h, seed=seed)


@pytest.mark.parametrize("ratio, flagged", [(2.0, True), (2.04, True), (1.96, True), (2.2, False), (1.5, False)])
def test_nf_flags_one_to_two_resonance(ratio, flagged):
    M, K, G, H = _two_dof(ratio)
    basis = modal_analysis(sp.csr_matrix(K), sp.csr_matrix(M))
    phi = basis.phi[:, 0]
    Gv, h, g = _modal_data(G, H, phi, basis.phi)
    nf = nf_modal(0, basis.omega, g, h, np.arange(2), labels=["(0,1)", "(0,2)"])
    assert not math.isnan(nf.T) and not any(math.isnan(c) for c in nf.C)
    kinds = [(f["kind"], f["mode"], f["label"]) for f in nf.flags]
    assert kinds == ([("internal_resonance_1_2", 1, "(0,2)")] if flagged else [])
    # DNF at (numerically) exact resonance: K - 4 w^2 M is singular to round-off, T is huge
    # (measured -2.7e14, NF -4.1e14 at ratio 2.0), not NaN
    d, _ = dnf(0, phi, basis.omega[0], Gv, h, _context(K, M, basis.rigid))
    assert not math.isnan(d.T)
    if not flagged:
        assert d.T == pytest.approx(nf.T, rel=RTOL)
    # the flag the pipeline attaches to DNF names the same mode
    pf = resonance_flags("dnf", 0, basis.omega, g, range(2), 2.0, Tolerances(), None)
    assert [f["mode"] for f in pf] == ([1] if flagged else [])


def test_nf_exact_one_to_two_gives_signed_infinity():
    """Exactly w_s = 2 w_p with g_s != 0: the NF sum diverges; T = -inf, C finite or inf, flagged, no NaN."""
    omega = np.array([1.0, 2.0, 3.1])
    g = np.array([0.2, 0.7, 0.1])
    nf = nf_modal(0, omega, g, 0.4, np.arange(3))
    assert nf.T == -math.inf
    assert not any(math.isnan(c) for c in nf.C)
    assert [(f["kind"], f["mode"]) for f in nf.flags] == [("internal_resonance_1_2", 1)]
    # the same mode uncoupled (g_s = 0 by symmetry) neither diverges nor is flagged
    g0 = np.array([0.2, 0.0, 0.1])
    nf0 = nf_modal(0, omega, g0, 0.4, np.arange(3))
    assert math.isfinite(nf0.T) and nf0.flags == []
    assert nf0.T == pytest.approx(nf_modal(0, omega[[0, 2]], g0[[0, 2]], 0.4, np.arange(2)).T, rel=1e-14)


def test_md_exact_one_to_one_coupled_pair_is_minus_infinity():
    """A coupled twin (w_s = w_p, g_s != 0) makes the modal derivative diverge: MD T = -inf, flagged."""
    omega = np.array([1.0, 1.0, 2.7])
    g = np.array([0.4, 0.6, 0.3])
    md = md_modal(0, omega, g, 0.5, np.arange(3))
    assert md.T == -math.inf
    assert not any(math.isnan(c) for c in md.C)
    assert md.to_dict()["T"] == "-inf"  # JSON-safe, and to_dict refuses NaN
    assert [(f["kind"], f["mode"]) for f in md.flags] == [("internal_resonance_1_1", 1)]
    # NF and SMD are not affected by 1:1
    assert math.isfinite(nf_modal(0, omega, g, 0.5, np.arange(3)).T)
    assert math.isfinite(smd_modal(0, omega, g, 0.5, np.arange(3)).T)


@pytest.mark.parametrize("twin_coupling", [0.0, 1e-17])
def test_md_uncoupled_degenerate_twin_does_not_blow_up(twin_coupling):
    """A twin with g_t = 0 by symmetry (or at round-off, below the 1e-8 coupling tolerance) is left out."""
    omega = np.array([1.0, 1.0, 2.7])
    g = np.array([0.4, twin_coupling, 0.3])
    md = md_modal(0, omega, g, 0.5, np.arange(3))
    ref = md_modal(0, omega[[0, 2]], g[[0, 2]], 0.5, np.arange(2))
    assert math.isfinite(md.T) and md.flags == []
    assert md.T == pytest.approx(ref.T, rel=1e-14)


def test_md_full_degenerate_twin():
    """Full-order MD with a degenerate pair: uncoupled twin -> finite and equal to the modal sum;
    coupled twin -> T = -inf with an internal_resonance_1_1 flag (never NaN)."""
    omega = np.array([1.0, 1.0, 2.7])
    for coupling in (0.0, 0.6):
        g = np.zeros((3, 3, 3))
        g[0, 0, 0] = 0.4
        for idx in [(2, 0, 0), (0, 2, 0), (0, 0, 2)]:
            g[idx] = 0.3
        for idx in [(1, 0, 0), (0, 1, 0), (0, 0, 1)]:
            g[idx] = coupling
        h = np.zeros((3,) * 4)
        h[0, 0, 0, 0] = 0.5
        M, K, G, H, P = modal_to_physical(omega, g, h, seed=4, return_transform=True)
        basis = modal_analysis(sp.csr_matrix(K), sp.csr_matrix(M))
        assert basis.degenerate_groups == [[0, 1]]
        # the exact modal vectors P e_0, P e_1: the eigen-solver's own basis of a degenerate pair is an
        # arbitrary rotation of it, in which the twin couples; a symmetric structure provides this basis
        phi, twin = P[:, 0], P[:, 1]
        Gv = np.einsum("abc,b,c->a", G, phi, phi)
        hp = float(phi @ np.einsum("abcd,b,c,d->a", H, phi, phi, phi))
        ctx = _context(K, M, basis.rigid)
        full = md_full(0, phi, 1.0, Gv, hp, ctx, twin[:, None], g=np.array([0.4, coupling, 0.3]))
        modal = md_modal(0, omega, np.array([0.4, coupling, 0.3]), 0.5, np.arange(3))
        if coupling == 0.0:
            assert math.isfinite(full.T) and full.flags == []
            assert full.T == pytest.approx(modal.T, rel=RTOL)
        else:
            assert full.T == -math.inf and modal.T == -math.inf
            assert [f["kind"] for f in full.flags] == ["internal_resonance_1_1"]
            assert not any(math.isnan(c) for c in full.C)



@pytest.mark.parametrize("power, rtol", [(4, 1e-2), (5, 1e-10)])
def test_dnf_T_error_is_first_order_change_between_amplitudes(power, rtol, monkeypatch):
    """``T_error`` (from the STEP check amplitude) equals the actual relative change of T, to first order.

    A small u^4 (even: changes G(phi, phi)) or u^5 (odd: changes h) term makes
    STEP amplitude-dependent; the DNF T from the results at q and at q/2
    differ by dT, and the linearised estimate must match |dT|/|T|. T is
    linear in h, so the u^5 case is exact to round-off (measured 1e-12
    relative, asserted 1e-10); T is quadratic in Gv, so the u^4 case carries a
    second-order remainder ~ |dGv|/|Gv| ~ 3e-4 (measured 6e-4, asserted 1 %).
    The STEP check flags both (changes ~1e-4 and above the 1e-4 tolerance).
    This tests the linearised formula on two amplitudes' results: STEP's own
    extrapolation of a non-cubic force (a third amplitude, tests/step/test_truncation.py)
    is switched off, as it would remove the u^5 change to round-off.
    """
    import stepnf.step.procedure as procedure
    from stepnf.step.procedure import ForceEvaluator, StepPolicy, step_amplitude, targeted_step
    from stepnf_polynomial import PolynomialAdapter

    monkeypatch.setattr(procedure, "refine", lambda *args, **kwargs: None)

    M, K, G, H = random_system(8, 13)
    adapter = PolynomialAdapter(M, K, G, H)
    basis = modal_analysis(adapter.stiffness_matrix(), adapter.mass_matrix())
    ctx = _context(K, M, basis.rigid)

    def forces(U):
        return adapter.internal_forces(U) + 1e-2 * U**power

    phi = basis.phi[:, 0]
    policy = StepPolicy()
    st = targeted_step(ForceEvaluator(forces, 8, Counters()), adapter.stiffness_matrix(), phi,
                       step_amplitude(phi, policy, None), policy)
    assert [f["kind"] for f in st.flags] == ["step_accuracy"]
    d, _ = dnf(0, phi, basis.omega[0], st.Gv, st.h, ctx, dGv=st.Gv - st.Gv_check, dh=st.h - st.h_check)
    d2, _ = dnf(0, phi, basis.omega[0], st.Gv_check, st.h_check, ctx)
    actual = abs(d.T - d2.T) / abs(d.T)
    assert 1e-5 < actual < 1e-3  # measured ~1e-4: visible, small
    assert d.T_error == pytest.approx(actual, rel=rtol)


@pytest.mark.filterwarnings("ignore::scipy.linalg.LinAlgWarning")
@pytest.mark.parametrize("backend", _backends())
def test_full_order_exact_resonance_is_infinite_and_flagged_not_a_crash(backend):
    """Analytic models can hit a resonance exactly: K - 4 w^2 M (DNF) or the bordered K - w^2 M (MD,
    a same-frequency mode not declared a twin) is then exactly singular. The result must be
    T = -inf with a flag, as for the modal sums, on every back end (was a NumericalError / RuntimeError)."""
    M = sp.identity(3, format="csr")
    Gv = np.array([0.3, 0.7, 0.2])
    K = sp.csr_matrix(np.diag([1.0, 4.0, 7.0]))  # w = 1, 2, sqrt(7): mode 1 at exactly 2 w_0
    d, _ = dnf(0, np.array([1.0, 0, 0]), 1.0, Gv, 0.5, _context(K, M, np.zeros((3, 0)), backend))
    nf = nf_modal(0, np.array([1.0, 2.0, np.sqrt(7.0)]), Gv, 0.5, np.arange(3))
    assert d.T == nf.T == -math.inf
    assert [f["kind"] for f in d.flags] == ["internal_resonance_1_2"]
    assert not any(math.isnan(c) for c in d.C)
    K2 = sp.csr_matrix(np.diag([1.0, 1.0, 7.0]))  # mode 1 at exactly w_0, coupled (g_1 = 0.7)
    md = md_full(0, np.array([1.0, 0, 0]), 1.0, Gv, 0.5, _context(K2, M, np.zeros((3, 0)), backend))
    assert md.T == -math.inf
    assert [f["kind"] for f in md.flags] == ["internal_resonance_1_1"]
    assert not any(math.isnan(c) for c in md.C)
