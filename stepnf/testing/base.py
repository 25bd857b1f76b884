"""What the adapter conformance checks share (:mod:`stepnf.testing.harness`): tolerances, outcomes, random fields."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.adapter import DIRECTIONS, SolverAdapter
from stepnf.plugin.dofs import MAX_ROTATION, rotation_mask


@dataclass(frozen=True)
class Tolerances:
    """Relative tolerances of the checks.

    ``symmetry``: ``|A - A^T| <= symmetry * |A|`` (max norms);
    ``zero_force``: ``|f(0)| <= zero_force * |K|`` times a unit field;
    ``slope``: central-difference slope against ``K u``;
    ``batch``: batch against loop; ``step``: STEP against intrusive tensors;
    ``conservative``: asymmetry of the nonlinear part of the tangent (see
    :func:`check_conservative_force`); ``None`` derives it from ``batch``.
    """

    symmetry: float = 1e-10
    zero_force: float = 1e-10
    slope: float = 1e-6
    batch: float = 1e-12
    step: float = 1e-7
    conservative: float | None = None

    def conservative_tolerance(self) -> float:
        """``conservative``, or ``max(1e-6, 1e3 * batch)``: ``batch`` is the relative round-off of
        one force (1e-12 in process, 1e-6 for a solver printing 7 digits); the asymmetry divides
        differences of forces by the step (0.1) and by the nonlinear share of the tangent (~0.1 at
        an amplitude of 0.1 length), so its noise is ~100x that round-off; x10 on top is the margin.
        1e-6 is the floor in process (noise ~1e-13): a non-conservative force (a wrong stress
        measure) is asymmetric at the 1e-2 .. 1 level, far above either."""
        return self.conservative if self.conservative is not None else max(1e-6, 1e3 * self.batch)


def force_rounding(adapter: SolverAdapter) -> float:
    """Largest relative rounding of one force entry the adapter declares (``force_digits``), 0 without one.

    A number printed with ``d`` significant digits (``%.{d-1}E``, ``m 10^e`` with ``1 <= |m| < 10``) is off by
    at most half a unit of its last digit, ``0.5 10^(e-d+1) <= 0.5 10^(1-d) |x|``: 5e-7 for CalculiX's 7.
    The round-off of forces computed in double precision is left to the tolerances' floors (it is relative
    to the largest element contribution, not to each entry, and far below them).
    """
    d = getattr(adapter, "force_digits", None)
    return 0.0 if d is None else 0.5 * 10.0 ** (1 - int(d))


class CheckSkipped(Exception):
    """A check does not apply to this adapter; the message says why."""


@dataclass(frozen=True)
class CheckResult:
    """The outcome of one check: ``status`` is ``"passed"``, ``"failed"`` or ``"skipped"``."""

    name: str
    status: str
    reason: str = ""

    @property
    def passed(self) -> bool:
        return self.status == "passed"


def maxabs(A) -> float:
    """The largest absolute entry of a dense or sparse matrix."""
    return float(abs(A).max()) if sp.issparse(A) else float(np.max(np.abs(A)))


def random_fields(adapter: SolverAdapter, k: int, seed: int = 1, per_direction: bool = False) -> np.ndarray:
    """Smooth random fields scaled to the characteristic length (small strains).

    With dof coordinates: quadratic polynomials of the position; ``per_direction``: with independent
    coefficients for every direction (:meth:`~stepnf.plugin.adapter.SolverAdapter.dof_directions`; without
    directions, dof ``i`` takes those of ``i % 3``, a node-major guess). The same polynomial in every
    direction moves every node along (1, 1, 1): every bar of a truss then stretches along one line, and a
    non-conservative force can look symmetric (:func:`check_conservative_force` asks for them). Rotation
    dofs (a shell's: :func:`stepnf.plugin.dofs.rotation_mask`) are scaled on their own (:func:`scaled`)."""
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
        if not per_direction:
            return scaled(rng.standard_normal((k, basis.shape[1])) @ basis.T, L, adapter.dof_directions())
        dirs = adapter.dof_directions()
        code = np.arange(n) % 3
        if dirs is not None and np.shape(dirs) == (n,):  # else check_dof_directions reports it
            code = np.clip(np.nan_to_num(np.asarray(dirs, dtype=float)), 0, len(DIRECTIONS) - 1).astype(int)
        coef = rng.standard_normal((k, len(DIRECTIONS), basis.shape[1]))
        U = np.einsum("kib,ib->ki", coef[:, code, :], basis)
    return scaled(U, L, adapter.dof_directions())


#: Largest rotation (radians) of a random field: the checks send up to ten times one
#: (:func:`~stepnf.testing.harness.check_conservative_force`, ``check_step_equals_intrusive``), which then
#: rotates by at most STEP's bound :data:`stepnf.plugin.dofs.MAX_ROTATION` (0.03 rad). A length is no
#: angle: 1% of a length in millimetres is radians by the dozen.
PROBE_ROTATION = MAX_ROTATION / 10


def scaled(U: np.ndarray, L: float, directions=None) -> np.ndarray:
    """Each row of ``U`` scaled to a largest entry of 1% of the length ``L``; with ``directions`` (one
    code per dof) that include rotations, its translations so and its rotations, on their own, to a
    largest of :data:`PROBE_ROTATION` radians."""
    n = np.shape(U)[1]
    rot = rotation_mask(directions) if directions is not None and np.shape(directions) == (n,) else None
    if rot is None:
        return 1e-2 * L * U / np.max(np.abs(U), axis=1, keepdims=True)
    out = np.array(U, dtype=float)
    for sel, size in ((~rot, 1e-2 * L), (rot, PROBE_ROTATION)):
        if sel.any():
            out[:, sel] = size * U[:, sel] / np.maximum(np.max(np.abs(U[:, sel]), axis=1, keepdims=True), 1e-300)
    return out
