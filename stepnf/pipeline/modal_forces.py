"""The internal forces of a model in modal coordinates, for the modal DPIM backbone.

A :class:`~stepnf.plugin.modal_model.ModalModel` hands the normal-form evaluators only ``g^s_pp`` and
``h^p_ppp``; a parametrisation to order N needs the whole force ``f(X) = diag(omega^2) X + g(X, X) +
h(X, X, X)``. :func:`modal_system` gives it, batched, for:

* a model with a method ``internal_forces(X)`` ((k, m) -> (k, m), its own modal forces) over all its
  modes;
* the von Karman shell (:class:`stepnf.models.vonkarman.VonKarmanShell`), from its Galerkin data: the
  potential ``V = 1/2 sum omega_s^2 X_s^2 + eps_c sum_b [beta_b^2 / 8 - sqrt(kappa) a_b beta_b / 2] / xi_b^4``
  with ``a_b = A_b(w)``, ``beta_b = B_b(w, w)``, ``w = sum X_s phi_s`` (the paper's potential
  ``1/2 sum omega_plate^2 X^2 + eps_c/2 sum xi_b^4 f_b^2`` with the Airy coefficients
  ``f_b = (sqrt(kappa) a_b - beta_b / 2) / xi_b^4`` eliminated, its quadratic part written in the shell
  modes), so ``f = grad V``::

      f_s = omega_s^2 X_s + eps_c sum_b [beta_b / 2 - sqrt(kappa) a_b] B_b(phi_s, w) / xi_b^4
                          - eps_c sqrt(kappa) / 2 sum_b beta_b A_b(phi_s) / xi_b^4

  whose ``g^s_pp`` and ``h^p_ppp`` are the model's (tests/dpim/test_backbone_modal.py). Over the modes a cos
  master drives by symmetry only: the cos companions of ``k = j k_p`` (``k_p = 0``: the axisymmetric
  modes), an invariant subspace of the model (``L`` of two such fields holds only cos harmonics
  ``j k_p``); a sin master is the rotation of its cos twin, which has the same backbone, so the twin's
  subspace is used. The truncation is the model's own (``k <= k_max``, ``n_transverse`` per k).

``W_max / h`` (h = 1: the model's displacement is ``w / h``): ``max |sum X_s phi_s(r, theta)|`` over a
polar grid (:data:`RADII` radii; :data:`ANGLES` angles over ``[0, pi / k_p]``, where a cos field of
harmonics ``j k_p`` is even and periodic), so it is a grid maximum: below the true one by at most
about ``dr^2 |R''| / (8 R) ~ 4e-5`` relative (``dr = 1/400``, ``|R''/R| <~ 50`` for these modes; the
peak of the cos fields lies at an angle of the grid, 0 or ``pi / k_p``).

The Galerkin data come from :meth:`stepnf.models.vonkarman.VonKarmanShell.galerkin`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from stepnf.models._couplings import trilinear
from stepnf.models._quadrature import angular_factors

#: The polar grid of W_max / h.
RADII, ANGLES = 401, 33


@dataclass
class ModalSystem:
    """A modal model restricted to the modes ``index`` (global positions) that master ``local`` drives.

    ``omega`` (m,) their angular frequencies; ``forces(X)`` (k, m) -> (k, m); ``transverse(Y)`` (m, j) ->
    (t, j): ``w / h`` of the fields on a grid (None when unknown).
    """

    index: np.ndarray
    local: int
    omega: np.ndarray
    forces: Callable[[np.ndarray], np.ndarray]
    transverse: Callable[[np.ndarray], np.ndarray] | None = None


def modal_system(model: Any, p: int) -> ModalSystem | None:
    """The :class:`ModalSystem` of master ``p``, or None when the model gives no forces (module docstring)."""
    omega = np.asarray(model.omegas(), dtype=float)
    own = getattr(model, "internal_forces", None)
    if callable(own):
        return ModalSystem(np.arange(len(omega)), p, omega, own)
    if not callable(getattr(model, "galerkin", None)):
        return None
    return VonKarmanForces(model, p).system()


def modal_subspace(model: Any, p: int) -> np.ndarray | None:
    """The global modes of :func:`modal_system`'s system of master ``p`` (for a sin master, its cos twin's),
    without forming its forces; None when the model gives no forces."""
    if callable(getattr(model, "internal_forces", None)):
        return np.arange(len(model.omegas()))
    if not callable(getattr(model, "galerkin", None)):
        return None
    return subspace(model.galerkin(), p)[2]


def subspace(gd: Any, p: int) -> tuple[int, list[int], np.ndarray]:
    """The von Karman shell's invariant subspace of master ``p`` (Galerkin data ``gd``; module docstring): its
    cos master (``p``, or the cos twin of a sin ``p``), the nodal-diameter numbers ``k = j k_p`` it holds and its
    global modes (the cos companions of those k, by k then n)."""
    _, kp, _, _, j = gd.rows[p]
    ks = [0] if kp == 0 else [k for k in range(0, gd.k_max + 1, kp)]
    ks = [k for k in ks if k in gd.families]
    index = np.asarray([gd.index[(k, i, "cos")] for k in ks for i in range(len(gd.families[k].omega))])
    return int(gd.index[(kp, j, "cos")]), ks, index


class VonKarmanForces:
    """The von Karman shell's modal forces over the invariant subspace of master ``p`` (module docstring)."""

    def __init__(self, model: Any, p: int):
        self.model = model
        self.data = gd = model.galerkin()
        kp = self.kp = int(gd.rows[p][1])
        # the cos master (itself, or the cos twin of a sin master)
        self.master, self.ks, self.index = subspace(gd, p)
        kb_top = 2 * max(self.ks)
        self.kbs = [0] if kp == 0 else [k for k in range(0, kb_top + 1, kp) if k in gd.airy_radial]
        self._tensors()

    def _tensors(self) -> None:
        """Every Airy class kb (cos) side by side, ``nb`` the Airy functions of all classes: :attr:`B` (nb * m, m),
        rows ``(b, i)``, ``B_b(phi_i, phi_j)`` (symmetrised); :attr:`A` (nb, m) ``A_b(phi_s)`` (zero unless
        ``k_s = kb``); :attr:`inv_xi4` (nb,) ``1 / xi_b^4``. The classes' sums are then one sum over ``b``."""
        md = self.data
        sizes = [len(md.families[k].omega) for k in self.ks]
        offs = np.concatenate([[0], np.cumsum(sizes)])
        m = int(offs[-1])
        Bs, As, xi4 = [], [], []
        for kb in self.kbs:
            nb = md.airy_radial[kb].shape[0]
            B = np.zeros((nb, m, m))
            for a, ki in enumerate(self.ks):
                for b, kj in enumerate(self.ks):
                    ang = angular_factors(("cos", kb), ("cos", ki), ("cos", kj))
                    if ang == (0.0, 0.0):
                        continue
                    B[:, offs[a]:offs[a + 1], offs[b]:offs[b + 1]] = trilinear(
                        md.airy_radial[kb], md.families[ki].f, ki, md.families[kj].f, kj, md.r, md.w, ang)
            A = np.zeros((nb, m))
            if kb in self.ks:
                a = self.ks.index(kb)
                A[:, offs[a]:offs[a + 1]] = md.families[kb].A
            Bs.append(0.5 * (B + B.transpose(0, 2, 1)))
            As.append(A)
            xi4.append(np.asarray(md.xi4[kb], dtype=float))
        self.B = np.ascontiguousarray(np.concatenate(Bs).reshape(-1, m))
        self.A = np.concatenate(As)
        self.inv_xi4 = 1.0 / np.concatenate(xi4)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """``f(X)`` (k, m) for modal fields ``X`` (k, m) over :attr:`index` (module docstring): one product with
        every class's ``B`` at once."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        md = self.data
        root, eps = math.sqrt(md.kappa), md.eps_c
        B, A, inv = self.B, self.A, self.inv_xi4
        k, m = X.shape
        Bw = (X @ B.T).reshape(k, -1, m)                                 # B_b(phi_i, w)   (k, nb, m)
        beta = np.einsum("kbi,ki->kb", Bw, X)                              # B_b(w, w)       (k, nb)
        a = X @ A.T                                                        # A_b(w)          (k, nb)
        out = X * md.omega[self.index] ** 2
        out += eps * np.einsum("kb,kbi->ki", (0.5 * beta - root * a) * inv, Bw)
        out -= (0.5 * eps * root) * ((beta * inv) @ A)
        return out

    def tangent(self, x: np.ndarray) -> np.ndarray:
        """``Df(x)`` (m, m), the tangent stiffness of one modal field ``x`` (m,): the Hessian of the module
        docstring's potential, ``diag(omega^2) + eps_c sum_b [c_b B_b + (B_b w)(B_b w - sqrt(kappa) A_b)^T / xi_b^4
        - sqrt(kappa) A_b (B_b w)^T / xi_b^4]`` with ``c_b = (beta_b / 2 - sqrt(kappa) a_b) / xi_b^4`` (symmetric:
        ``B_b`` is)."""
        x = np.asarray(x, dtype=float)
        md = self.data
        root, eps = math.sqrt(md.kappa), md.eps_c
        B, A, inv = self.B, self.A, self.inv_xi4
        m = len(x)
        Bw = (B @ x).reshape(-1, m)                                        # (nb, m)
        c = (0.5 * (Bw @ x) - root * (A @ x)) * inv                        # (nb,)
        J = (c @ B.reshape(-1, m * m)).reshape(m, m)
        J += (Bw.T * inv) @ (Bw - root * A) - root * (A.T * inv) @ Bw
        J *= eps
        J[np.diag_indices(m)] += md.omega[self.index] ** 2
        return J

    def transverse(self) -> Callable[[np.ndarray], np.ndarray]:
        """``Y`` (m, j) -> ``w / h`` (t, j) on the polar grid (module docstring)."""
        md, gd = self.model, self.data
        r = np.linspace(0.0, 1.0, RADII)
        th = np.zeros(1) if self.kp == 0 else np.linspace(0.0, np.pi / self.kp, ANGLES)
        R = np.asarray([md.radial_shape(int(s), r) for s in self.index])       # (m, nr)
        ks = np.asarray([gd.rows[int(s)][1] for s in self.index])
        C = np.cos(np.outer(ks, th))                                            # (m, nt)
        Phi = (R[:, :, None] * C[:, None, :]).reshape(len(self.index), -1).T    # (t, m)
        last: dict[bytes, np.ndarray] = {}

        def op(Y: np.ndarray) -> np.ndarray:  # the same coefficients come again at every rho: keep the last
            Y = np.ascontiguousarray(Y)  # real, or complex (a manifold's W[alpha]: Phi is real, so is linear)
            Y = Y if np.iscomplexobj(Y) else Y.astype(float, copy=False)
            key = Y.tobytes() + bytes(str(Y.shape) + Y.dtype.str, "ascii")
            if key not in last:
                last.clear()
                last[key] = Phi @ Y
            return last[key]

        return op

    def system(self) -> ModalSystem:
        local = int(np.flatnonzero(self.index == self.master)[0])
        return ModalSystem(self.index, local, self.data.omega[self.index].copy(), self, self.transverse())
