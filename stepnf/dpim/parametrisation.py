"""Direct parametrisation of the single-mode invariant manifold (DPIM), conservative, full order.

Vizzaccaro, Opreni, Salles, Frangi, Touze, Nonlinear Dyn. 2022; Opreni et al.
2023. Model ``M x'' + f(x) = 0``, ``f(x) = K x + G(x, x) + H(x, x, x)``; master
mode ``phi`` (M-normalised, ``K phi = w^2 M phi``).

**Parametrisation (complex normal form style).** Normal coordinates
``z1 = (rho/2) e^{i theta}``, ``z2 = conj(z1)``, displacement
``x = W(z1, z2) = sum W_ab z1^a z2^b`` and reduced dynamics with resonant
monomials only (``a - b = +-1``)::

    z1' = i z1 Omega(z1 z2),    Omega = w + sum_k c_k rho^(2k)

For a conservative system the resonant coefficients are purely imaginary (so
``rho`` is constant and ``theta' = Omega(rho)``); the recursion below solves
every homological equation with this form, which proves it consistent. Then
``W_ab`` are real and ``W_ab = W_ba``, so the manifold is the cosine series::

    x(theta, rho) = sum_{p=1..N} rho^p sum_{m = p, p-2, ... >= 0} Y[p, m] cos(m theta)
    W_ab = 2^(p-1) Y[p, a-b]  (a > b),   W_aa = 2^p Y[2a, 0],   p = a + b,   Y[1, 1] = phi

and the velocity parametrisation is ``v = Omega(rho) dx/dtheta``. Since the
time derivative acts on ``cos(m theta)`` as ``-(m Omega)^2``, invariance
``M x_tt + f(x) = 0`` at ``rho^p cos(m theta)`` reads (homological equation)::

    (K - (m w)^2 M) Y[p, m] = m^2 sum_{k>=1} S_k M Y[p-2k, m] - F[p, m]
    S_k = [rho^(2k)] Omega^2 = 2 w c_k + sum_{i+j=k} c_i c_j

``F[p, m]`` the ``cos(m theta)`` coefficient of the ``rho^p`` part of
``G(x, x) + H(x, x, x)`` built from the orders below p:
``sum_q G(w_q, w_{p-q}) + sum_{a+b+c=p} H(w_a, w_b, w_c)`` with
``w_q(theta) = sum_m Y[q, m] cos(m theta)``; these are evaluated at
J = (N + 1) / 2 phase nodes shared by every order (DCT-II/IV nodes, exact) by
polarisation of f, each probe direction sent once for all orders
(:mod:`stepnf.dpim.nonlinear_terms`): one batched force call per order.
At the resonant ``(p = 2k+1, m = 1)`` the left side is singular; its
solvability ``phi^T rhs = 0`` gives ``S_k = phi^T F[p, 1]`` (with the
normalisation ``phi^T M Y[p, 1] = 0``, p >= 3), hence ``c_k``, and ``Y[p, 1]``
comes from the bordered system (:mod:`stepnf.dpim.solves`).

Order 3: ``c_1 = phi^T F[3, 1] / (2 w)`` and ``T = c_1 / w`` (``A = rho + O(rho^3)``):
DNF's T. The backbone against the amplitude ``A`` of ``q_p = phi^T M x`` is in
:mod:`stepnf.dpim.backbone`.

**The object.** :class:`DPIM` holds what belongs to the model: its forces, ``K``, ``M``, its computed
modes (:class:`ModeSpectrum`: frequencies, rigid modes, shapes, declared twins), the solvers the caller
gives (:class:`stepnf.dpim.solves.Solvers`), the counters and the tolerances (:class:`DPIMTolerances`);
:meth:`DPIM.parametrise` takes one master mode to an order::

    DPIM(forces, K, M, ModeSpectrum(omega, rigid)).parametrise(phi, w, 7, probe=1.0, master=p)

Checks: the master is an eigenpair to the eigen-solver's own accuracy on the model
(:func:`eigenpair_tolerance`: eps lambda_max / lambda_p, not a fixed figure); a degenerate twin that
couples is refused (NumericalError naming the
modes); modes near ``m w`` (m = 0 excluded, 2 <= m <= N, and 1 for non-twins)
are flagged naming the mode, from the spectrum given (or computed densely for
n <= 2000).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from stepnf.flags import new_flag
from stepnf.linalg.block_product import block_product
from stepnf.runtime.counters import Counters
from stepnf.dpim.backbone import Backbone
from stepnf.dpim.solves import ShiftedSolves, Solvers
from stepnf.errors import NumericalError
from stepnf.dpim.nonlinear_terms import OrderForcing
from stepnf.dpim.polarisation import ForceBatch

DENSE_SPECTRUM_LIMIT = 2000


@dataclass
class DPIMResult:
    """The parametrisation of one master mode to odd order ``order``.

    ``Y[(p, m)]`` (n,) cosine coefficients (module docstring), ``c`` (K,)
    with ``Omega(rho) = omega + sum_k c[k-1] rho^(2k)``; ``omega`` rad per
    model time unit; ``counts`` one dict per order p = 2..N (force
    evaluations, batched calls, linear solves, factorisations, seconds);
    ``flags`` internal resonances met.
    """

    omega: float
    phi: np.ndarray
    M: Any
    order: int
    Y: dict[tuple[int, int], np.ndarray]
    c: np.ndarray
    counts: list[dict[str, Any]] = field(default_factory=list)
    flags: list[dict[str, Any]] = field(default_factory=list)
    #: ``(keys, array, rows)`` of :meth:`stacked`: the (k, n) array whose rows ``Y``'s values are (views)
    _stack: tuple | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def T(self) -> float:
        """Backbone coefficient ``w_NL = w (1 + T A^2 + ...)``: ``c_1 / w``."""
        return float(self.c[0] / self.omega) if len(self.c) else 0.0

    def normal_form(self) -> tuple[dict[tuple[int, int], np.ndarray], np.ndarray]:
        """``({(a, b): W_ab} for a >= b, f)``: ``z1' = i w z1 + sum_k f[k-1] z1^(k+1) z2^k``, ``f_k = i 4^k c_k``.

        With ``z1 = (rho/2) e^{i theta}``, ``x = sum W_ab z1^a z2^b`` (``W_ba = W_ab``).
        """
        W = {}
        for (p, m), y in self.Y.items():
            a, b = (p + m) // 2, (p - m) // 2
            W[(a, b)] = (2.0 ** (p - 1) if m else 2.0 ** p) * y
        f = 1j * self.c * 4.0 ** np.arange(1, len(self.c) + 1)
        return W, f

    def displacement(self, theta: float, rho: float) -> np.ndarray:
        """``x(theta, rho) = sum_p rho^p sum_m Y[p, m] cos(m theta)`` (n,), model length units."""
        return sum(rho ** p * np.cos(m * theta) * y for (p, m), y in self.Y.items())

    def velocity(self, theta: float, rho: float) -> np.ndarray:
        """``v = Omega(rho) dx/dtheta`` (n,): the velocity parametrisation, on the motion ``theta' = Omega``."""
        om = self.omega + sum(ck * rho ** (2 * k) for k, ck in enumerate(self.c, start=1))
        return -om * sum(rho ** p * m * np.sin(m * theta) * y for (p, m), y in self.Y.items())

    def arrays(self) -> dict[str, np.ndarray]:
        """The coefficients as arrays (for HDF5).

        ``index`` (k, 2) of (p, m), ``Y`` (k, n), ``c`` (K,), ``phi`` (n,), ``omega``.
        """
        keys = sorted(self.Y)
        return {"index": np.asarray(keys, dtype=int).reshape(-1, 2), "Y": self.stacked(keys),
                "c": np.asarray(self.c, dtype=float), "phi": self.phi, "omega": np.asarray(self.omega)}

    def stacked(self, keys: list[tuple[int, int]]) -> np.ndarray:
        """``Y[k]`` for ``k`` in ``keys`` as one (k, n) array, and ``Y``'s values made its rows (views, the same
        numbers): the coefficients are then held once, not twice, by a caller that keeps the array (a run keeps
        every master's for its HDF5 file: k x n doubles each, 19 x 500k x 8 B = 76 MB per master at order 7 on a
        500k-dof model). Asked again with the same keys while ``Y`` still holds those rows: the same array."""
        kept = self._stack
        if kept is not None and kept[0] == keys and all(self.Y.get(k) is row for k, row in zip(keys, kept[2])):
            return kept[1]
        Y = np.asarray([self.Y[k] for k in keys])
        rows = list(Y)
        for k, row in zip(keys, rows):
            self.Y[k] = row
        self._stack = (list(keys), Y, rows)
        return Y

    def truncated(self, order: int) -> "DPIMResult":
        """The same parametrisation truncated at odd ``order`` (terms p <= order, c_k with 2k+1 <= order)."""
        if order % 2 == 0 or order < 1 or order > self.order:
            raise ValueError(f"truncation order must be odd, between 1 and {self.order}; got {order}")
        Y = {k: v for k, v in self.Y.items() if k[0] <= order}
        return DPIMResult(self.omega, self.phi, self.M, order, Y, self.c[: (order - 1) // 2],
                          self.counts[: max(order - 1, 0)], self.flags)

    def backbone(self) -> Backbone:
        """The backbone ``omega(A)`` of this parametrisation (:class:`stepnf.dpim.backbone.Backbone`)."""
        return Backbone(self)


@dataclass(frozen=True, eq=False)
class ModeSpectrum:
    """What the DPIM knows of the model's modes; every field optional.

    ``omega`` (m,): angular frequencies of the computed modes (rad per model time unit), a mode's index
    its position: internal resonances and twins are flagged by it (None: every mode computed densely
    when n <= 2000, numbered from 0 in ascending order, rigid ones included). ``rigid`` (n, r):
    rigid-body modes, M-orthonormal. ``modes`` (n, m): the computed mode shapes, M-normalised, indexed
    like ``omega``. ``twins``: master index -> indices (in ``modes``) of its declared degenerate twins,
    handled when the master does not drive them, refused otherwise.
    """

    omega: np.ndarray | None = None
    rigid: np.ndarray | None = None
    modes: np.ndarray | None = None
    twins: Mapping[int, Sequence[int]] = field(default_factory=dict)

    def twins_of(self, master: int | None) -> tuple[np.ndarray | None, list[int] | None]:
        """``(shapes (n, t), indices)`` of ``master``'s declared twins, ``(None, None)`` without any."""
        index = [] if master is None else list(self.twins.get(master, ()))
        if not index:
            return None, None
        return self.modes[:, index], index


@dataclass(frozen=True)
class DPIMTolerances:
    """``resonance``: a mode with ``|w_s / w - m| <= resonance m`` (2 <= m <= N) is flagged; ``twin``: a mode
    with ``|w_s / w - 1| <= twin`` is a degenerate twin; ``coupling``: a declared twin whose cosine with the
    master's resonant forcing exceeds it is driven (refused: :class:`~stepnf.errors.NoSingleModeManifold`)."""

    resonance: float = 0.05
    twin: float = 1e-6
    coupling: float = 1e-5


@dataclass(frozen=True, eq=False)
class DPIM:
    """The DPIM of one model, for any of its master modes (:meth:`parametrise`).

    ``forces(U)``: internal forces (m, n) for fields ``U`` (m, n) (e.g. a
    :class:`stepnf.step.forces.ForceEvaluator`); ``K``, ``M`` (n, n) sparse or dense; ``spectrum``:
    its computed modes (:class:`ModeSpectrum`); ``solves``: the solvers the caller provides
    (:class:`stepnf.dpim.solves.Solvers`; the solves of one order go together,
    :meth:`~stepnf.dpim.solves.ShiftedSolves.solve_many`); ``counters``: where solves and
    factorisations are counted (a new :class:`~stepnf.runtime.counters.Counters` per master when None);
    ``tolerances``: of the resonance and twin checks (:class:`DPIMTolerances`); ``rotations``: a shell's
    rotation dofs (bool (n,), radians; ``None``: none), whose probe values are bounded on their own
    (:class:`~stepnf.dpim.nonlinear_terms.OrderForcing`).
    """

    forces: ForceBatch
    K: Any
    M: Any
    spectrum: ModeSpectrum = ModeSpectrum()
    solves: Solvers = Solvers()
    counters: Counters | None = None
    tolerances: DPIMTolerances = DPIMTolerances()
    rotations: np.ndarray | None = None

    def parametrise(self, phi: np.ndarray, omega: float, order: int, *, probe: float, master: int | None = None,
                    progress: Callable[[int], None] | None = None) -> DPIMResult:
        """The DPIM of master mode ``phi`` (M-normalised, angular frequency ``omega``) to odd ``order``.

        ``probe``: polarisation probe size (model length units, see :mod:`stepnf.dpim.polarisation`);
        ``master``: the master's index in the spectrum (names it in flags and messages; its declared
        twins; None: the computed mode nearest to ``omega``); ``progress(p)`` after each order p.
        """
        K, M = self.K, self.M
        order = int(order)
        if order < 3 or order % 2 == 0:
            raise ValueError(f"DPIM order must be odd and >= 3, got {order}")
        phi = np.asarray(phi, dtype=float)
        check_mode(K, M, phi, omega, master)
        counters = self.counters if self.counters is not None else Counters()
        twins, twin_index = self.spectrum.twins_of(master)
        flags = resonance_flags(K, M, omega, order, self.spectrum.omega, master, twins, twin_index,
                                self.tolerances.resonance, self.tolerances.twin)
        solves = ShiftedSolves(K, M, phi, omega, self.solves, R=self.spectrum.rigid, counters=counters,
                               master=master, twins=twins, twin_index=twin_index, coupling=self.tolerances.coupling,
                               resonant_exclude=self.resonant_exclude(omega, master, twin_index))
        forcing = OrderForcing(self.forces, K, probe, order, shared_nodes(order), self.rotations)
        return recursion(forcing, solves, counters, M, phi, omega, order, flags, progress)

    def resonant_exclude(self, omega: float, master: int | None, twin_index: Sequence[int] | None) -> list[int] | None:
        """The columns of the deflated solver (rigid modes first, then the spectrum's modes) left out of the
        resonant solve: the master and its twins; None without a deflated solver admitting ``omega^2``."""
        d = self.solves.deflated
        if d is None or master is None or not d.admissible(float(omega) ** 2):
            return None
        nr = 0 if self.spectrum.rigid is None else self.spectrum.rigid.shape[1]
        return [nr + master] + [nr + t for t in twin_index or ()]


def recursion(forcing: OrderForcing, solves: ShiftedSolves, counters: Counters, M, phi: np.ndarray, omega: float,
              order: int, flags: list[dict[str, Any]], progress: Callable[[int], None] | None) -> DPIMResult:
    """Orders 2..``order`` of the homological equations (module docstring), the solves freed at the end."""
    Msp = sp.csr_matrix(M) if sp.issparse(M) else np.asarray(M)
    Y: dict[tuple[int, int], np.ndarray] = {(1, 1): phi.copy()}
    Mblock = block_product(Msp)
    MY: dict[tuple[int, int], np.ndarray] = {(1, 1): Msp @ phi}
    c: list[float] = []
    S: list[float] = []
    counts: list[dict[str, Any]] = []
    try:  # the factorisations are freed also when a solve refuses (the run may go on: NoSingleModeManifold)
        for p in range(2, order + 1):
            t0 = time.perf_counter()
            before = (forcing.stats.force_evaluations, forcing.stats.calls, counters.linear_solves,
                      counters.factorizations, len(solves.shifts_factorised))
            ms, F = forcing(Y, p)
            rhs = []
            for j, m in enumerate(ms):
                if m == 1:  # resonant: solvability gives S_k, then c_k
                    k = (p - 1) // 2
                    Sk = float(phi @ F[j]) - sum(S[i - 1] * float(phi @ MY[(p - 2 * i, 1)]) for i in range(1, k))
                    S.append(Sk)
                    c.append((Sk - sum(c[i - 1] * c[k - i - 1] for i in range(1, k))) / (2.0 * omega))
                b = -F[j]
                for k in range(1, (p - m) // 2 + 1 if m else 1):  # m = 0: no inertia term
                    b = b + (m * m) * S[k - 1] * MY[(p - 2 * k, m)]
                rhs.append(b)
            # the harmonics of one order are independent (their right-hand sides use lower orders only)
            ys = solves.solve_many(list(zip(ms, rhs)))
            Mys = np.ascontiguousarray((Mblock @ np.column_stack(ys)).T)  # one block product: rows M y
            for m, y, My in zip(ms, ys, Mys):
                Y[(p, m)] = y
                MY[(p, m)] = My
            counts.append({"order": p, "force_evaluations": forcing.stats.force_evaluations - before[0],
                           "force_calls": forcing.stats.calls - before[1],
                           "linear_solves": counters.linear_solves - before[2],
                           "factorizations": max(counters.factorizations - before[3],
                                                 len(solves.shifts_factorised) - before[4]),
                           "seconds": round(time.perf_counter() - t0, 4)})
            if progress is not None:
                progress(p)
    finally:
        solves.release()
    return DPIMResult(float(omega), phi, M, order, Y, np.asarray(c), counts, flags)


#: How many times the eigen-solver's own backward error bound a master's eigen-residual may reach
#: (:func:`eigenpair_tolerance`). Measured defect / bound: 0.68 and 0.92 for the first two modes of issue 31's
#: cantilever plate deck (C3D20, L/h = 300, 540 dofs, LAPACK eigh: defects 3.4e-5 and 1.2e-6, which the fixed
#: 1e-6 of before refused), 0.3 on a random 8-dof system of spread 1e10.5 (tests/pipeline/test_backbone_failure.py).
#: The constant of a backward-stable solver grows slowly with n and with the nonzeros per row, hence 100 (two
#: decades); a wrong pair (another mode: a defect ~1; the frequency 1% off: 2e-2) stays above the tolerance
#: while the spread lambda_max / lambda_p is below ~1e12 (where the tolerance reaches 2e-2).
EIGENPAIR_SAFETY = 100.0
#: The floor of the eigen-residual check and the tolerance of ``phi^T M phi = 1`` (relative).
EIGENPAIR_FLOOR = 1e-6
#: Rows read at a time by :func:`norm_1` (a block of a sparse matrix is copied, the matrix never is).
NORM_ROWS = 65536


def norm_1(A) -> float:
    """``max_i sum_j |A_ij|``: the infinity-norm, equal to the 1-norm of a symmetric ``A`` and an upper bound of its
    2-norm; read ``NORM_ROWS`` rows at a time (no copy of a large sparse matrix)."""
    if not sp.issparse(A):
        A = np.asarray(A)
        return float(np.abs(A).sum(axis=1).max()) if A.size else 0.0
    A = A if A.format == "csr" else sp.csr_matrix(A)
    return max((float(abs(A[lo:lo + NORM_ROWS]).sum(axis=1).max()) for lo in range(0, A.shape[0], NORM_ROWS)),
               default=0.0)


def eigenpair_tolerance(K, M, phi: np.ndarray, omega: float, Kphi: np.ndarray | None = None) -> float:
    """The largest ``|K phi - w^2 M phi| / |K phi|`` an eigen-solver's answer may carry: ``EIGENPAIR_SAFETY`` times
    its backward error bound ``eps (|K|_1 + w^2 |M|_1) |phi| / |K phi|``, at least ``EIGENPAIR_FLOOR``.

    A backward-stable eigen-solver returns ``phi`` with a residual of ``eps (|K| + w^2 |M|) |phi|`` (times a
    modest constant), whatever the mode: relative to ``|K phi| = w^2 |M phi|`` that is ~ eps lambda_max /
    lambda_p, 2e-5 for the lowest mode of a slender structure whose eigenvalues spread over 1e11
    (:data:`EIGENPAIR_SAFETY` says why 100 times it)."""
    Kphi = K @ phi if Kphi is None else Kphi
    scale = (norm_1(K) + omega ** 2 * norm_1(M)) * float(np.linalg.norm(phi))
    bound = float(np.finfo(float).eps) * scale / max(float(np.linalg.norm(Kphi)), 1e-300)
    return max(EIGENPAIR_FLOOR, EIGENPAIR_SAFETY * bound)


def check_mode(K, M, phi: np.ndarray, omega: float, master: int | None = None, tol: float | None = None) -> None:
    """NumericalError unless ``phi^T M phi = 1`` to ``EIGENPAIR_FLOOR`` and ``K phi = omega^2 M phi`` to ``tol``
    (relative; None: :func:`eigenpair_tolerance`, the eigen-solver's own accuracy on this model)."""
    who = "the master mode" if master is None else f"master mode {master}"
    Mphi, Kphi = M @ phi, K @ phi
    mass = float(phi @ Mphi)
    if not (np.isfinite(mass) and abs(mass - 1.0) <= EIGENPAIR_FLOOR):
        raise NumericalError(f"DPIM: {who} is not mass-normalised (phi^T M phi = {mass:.9g}, expected 1)")
    defect = float(np.linalg.norm(Kphi - omega ** 2 * Mphi) / max(np.linalg.norm(Kphi), 1e-300))
    if tol is None:
        tol = eigenpair_tolerance(K, M, phi, omega, Kphi)
    if not defect <= tol:
        raise NumericalError(f"DPIM: {who} and w = {omega:.9g} are not an eigenpair of (K, M): "
                             f"|K phi - w^2 M phi| / |K phi| = {defect:.2e} > {tol:.2e} ({EIGENPAIR_SAFETY:g} x "
                             "the eigen-solver's backward error eps (|K| + w^2 |M|) |phi| / |K phi|, at least "
                             f"{EIGENPAIR_FLOOR:g})")


def phase_nodes(p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Harmonics ``m`` of order p (same parity, 0..p), nodes ``theta`` (J,) and basis ``B[l, j] = cos(m_j theta_l)``.

    Even p: ``2 theta_l = pi (l + 1/2) / J`` (DCT-II nodes); odd p:
    ``theta_l = pi (2l + 1) / (4J)`` (DCT-IV nodes): B has orthogonal columns,
    so the J cosine coefficients of an order-p term are exact from J samples.
    """
    ms = np.arange(p % 2, p + 1, 2)
    J = len(ms)
    l = np.arange(J)
    theta = np.pi * (l + 0.5) / (2 * J) if p % 2 == 0 else np.pi * (2 * l + 1) / (4 * J)
    return ms, theta, np.cos(np.outer(theta, ms))


def shared_nodes(order: int) -> tuple[np.ndarray, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """The phase nodes every order of a DPIM to odd ``order`` uses, and per parity the harmonics and basis.

    ``(theta (J,), {0: (0, 2, .., N-1; B), 1: (1, 3, .., N; B)})``, J = (N + 1) / 2: the nodes of
    :func:`phase_nodes` of orders N and N - 1 are the same, and each basis is square and orthogonal.
    """
    ms1, theta, B1 = phase_nodes(order)
    ms0, _, B0 = phase_nodes(order - 1)  # the same nodes: pi (2l + 1) / (4J) for both parities
    return theta, {0: (ms0, B0), 1: (ms1, B1)}


def dense_spectrum(K, M) -> np.ndarray:
    """Every angular frequency of (K, M), ascending, by a dense generalised eigen-solve (negative round-off
    eigenvalues clipped to 0): for models of at most :data:`DENSE_SPECTRUM_LIMIT` dofs."""
    Kd = K.toarray() if sp.issparse(K) else np.asarray(K)
    Md = M.toarray() if sp.issparse(M) else np.asarray(M)
    return np.sqrt(np.clip(sla.eigh(Kd, Md, eigvals_only=True), 0.0, None))


def resonance_flags(K, M, omega: float, order: int, spectrum, master, twins, twin_index,
                    tol: float, twin_tol: float) -> list[dict[str, Any]]:
    """Flags of modes near ``m omega`` (2 <= m <= order; m = 1 for a non-declared mode); refuses undeclared twins.

    ``spectrum``: angular frequencies (same unit as ``omega``) indexed like
    the caller's modes; when None and n <= 2000, every generalised
    eigenvalue of (K, M) is computed (modes then numbered from 0 in
    ascending order, rigid ones included). A mode s != master, not among
    ``twin_index``, with ``|w_s / w - 1| <= twin_tol`` is an undeclared
    degenerate twin: NumericalError naming both modes.
    """
    n = K.shape[0]
    flags: list[dict[str, Any]] = []
    if spectrum is None:
        if n > DENSE_SPECTRUM_LIMIT:
            return [new_flag("resonance_check_skipped", mode=None,
                             message="DPIM: no spectrum given for a large model: internal resonances not checked")]
        spectrum = dense_spectrum(K, M)
    spectrum = np.asarray(spectrum, dtype=float)
    if master is None:  # the master is the computed mode nearest to omega
        master = int(np.argmin(np.abs(spectrum - omega)))
    declared = {int(i) for i in twin_index} if twin_index is not None else set()
    n_twins = 0 if twins is None else np.asarray(twins).reshape(n, -1).shape[1]
    who = f"master mode {master}"
    r_all = spectrum / omega
    same = [s for s in range(len(spectrum)) if s != master and abs(r_all[s] - 1.0) <= twin_tol]
    undeclared = [s for s in same if s not in declared]
    if undeclared and len(same) > n_twins:  # (a dense spectrum numbers modes its own way: count them)
        r = r_all[undeclared[0]]
        raise NumericalError(
            f"DPIM: mode {undeclared[0]} has the frequency of {who} (w_s/w_p = {r:.9f}): a degenerate twin "
            f"(1:1 internal resonance); a single-mode parametrisation is refused unless the twin is "
            f"declared (twins=...) and symmetry keeps it uncoupled")
    for s, r in enumerate(r_all):
        if s == master or s in same or spectrum[s] <= 0:
            continue
        m = int(round(r))
        if 1 <= m <= order and abs(r - m) <= tol * m:
            flags.append(new_flag(f"internal_resonance_1_{m}", mode=int(s), harmonic=m, ratio=float(r),
                                  message=f"DPIM: mode {s} is near {m} x the frequency of {who} "
                                          f"(w_s/w_p = {r:.4f}): K - ({m} w)^2 M is nearly singular, the "
                                          f"harmonic {m} of the parametrisation has a small denominator"))
    return flags
