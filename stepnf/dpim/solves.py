"""The linear solves of the direct parametrisation: ``(K - (m w)^2 M) y = b``, factorisations shared.

Three kinds of shift ``sigma = (m w)^2`` (``w`` the master's angular frequency):

``m = 0``
    ``K^+ b``: with rigid-body modes ``R`` (M-orthonormal, (n, r)) the
    right-hand side is self-equilibrated and the solution is taken
    M-orthogonal to ``R`` (:class:`stepnf.linalg.factorization.PseudoInverse`, or the
    caller's ``pinv``).
``m = 1`` (resonant)
    ``K - w^2 M`` is singular (phi_p in its kernel). The solution with
    ``phi_p^T M y = 0`` of ``(K - w^2 M) y = b`` (b with ``phi_p^T b = 0``)
    comes from the bordered system ``[[K - w^2 M, M phi], [phi^T M, 0]]``, or
    from the caller's ``resonant`` solve, or from the ``deflated`` solver with the
    columns ``resonant_exclude`` (the master and its twins) left out. A singular
    bordered matrix means a degenerate twin.
``m >= 2``
    one factorisation per shift, kept in a dict keyed by the shift and reused
    by every order; made by ``factory(sigma, label)`` (the pipeline's own,
    e.g. ``FullOrderContext.shifted_factorization`` without its one-slot
    cache; by default :meth:`stepnf.linalg.shifted.ShiftedFactorizer.factorizer`), or replaced by the
    caller's ``deflated`` solver when the shift is admissible for it.

Every solve and factorisation is counted (``solves``, ``factorizations`` and
the shifts used), so the caller can report counts per order.

:meth:`ShiftedSolves.solve_many` takes the independent solves of one order together: those the
``deflated`` solver does (``m = 0`` without a ``pinv``, ``m = 1`` with ``resonant_exclude``, any
admissible shift) run as one lockstep CG with block solves
(:meth:`stepnf.linalg.deflation.DeflatedSolver.solve_many`), the others one by one.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.runtime.counters import Counters
from stepnf.errors import NoSingleModeManifold, NumericalError
from stepnf.linalg.factorization import Factorization, PseudoInverse, factorize
from stepnf.linalg.shifted import ShiftedFactorizer

FactorizationFactory = Callable[[float, str], Factorization]
Solve = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Solvers:
    """The solvers a caller gives the DPIM in place of its own (module docstring); all optional.

    ``factory(sigma, label)``: the shifted factorisations (``m >= 2``); ``pinv``: ``K^+ b`` (``m = 0``);
    ``resonant``: the resonant solve of one master (``m = 1``, M-orthogonal to the master and its twins);
    ``deflated``: a :class:`stepnf.linalg.deflation.DeflatedSolver` over the computed modes (rigid ones
    first), used for every shift it admits; ``backend``: of the factorisations stepnf makes
    (:func:`stepnf.linalg.factorization.factorize`).
    """

    factory: FactorizationFactory | None = None
    pinv: Solve | None = None
    resonant: Solve | None = None
    deflated: Any | None = None
    backend: str = "auto"


class ShiftedSolves:
    """Solves with ``K - (m w)^2 M`` for the harmonics ``m`` of the parametrisation (module docstring).

    ``K``, ``M`` sparse or dense (n, n); ``phi`` the M-normalised master mode;
    ``omega`` its angular frequency; ``solvers``: optional replacements of the
    default factorisations (:class:`Solvers`); ``R`` rigid modes (n, r) or None;
    ``master`` the master's index (in messages); ``twins`` (n, t) its declared
    degenerate twins (``twin_index`` their indices), refused when the master's
    forces drive them (cosine above ``coupling``); ``resonant_exclude``: the
    columns of ``solvers.deflated`` left out of the resonant solve.
    """

    def __init__(self, K, M, phi: np.ndarray, omega: float, solvers: Solvers = Solvers(), *,
                 R: np.ndarray | None = None, counters: Counters | None = None, master: int | None = None,
                 twins: np.ndarray | None = None, twin_index: Any = None, coupling: float = 1e-5,
                 resonant_exclude: Sequence[int] | None = None):
        self.K = sp.csr_matrix(K)
        self.M = sp.csr_matrix(M)
        self.phi = np.asarray(phi, dtype=float)
        self.omega = float(omega)
        self.R = np.zeros((len(phi), 0)) if R is None else np.asarray(R, dtype=float)
        self.counters = counters if counters is not None else Counters()
        self.backend = solvers.backend
        self.factory = solvers.factory
        self.deflated = solvers.deflated
        self.master = master
        self._pinv = solvers.pinv
        self._resonant = solvers.resonant
        self.resonant_exclude = None if resonant_exclude is None else tuple(int(i) for i in resonant_exclude)
        self.twins = np.zeros((len(phi), 0)) if twins is None else np.asarray(twins, dtype=float).reshape(len(phi), -1)
        self.twin_index = list(range(self.twins.shape[1])) if twin_index is None else list(twin_index)
        self.coupling = float(coupling)
        self._cache: dict[float, Solve] = {}
        self._basis: tuple[np.ndarray, np.ndarray] | None = None  # (D, M D) of the resonant solves
        self._factors: list[Any] = []  # factorisations made here, released by release()
        self.shifts_factorised: list[float] = []

    # ------------------------------------------------------------------ API
    def solve(self, m: int, b: np.ndarray) -> np.ndarray:
        """``y`` with ``(K - (m w)^2 M) y = b`` (for m = 1: ``phi^T M y = 0``, b's phi part ignored)."""
        m = abs(int(m))
        if m == 1:
            return self._solve_resonant(b)
        sigma = (m * self.omega) ** 2
        solver = self._cache.get(sigma)
        if solver is None:
            solver = self._make(m, sigma)
            self._cache[sigma] = solver
        return solver(b)

    def solve_many(self, items: Sequence[tuple[int, np.ndarray]]) -> list[np.ndarray]:
        """``[solve(m, b) for m, b in items]``, the deflated ones in one lockstep run (module docstring), the
        others one by one, those whose factorisation the ``factory`` holds now (its ``holds(sigma)``) first."""
        out: list[np.ndarray | None] = [None] * len(items)
        plans = [(i, self._deflated_plan(abs(int(m)), b)) for i, (m, b) in enumerate(items)]
        plans = [(i, plan) for i, plan in plans if plan is not None]
        if len(plans) == 1:  # one deflated solve: as planned, not planned again by solve()
            i, (rhs, sigma, exclude, finish) = plans[0]
            out[i] = finish(self.deflated.solve(rhs, sigma, exclude=exclude))
        elif plans:
            X = self.deflated.solve_many(np.column_stack([plan[0] for _, plan in plans]),
                                         [plan[1] for _, plan in plans], [plan[2] for _, plan in plans])
            for j, (i, plan) in enumerate(plans):
                out[i] = plan[3](X[:, j])
        held = getattr(self.factory, "holds", None)  # a shift whose factorisation is alive goes first
        rest = [i for i, y in enumerate(out) if y is None]
        if held is not None:
            ms = {i: abs(int(items[i][0])) for i in rest}
            rest.sort(key=lambda i: not (ms[i] >= 2 and held((ms[i] * self.omega) ** 2)))
        for i in rest:
            out[i] = self.solve(*items[i])
        return out

    def release(self) -> None:
        """Free every kept factorisation (``release()`` of those that have one: a MUMPS factorisation keeps
        its memory until it is destroyed, dropping the object is not enough)."""
        self._cache.clear()
        release_all(self._factors)

    # ------------------------------------------------------------ internals
    def _make(self, m: int, sigma: float) -> Solve:
        label = f"K - ({m} w)^2 M (DPIM{'' if self.master is None else f', mode {self.master}'})"
        if m == 0:
            if self._pinv is not None:
                return self._count(self._pinv)
            if self.deflated is not None:  # K^+ from the computed modes (rigid ones excluded)
                return self.deflated.pinv
            if self.R.shape[1]:
                P = PseudoInverse(self.K, self.M, self.R, counters=self.counters, backend=self.backend)
                self.shifts_factorised.append(0.0)
                return P
        if self.deflated is not None and self.deflated.admissible(sigma):
            d = self.deflated
            return lambda b: d.solve(b, sigma)  # counts its own CG iterations as solves
        if self.factory is None:  # stepnf's own: K - sigma M on one pattern shared with K and M
            self.factory = ShiftedFactorizer(self.K, self.M, counters=self.counters,
                                             backend=self.backend).factorizer
        try:
            fac = self.factory(sigma, label)
        except NumericalError as exc:  # K - (m w)^2 M singular: a mode at exactly m w (1:m resonance)
            who = "the master mode" if self.master is None else f"master mode {self.master}"
            raise NoSingleModeManifold(f"DPIM: K - ({m} w)^2 M is singular for {who}: a mode at exactly {m} times "
                                       f"its frequency (1:{m} internal resonance), the parametrisation diverges "
                                       f"there ({exc})", kind=f"internal_resonance_1_{m}") from exc
        self.shifts_factorised.append(sigma)
        self._factors.append(fac)
        return fac.solve

    def _deflated_plan(self, m: int, b: np.ndarray) -> tuple[np.ndarray, float, tuple[int, ...], Callable] | None:
        """``(rhs, sigma, exclude, finish)`` when the deflated solver does ``solve(m, b)``: its answer is
        ``finish(deflated.solve(rhs, sigma, exclude))``; None when it does not."""
        d = self.deflated
        if d is None:
            return None
        if m == 0:
            return (b, 0.0, tuple(range(d.n_rigid)), _same) if self._pinv is None else None
        if m == 1:
            if not self._resonant_deflated():
                return None
            DMD = self._resonant_basis()
            return (self._resonant_rhs(b, DMD), self.omega ** 2, self.resonant_exclude,
                    lambda y: _m_orthogonal(y, DMD))
        sigma = (m * self.omega) ** 2
        return (b, sigma, (), _same) if d.admissible(sigma) else None

    def _count(self, f: Solve) -> Solve:
        def g(b):
            self.counters.linear_solves += 1
            return f(b)
        return g

    def _resonant_deflated(self) -> bool:
        """Whether the resonant solve is the deflated solver's (``resonant_exclude`` given, no ``resonant``)."""
        return (self._resonant is None and self.resonant_exclude is not None and self.deflated is not None
                and self.deflated.admissible(self.omega ** 2))

    def _resonant_basis(self) -> tuple[np.ndarray, np.ndarray]:
        """``(D, M D)``, ``D = [phi, twins]`` (made once)."""
        if self._basis is None:
            D = np.column_stack([self.phi, self.twins])
            self._basis = (D, np.asarray(self.M @ D, dtype=float))
        return self._basis

    def _resonant_rhs(self, b: np.ndarray, DMD: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """``b`` without its part along phi and the twins; a twin that ``b`` drives is refused."""
        D, MD = DMD
        who = "the master mode" if self.master is None else f"master mode {self.master}"
        if self.twins.shape[1]:  # a twin that the master drives makes the single-mode manifold impossible
            cos = np.abs(self.twins.T @ b) / max(np.linalg.norm(b) * 1.0, 1e-300)
            cos /= np.maximum(np.linalg.norm(self.twins, axis=0), 1e-300)
            if np.any(cos > self.coupling):
                j = int(np.argmax(cos))
                raise NoSingleModeManifold(
                    f"DPIM: mode {self.twin_index[j]}, a degenerate twin of {who} (same frequency, 1:1 "
                    f"internal resonance), is driven by the master's nonlinear forces (coupling {cos[j]:.2e} > "
                    f"{self.coupling:.1e}): a single-mode invariant manifold does not exist; a two-mode "
                    "parametrisation is needed", mode=int(self.twin_index[j]))
        return b - MD @ (D.T @ b)  # phi's part is the solvability condition (met up to round-off); twins' checked

    def _solve_resonant(self, b: np.ndarray) -> np.ndarray:
        DMD = self._resonant_basis()
        D, MD = DMD
        who = "the master mode" if self.master is None else f"master mode {self.master}"
        b = self._resonant_rhs(b, DMD)
        if self._resonant is not None:
            self.counters.linear_solves += 1
            return _m_orthogonal(np.asarray(self._resonant(b), dtype=float), DMD)
        if self._resonant_deflated():  # it counts its own CG iterations
            return _m_orthogonal(self.deflated.solve(b, self.omega ** 2, exclude=self.resonant_exclude), DMD)
        solver = self._cache.get(-1.0)
        if solver is None:
            w2 = self.omega ** 2
            A = sp.bmat([[self.K - w2 * self.M, sp.csr_matrix(MD)],
                         [sp.csr_matrix(MD.T), None]]).tocsr()
            try:
                fac = factorize(A, counters=self.counters, backend=self.backend,
                                label=f"bordered K - w^2 M ({who})")
            except NumericalError as exc:
                raise NumericalError(
                    f"DPIM: K - w^2 M bordered with phi is singular for {who} (w = {self.omega:.6g} rad/s): "
                    f"another mode has the same frequency (a degenerate twin, 1:1 internal resonance); "
                    f"pass its mode shape as a twin if symmetry keeps it uncoupled ({exc})") from exc
            self.shifts_factorised.append(w2)
            self._factors.append(fac)
            n, k = len(b), D.shape[1]
            solver = lambda rhs: fac.solve(np.concatenate([rhs, np.zeros(k)]))[:n]  # noqa: E731
            self._cache[-1.0] = solver
        return solver(b)


def release_all(factors: list[Any]) -> None:
    """``release()`` every factorisation of ``factors`` that has one, then empty the list (a MUMPS factorisation
    keeps its memory until it is destroyed)."""
    for fac in factors:
        free = getattr(fac, "release", None)
        if callable(free):
            free()
    factors.clear()


def _same(y: np.ndarray) -> np.ndarray:
    return y


def _m_orthogonal(y: np.ndarray, DMD: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """``y`` without its part along ``D`` (M-orthonormal columns), ``DMD = (D, M D)``."""
    D, MD = DMD
    return y - D @ (MD.T @ y)
