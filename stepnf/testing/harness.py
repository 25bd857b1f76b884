"""Conformance harness for solver adapters (in the spirit of scikit-learn's ``parametrize_with_checks``).

Every adapter should pass the same checks::

    from stepnf.testing.harness import parametrize_with_checks

    @parametrize_with_checks(lambda: MyAdapter(...))
    def test_conformance(check):
        check()

Checks (each its own pytest id): M and K symmetric; M positive on the
diagonal; ``f(0) = 0``; the finite-difference slope of f along random fields
equals ``K`` (central differences, error O(eps^2) for a cubic f); the batch
equals the loop; STEP recovers the intrusive tensors where the adapter offers
them; the force is conservative (its tangent at a nonzero field is symmetric,
probed by finite differences); ``dof_coordinates`` and ``dof_directions`` have
one finite entry per dof; ``transverse_displacements``, where offered, is
linear and agrees with ``transverse_amplitude``; the declared ``[model]`` keys are well formed;
``from_config`` builds the adapter from a ``[model]`` table (the scene's, or the
documented defaults) and the defaults it documents are the ones it applies.
Tolerances are relative and can be loosened per adapter for solvers that
print few digits (CalculiX: 7); an adapter that declares the digits it prints
(``force_digits``) gets the bound of their rounding added where the checks
difference forces (``conservative_force``).

Each check passes, fails (``AssertionError``) or does not apply to the adapter
(:class:`CheckSkipped`, with the reason; under pytest the test is reported as
skipped). :func:`run_checks` runs them all outside pytest and returns one
:class:`CheckResult` (``passed`` / ``failed`` / ``skipped`` and why) per check;
an exception other than a failed assertion (an adapter raising while it
computes) is a failed check there, with the exception as the reason.
``stepnf check SCENE`` (:mod:`stepnf.cli.check`) runs them on a scene's model.
"""
from __future__ import annotations

import functools
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from stepnf.plugin.adapter import DIRECTIONS, SolverAdapter
from stepnf.testing.base import CheckResult, CheckSkipped, Tolerances, force_rounding, maxabs, random_fields
from stepnf.testing.model_keys import check_from_config, check_model_keys

__all__ = ["CHECKS", "CheckResult", "CheckSkipped", "Tolerances", "adapter_checks", "check_batch_equals_loop",
           "check_conservative_force", "check_dof_coordinates", "check_dof_directions", "check_from_config",
           "check_model_keys", "check_slope_equals_K", "check_step_equals_intrusive", "check_symmetric_matrices",
           "check_transverse_displacements", "check_zero_force", "parametrize_with_checks", "run_checks"]


def check_symmetric_matrices(adapter: SolverAdapter, tol: Tolerances) -> None:
    for name, A in (("M", adapter.mass_matrix()), ("K", adapter.stiffness_matrix())):
        n = adapter.n_dofs
        assert A.shape == (n, n), f"{name} has shape {A.shape}, expected ({n}, {n})"
        asym = maxabs(A - A.T)
        assert asym <= tol.symmetry * maxabs(A), f"{name} is not symmetric: max|A - A^T| = {asym:.3e}"
    dM = np.asarray(adapter.mass_matrix().diagonal()).ravel()
    assert np.all(dM > 0), "M has non-positive diagonal entries"


def check_zero_force(adapter: SolverAdapter, tol: Tolerances) -> None:
    f0 = adapter.internal_force(np.zeros(adapter.n_dofs))
    L = adapter.characteristic_length() or 1.0
    scale = maxabs(adapter.stiffness_matrix()) * L
    assert np.max(np.abs(f0)) <= tol.zero_force * scale, f"f(0) != 0: max|f(0)| = {np.max(np.abs(f0)):.3e}"


def check_slope_equals_K(adapter: SolverAdapter, tol: Tolerances) -> None:
    K = adapter.stiffness_matrix()
    for u in random_fields(adapter, 2, seed=2):
        eps = 1e-3
        F = adapter.internal_forces(np.stack([eps * u, -eps * u]))
        slope = (F[0] - F[1]) / (2 * eps)  # = K u + eps^2 H(u,u,u)
        Ku = K @ u
        err = np.max(np.abs(slope - Ku)) / np.max(np.abs(Ku))
        assert err <= tol.slope, f"finite-difference slope of f differs from K u by {err:.3e} (relative)"


def check_batch_equals_loop(adapter: SolverAdapter, tol: Tolerances) -> None:
    U = random_fields(adapter, 3, seed=3)
    Fb = adapter.internal_forces(U)
    Fl = np.stack([adapter.internal_force(u) for u in U])
    err = np.max(np.abs(Fb - Fl)) / max(np.max(np.abs(Fl)), 1e-300)
    assert err <= tol.batch, f"batch and loop internal forces differ by {err:.3e} (relative)"


def check_step_equals_intrusive(adapter: SolverAdapter, tol: Tolerances) -> None:
    if not adapter.provides_intrusive_tensors:
        raise CheckSkipped("the adapter does not provide intrusive tensors (provides_intrusive_tensors is False)")
    from stepnf.runtime.counters import Counters
    from stepnf.step.procedure import ForceEvaluator, StepPolicy, targeted_step

    K = adapter.stiffness_matrix()
    u = random_fields(adapter, 1, seed=4)[0] * 10
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


def _nonlinear_products(adapter: SolverAdapter, u: np.ndarray, V: np.ndarray,
                        h: float) -> tuple[np.ndarray, np.ndarray]:
    """``(J(u) - K) v`` for every row ``v`` of ``V``: Richardson-extrapolated central differences of f
    with steps ``h`` and ``h/2`` (exact for a cubic f, O(h^4) otherwise), all fields in one batch; and a
    bound on the error each entry gets from the rounding of the forces the adapter prints
    (:func:`~stepnf.testing.base.force_rounding` ``r``: each force entry ``F`` is off by at most ``r |F|``, so
    ``(4 (F(h/2) - F(-h/2)) / h - (F(h) - F(-h)) / (2 h)) / 3`` is off by at most
    ``r (4 (|F(h/2)| + |F(-h/2)|) / (3 h) + (|F(h)| + |F(-h)|) / (6 h))``; zeros in double precision)."""
    steps = (h, -h, h / 2, -h / 2)
    F = adapter.internal_forces(np.concatenate([u + s * V for s in steps]))
    Fh1, Fh2, Fq1, Fq2 = F.reshape(4, len(V), -1)
    Jv = (4 * (Fq1 - Fq2) / h - (Fh1 - Fh2) / (2 * h)) / 3
    r = force_rounding(adapter)
    bound = r * (4 * (np.abs(Fq1) + np.abs(Fq2)) / (3 * h) + (np.abs(Fh1) + np.abs(Fh2)) / (6 * h))
    return Jv - (adapter.stiffness_matrix() @ V.T).T, bound


def _asymmetry(V: np.ndarray, D: np.ndarray, KV: np.ndarray, bound: np.ndarray,
               floor: float) -> tuple[float, float]:
    """The worst pair of rows: its ``|w.Dv - v.Dw|`` relative to ``|Dv||w| + |Dw||v|`` (floored at 1e-4 of
    the same with K: a force linear at this amplitude has nothing to be non-conservative in), and what
    that pair is allowed: ``floor`` plus the most the rounding of printed forces can make of it,
    ``|w|.bound_v + |v|.bound_w`` relative to the same (``bound``: the entries' rounding bounds, every one
    taken with the sign that hurts, so a rigorous bound). The worst pair is the one furthest above (or
    nearest below) its limit."""
    worst, allowed, excess = 0.0, floor, -np.inf
    nrm = np.linalg.norm
    for i in range(len(V)):
        for j in range(i + 1, len(V)):
            v, w = V[i], V[j]
            scale = max(nrm(D[i]) * nrm(w) + nrm(D[j]) * nrm(v), 1e-4 * (nrm(KV[i]) * nrm(w) + nrm(KV[j]) * nrm(v)))
            scale = max(scale, 1e-300)
            asym = abs(w @ D[i] - v @ D[j]) / scale
            limit = floor + (np.abs(w) @ bound[i] + np.abs(v) @ bound[j]) / scale
            if asym - limit > excess:
                worst, allowed, excess = asym, limit, asym - limit
    return worst, allowed


def check_conservative_force(adapter: SolverAdapter, tol: Tolerances) -> None:
    """The tangent ``J = df/du`` at a nonzero field is symmetric (f is the gradient of an energy).

    Probed with three random fields ``v`` (``w.Jv`` against ``v.Jw`` for each pair), never forming J.
    Only the nonlinear part ``J - K`` is compared (K is symmetric by :func:`check_symmetric_matrices`
    and would hide an asymmetry that only the nonlinear terms carry, as with a wrong stress measure).
    The field has amplitude 0.1 length (so the nonlinear share of J is ~0.1 for a quadratic f), the
    probes the same, the steps 0.1 and 0.05 of that (see :meth:`Tolerances.conservative_tolerance`); a
    shell's rotations at most :data:`~stepnf.step.procedure.MAX_ROTATION` (0.03 rad: ten times
    :data:`~stepnf.testing.base.PROBE_ROTATION`), as STEP's.
    An adapter that prints its forces rounded (``force_digits``, CalculiX: 7) is allowed, on top of that
    tolerance, the bound of what the rounding can make of each pair (:func:`_asymmetry`; measured on
    coarse CalculiX caps: asymmetry 2e-6 .. 5e-5, allowed 3e-4 .. 3e-3, the same caps in FEniCSx 1e-13,
    and 1e-6 .. 2e-5 with their forces rounded to 7 digits): a non-conservative force (a wrong stress
    measure) is asymmetric at the 1e-2 .. 1 level, above it.
    An adapter's own ``tangent_stiffness`` is held to the same test (without the rounding: the
    tangents are not printed forces).
    """
    n = adapter.n_dofs
    if n < 2:
        raise CheckSkipped("a single dof: every tangent is symmetric")
    u = 10 * random_fields(adapter, 1, seed=5, per_direction=True)[0]
    V = 10 * random_fields(adapter, 3, seed=6, per_direction=True)
    KV = (adapter.stiffness_matrix() @ V.T).T
    floor = tol.conservative_tolerance()
    D, bound = _nonlinear_products(adapter, u, V, 0.1)
    asym, limit = _asymmetry(V, D, KV, bound, floor)
    digits = getattr(adapter, "force_digits", None)
    why = f"; forces printed with {digits} significant digits" if digits is not None and limit > floor else ""
    assert asym <= limit, (f"the internal force is not conservative: its tangent at a nonzero field is not symmetric "
                           f"(|w.(J-K)v - v.(J-K)w| = {asym:.3e} relative, allowed {limit:.1e}{why}); f must be the "
                           "gradient of an energy (a work-conjugate stress and strain measure, no follower load)")
    if adapter.provides_tangent_stiffness:
        JT = adapter.tangent_stiffness(u)
        asym, limit = _asymmetry(V, (JT @ V.T).T - KV, KV, np.zeros_like(V), floor)
        assert asym <= limit, f"tangent_stiffness(u) is not symmetric: {asym:.3e} relative (allowed {limit:.1e})"


def _dof_array(adapter: SolverAdapter, what: str, shape: tuple[int, ...], meaning: str) -> np.ndarray:
    """``adapter.<what>()`` as an array of ``shape``; :class:`CheckSkipped` when the adapter gives none."""
    a = getattr(adapter, what)()
    if a is None:
        raise CheckSkipped(f"the adapter gives no {what.replace('_', ' ')} ({what}() is None)")
    a = np.asarray(a)
    assert a.shape == shape, f"{what}() has shape {a.shape}, expected {shape}: {meaning}"
    return a


def check_dof_coordinates(adapter: SolverAdapter, tol: Tolerances) -> None:
    X = _dof_array(adapter, "dof_coordinates", (adapter.n_dofs, 3), "one node per dof")
    assert X.dtype.kind in "biuf" and np.all(np.isfinite(X)), "dof_coordinates() holds non-finite or non-real values"


def check_dof_directions(adapter: SolverAdapter, tol: Tolerances) -> None:
    d = _dof_array(adapter, "dof_directions", (adapter.n_dofs,), "one direction per dof")
    assert d.dtype.kind in "iu" or (d.dtype.kind == "f" and np.all(d == np.round(d))), \
        f"dof_directions() has dtype {d.dtype}; expected integer codes"
    bad = (d < 0) | (d >= len(DIRECTIONS))
    assert not bad.any(), (f"dof_directions() has codes outside 0..{len(DIRECTIONS) - 1} ({DIRECTIONS}), "
                           f"e.g. {d[bad][:5].tolist()}")


def check_transverse_displacements(adapter: SolverAdapter, tol: Tolerances) -> None:
    """``transverse_displacements`` (when offered) is linear in the fields, takes columns one by one or
    together, and its largest ``|w|`` is ``transverse_amplitude`` (the backbone uses one for the other)."""
    U = random_fields(adapter, 2, seed=5).T  # (n, 2)
    W = adapter.transverse_displacements(U)
    if W is None:
        raise CheckSkipped("the adapter offers no transverse_displacements (None)")
    W = np.asarray(W)
    assert W.ndim == 2 and W.shape[1] == 2 and np.all(np.isfinite(W)), \
        f"transverse_displacements of (n, 2) fields gave shape {W.shape} (or non-finite values); expected (t, 2)"
    scale = max(float(np.max(np.abs(W))), 1e-300)
    one = np.column_stack([np.asarray(adapter.transverse_displacements(U[:, [j]]))[:, 0] for j in range(2)])
    mix = np.asarray(adapter.transverse_displacements(U @ np.array([[2.0], [-3.0]])))[:, 0]
    err = max(float(np.max(np.abs(one - W))), float(np.max(np.abs(mix - (2 * W[:, 0] - 3 * W[:, 1]))) / 5))
    assert err <= tol.batch * scale, f"transverse_displacements is not linear column by column ({err / scale:.2e})"
    for j in range(2):
        peak = adapter.transverse_amplitude(U[:, j])
        if peak is not None:
            ref = float(np.max(np.abs(W[:, j])))
            assert abs(peak - ref) <= tol.batch * scale, (
                f"transverse_amplitude = {peak:.9g} but max |transverse_displacements| = {ref:.9g}")


CHECKS: dict[str, Callable[[SolverAdapter, Tolerances], None]] = {
    "symmetric_matrices": check_symmetric_matrices,
    "zero_force": check_zero_force,
    "slope_equals_K": check_slope_equals_K,
    "batch_equals_loop": check_batch_equals_loop,
    "step_equals_intrusive": check_step_equals_intrusive,
    "conservative_force": check_conservative_force,
    "dof_coordinates": check_dof_coordinates,
    "dof_directions": check_dof_directions,
    "transverse_displacements": check_transverse_displacements,
    "model_keys": check_model_keys,
    "from_config": check_from_config,
}
#: Checks that also take the ``[model]`` table (``config``, ``base_dir``) given to the harness.
_TABLE_CHECKS = ("from_config",)


def run_checks(make_adapter: Callable[[], SolverAdapter], tolerances: Tolerances | None = None,
               only: Sequence[str] | None = None, *, config: Mapping[str, Any] | None = None,
               base_dir: str | Path | None = None) -> list[CheckResult]:
    """Every check (or those named in ``only``) on one adapter, outside pytest: a result per check.

    ``config`` and ``base_dir``: a ``[model]`` table (without ``solver``) for :func:`check_from_config`.
    A check whose adapter raises (anything but a failed assertion or a skip) is failed, the exception its
    reason; so is every check when ``make_adapter`` itself raises.
    """
    out = []
    for name, check in adapter_checks(make_adapter, tolerances, skip=_raise_skip, config=config, base_dir=base_dir):
        if only is not None and name not in only:
            continue
        try:
            out.append(check())
        except CheckSkipped as exc:
            out.append(CheckResult(name, "skipped", str(exc)))
        except AssertionError as exc:
            out.append(CheckResult(name, "failed", str(exc)))
        except Exception as exc:  # noqa: BLE001 - the adapter under test may raise anything
            out.append(CheckResult(name, "failed", f"{type(exc).__name__}: {exc}"))
    return out


def _raise_skip(reason: str) -> None:
    raise CheckSkipped(reason)


def _pytest_skip(reason: str) -> None:
    try:
        import pytest
    except ImportError:  # pragma: no cover - outside pytest the reason still travels
        raise CheckSkipped(reason) from None
    pytest.skip(reason)


def adapter_checks(make_adapter: Callable[[], SolverAdapter], tolerances: Tolerances | None = None,
                   skip: Callable[[str], None] = _pytest_skip, *, config: Mapping[str, Any] | None = None,
                   base_dir: str | Path | None = None) -> Iterator[tuple[str, Callable[[], CheckResult]]]:
    """Yield ``(name, check)``; each check builds the adapter once (cached) and asserts. A check returns a
    passed :class:`CheckResult`, raises ``AssertionError`` when it fails, and calls ``skip(reason)`` when it
    does not apply (``pytest.skip`` by default, so pytest reports it as skipped, not passed)."""
    tol = tolerances or Tolerances()
    get = functools.lru_cache(maxsize=1)(make_adapter)
    table = {"config": config, "base_dir": base_dir}
    for name, fn in CHECKS.items():
        yield name, _bind(name, fn, get, tol, skip, table if name in _TABLE_CHECKS else {})


def _bind(name, fn, get, tol, skip, extra):
    def check() -> CheckResult:
        try:
            fn(get(), tol, **extra)
        except CheckSkipped as exc:
            skip(str(exc))
            return CheckResult(name, "skipped", str(exc))
        return CheckResult(name, "passed")
    check.__name__ = fn.__name__
    return check


def parametrize_with_checks(make_adapter: Callable[[], SolverAdapter], tolerances: Tolerances | None = None, *,
                            config: Mapping[str, Any] | None = None, base_dir: str | Path | None = None):
    """A ``pytest.mark.parametrize`` over the conformance checks, one test id per check (``config``,
    ``base_dir``: a ``[model]`` table for :func:`check_from_config`)."""
    import pytest

    checks = list(adapter_checks(make_adapter, tolerances, config=config, base_dir=base_dir))
    return pytest.mark.parametrize("check", [c for _, c in checks], ids=[n for n, _ in checks])
