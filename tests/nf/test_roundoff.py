"""T's rounding bound and the STEP along the quadratic manifold (issue 31, docs/design.md "Round-off of T").

A two-dof 'slender structure' built to lose its digits: a bending coordinate x1 (w^2 = 1) and a stiff
membrane coordinate x2 (k2 = 1e8) from the potential ``x1^2/2 + k2 x2^2/2 + a x1^2 x2 + b x1^4/4``,
a = 1e4, b = 2 a^2/k2 + eps_b: h = b = 2 + eps_b and A = -(a^2/k2 + a^2/(k2 - 4)) ~ -2 cancel to
``h_s = eps_b = 1e-6`` (six digits), as a cantilever's membrane relaxation does. Closed forms (M = I):
``h_s = b - 2 a^2/k2``, ``B = 4 a^2/(k2 (k2 - 4))``, ``T = 3 h_s/8 - B/4``.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.flags import t_unusable
from stepnf.linalg.factorization import PseudoInverse
from stepnf.nf.condensed import dnf_condensed
from stepnf.nf.evaluators import FullOrderContext, Rounding, dnf
from stepnf.runtime.counters import Counters
from stepnf.step.forces import ForceEvaluator
from stepnf.step.manifold_probe import manifold_probe
from stepnf.step.procedure import StepPolicy, targeted_step
from helpers.systems import random_system

K2, A_, EPS_B = 1e8, 1e4, 1e-6
B_ = 2 * A_**2 / K2 + EPS_B
T_EXACT = 3 * EPS_B / 8 - A_**2 / (K2 * (K2 - 4))


def forces_of(digits: int | None):
    """f(x) of the two-dof system, each entry rounded to ``digits`` significant digits (None: exact)."""
    def f(U: np.ndarray) -> np.ndarray:
        x1, x2 = U[:, 0], U[:, 1]
        F = np.column_stack([x1 + 2 * A_ * x1 * x2 + B_ * x1**3, K2 * x2 + A_ * x1**2])
        return F if digits is None else np.vectorize(lambda v: float(f"{v:.{digits - 1}e}"))(F)
    return f


def context() -> tuple[FullOrderContext, sp.spmatrix]:
    K, M = sp.csr_matrix(np.diag([1.0, K2])), sp.identity(2, format="csr")
    return FullOrderContext(K, M, PseudoInverse(K, M, np.zeros((2, 0)), counters=Counters()), Counters()), K


def dnf_at(q: float, digits: int | None):
    ctx, K = context()
    phi = np.array([1.0, 0.0])
    st = targeted_step(ForceEvaluator(forces_of(digits), 2, Counters()), K, phi, q, StepPolicy())
    r, y = dnf(0, phi, 1.0, st.Gv, st.h, ctx, dGv=st.Gv - st.Gv_check, dh=st.h - st.h_check,
               rounding=Rounding(st.q, st.Hv, digits))
    return r, y


def test_the_closed_form_and_a_bound_at_round_off():
    """Exact forces (double precision): T to the bound, and the bound small (measured 2e-9 relative)."""
    r, _ = dnf_at(0.5, None)
    err = abs(r.T / T_EXACT - 1)
    assert r.extra["roundoff"] < 1e-6 and err <= r.extra["roundoff"]
    assert r.extra["cancellation"] > 1e6  # |3(A + h)| + |B| against T: the digits the case is built to lose
    assert r.extra["B"] == pytest.approx(4 * A_**2 / (K2 * (K2 - 4)), rel=1e-12)  # 4 y^T M z, one product


def test_a_case_built_to_lose_its_digits_is_na_never_a_wrong_sign():
    """Forces printed with 7 digits (CalculiX's .dat): the STEP at +-q phi cannot resolve h_s = 1e-6 of
    h = 2, at the default amplitude nor at 100 x it; the bound says so (>= 1: n/a), and holds the error."""
    for q in (0.5, 50.0):
        r, _ = dnf_at(q, 7)
        err = abs(r.T / T_EXACT - 1)
        assert r.extra["roundoff"] >= 1.0 and r.extra["roundoff"] >= err, (q, r.T, r.extra["roundoff"], err)
        r.flags.append({"kind": "t_roundoff", "value": r.extra["roundoff"]})  # as pipeline/apply_method adds it
        assert t_unusable(r)[0] == "t_roundoff"


def test_the_manifold_probe_removes_the_cancellation_of_printed_forces():
    """Along u = s phi - s^2 y the solver computes the relaxed force (here f2 = 0 and f1 = s + eps_b s^3
    exactly): at s = 50 the 7-digit forces give h_s to a few 1e-3 relative (estimate ~0.1: five standard
    errors of the least-squares fit and the printing of f1's linear part, 5e-7 t, over eps_b t^3 at t down to
    s/11, 5 standard deviations through the fit's weights), where the STEP at +-s phi is off by 100% and
    more (test above)."""
    phi = np.array([1.0, 0.0])
    first, y = dnf_at(50.0, 7)
    pr = manifold_probe(ForceEvaluator(forces_of(7), 2, Counters()), phi, y, 50.0, 7, plan=None)
    assert abs(pr.h_s - EPS_B) <= pr.dh_s and pr.dh_s < 0.2 * EPS_B
    r = dnf_condensed(1.0, pr.h_s, pr.dh_s, first)
    assert abs(r.T / T_EXACT - 1) <= r.T_error < 0.2
    assert r.extra["T_change"] is None  # no second amplitude: no step_accuracy flag from it
    assert pr.standard_error > 0 and pr.dh_s >= 5 * pr.standard_error


def test_B_as_4_yMz_equals_the_difference_form():
    """``B = 4 y^T M z`` equals ``(z - y)^T Gv / w^2`` (resolvent identity) on a random system, with and
    without rigid modes (the difference form loses ~|y^T Gv| / |B w^2| ~ 10 eps here, measured 1e-13:
    1e-10 asserted, the margin for other BLAS builds)."""
    for rigid in (0, 2):
        Mm, Km, G, H = random_system(8, 5, rigid=rigid)
        from stepnf.linalg.modal_analysis import modal_analysis
        K, M = sp.csr_matrix(Km), sp.csr_matrix(Mm)
        basis = modal_analysis(K, M)
        ctx = FullOrderContext(K, M, PseudoInverse(K, M, basis.rigid, counters=Counters()), Counters())
        phi, w = basis.phi[:, 0], basis.omega[0]
        Gv = np.einsum("ijk,j,k->i", G, phi, phi)
        r, y = dnf(0, phi, w, Gv, 1.0, ctx)
        R = basis.rigid
        z = np.linalg.solve(Km - 4 * w**2 * Mm, Gv - Mm @ R @ (R.T @ Gv)) if R.shape[1] else \
            np.linalg.solve(Km - 4 * w**2 * Mm, Gv)
        if R.shape[1]:
            z = z - R @ (R.T @ (Mm @ z))
        assert r.extra["B"] == pytest.approx(float((z - y) @ Gv) / w**2, rel=1e-10)
