"""OrbitMeasure.w_max of a multi-mode manifold against a brute-force search (stepnf.dpim.multimode.measures).

The measure searches its grid only on the dofs whose bound ``sum_n |a_n| + |b_n|`` reaches the largest value on a
sixteenth of the grid; the reference evaluates every dof on a grid 8 times finer and refines the best points with
a bounded scalar search (scipy). Both find the same maximum of a trigonometric polynomial: asserted to 1e-13
relative (measured 0 to 2.2e-16: each value is a sum of ~60 terms no larger than the field, rounding ~1e-14 at
most; the refinements stop within 1e-13 of the same theta, where the maximum is flat, an error quadratic in it).
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import minimize_scalar

from stepnf.dpim.multimode.measures import OrbitMeasure
from stepnf.dpim.multimode.monomials import conj, monomials
from stepnf.errors import NumericalError


def manifold(n: int, order: int, seed: int) -> SimpleNamespace:
    """Two masters, random conjugate-symmetric fields of orders 1..order on n dofs, masters' shapes on dofs 0, 1."""
    rng = np.random.default_rng(seed)
    W = {}
    for p in range(1, order + 1):
        for a in monomials(2, p):
            if a in W:
                continue
            w = rng.standard_normal(n) * 0.5 ** p
            if a != conj(a):
                w = w + 1j * rng.standard_normal(n) * 0.5 ** p
            W[a], W[conj(a)] = w, np.conj(w)
    phi = np.zeros((n, 2))
    phi[0, 0] = phi[1, 1] = 1.0
    return SimpleNamespace(W=W, phi=phi, M=sp.identity(n, format="csr"), order=order)


def brute_force(man: SimpleNamespace, ratios, zeta: np.ndarray, rows: np.ndarray) -> float:
    """max over ``rows`` and theta of ``|x_i(theta)|``, ``x = sum W[alpha] zeta^alpha e^{i n_alpha theta}``."""
    k = np.asarray(ratios)
    keys = list(man.W)
    z = np.concatenate([zeta, np.conj(zeta)])
    coef = np.array([np.prod(z ** np.asarray(a)) for a in keys])
    n_of = np.array([(np.asarray(a[:2]) - np.asarray(a[2:])) @ k for a in keys])
    T = np.column_stack([man.W[a][rows] for a in keys]) * coef

    def x(theta: np.ndarray) -> np.ndarray:  # (rows, len(theta)), real part (the imaginary one is round-off)
        return (T @ np.exp(1j * np.outer(n_of, np.atleast_1d(theta)))).real

    grid = np.linspace(0.0, 2 * np.pi, 8 * 64 * man.order * int(k.max()), endpoint=False)
    X = np.abs(x(grid))
    best = 0.0
    h = grid[1] - grid[0]
    for flat in np.argsort(X, axis=None)[-8:]:
        i, t = np.unravel_index(flat, X.shape)
        r = minimize_scalar(lambda s: -abs(x(s)[i, 0]), bounds=(grid[t] - h, grid[t] + h), method="bounded",
                            options={"xatol": 1e-13})
        best = max(best, -r.fun, X[i, t])
    return best


def test_w_max_equals_a_brute_force_search():
    man = manifold(400, 5, 3)
    ratios = (1, 2)
    meas = OrbitMeasure(man, ratios)
    rows = np.arange(0, 400, 3)
    for seed in range(3):
        zeta = np.random.default_rng(seed).standard_normal(2) * (0.7, 0.4) + 0j
        zeta[1] *= np.exp(0.3j * seed)
        assert meas.w_max(zeta, rows, 0.5) == pytest.approx(brute_force(man, ratios, zeta, rows) / 0.5, rel=1e-13)


def test_w_max_finds_a_peak_between_the_coarse_points():
    """Dof 0 carries only the highest harmonic (n = 10: z_1^5, ratios (1, 2)) at 1.2 times the other dofs' largest
    value, phased so that every point of the coarse grid (40 per period) sees 0.707 of its peak: below the others'
    largest coarse value, so only the bound keeps it in the search."""
    man = manifold(400, 5, 3)
    zeta = np.array([0.8, 0.5], dtype=complex)
    rows = np.arange(0, 400, 3)
    others = brute_force(man, (1, 2), zeta, rows[1:])
    top = (0, 5, 0, 0)
    for a in man.W:
        man.W[a] = man.W[a].copy()
        man.W[a][0] = 0.0
    man.W[top][0] = 1.2 * others / (2 * 0.5 ** 5) * np.exp(0.25j * np.pi)
    man.W[conj(top)][0] = np.conj(man.W[top][0])
    meas = OrbitMeasure(man, (1, 2))
    assert len(meas.theta) // 16 == 40
    assert meas.w_max(zeta, rows, 1.0) == pytest.approx(1.2 * others, rel=1e-13)
    assert meas.w_max(zeta, rows[1:], 1.0) == pytest.approx(others, rel=1e-13)


def test_a_non_finite_orbit_is_a_numerical_error():
    """A branch point whose coordinates are not finite: NumericalError naming W_max (the search had no dof left
    and numpy raised its own ValueError; before the search, a NaN)."""
    meas = OrbitMeasure(manifold(40, 3, 1), (1, 2))
    with pytest.raises(NumericalError, match="W_max"):
        meas.w_max(np.array([np.nan, 0.1], dtype=complex), np.arange(40))
