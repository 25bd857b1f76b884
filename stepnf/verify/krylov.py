"""Newton-Krylov for one implicit step when the model gives no tangent: ``J v`` by directional differences
of the forces, GMRES preconditioned by the factorisation of the modified iteration matrix.

Why: the modified Newton of :class:`stepnf.verify.integrate.EnergyConserving` iterates with
``J0 = (2 / dt^2) M + K / 2``. On a slender structure at tip deflections of a few thicknesses the
tangent ``Kt(x)`` differs from ``K`` by the membrane-bending coupling (``|Kt - K| / |K|`` ~ 2% on a
cantilever at ``W / h = 2``, L/h = 100, but on a few directions where ``J0^-1 J`` has eigenvalues up
to ~10 away from 1), and the modified iteration diverges along them whatever its acceleration. A
black-box solver (FEniCSx, an external program) offers no tangent, but ``J v`` is one batched call::

    J v = (2 / dt^2) M v + [2 Df(xm) v + Df(x1) v] / 6,
    Df(x) v ~ [f(x + e v) - f(x - e v)] / (2 e)            (the four fields in one call)

with ``e |v|_inf = DIFFERENCE_STEP * scale`` (central differences: truncation ``e^2`` relative to the
nonlinearity's length, round-off ``eps / e``; both near 1e-10 at 1e-6). Each Newton correction is
the solution of ``J dx = -r`` by ``lgmres`` (scipy) to a relative residual :data:`INNER_TOL`,
preconditioned by ``J0`` (its factorisation is already there), with the Krylov vectors of the
previous solves kept (``outer_v``: the few bad directions change slowly from one step to the next,
so later solves take fewer products). The residual and the stopping rule are those of the modified
Newton: the converged step is the same discrete solution, only reached differently.
"""
from __future__ import annotations

import inspect
from typing import Callable

import numpy as np
import scipy.sparse.linalg as spla

#: Directional-difference step relative to the state's scale (central differences, module docstring).
DIFFERENCE_STEP = 1e-6
#: Relative residual of each linear solve: Newton's error goes from e to ~INNER_TOL e + C e^2, so two or
#: three corrections take a step's first guess (modified step ~1e-5 of the state) to the 1e-10 tolerance.
INNER_TOL = 1e-4
#: Krylov products per linear solve at most (lgmres: inner restarts of INNER_M, outer augmentation).
INNER_M = 40
OUTER_K = 10

ForceBatch = Callable[[np.ndarray], np.ndarray]

_TOL_NAME = "rtol" if "rtol" in inspect.signature(spla.lgmres).parameters else "tol"  # scipy >= 1.12: rtol


class KrylovNewton:
    """Newton-Krylov on the energy-conserving step's residual (module docstring).

    ``M`` (n, n) the mass matrix; ``forces(U)`` (m, n) -> (m, n) the batched internal forces (counted by the
    caller's ``forces``); ``tol`` Newton's stopping increment relative to ``scale``; ``maxiter`` Newton
    corrections at most. :attr:`products` counts the Jacobian-vector products, :attr:`solves` the
    linear solves. One object per integrator: its Krylov memory carries over from step to step.
    """

    def __init__(self, M, forces: ForceBatch, *, tol: float, maxiter: int = 12):
        self.M, self.forces, self.tol, self.maxiter = M, forces, float(tol), int(maxiter)
        self.products = 0
        self.solves = 0
        self._outer: list = []

    def solve(self, x0: np.ndarray, v0: np.ndarray, f0: np.ndarray, x1: np.ndarray, dt: float, J0,
              scale: float) -> tuple[np.ndarray, np.ndarray, int, bool]:
        """``x1`` of the step from ``(x0, v0)`` (forces ``f0``), from the guess ``x1``; ``J0`` the factorised
        modified matrix (``.solve``). Returns ``(x1, f(x1), Newton iterations, converged)`` as
        :meth:`stepnf.verify.integrate.EnergyConserving._newton`."""
        n = len(x0)
        Mx = 2.0 / dt ** 2
        x1 = np.asarray(x1, dtype=float).copy()
        last = np.inf
        for it in range(1, self.maxiter + 1):
            xm = 0.5 * (x0 + x1)
            F = np.asarray(self.forces(np.stack([xm, x1])), dtype=float)
            r = Mx * (self.M @ (x1 - x0 - dt * v0)) + (f0 + 4.0 * F[0] + F[1]) / 6.0
            if not np.all(np.isfinite(r)):
                return x1, F[1], it, False

            def jv(v: np.ndarray, xm=xm, x1=x1) -> np.ndarray:
                v = np.asarray(v, dtype=float).ravel()
                size = float(np.abs(v).max())
                if size == 0.0:
                    return np.zeros(n)
                e = DIFFERENCE_STEP * scale / size
                D = np.asarray(self.forces(np.stack([xm + 0.5 * e * v, xm - 0.5 * e * v, x1 + e * v, x1 - e * v])),
                               dtype=float)
                self.products += 1
                # d f(xm)/d x1 = Df(xm) / 2: the xm fields move by e v / 2
                return Mx * (self.M @ v) + (4.0 * (D[0] - D[1]) + (D[2] - D[3])) / (12.0 * e)

            A = spla.LinearOperator((n, n), matvec=jv, dtype=float)
            P = spla.LinearOperator((n, n), matvec=lambda b: J0.solve(np.asarray(b, dtype=float).ravel()),
                                    dtype=float)
            self.solves += 1
            try:
                dx, _ = spla.lgmres(A, -r, M=P, atol=0.0, maxiter=2, inner_m=INNER_M, outer_k=OUTER_K,
                                    outer_v=self._outer, store_outer_Av=False, prepend_outer_v=True,
                                    **{_TOL_NAME: INNER_TOL})
            except (ValueError, ArithmeticError, np.linalg.LinAlgError):  # a product not finite
                dx = np.full(n, np.nan)
            size = float(np.abs(dx).max())
            if not np.isfinite(size):
                self._outer.clear()
                return x1, F[1], it, False
            x1 = x1 + dx
            if size <= self.tol * scale:
                return x1, np.asarray(self.forces(x1[None]), dtype=float)[0], it, True
            if it >= 4 and size > 0.5 * last:  # not converging (quadratically, or at all)
                return x1, F[1], it, False
            last = size
        return x1, F[1], self.maxiter, False
