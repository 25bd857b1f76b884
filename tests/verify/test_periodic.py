"""Shooting (stepnf.verify.periodic) reproduces the Duffing oscillator's exact period: the reference is trustworthy.

Exact: ``x'' + w^2 x + g x^3 = 0`` with ``x(0) = A``, ``x'(0) = 0`` is ``x = A cn(W t, m)``,
``W^2 = w^2 + g A^2``, ``m = g A^2 / (2 W^2)`` (m < 0 for softening), period ``4 K(m) / W``.
Tolerance 1e-10 relative: DOP853 with rtol = 1e-12 over half a period (a few hundred steps, local
errors accumulating to ~1e-12..1e-11 in the half-period condition); measured 1e-14..6e-14.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.special import ellipk

from stepnf.errors import NumericalError
from stepnf.verify.periodic import Shooting

W0 = 1.3


def exact(g, A):
    m = g * A * A / (2 * (W0 ** 2 + g * A * A))
    return np.pi * np.sqrt(W0 ** 2 + g * A * A) / (2 * ellipk(m))


@pytest.mark.parametrize("g,A", [(0.4, 0.2), (0.4, 2.0), (-0.4, 0.5), (-0.4, 1.5)])
@pytest.mark.parametrize("tangent", [False, True], ids=["fd-jacobian", "tangent"])
def test_duffing_period_exact(g, A, tangent):
    f = lambda x: W0 ** 2 * x + g * x ** 3  # noqa: E731
    tan = (lambda x: np.diag(W0 ** 2 + 3 * g * x ** 2)) if tangent else None
    sh = Shooting(np.eye(1), np.eye(1) * W0 ** 2, f, np.array([1.0]), W0, tangent=tan)
    orb = sh.at_amplitude(A)
    assert orb.amplitude == pytest.approx(A, rel=1e-12)  # the secant on q0 stops at 1e-12
    assert orb.omega == pytest.approx(exact(g, A), rel=1e-10)
    assert orb.residual < 1e-10


def test_sparse_mass_and_two_dofs_uncoupled():
    """Two uncoupled Duffing oscillators with a sparse diagonal M: the master's orbit is the 1-dof one."""
    m = np.array([2.0, 1.0])
    M = sp.diags(m).tocsc()
    k = np.array([2.0 * W0 ** 2, 7.0])
    g = 0.4
    f = lambda x: k * x + np.array([2 * g, 0.3]) * x ** 3  # noqa: E731 (mode 0: 2 x'' + 2 w^2 x + 2 g x^3)
    phi = np.array([1 / np.sqrt(2.0), 0.0])
    sh = Shooting(M, sp.diags(k), f, phi, W0)
    A = 0.8  # q = phi^T M x = sqrt(2) x_0: amplitude of x_0 is A / sqrt(2)
    orb = sh.at_amplitude(A)
    assert orb.omega == pytest.approx(exact(g, A / np.sqrt(2)), rel=1e-10)
    assert abs(orb.x0[1]) < 1e-12


def test_unreachable_amplitude_is_a_numerical_error():
    """Softening beyond the separatrix (A^2 > w^2/|g|): no periodic orbit; a NumericalError, not a hang."""
    g = -0.4
    f = lambda x: W0 ** 2 * x + g * x ** 3  # noqa: E731
    sh = Shooting(np.eye(1), np.eye(1) * W0 ** 2, f, np.array([1.0]), W0)
    with pytest.raises(NumericalError):
        sh.at_amplitude(2.5)


@pytest.mark.parametrize("sparse", [False, True], ids=["dense-M", "sparse-M"])
@pytest.mark.parametrize("free", [False, True], ids=["brake", "free"])
def test_a_diverging_trajectory_is_a_numerical_error(sparse, free):
    """A force that overflows (a Newton iterate far from the orbit: here the model's own inf beyond |x| = 2) is a
    NumericalError naming the divergence, for both shootings and both kinds of M; it used to be LAPACK's
    ValueError (dense M: a traceback in the middle of a continuation) or NaNs the integrator chased."""
    from stepnf.verify.free_shooting import FreeShooting

    f = lambda x: np.where(np.abs(x) > 2.0, np.inf, W0 ** 2 * x)  # noqa: E731
    M = sp.identity(1, format="csr") if sparse else np.eye(1)
    if free:
        sh = FreeShooting(M, np.eye(1) * W0 ** 2, f, np.array([1.0]), W0)
        with pytest.raises(NumericalError, match="diverged"):
            sh.at_amplitude(3.0, (np.array([3.0]), np.zeros(1), 2 * np.pi / W0))
    else:
        sh = Shooting(M, np.eye(1) * W0 ** 2, f, np.array([1.0]), W0)
        with pytest.raises(NumericalError, match="diverged"):
            sh.orbit(3.0, np.array([3.0]), 2 * np.pi / W0)
