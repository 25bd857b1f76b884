"""Shifted solves from the computed modes and ONE factorisation: spectral deflation + preconditioned CG.

For ``(K - sigma M) x = b`` with M-orthonormal computed modes ``Psi`` (the
rigid ones and the lowest elastic ones, eigenvalues ``lam``)::

    x = sum_s psi_s (psi_s^T b) / (lam_s - sigma)  +  x_c

where ``x_c`` lives in the M-orthogonal complement of the computed modes,
on which ``K - sigma M`` is positive definite as long as ``sigma`` lies below
the first uncomputed eigenvalue. ``x_c`` is found by conjugate gradients
preconditioned by the eigen-solver's own factorisation of ``K - sigma_0 M``
(sigma_0 <= 0): the preconditioned operator has its eigenvalues in
``[(lam_c - sigma)/(lam_c - sigma_0), 1]``, ``lam_c`` the first uncomputed
eigenvalue, so CG converges in a few tens of iterations when ``sigma`` is
well below ``lam_c``. This replaces a new factorisation per shift (seconds on
a 40k-dof cap) by a few tens of solves (tens of milliseconds each).

Used for ``K^+`` (sigma = 0, the rigid modes left out), the full-order modal
derivative (sigma = w_p^2, the master and its twins left out) and DNF's
``K - 4 w_p^2 M`` when ``4 w_p^2`` lies well inside the computed spectrum.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.linalg.block_product import block_product
from stepnf.runtime.counters import Counters
from stepnf.errors import NumericalError


#: A shift is solved by deflation when the first uncomputed eigenvalue is at least this many times it:
#: the preconditioned operator's eigenvalues on the uncomputed modes then lie in [1 - 1/1.25, 1], and CG
#: converges in a few tens of iterations.
ADMISSIBLE_MARGIN = 1.25


class DeflatedSolver:
    """Solves ``(K - sigma M) x = b`` for any admissible sigma with one factorisation (see module docstring).

    ``Phi`` (n, m) elastic modes with eigenvalues ``lam`` (m,), ``R`` (n, r)
    rigid modes (eigenvalue 0), all M-orthonormal; ``precond(b)`` applies
    ``(K - sigma_0 M)^-1`` (sigma_0 <= 0, SPD); ``lam_next`` a lower bound of
    the first eigenvalue not computed (the largest computed one).
    """

    def __init__(self, K: sp.spmatrix, M: sp.spmatrix, Phi: np.ndarray, lam: np.ndarray, R: np.ndarray,
                 precond, counters: Counters | None = None, *, rtol: float = 1e-12, maxiter: int = 300):
        self.K, self.M = K, M
        self._K_block, self._M_block = block_product(K), block_product(M)  # block products (PETSc)
        self.Psi = np.column_stack([R, Phi]) if R.shape[1] else Phi
        self.lam = np.concatenate([np.zeros(R.shape[1]), lam])
        self.n_rigid = R.shape[1]
        self.MPsi = self._M_block @ self.Psi
        self.precond = precond
        self.counters = counters
        self.rtol = rtol
        self.maxiter = maxiter
        self.lam_next = float(lam[-1]) if len(lam) else 0.0
        self.iterations: list[int] = []

    def admissible(self, sigma: float, margin: float = ADMISSIBLE_MARGIN) -> bool:
        """True when CG will converge fast: ``sigma`` at most ``lam_next / margin``."""
        return sigma * margin <= self.lam_next

    def _project_rhs(self, b: np.ndarray) -> np.ndarray:  # P^T b: remove the computed modes' part
        return b - self.MPsi @ (self.Psi.T @ b)

    def _project(self, x: np.ndarray) -> np.ndarray:  # P x: M-orthogonal to the computed modes
        return x - self.Psi @ (self.MPsi.T @ x)

    def solve(self, b: np.ndarray, sigma: float, exclude: Sequence[int] = ()) -> np.ndarray:
        """``x`` with ``(K - sigma M) x = b`` on every mode but the excluded ones.

        ``exclude`` lists columns of ``Psi`` (rigid modes first, then elastic
        ones) whose component of ``x`` is set to zero and whose component of
        ``b`` is ignored: the pseudo-inverse (sigma = 0, rigid excluded) and
        the bordered modal-derivative system (master and twins excluded).
        """
        coef = self._modal_coefficients(self.Psi.T @ b, sigma, exclude)
        return self.Psi @ coef + self._pcg(self._project_rhs(b), sigma)

    def solve_many(self, B: np.ndarray, sigmas: Sequence[float], excludes: Sequence[Sequence[int]]) -> np.ndarray:
        """``X`` (n, k): column j solves ``(K - sigmas[j] M) x = B[:, j]`` as :meth:`solve` with ``excludes[j]``.

        The k conjugate-gradient runs go in lockstep, so each iteration applies the preconditioner
        to every unconverged column in one block solve (MUMPS reads its factors once for all of
        them); each column stops on its own test, that of :meth:`solve`. The result equals k calls
        of :meth:`solve` up to round-off (sums in another order, the block solve's own rounding).
        """
        B = np.asarray(B, dtype=float)
        k = B.shape[1]
        if len(sigmas) != k or len(excludes) != k:
            raise ValueError(f"{k} right-hand sides, {len(sigmas)} shifts and {len(excludes)} exclusion lists")
        sig = np.asarray(sigmas, dtype=float)
        coef = np.zeros((len(self.lam), k))
        C = self.Psi.T @ B
        for j in range(k):
            coef[:, j] = self._modal_coefficients(C[:, j], sig[j], excludes[j])
        return self.Psi @ coef + self._pcg_many(self._project_rhs(B), sig)

    def _modal_coefficients(self, c: np.ndarray, sigma: float, exclude: Sequence[int]) -> np.ndarray:
        """The computed modes' part of the solution, ``c = Psi^T b`` (:meth:`solve`)."""
        if not self.admissible(sigma, 1.0):
            raise NumericalError(f"deflated solve: shift {sigma:.4g} is not below the computed spectrum "
                                 f"(largest computed eigenvalue {self.lam_next:.4g})")
        den = self.lam - sigma
        keep = np.ones(len(c), dtype=bool)
        keep[list(exclude)] = False
        if np.any(keep & (den == 0)):
            raise NumericalError(f"deflated solve: shift {sigma:.6g} is an eigenvalue of a mode not excluded")
        return np.where(keep, c / np.where(den == 0, 1.0, den), 0.0)

    def _pcg_many(self, R0: np.ndarray, sig: np.ndarray) -> np.ndarray:
        """:meth:`_pcg` for the columns of ``R0`` (shift ``sig[j]`` each), in lockstep."""
        X = np.zeros_like(R0)
        R = R0.copy()
        nb = np.linalg.norm(R0, axis=0)
        act = np.flatnonzero(nb > 0)
        if act.size == 0:
            return X
        D = np.zeros_like(R0)
        Z = self._apply_precond(R[:, act])
        D[:, act] = Z
        rz = np.zeros(R0.shape[1])
        rz[act] = np.einsum("ij,ij->j", R[:, act], Z)
        for it in range(1, self.maxiter + 1):
            Da = D[:, act]
            AD = self._project_rhs(self._K_block @ Da - (self._M_block @ Da) * sig[act])
            dAd = np.einsum("ij,ij->j", Da, AD)
            if np.any(dAd <= 0):
                raise NumericalError("deflated solve: K - sigma M is not positive on the uncomputed modes")
            alpha = rz[act] / dAd
            X[:, act] += Da * alpha
            R[:, act] -= AD * alpha
            if self.counters is not None:
                self.counters.linear_solves += act.size
            done = np.linalg.norm(R[:, act], axis=0) <= self.rtol * nb[act]
            self.iterations.extend([it] * int(done.sum()))
            act = act[~done]
            if act.size == 0:
                return X
            Z = self._apply_precond(R[:, act])
            rz_new = np.einsum("ij,ij->j", R[:, act], Z)
            D[:, act] = Z + D[:, act] * (rz_new / rz[act])
            rz[act] = rz_new
        worst = float(np.max(np.linalg.norm(R[:, act], axis=0) / nb[act]))
        raise NumericalError(f"deflated solve: CG did not converge in {self.maxiter} iterations "
                             f"(residual {worst:.1e})")

    def _apply_precond(self, R: np.ndarray) -> np.ndarray:
        """``P (K - sigma_0 M)^-1 P^T`` on the columns of ``R``: one block solve."""
        Z = self.precond(self._project_rhs(R))
        return self._project(Z.reshape(R.shape))

    def _pcg(self, r0: np.ndarray, sigma: float) -> np.ndarray:
        A = lambda v: self.K @ v - sigma * (self.M @ v)  # noqa: E731
        apply_p = lambda r: self._project(self.precond(self._project_rhs(r)))  # noqa: E731
        x = np.zeros_like(r0)
        r = r0.copy()
        nb = np.linalg.norm(r0)
        if nb == 0:
            return x
        z = apply_p(r)
        d = z.copy()
        rz = float(r @ z)
        for it in range(1, self.maxiter + 1):
            Ad = self._project_rhs(A(d))
            dAd = float(d @ Ad)
            if dAd <= 0:
                raise NumericalError("deflated solve: K - sigma M is not positive on the uncomputed modes")
            alpha = rz / dAd
            x += alpha * d
            r -= alpha * Ad
            if self.counters is not None:
                self.counters.linear_solves += 1
            if np.linalg.norm(r) <= self.rtol * nb:
                self.iterations.append(it)
                return x
            z = apply_p(r)
            rz_new = float(r @ z)
            d = z + (rz_new / rz) * d
            rz = rz_new
        raise NumericalError(f"deflated solve: CG did not converge in {self.maxiter} iterations "
                             f"(residual {np.linalg.norm(r) / nb:.1e})")

    def pinv(self, b: np.ndarray) -> np.ndarray:
        """``K^+ b``: the rigid modes left out (b's rigid part ignored, x M-orthogonal to them)."""
        return self.solve(b, 0.0, exclude=range(self.n_rigid))
