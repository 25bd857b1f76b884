"""A null vector of K is a vector whose Rayleigh quotient is zero within its own rounding (issue 31, item 3):
``|x^T K x| <= NULL_SAFETY eps |x|^T |K| |x|`` (stepnf.linalg.null_space.null_mask), decided per vector.

A spring chain of 10 unit masses (springs k between neighbours, g from the first to the ground; M = I): held
(g = 1) its fundamental moves it almost rigidly, free (g = 0) the rigid translation is a null vector. The
measured ratios ``|x^T K x| / (eps |x|^T |K| |x|)`` are in each test's docstring; NULL_SAFETY = 10.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.linalg as sla

from stepnf.linalg.modal_analysis import modal_analysis
from stepnf.linalg.null_space import NULL_SAFETY, energy_ratios, null_mask, rigid_indices

EPS = np.finfo(float).eps


def chain(n: int, k: float, g: float) -> sp.csr_matrix:
    main = np.full(n, 2.0 * k)
    main[0], main[-1] = k + g, k
    return sp.diags([main, -k * np.ones(n - 1), -k * np.ones(n - 1)], [0, 1, -1]).tocsr()


def test_a_held_chain_whose_fundamental_is_tiny_is_elastic():
    """k = 3.7e12, g = 1: the fundamental (w^2 = 0.1, 7e-15 of the largest, below rigid_tolerance 1e-11) has a ratio
    of 33.8 (measured), above NULL_SAFETY: elastic, mode 0 (before: its residual ||K x|| / || |K| |x| || = 33 eps
    was under the old 100 eps, and the structure was called a mechanism: one rigid mode, mode 0 at 1.4e6 rad/s)."""
    K = chain(10, 3.7e12, 1.0)
    lam, vec = sla.eigh(K.toarray())
    assert NULL_SAFETY < energy_ratios(K, vec[:, :1])[0] / EPS < 100
    assert len(rigid_indices(lam, vec, K, float(lam[-1]), 1e-11)) == 0
    b = modal_analysis(K, sp.identity(10, format="csr"), 2)
    assert b.rigid.shape[1] == 0 and abs(b.omega[0] ** 2 - 0.1) < 1e-2 * 0.1  # 7e-4 off (its own bound 3e-2)


def test_a_real_mechanism_is_still_found():
    """The same chain free (g = 0): the translation's ratio is ~1e-15 (measured 1.7e-15), a null vector, although
    LAPACK puts its eigenvalue at 2.4e-4 (eps ||K||); and when its stiff springs are 1e14 with g = 1 the
    fundamental is zero within its rounding too (ratio 1.25: an eigenvalue 6% off, nothing resolved)."""
    K = chain(10, 3.7e12, 0.0)
    b = modal_analysis(K, sp.identity(10, format="csr"), 2)
    assert b.rigid.shape[1] == 1 and b.omega[0] > 1e5
    lam, vec = sla.eigh(chain(10, 1e14, 1.0).toarray())
    assert null_mask(chain(10, 1e14, 1.0), vec[:, :1])[0]


def test_a_loose_dof_is_a_null_vector():
    """A dof no spring touches (a loose node): its unit vector has x^T K x = 0 and |x|^T |K| |x| = 0; counted with
    the largest row sum, it is a null vector (ratio 0), and the chain's modes are not."""
    K = sp.block_diag([chain(5, 1e3, 1.0), sp.csr_matrix((1, 1))]).tocsr()
    lam, vec = sla.eigh(K.toarray())
    mask = null_mask(K, vec)
    assert mask.tolist() == [True] + [False] * 5
