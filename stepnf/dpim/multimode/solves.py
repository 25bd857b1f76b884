"""The linear solves of a manifold of several master modes: ``(K - s M) W = b``, one real factorisation per shift.

A monomial ``alpha`` of frequencies ``c = a - b`` has the real shift ``s = (sum_j c_j omega_j)^2 >= 0``
(:mod:`stepnf.dpim.multimode.manifold`); every monomial of the same shift (any order) shares one factorisation,
made when first needed and kept to the end of the run, or, with ``max_live``, while it is among the ``max_live``
most recently used ones (a large model: on the 38k-dof cap each MUMPS factorisation holds ~220 MB and a two-mode
manifold at order 5 meets ~30 shifts; keeping them all took the 24 GB machine out of memory). Complex right-hand sides go as two real columns (n, 2k),
the monomials of one shift and order in ONE call.

``bordered`` (positions of masters, resonant for this shift): the system is
``[[K - s M, M Phi_J], [Phi_J^T M, 0]] [W; mu] = [b; 0]``, so ``phi_j^T M W = 0`` for those masters (their
``phi_j^T b`` is taken out by the caller first: it is the reduced dynamics' coefficient), singular only when a
mode outside ``J`` shares the shift. Without it, the factorisation of ``K - s M`` comes from ``solvers.factory``
when given, else from :class:`stepnf.linalg.shifted.ShiftedFactorizer`; ``s = 0`` with rigid modes is ``K^+``
(:class:`~stepnf.linalg.factorization.PseudoInverse`, or ``solvers.pinv``). A singular shift is an internal
resonance with a mode outside the manifold: :class:`~stepnf.errors.NumericalError` naming the mode nearest
``sqrt(s)`` and its ratio to the first master. Not used yet: ``solvers.deflated`` and ``solvers.resonant`` (the
single-mode DPIM's iterative and adapter-side resonant solves) and declared twins outside the manifold.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.dpim.solves import Solvers, release_all
from stepnf.errors import NumericalError
from stepnf.linalg.factorization import PseudoInverse, factorize
from stepnf.linalg.shifted import ShiftedFactorizer
from stepnf.runtime.counters import Counters

#: Shifts equal to this relative precision share a factorisation (the same sum of frequencies computed in two
#: orders differs in the last bits only).
SHIFT_DIGITS = 12


def shift_key(s: float) -> float:
    """``s`` rounded to :data:`SHIFT_DIGITS` significant digits: the key of its factorisation."""
    return float(f"{s:.{SHIFT_DIGITS}e}")


class ManifoldSolves:
    """``(K - s M) W = b`` with shared real factorisations (module docstring).

    ``Phi`` (n, m) the masters' shapes (M-normalised), ``masters`` their indices (in messages), ``omega`` (m,);
    ``spectrum`` angular frequencies of the computed modes (names the mode of a singular shift; None: unnamed);
    ``R`` rigid modes (n, r) or None; ``rigid_window``: a shift ``0 < s <= rigid_window`` is near the rigid modes'
    eigenvalue 0 (monomials of a small frequency ``|d|``, e.g. ``z_0 conj(z_1)`` of near-twin masters): the system
    is then bordered with ``M R`` as well, so that ``R^T M W = 0`` as at ``s = 0`` (the internal forces and the
    masters' inertia terms have no rigid part; without the border ``K - s M`` is nearly singular along R and the
    rounding of the solve, ``~ eps |K| / s``, came out as W of 1e6 at ``|d| = 1e-9``, review of issue 33).
    ``max_live``: at most this many factorisations alive (least recently used freed first; None: all kept).
    """

    def __init__(self, K, M, Phi: np.ndarray, masters: Sequence[int], omega: np.ndarray, solvers: Solvers,
                 counters: Counters, *, R: np.ndarray | None = None, spectrum: np.ndarray | None = None,
                 rigid_window: float = 0.0, max_live: int | None = None):
        self.K, self.M = sp.csr_matrix(K), sp.csr_matrix(M)
        self.Phi = np.asarray(Phi, dtype=float)
        self.MPhi = np.asarray(self.M @ self.Phi)
        self.masters, self.omega = tuple(masters), np.asarray(omega, dtype=float)
        self.solvers, self.counters = solvers, counters
        self.R = None if R is None or not np.asarray(R).size else np.asarray(R, dtype=float)
        self.MR = None if self.R is None else np.asarray(self.M @ self.R)
        self.rigid_window = float(rigid_window)
        self.spectrum = None if spectrum is None else np.asarray(spectrum, dtype=float)
        self._cache: dict[tuple[float, tuple[int, ...]], Callable[[np.ndarray], np.ndarray]] = {}  # LRU order
        self._factors: dict[tuple[float, tuple[int, ...]], Any] = {}
        self.max_live = None if max_live is None else max(int(max_live), 1)
        self._factory = solvers.factory
        self.shifts_factorised: list[float] = []

    def solve(self, s: float, bordered: tuple[int, ...], B: np.ndarray, where: str) -> np.ndarray:
        """``W`` (n, k) complex for right-hand sides ``B`` (n, k) complex; ``where`` names the monomials."""
        key = (shift_key(s), tuple(sorted(bordered)))
        solver = self._cache.pop(key, None)
        if solver is None:
            if self.max_live is not None:
                while len(self._cache) >= self.max_live:
                    old = next(iter(self._cache))
                    del self._cache[old]
                    release_all([self._factors.pop(old, None)])
            solver = self._make(s, key[1], where, key)
        self._cache[key] = solver  # the most recently used last
        k = B.shape[1]
        X = solver(np.concatenate([B.real, B.imag], axis=1))
        return X[:, :k] + 1j * X[:, k:]

    def release(self) -> None:
        """Free every factorisation made here."""
        self._cache.clear()
        release_all(list(self._factors.values()))
        self._factors.clear()

    def _make(self, s: float, bordered: tuple[int, ...], where: str,
              key: tuple[float, tuple[int, ...]]) -> Callable[[np.ndarray], np.ndarray]:
        label = f"K - {s:.6g} M (DPIM manifold of modes {self.masters}{', bordered' if bordered else ''})"
        rigid = self.R is not None and 0.0 < s <= self.rigid_window
        try:
            if bordered or rigid:
                MD = sp.csr_matrix(np.column_stack([self.MPhi[:, list(bordered)]] + ([self.MR] if rigid else [])))
                A = sp.bmat([[self.K - s * self.M, MD], [MD.T, None]]).tocsr()
                fac = factorize(A, counters=self.counters, backend=self.solvers.backend, label=label)
                n, nb = self.K.shape[0], MD.shape[1]
                solve = lambda X: fac.solve(np.vstack([X, np.zeros((nb, X.shape[1]))]))[:n]  # noqa: E731
            elif s == 0.0 and self.solvers.pinv is not None:
                pinv = self.solvers.pinv
                self.counters.factorizations += 1
                return lambda X: np.column_stack([pinv(X[:, j]) for j in range(X.shape[1])])
            elif s == 0.0 and self.R is not None:
                fac = PseudoInverse(self.K, self.M, self.R, counters=self.counters, backend=self.solvers.backend)
                solve = fac
            else:
                if self._factory is None:
                    self._factory = ShiftedFactorizer(self.K, self.M, counters=self.counters,
                                                      backend=self.solvers.backend).factorizer
                fac = self._factory(s, label)
                solve = fac.solve
        except NumericalError as exc:
            raise NumericalError(self._singular(s, bordered, where, exc)) from exc
        self.shifts_factorised.append(s)
        self._factors[key] = fac
        return solve

    def _singular(self, s: float, bordered: tuple[int, ...], where: str, exc: Exception) -> str:
        """The message of a singular shift: the mode outside the manifold at ``sqrt(s)``."""
        d = float(np.sqrt(max(s, 0.0)))
        who = "a mode outside the manifold"
        if self.spectrum is not None and len(self.spectrum):
            out = [i for i in range(len(self.spectrum)) if i not in self.masters]
            if out:
                i = min(out, key=lambda i: abs(self.spectrum[i] - d))
                who = f"mode {i} (w = {self.spectrum[i]:.9g}, {self.spectrum[i] / self.omega[0]:.6f} x w of " \
                      f"mode {self.masters[0]})"
        return (f"DPIM manifold of modes {self.masters}: K - s M is singular at s = {s:.9g} (frequency "
                f"{d:.9g} = {d / self.omega[0]:.6f} x w of mode {self.masters[0]}, monomial {where}): an internal "
                f"resonance with {who}; add it to the masters ({exc})")
