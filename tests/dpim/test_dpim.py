"""DPIM (stepnf.dpim.parametrisation) and polarisation (stepnf.dpim.polarisation) against exact and independent references.

* Duffing 1-dof ``x'' + w^2 x + g x^3 = 0``: exact ``w_NL(A) = pi sqrt(w^2 + g A^2) / (2 K(m))``,
  ``m = g A^2 / (2 (w^2 + g A^2))``; the error's decrease with the order is tested as a rate.
* A 2-dof system with quadratic and cubic terms against shooting (stepnf.verify.periodic) at A where
  w_NL changes by more than 10%.
* Order 3 equals DNF's T; polarisation equals the tensors; a 1:1 twin is refused (or handled when
  uncoupled); a mode near 3 w is flagged.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.special import ellipk

from stepnf.runtime.counters import Counters
from stepnf.dpim.parametrisation import DPIM, DPIMResult, DPIMTolerances, ModeSpectrum, phase_nodes, shared_nodes
from stepnf.dpim.solves import Solvers
from stepnf.dpim.nonlinear_terms import planned_evaluations
from stepnf.errors import NumericalError
from stepnf.nf.evaluators import FullOrderContext, dnf
from stepnf.linalg.factorization import PseudoInverse
from stepnf.linalg.modal_analysis import modal_analysis
from stepnf.verify.periodic import Shooting
from stepnf.dpim.polarisation import Polariser
from helpers.systems import batch_force, modal_to_physical, modes, random_system, sym, two_dof


# ------------------------------------------------------------------ (a) Duffing
W0 = 1.3


def duffing_exact(g, A):
    m = g * A * A / (2 * (W0 ** 2 + g * A * A))
    return np.pi * np.sqrt(W0 ** 2 + g * A * A) / (2 * ellipk(m))


@pytest.mark.parametrize("g", [0.4, -0.4], ids=["hardening", "softening"])
def test_duffing_error_decreases_geometrically(g):
    """Error at fixed A against the order, as a rate.

    The exact w_NL is analytic in ``s = g A^2 / w^2`` for ``|s| < 1`` (nearest singularity
    ``s = -1``, where ``w^2 + g A^2 = 0``), so each added power of A^2 (order step N -> N+2)
    must gain at least ``1/|s|`` on average; at ``|s| = 0.2`` that is 5. Single steps are
    irregular (the coefficients' signs oscillate: a complex singularity pair), so the rate is the
    least-squares slope of log(error) over N = 3..15. Measured: 12.7 (hardening), 13.6 (softening);
    errors 1.9e-3 (N = 3) down to 3.9e-10 (N = 15, hardening; 5.8e-10 softening): truncation, not
    round-off (the coefficients c_k agree to 2e-14 between two polarisation schemes).
    """
    K, M = np.array([[W0 ** 2]]), np.array([[1.0]])
    f = lambda U: W0 ** 2 * U + g * U ** 3  # noqa: E731
    res = DPIM(f, K, M).parametrise(np.array([1.0]), W0, 15, probe=1.0)
    assert res.T == pytest.approx(3 * g / (8 * W0 ** 2), rel=1e-14)  # classical 3g/(8w^2), round-off only
    s = 0.2
    A = np.sqrt(s * W0 ** 2 / abs(g))
    orders = np.arange(3, 16, 2)
    err = np.array([abs(res.truncated(int(N)).backbone().omega_at(A)[0] / duffing_exact(g, A) - 1) for N in orders])
    slope = np.polyfit(orders / 2.0, np.log(err), 1)[0]  # per order step (N -> N + 2)
    assert np.exp(-slope) >= 1 / s, (err, np.exp(-slope))
    assert err[-1] < 1e-9  # measured 3.9e-10 / 5.8e-10, the truncation of a 1-dof polynomial: deterministic
    # counts: one batched force call per order, every order present
    assert [c["order"] for c in res.counts] == list(range(2, 16))
    assert all(c["force_calls"] == 1 for c in res.counts)
    # 1 dof: equal unit vectors and zero terms take the shortcuts, so at most the plan (equality: 2-dof test)
    assert all(c["force_evaluations"] <= n for c, n in zip(res.counts, planned_evaluations(15)))
    # directions shared by the orders (stepnf.dpim.nonlinear_terms): 2336 and 176, against 5920 and 368 term by term
    # (and 2624 and 200 with a probe along u - v for every pair)
    assert sum(planned_evaluations(15)) == 2336 and sum(planned_evaluations(7)) == 176


def test_duffing_validity_limit_brackets_the_error():
    """Below the validity limit (orders 13 and 15 within 1e-6), order 15 is within 1e-6 of the exact curve."""
    g = 0.4
    f = lambda U: W0 ** 2 * U + g * U ** 3  # noqa: E731
    bb = DPIM(f, np.array([[W0 ** 2]]), np.array([[1.0]])).parametrise(np.array([1.0]), W0, 15,
                                                                       probe=1.0).backbone()
    A_max, why = bb.validity_limit(1e-6)
    assert why == "orders differ" and A_max > 0.5
    for A in np.linspace(0.1, A_max, 5):
        assert abs(bb.omega_at(A)[0] / duffing_exact(g, A) - 1) < 1e-6


# ------------------------------------------------------- (b) 2-dof vs shooting

def test_two_dof_against_shooting():
    """DPIM order 21 against shooting at A = 0.5 (w_NL/w - 1 = 4%) and A = 0.8 (11%), to 1e-5.

    The reference is exact to ~1e-12 (DOP853, rtol 1e-12; Duffing check in test_periodic). The DPIM
    truncation error at A = 0.8 is measured ~2e-6 (N = 15) and < 1e-7 (N = 21); at A = 0.5, 1e-10.
    """
    M, K, G, H = two_dof()
    f = batch_force(K, G, H)
    w, V = modes(K, M)
    res = DPIM(f, K, M).parametrise(V[:, 0], w[0], 21, probe=1.0)
    assert res.flags == []
    sh = Shooting(M, K, lambda x: f(x[None])[0], V[:, 0], w[0])
    shifts = []
    for A in (0.5, 0.8):
        orb = sh.at_amplitude(A)
        shifts.append(orb.omega / w[0] - 1)
        assert res.backbone().omega_at(A)[0] == pytest.approx(orb.omega, rel=1e-5)
        assert res.truncated(15).backbone().omega_at(A)[0] == pytest.approx(orb.omega, rel=1e-5)
        # W_max of dof 1 over the period (h = 0.1) against the orbit's, on a 20001-point grid (error ~5e-8).
        # The displacements converge more slowly than the frequency (stationary in the orbit): measured
        # 1.5e-7 at A = 0.5 but 1e-3 at A = 0.8 (orders 13..21 oscillate by 2e-3 there), so 0.5 only.
        if A == 0.5:
            sol = sh.integrate(orb.x0, orb.period, dense=True)
            ref = np.abs(sol.sol(np.linspace(0, orb.period, 20001))[1]).max() / 0.1
            assert res.backbone().w_max_at(A, [1], 0.1)[0] == pytest.approx(ref, rel=1e-5)
    assert shifts[1] > 0.10


# --------------------------------------------------------------- (c) vs DNF
@pytest.mark.parametrize("rigid", [0, 6], ids=["no-rigid", "rigid6"])
def test_order3_equals_dnf(rigid):
    """T of DPIM order 3 equals DNF's T (full order) to 1e-12 relative, every elastic mode.

    Both use the same two solves (K^+ and K - 4 w^2 M applied to G(phi, phi)); they differ by
    the polarisation's round-off (~1e-15 relative with unit probes on these O(1..10) tensors) and
    DPIM's third-order term from polarised H (same size), amplified by the conditioning of
    K - 4 w^2 M (nearest mode at least ~5% from 2 w_p here: a factor <= ~100). Measured worst:
    see the assertion's message (1e-14 range).
    """
    n = 12
    M, K, G, H = random_system(n, 5, rigid=rigid)
    f = batch_force(K, G, H)
    basis = modal_analysis(sp.csr_matrix(K), sp.csr_matrix(M))
    c = Counters()
    ctx = FullOrderContext(sp.csr_matrix(K), sp.csr_matrix(M),
                           PseudoInverse(sp.csr_matrix(K), sp.csr_matrix(M), basis.rigid, counters=c), c)
    worst = 0.0
    for p in range(basis.n_elastic):
        phi, wp = basis.phi[:, p], basis.omega[p]
        Gv = np.einsum("abc,b,c->a", G, phi, phi)
        h = float(phi @ np.einsum("abcd,b,c,d->a", H, phi, phi, phi))
        ref = dnf(p, phi, wp, Gv, h, ctx)[0].T
        spectrum = ModeSpectrum(omega=basis.omega, rigid=basis.rigid if rigid else None)
        res = DPIM(f, K, M, spectrum).parametrise(phi, wp, 3, probe=1.0, master=p)
        worst = max(worst, abs(res.T / ref - 1))
    assert worst < 1e-12, worst


# ----------------------------------------------------------- (d) polarisation
def test_polarisation_reproduces_the_tensors():
    """G(u, v), G(u, u), H(u, v, w), H(u, u, v), H(u, u, u) from forces equal the tensors' contractions.

    Round-off (stepnf.dpim.polarisation): eps (|K| l + |G| l^2 + |H| l^3) / (|G| l^2) for G with
    l = probe = 1 and |K|, |G|, |H| = O(10) here: a few 1e-15 relative to |G| |u| |v|, times the
    polarisation's sums (<= 8 terms) -> bound 1e-13. Vectors of very different sizes (1 and
    1e-6) must not lose digits (each term is computed on unit vectors).
    """
    n = 9
    M, K, G, H = random_system(n, 3)
    f = batch_force(K, G, H)
    calls = []
    pol = Polariser(lambda U: calls.append(len(U)) or f(U), K, probe=1.0)
    rng = np.random.default_rng(1)
    u, v, w = rng.standard_normal((3, n))
    v = 1e-6 * v
    pairs = [(u, v), (u, u), (v, w)]
    triples = [(u, v, w), (u, u, v), (v, u, u), (u, v, u), (w, w, w), (u, np.zeros(n), w)]
    Gs, Hs = pol.terms(pairs, triples)
    assert calls == [4 + 2 + 4 + 8 + 6 + 6 + 6 + 2]  # ONE batched call (+-s z of every probe field)
    assert pol.stats.force_evaluations == calls[0]

    def chk(got, ref, *vecs):
        scale = max(np.abs(G).max(), np.abs(H).max()) * np.prod([np.linalg.norm(x) for x in vecs])
        assert np.abs(got - ref).max() <= 1e-13 * scale * n, np.abs(got - ref).max() / scale

    for (a, b), g in zip(pairs, Gs):
        chk(g, np.einsum("ijk,j,k->i", G, a, b), a, b)
    for (a, b, c), h in zip(triples, Hs):
        chk(h, np.einsum("ijkl,j,k,l->i", H, a, b, c), a, b, c)
    assert not Hs[-1].any()



def test_polarisation_applies_K_only_to_lone_cubes_and_may_write_over_its_fields():
    """One probe scale per term makes the fields' ``s K z`` cancel in every H recipe but the lone
    H(u, u, u): K is applied to one column here. A ``forces`` that writes over its fields (``accepts_out``,
    as ForceEvaluator) gets the request's own array and gives the same terms bit for bit."""
    n = 9
    M, K, G, H = random_system(n, 3)
    f = batch_force(K, G, H)
    rng = np.random.default_rng(2)
    u, v, w = rng.standard_normal((3, n))
    pairs, triples = [(u, v), (v, v)], [(u, v, w), (u, u, v), (w, w, w)]

    class CountingK:
        columns = 0

        def __matmul__(self, X):
            CountingK.columns += X.shape[1] if X.ndim == 2 else 1
            return K @ X

    ref = Polariser(f, CountingK(), probe=1.0).terms(pairs, triples)
    assert CountingK.columns == 1

    class InPlace:
        accepts_out = True
        given = None

        def __call__(self, U, *, out=None):
            InPlace.given = (U, out)
            out[:] = f(U)
            return out

    got = Polariser(InPlace(), K, probe=1.0).terms(pairs, triples)
    assert InPlace.given[1] is InPlace.given[0]
    for a, b in zip(got, ref):
        assert np.array_equal(a, b)


def test_shared_forcing_equals_the_tensors_at_every_order():
    """stepnf.dpim.nonlinear_terms: F[p, m] of orders 2..9 from directions shared across orders (H(u, v, w) by
    inclusion-exclusion of seven H3 values) equals the contraction of the exact tensors with the node
    vectors w_q(theta), then the cosine transform. Random 9-dof cubic with |K|, |G|, |H| ~ 10 and probe 1:
    round-off of polarisation ~1e-15 of the terms (module docstring of stepnf.dpim.polarisation), summed over
    <= 20 terms per order and amplified by the DCT (condition <= sqrt 2): 1e-12 of the largest term
    (measured <= 2.8e-15)."""
    from stepnf.dpim.nonlinear_terms import OrderForcing

    n, N = 9, 9
    M, K, G, H = random_system(n, 3)
    rng = np.random.default_rng(5)
    Y = {(q, m): rng.standard_normal(n) / 2 ** q for q in range(1, N) for m in range(q % 2, q + 1, 2)}
    theta, bases = shared_nodes(N)
    calls, errs = [], []
    forcing = OrderForcing(lambda U: calls.append(len(U)) or batch_force(K, G, H)(U), K, 1.0, N,
                           (theta, bases))
    for p in range(2, N + 1):
        w = {q: np.cos(np.outer(theta, np.arange(q % 2, q + 1, 2))) @ np.stack(
            [Y[(q, m)] for m in range(q % 2, q + 1, 2)]) for q in range(1, p)}
        ref = sum(np.einsum("ijk,lj,lk->li", G, w[q], w[p - q]) for q in range(1, p))
        ref = ref + sum(np.einsum("ijkm,lj,lk,lm->li", H, w[a], w[b], w[p - a - b])
                        for a in range(1, p) for b in range(1, p - a))
        ms_ref, B = bases[p % 2]
        F_ref = np.linalg.solve(B, ref)[ms_ref <= p]
        ms, F = forcing(Y, p)
        assert list(ms) == list(ms_ref[ms_ref <= p])
        errs.append(np.abs(F - F_ref).max() / np.abs(F_ref).max())
        assert errs[-1] <= 1e-12, (p, errs)
    assert calls == planned_evaluations(N)  # one batched call per order, as planned


def test_phase_nodes_are_exact():
    """The cosine coefficients of an order-p term are recovered exactly from J nodes (orthogonal basis)."""
    for p in range(2, 12):
        ms, theta, B = phase_nodes(p)
        assert len(theta) == len(ms) and np.linalg.cond(B) < 1.5  # DCT-II/IV: sqrt(2) at most
    for N in range(3, 26, 2):  # one set of nodes for both parities (every order of a DPIM to N)
        theta, bases = shared_nodes(N)
        assert list(bases[1][0]) == list(range(1, N + 1, 2)) and list(bases[0][0]) == list(range(0, N, 2))
        assert np.allclose(theta, phase_nodes(N - 1)[1]) and max(np.linalg.cond(B) for _, B in bases.values()) < 1.5


# ------------------------------------------------------ (e) twin, (f) resonance
def test_degenerate_twin_refused_or_handled():
    """Modes 0 and 1 at the same frequency: refused naming both when undeclared or coupled; handled when
    the twin is declared and symmetry keeps it uncoupled (then it equals the system without the twin)."""
    om = np.array([1.0, 1.0, 2.3])
    g = sym((3, 3, 3), {(0, 0, 0): 0.1, (1, 0, 0): 0.2, (2, 0, 0): 0.1})
    h = sym((3, 3, 3, 3), {(0, 0, 0, 0): 0.5})
    M, K, G, H, P = modal_to_physical(om, g, h, seed=4, return_transform=True)
    f = batch_force(K, G, H)
    phi, twin = P[:, 0], P[:, 1]
    with pytest.raises(NumericalError, match=r"mode 1 has the frequency of master mode 0.*degenerate twin"):
        DPIM(f, K, M, ModeSpectrum(omega=om)).parametrise(phi, 1.0, 5, probe=1.0, master=0)
    with pytest.raises(NumericalError, match=r"mode 1, a degenerate twin of master mode 0.*driven"):
        DPIM(f, K, M, ModeSpectrum(omega=om, modes=P, twins={0: [1]})).parametrise(phi, 1.0, 5, probe=1.0, master=0)
    # uncoupled twin (g^1_00 = 0 and no odd coupling): handled, same T as without it
    g0 = sym((3, 3, 3), {(0, 0, 0): 0.1, (2, 0, 0): 0.1})
    M, K, G, H, P = modal_to_physical(om, g0, h, seed=4, return_transform=True)
    res = DPIM(batch_force(K, G, H), K, M, ModeSpectrum(omega=om, modes=P, twins={0: [1]})).parametrise(
        P[:, 0], 1.0, 5, probe=1.0, master=0)
    # the same without a spectrum: the dense eigen-solve finds the twin, which is declared
    res2 = DPIM(batch_force(K, G, H), K, M, ModeSpectrum(modes=P, twins={0: [1]})).parametrise(P[:, 0], 1.0, 5,
                                                                                             probe=1.0, master=0)
    assert res2.c == pytest.approx(res.c, rel=1e-12) and res2.flags == []
    M2, K2, G2, H2 = modal_to_physical(om[[0, 2]], g0[np.ix_([0, 2], [0, 2], [0, 2])],
                                       h[np.ix_([0, 2], [0, 2], [0, 2], [0, 2])], seed=4)
    w2, V2 = modes(K2, M2)
    ref = DPIM(batch_force(K2, G2, H2), K2, M2).parametrise(V2[:, 0], w2[0], 5, probe=1.0)
    assert res.c == pytest.approx(ref.c, rel=1e-12)


def test_internal_resonance_flagged():
    """A mode at 3.02 w (within 5% of 3 w) is flagged with its index and harmonic; none near 2 w."""
    om = np.array([1.0, 3.02, 5.5])
    g = sym((3, 3, 3), {(0, 0, 0): 0.1, (1, 0, 0): 0.1})
    h = sym((3, 3, 3, 3), {(0, 0, 0, 0): 0.5, (1, 0, 0, 0): 0.1})
    M, K, G, H, P = modal_to_physical(om, g, h, seed=2, return_transform=True)
    res = DPIM(batch_force(K, G, H), K, M, ModeSpectrum(omega=om)).parametrise(P[:, 0], 1.0, 5, probe=1.0,
                                                                            master=0)
    assert [(fl["kind"], fl["mode"]) for fl in res.flags] == [("internal_resonance_1_3", 1)]
    assert "mode 1" in res.flags[0]["message"]
    # without a spectrum the dense eigen-solve finds it too (modes numbered in ascending order)
    res = DPIM(batch_force(K, G, H), K, M).parametrise(P[:, 0], 1.0, 5, probe=1.0)
    assert [(fl["kind"], fl["mode"]) for fl in res.flags] == [("internal_resonance_1_3", 1)]
    # the model's tolerance reaches the check: |3.02 - 3| = 0.02 > 0.005 x 3, not flagged
    narrow = DPIM(batch_force(K, G, H), K, M, ModeSpectrum(omega=om), tolerances=DPIMTolerances(resonance=0.005))
    assert narrow.parametrise(P[:, 0], 1.0, 5, probe=1.0, master=0).flags == []


def test_one_object_for_every_master_of_a_model():
    """A DPIM built once for a model (its spectrum with rigid modes, one Counters) parametrises each master
    as an object made for that master alone, bit for bit (the same operations in the same order); the
    shared counters add up every master's solves and factorisations. Declared twins are the spectrum's:
    none here (the masters' twins would be its ``modes`` columns)."""
    M, K, G, H = random_system(12, 5, rigid=3)
    f = batch_force(K, G, H)
    b = modal_analysis(sp.csr_matrix(K), sp.csr_matrix(M))
    shared = Counters()
    model = DPIM(f, K, M, ModeSpectrum(omega=b.omega, rigid=b.rigid, modes=b.phi), counters=shared)
    assert model.spectrum.twins_of(0) == (None, None) and model.resonant_exclude(b.omega[0], 0, None) is None
    alone_counts = []
    for p in range(3):
        res = model.parametrise(b.phi[:, p], b.omega[p], 5, probe=1.0, master=p)
        c = Counters()
        alone = DPIM(f, K, M, ModeSpectrum(omega=b.omega, rigid=b.rigid), counters=c).parametrise(
            b.phi[:, p], b.omega[p], 5, probe=1.0, master=p)
        alone_counts.append((c.linear_solves, c.factorizations))
        assert np.array_equal(res.c, alone.c) and res.flags == alone.flags
        assert all(np.array_equal(res.Y[k], alone.Y[k]) for k in alone.Y)
    assert (shared.linear_solves, shared.factorizations) == tuple(map(sum, zip(*alone_counts)))


# ------------------------------------------------ solvers given by the caller
def test_callers_solvers_and_shared_factorisations():
    """A factorisation factory, a deflated solver (modes + CG) and a resonant solve from the caller give
    the same coefficients as the defaults (1e-10 relative: CG stops at 1e-12 residual, amplified by the
    recursion's ~10 levels); each shift is factorised once for all orders (N + 1 shifts: m = 0..N,
    m = 1 bordered)."""
    from stepnf.linalg.deflation import DeflatedSolver
    from stepnf.linalg.factorization import factorize
    from stepnf.linalg.shifted import ShiftedFactorizer

    from helpers.systems import full_symmetrize

    om = np.array([1.0, 1.37, 1.75, 2.35, 2.7, 3.4, 3.7, 4.45, 5.3, 5.6, 6.5, 7.45])  # no ratio within 5% of an integer
    rng = np.random.default_rng(8)
    g = 0.1 * full_symmetrize(rng.standard_normal((12,) * 3))
    h = 0.1 * full_symmetrize(rng.standard_normal((12,) * 4))
    M, K, G, H = modal_to_physical(om, g, h, seed=8, rigid=6)
    f = batch_force(K, G, H)
    Ks, Ms = sp.csr_matrix(K), sp.csr_matrix(M)
    b = modal_analysis(Ks, Ms)
    p, N = 0, 7
    phi, wp = b.phi[:, p], b.omega[p]
    ref = DPIM(f, K, M, ModeSpectrum(omega=b.omega, rigid=b.rigid)).parametrise(phi, wp, N, probe=1.0, master=p)
    assert ref.flags == [] and sum(c["factorizations"] for c in ref.counts) == N + 1
    made = []

    def factory(sigma, label):
        made.append(sigma)
        return ShiftedFactorizer(Ks, Ms).factorizer(sigma, label)

    F0 = factorize((Ks + Ms).tocsc())
    k = 8  # the modes an eigen-solver would have computed: the 8 lowest elastic ones
    ds = DeflatedSolver(Ks, Ms, b.phi[:, :k], b.omega[:k] ** 2, b.rigid, F0.solve)
    spectrum = ModeSpectrum(omega=b.omega, rigid=b.rigid)
    resonant = lambda v: ds.solve(v, wp ** 2, exclude=[b.rigid.shape[1] + p])  # noqa: E731
    res = DPIM(f, K, M, spectrum, Solvers(factory=factory, resonant=resonant, deflated=ds)).parametrise(
        phi, wp, N, probe=1.0, master=p)
    assert res.c == pytest.approx(ref.c, rel=1e-10)
    # shifts inside the computed spectrum (m w_p)^2 * 1.25 <= w_max^2 go to CG; the others to the factory, once each
    inside = [m for m in range(N + 1) if m != 1 and 1.25 * (m * wp) ** 2 <= b.omega[k - 1] ** 2]
    assert inside == [0, 2, 3]
    assert sorted(made) == sorted((m * wp) ** 2 for m in range(2, N + 1) if m not in inside)
    # the same with the resonant solve left to the deflated solver: an order's deflated solves (K^+, the
    # resonant one, the shifts inside) then go through one lockstep run; same coefficients, same factorisations
    made.clear()
    blocks = []
    lockstep = ds.solve_many
    ds.solve_many = lambda B, s, e: blocks.append(B.shape[1]) or lockstep(B, s, e)
    # (the master's column of the deflated solver, rigid modes first, is left out: DPIM.resonant_exclude)
    model = DPIM(f, K, M, spectrum, Solvers(factory=factory, deflated=ds))
    assert model.resonant_exclude(wp, p, None) == [b.rigid.shape[1] + p]
    batched = model.parametrise(phi, wp, N, probe=1.0, master=p)
    assert batched.c == pytest.approx(ref.c, rel=1e-10)
    assert sorted(made) == sorted((m * wp) ** 2 for m in range(2, N + 1) if m not in inside)
    assert blocks == [2] * (N - 1)  # orders 2..7: m = 0 and 2 (even orders), 1 and 3 (odd); 4..7 factorised
    with pytest.raises(NumericalError, match="not mass-normalised"):
        DPIM(f, K, M, ModeSpectrum(rigid=b.rigid)).parametrise(2 * phi, wp, 3, probe=1.0)
    with pytest.raises(NumericalError, match="not an eigenpair"):
        DPIM(f, K, M, ModeSpectrum(rigid=b.rigid)).parametrise(phi, 1.01 * wp, 3, probe=1.0)


def test_invariance_residual_and_normal_form():
    """The parametrisation solves ``M x_tt + f(x) = 0`` up to O(rho^(N+1)): halving rho divides the residual
    by 2^(N+1) = 256 for N = 7, up to the next order's share, O(rho) (measured 257.6 at rho = 0.2; 65.4
    and 1025 for N = 5 and 9; asserted within 5%). The complex normal form's W_ab rebuild the same x."""
    M, K, G, H = two_dof()
    f = batch_force(K, G, H)
    w, V = modes(K, M)
    N = 7
    res = DPIM(f, K, M).parametrise(V[:, 0], w[0], N, probe=1.0)
    th = np.linspace(0, np.pi, 7)

    def residual(rho):
        om = res.backbone().frequency(rho)
        out = 0.0
        for t in th:
            x = res.displacement(t, rho)
            xtt = -om ** 2 * sum(rho ** p * m * m * np.cos(m * t) * y for (p, m), y in res.Y.items())
            out = max(out, np.abs(M @ xtt + f(x[None])[0]).max())
        return out

    assert [c["force_evaluations"] for c in res.counts] == planned_evaluations(N)
    r1, r2 = residual(0.2), residual(0.1)
    assert r1 / r2 == pytest.approx(2 ** (N + 1), rel=0.05)
    W, fk = res.normal_form()
    rho, t = 0.3, 0.7
    z1 = rho / 2 * np.exp(1j * t)
    x = sum(Wab * (z1 ** a * np.conj(z1) ** b + (z1 ** b * np.conj(z1) ** a if a != b else 0))
            for (a, b), Wab in W.items())
    np.testing.assert_allclose(x.real, res.displacement(t, rho), rtol=1e-13, atol=1e-15)
    assert np.all(fk.real == 0) and fk[0].imag == pytest.approx(4 * res.c[0])
    # velocity = d/dt of the displacement along theta' = Omega
    d = 1e-6
    v_fd = (res.displacement(t + d, rho) - res.displacement(t - d, rho)) / (2 * d) * res.backbone().frequency(rho)
    np.testing.assert_allclose(res.velocity(t, rho), v_fd, rtol=1e-8)


def test_through_an_adapter_and_force_evaluator():
    """The pipeline's route: the polynomial adapter's batched internal_forces behind a ForceEvaluator,
    whose counters see exactly the evaluations the per-order counts report (one solver run per order
    while an order's fields fit one batch of 256)."""
    from stepnf.step.procedure import ForceEvaluator
    from stepnf_polynomial import PolynomialAdapter

    M, K, G, H = two_dof()
    ad = PolynomialAdapter(M, K, G, H)
    c = Counters()
    fe = ForceEvaluator(ad.internal_forces, 2, c)
    w, V = modes(K, M)
    res = DPIM(fe, ad.stiffness_matrix(), ad.mass_matrix()).parametrise(V[:, 0], w[0], 7, probe=1.0)
    ref = DPIM(batch_force(K, G, H), K, M).parametrise(V[:, 0], w[0], 7, probe=1.0)
    assert res.c == pytest.approx(ref.c, rel=1e-12)
    assert c.force_evaluations == sum(x["force_evaluations"] for x in res.counts) == sum(planned_evaluations(7)) == 176
    assert c.solver_runs == 6  # orders 2..7, each <= 256 fields


def test_arrays_hold_the_coefficients_once():
    """``arrays()``'s ``Y`` and the result's ``Y`` share their memory (a run keeps both for every master): the same
    numbers bit for bit, the same array when asked again, a new one when ``Y`` changed."""
    rng = np.random.default_rng(3)
    keys = [(p, m) for p in range(1, 6) for m in range(p % 2, p + 1, 2)]
    Y = {k: rng.standard_normal(7) for k in reversed(keys)}  # not in sorted order
    before = {k: v.copy() for k, v in Y.items()}
    res = DPIMResult(1.3, Y[(1, 1)], sp.identity(7), 5, Y, np.array([0.1, 0.2]))
    A = res.arrays()["Y"]
    assert [tuple(k) for k in res.arrays()["index"]] == sorted(keys)
    for i, k in enumerate(sorted(keys)):
        assert np.array_equal(A[i], before[k]) and np.array_equal(res.Y[k], before[k])
        assert np.shares_memory(res.Y[k], A)
    assert res.arrays()["Y"] is A
    res.Y[(5, 5)] = np.zeros(7)  # a coefficient replaced: stacked again, with the new values
    B = res.arrays()["Y"]
    assert B is not A and np.array_equal(B[-1], np.zeros(7))
    a = res.backbone().a  # what reads the rows reads the same numbers (the same operations: bit for bit)
    assert a[5, 5] == 0.0 and a[3, 1] == float((res.M @ before[(1, 1)]) @ before[(3, 1)])
