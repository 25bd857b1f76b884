"""Conformance harness for solver adapters (in the spirit of scikit-learn's ``parametrize_with_checks``).

Every adapter should pass the same checks::

    from stepnf.testing import parametrize_with_checks

    @parametrize_with_checks(lambda: MyAdapter(...))
    def test_conformance(check):
        check()

Checks (each its own pytest id): M and K symmetric; M positive on the
diagonal; ``f(0) = 0``; the finite-difference slope of f along random fields
equals ``K`` (central differences, error O(eps^2) for a cubic f); the batch
equals the loop; STEP recovers the intrusive tensors where the adapter offers
them. Tolerances are relative and can be loosened per adapter for solvers that
print few digits (CalculiX: 7).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np
import scipy.sparse as sp

from .adapter import SolverAdapter


@dataclass(frozen=True)
class Tolerances:
    """Relative tolerances of the checks.

    ``symmetry``: ``|A - A^T| <= symmetry * |A|`` (max norms);
    ``zero_force``: ``|f(0)| <= zero_force * |K|`` times a unit field;
    ``slope``: central-difference slope against ``K u``;
    ``batch``: batch against loop; ``step``: STEP against intrusive tensors.
    """

    symmetry: float = 1e-10
    zero_force: float = 1e-10
    slope: float = 1e-6
    batch: float = 1e-12
    step: float = 1e-7


def _maxabs(A) -> float:
    return float(abs(A).max()) if sp.issparse(A) else float(np.max(np.abs(A)))


def _random_fields(adapter: SolverAdapter, k: int, seed: int = 1) -> np.ndarray:
    """Smooth-ish random fields scaled to the characteristic length (small strains)."""
    rng = np.random.default_rng(seed)
    n = adapter.n_dofs
    L = adapter.characteristic_length() or 1.0
    U = rng.standard_normal((k, n))
    X = adapter.dof_coordinates()
    if X is not None:  # low-order polynomial fields in space: rigid-ish, realistic strains
        X = np.asarray(X, float)
        c = X - X.mean(0)
        span = max(np.ptp(X, axis=0).max(), 1e-300)
        basis = np.column_stack([np.ones(n), c / span, (c / span) ** 2])
        U = rng.standard_normal((k, basis.shape[1])) @ basis.T
    return 1e-2 * L * U / np.max(np.abs(U), axis=1, keepdims=True)


def check_symmetric_matrices(adapter: SolverAdapter, tol: Tolerances) -> None:
    for name, A in (("M", adapter.mass_matrix()), ("K", adapter.stiffness_matrix())):
        n = adapter.n_dofs
        assert A.shape == (n, n), f"{name} has shape {A.shape}, expected ({n}, {n})"
        asym = _maxabs(A - A.T)
        assert asym <= tol.symmetry * _maxabs(A), f"{name} is not symmetric: max|A - A^T| = {asym:.3e}"
    dM = np.asarray(adapter.mass_matrix().diagonal()).ravel()
    assert np.all(dM > 0), "M has non-positive diagonal entries"


def check_zero_force(adapter: SolverAdapter, tol: Tolerances) -> None:
    f0 = adapter.internal_force(np.zeros(adapter.n_dofs))
    L = adapter.characteristic_length() or 1.0
    scale = _maxabs(adapter.stiffness_matrix()) * L
    assert np.max(np.abs(f0)) <= tol.zero_force * scale, f"f(0) != 0: max|f(0)| = {np.max(np.abs(f0)):.3e}"


def check_slope_equals_K(adapter: SolverAdapter, tol: Tolerances) -> None:
    K = adapter.stiffness_matrix()
    for u in _random_fields(adapter, 2, seed=2):
        eps = 1e-3
        F = adapter.internal_forces(np.stack([eps * u, -eps * u]))
        slope = (F[0] - F[1]) / (2 * eps)  # = K u + eps^2 H(u,u,u)
        Ku = K @ u
        err = np.max(np.abs(slope - Ku)) / np.max(np.abs(Ku))
        assert err <= tol.slope, f"finite-difference slope of f differs from K u by {err:.3e} (relative)"


def check_batch_equals_loop(adapter: SolverAdapter, tol: Tolerances) -> None:
    U = _random_fields(adapter, 3, seed=3)
    Fb = adapter.internal_forces(U)
    Fl = np.stack([adapter.internal_force(u) for u in U])
    err = np.max(np.abs(Fb - Fl)) / max(np.max(np.abs(Fl)), 1e-300)
    assert err <= tol.batch, f"batch and loop internal forces differ by {err:.3e} (relative)"


def check_step_equals_intrusive(adapter: SolverAdapter, tol: Tolerances) -> None:
    if not adapter.provides_intrusive_tensors:
        return
    from .counters import Counters
    from .step import ForceEvaluator, StepPolicy, targeted_step

    K = adapter.stiffness_matrix()
    u = _random_fields(adapter, 1, seed=4)[0] * 10
    ev = ForceEvaluator(adapter.internal_forces, adapter.n_dofs, Counters())
    q = 1.0
    res = targeted_step(ev, K, u, q, StepPolicy(check=False))
    G_ex = adapter.quadratic_force(u, u)
    H_ex = float(u @ adapter.cubic_force(u, u, u))
    errG = np.max(np.abs(res.Gv - G_ex)) / max(np.max(np.abs(G_ex)), 1e-300)
    lin = float(u @ (K @ u))
    errH = abs(res.h - H_ex) / max(abs(H_ex), 1e-300 + 1e-12 * abs(lin))
    assert errG <= tol.step, f"STEP G(u,u) differs from the intrusive one by {errG:.3e} (relative)"
    assert errH <= tol.step, f"STEP u.H(u,u,u) differs from the intrusive one by {errH:.3e} (relative)"


CHECKS: dict[str, Callable[[SolverAdapter, Tolerances], None]] = {
    "symmetric_matrices": check_symmetric_matrices,
    "zero_force": check_zero_force,
    "slope_equals_K": check_slope_equals_K,
    "batch_equals_loop": check_batch_equals_loop,
    "step_equals_intrusive": check_step_equals_intrusive,
}


def adapter_checks(make_adapter: Callable[[], SolverAdapter], tolerances: Tolerances | None = None
                   ) -> Iterator[tuple[str, Callable[[], None]]]:
    """Yield ``(name, check)``; each check builds the adapter once (cached) and asserts."""
    tol = tolerances or Tolerances()
    get = functools.lru_cache(maxsize=1)(make_adapter)
    for name, fn in CHECKS.items():
        yield name, _bind(fn, get, tol)


def _bind(fn, get, tol):
    def check() -> None:
        fn(get(), tol)
    check.__name__ = fn.__name__
    return check


def parametrize_with_checks(make_adapter: Callable[[], SolverAdapter], tolerances: Tolerances | None = None):
    """A ``pytest.mark.parametrize`` over the conformance checks, one test id per check."""
    import pytest

    checks = list(adapter_checks(make_adapter, tolerances))
    return pytest.mark.parametrize("check", [c for _, c in checks], ids=[n for n, _ in checks])
