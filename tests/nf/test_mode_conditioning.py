"""Each mode's own conditioning (issue 31, item 1): an eigenvalue is refused only when ITS rounding bound
``eps |phi|^T |K| |phi| / lambda`` (stepnf.nf.roundoff.eigenvalue_roundoff) exceeds 1%, not because the
model's lowest and largest eigenvalues are far apart.

The systems: a spring chain of n unit masses, springs k between neighbours and g from the first mass to the
ground (its fundamental moves the chain almost rigidly: the terms of ``phi^T K phi`` cancel, ~4k each against
a sum of g), beside one decoupled dof of stiffness ``soft``. Reference eigenvalues: mpmath's symmetric
eigen-solver at 60 digits on the same stored matrix (exact for our purpose: 1e-60 against errors >= 1e-16).
"""
from __future__ import annotations

import mpmath
import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

from stepnf.errors import NumericalError
from stepnf.flags import t_unusable
from stepnf.linalg.modal_analysis import ModalBasis, modal_analysis
from stepnf.nf.coefficient import MethodResult
from stepnf.nf.diagnostics import check_conditioning, conditioning_flags, soft_mode_flags, unresolved_flags
from stepnf.nf.roundoff import eigenvalue_roundoff

EPS = np.finfo(float).eps


def chain(n: int, k: float, g: float, soft: float | None = None) -> sp.csr_matrix:
    """The chain's K (n, n), with a decoupled dof of stiffness ``soft`` first when given."""
    main = np.full(n, 2.0 * k)
    main[0], main[-1] = k + g, k
    K = sp.diags([main, -k * np.ones(n - 1), -k * np.ones(n - 1)], [0, 1, -1])
    return (sp.block_diag([sp.csr_matrix([[soft]]), K]) if soft is not None else K).tocsr()


def exact_eigenvalues(K: sp.spmatrix) -> np.ndarray:
    mpmath.mp.dps = 60
    return np.array(sorted(float(x) for x in mpmath.eigsy(mpmath.matrix(K.toarray().tolist()))[0]))


def test_a_mode_built_to_lose_its_digits_is_refused_and_its_master_n_a():
    """Chain k = 3.7e12, g = 1 (n = 10): its fundamental (0.1) is 33.8 eps |phi|^T |K| |phi| (measured), so its own
    bound is 3.0e-2 > 1%: refused, its master's T n/a. It does lose digits: LAPACK's eigenvalue is 5.1e-4 off the
    60-digit one (measured; the bound holds it 58-fold). A well-resolved mode of the same model (the decoupled
    dof, w^2 = 1e-2, 7e-16 of the largest) is accepted: the old global ratio eps lambda_max / lambda_1 = 0.16
    refused the whole model (NumericalError, before this change)."""
    K = chain(10, 3.7e12, 1.0, soft=1e-2)
    M = sp.identity(11, format="csr")
    basis = modal_analysis(K, M, 4)
    assert basis.rigid.shape[1] == 0  # the chain's fundamental is elastic: K has no null vector
    lam = basis.omega ** 2
    bound = eigenvalue_roundoff(K, basis.phi, lam)
    ref = exact_eigenvalues(K)
    # the bound holds the actual error of every mode (+ 2 eps: the eigenvalue's last rounding and this division's)
    assert np.all(np.abs(lam / ref - 1) <= bound + 2 * EPS)
    assert bound[0] < 1e-14 and bound[1] > 1e-2  # the soft dof: exact to eps; the chain: beyond 1%
    flags = conditioning_flags(basis, K, masters=[0, 1])
    (ill,) = flags
    assert ill["kind"] == "ill_conditioned" and ill["refused"] == [1]
    assert ill["value"] == pytest.approx(bound[1]) and 0 not in ill["bounds"]
    assert unresolved_flags(0, flags) == []
    (na,) = unresolved_flags(1, flags)
    r = MethodResult("dnf", 0.1, (0.0,), flags=[na])
    assert t_unusable(r)[0] == "unresolved_mode"


def test_a_mode_between_the_thresholds_is_flagged_not_refused():
    """Chain k = 1e10, g = 1: the fundamental's own bound is ~1e-4 (between 1e-6 and 1%): flagged, its T kept;
    measured bound 8.0e-5 against an actual error 1.4e-5 (LAPACK against 60 digits)."""
    K = chain(10, 1e10, 1.0)
    basis = modal_analysis(K, sp.identity(10, format="csr"), 2)
    bound = eigenvalue_roundoff(K, basis.phi, basis.omega ** 2)
    assert abs(basis.omega[0] ** 2 / exact_eigenvalues(K)[0] - 1) <= bound[0]
    (ill,) = conditioning_flags(basis, K, masters=[0])
    assert 1e-6 < ill["value"] < 1e-2 and ill["refused"] == []
    assert unresolved_flags(0, [ill]) == []


def test_a_smooth_mode_of_a_very_ill_conditioned_k_is_accepted():
    """K = diag(1, 1e14): lambda_1 / lambda_max = 1e-14, which the global criterion refused (eps / 1e-14 = 2%);
    the fundamental's own bound is eps (no cancellation in phi^T K phi), and LAPACK's eigenvalue is exact."""
    K = sp.diags([1.0, 1e14]).tocsr()
    basis = modal_analysis(K, sp.identity(2, format="csr"), 1)
    assert eigenvalue_roundoff(K, basis.phi, basis.omega ** 2)[0] == pytest.approx(EPS)
    assert conditioning_flags(basis, K, masters=[0]) == []


def test_the_model_stage_check_refuses_a_field_beyond_reach():
    """The smoothest field's own bound above 1%: the model is refused before any eigen-solve (exit 3), one line
    naming the figure; between 1e-6 and 1% a flag."""
    with pytest.raises(NumericalError, match="ill-conditioned model: the smoothest field's eigenvalue: .* 3e-02"):
        check_conditioning(0.03)
    (flag,) = check_conditioning(1e-4)
    assert flag["kind"] == "ill_conditioned" and flag["value"] == 1e-4
    assert check_conditioning(1e-7) == []


def test_a_soft_mode_counted_rigid_names_its_own_round_off():
    """w^2 = 1 counted rigid (below 1e-11 x lambda_max = 1e12) is 4.5e3 times its round-off eps x 1e12 = 2.2e-4: the
    message prints that round-off and the factor 100 (1 / the 1% refusal) it is compared with (before this review
    it printed 100 x the round-off, 2.2e-02, as "their round-off")."""
    (flag,) = soft_mode_flags(np.array([1.0]), 1e12, 1e-11)
    assert flag["modes"] == [0] and f"above 100 x their round-off ({EPS * 1e12:.1e})" in flag["message"], flag
    assert soft_mode_flags(np.array([1e-3]), 1e12, 1e-11) == []  # 4.5 x its round-off: zero within 1%


def test_a_dense_solve_of_a_graded_model_is_caught_by_its_rayleigh_quotient():
    """A soft chain (k = 1e3, g = 1, n = 10) tied by a unit spring to a stiff random block (10 dofs, ~1e14), dofs
    interleaved (a fixed permutation), 20 dofs: stepnf's dense eigen-solve (Householder: backward error ~eps ||K||,
    not eps |K|) puts the fundamental 2.7e-2 off the 60-digit value (measured), where eps |phi|^T |K| |phi| / lambda
    says 3.9e-12. The pair is inconsistent: its eigenvalue is 2.6e-2 off the Rayleigh quotient of its own vector
    (itself 4e-7 off: second order), which the bound now takes: the fundamental's master is refused (before this
    review: bound 3.9e-12, no flag, a frequency 1.3% off given as exact). 1.001: the Rayleigh quotient's own error
    (4e-7 relative) beside the bound (2.6e-2)."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((10, 10))
    K = np.zeros((20, 20))
    K[:10, :10], K[10:, 10:] = chain(10, 1e3, 1.0).toarray(), 1e14 * (A @ A.T / 10 + np.eye(10))
    K[9, 10] = K[10, 9] = 1.0
    K[9, 9] += 1.0
    K[10, 10] += 1.0
    P = rng.permutation(20)
    K = sp.csr_matrix(K[np.ix_(P, P)])
    ref = exact_eigenvalues(K)[:3]
    # issue 35: the dense path now refines its low modes (stepnf.linalg.refined_modes): measured 1.5e-14, 5.5e-15
    # and 5.6e-15 relative, a few eps (the fundamental's own bound is 4e-12)
    refined = modal_analysis(K, sp.identity(20, format="csr"), 3)
    np.testing.assert_allclose(refined.omega[:3] ** 2, ref, rtol=1e-13)
    # the unrefined dense solve (scipy's eigh(K, M), the dense path before issue 35): the pair the bound catches
    lam_all, vec = sla.eigh(K.toarray(), np.eye(20))
    basis = ModalBasis(omega=np.sqrt(lam_all), phi=vec, rigid=np.zeros((20, 0)), rigid_eigenvalues=np.zeros(0),
                       complete=True, solver="dense")
    lam = basis.omega[:3] ** 2
    bound = eigenvalue_roundoff(K, basis.phi[:, :3], lam)
    assert 1e-2 < abs(lam[0] / ref[0] - 1) < 0.1  # the dense solve's error (measured 2.7e-2)
    assert np.all(np.abs(lam - ref) <= 1.001 * bound * lam)
    (ill,) = conditioning_flags(basis, K, masters=[0, 1])
    assert ill["refused"] == [0] and 1e-6 < ill["bounds"][1] < 1e-2  # mode 1: 4.8e-5 off, flagged, kept
