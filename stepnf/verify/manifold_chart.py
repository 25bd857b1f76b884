"""A run's manifold of several master modes read back for ``stepnf verify``, and the distance of a state from it.

The run keeps each manifold's coefficients and each master's branches as arrays (HDF5 ``arrays/``,
:mod:`stepnf.pipeline.manifolds`): ``backbone_<s>_manifold_*`` once, under the master ``s`` its masters' blocks
name (``manifold.stored_with``), and ``backbone_<p>_branch<i>_*`` per master ``p`` (i = 0 the branch that continues
its mode when it has one, then the coupled ones, in the order of the block's ``branch`` and ``coupled_branches``).
:func:`manifold_of` and :func:`branches_of` rebuild the :class:`~stepnf.dpim.multimode.manifold.ManifoldResult` and
the :class:`~stepnf.dpim.multimode.branches.Branch` es from them (the arrays hold the coefficients as they were:
the same numbers, no recomputation).

:class:`ManifoldChart`: the point ``(W(z), V(z))`` of the manifold with the same masters' coordinates and rates as a
state ``(x, v)``: ``phi_l^T M W(z) = phi_l^T M x``, ``phi_l^T M V(z) = phi_l^T M v`` for every master l (2m real
equations in ``zeta`` in C^m, ``z = (zeta, conj zeta)``; Newton from a guess, its Jacobian by central differences),
and the distance as for single-mode backbones (:class:`stepnf.verify.command.Chart`): the energy norm
``sqrt(dx^T K dx + dv^T M dv)`` over ``sqrt(x^T K x + v^T M v)``.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from stepnf.dpim.multimode.branches import Branch
from stepnf.dpim.multimode.manifold import ManifoldResult
from stepnf.dpim.multimode.monomials import powers
from stepnf.errors import NumericalError


def manifold_of(arrays: dict, stored_with: int, M: Any) -> ManifoldResult:
    """The manifold stored under master ``stored_with`` (module docstring); ``M`` the model's mass matrix."""
    def g(key: str) -> np.ndarray:
        name = f"backbone_{stored_with}_manifold_{key}"
        if name not in arrays:
            raise NumericalError(f"verify: the run kept no array {name} (the manifold's coefficients)")
        return np.asarray(arrays[name])
    keys = [tuple(int(t) for t in a) for a in g("index")]
    W, V = g("W_re") + 1j * g("W_im"), g("V_re") + 1j * g("V_im")
    f = {(int(r[0]), tuple(int(t) for t in r[1:])): complex(a, b)
         for r, a, b in zip(g("f_index"), g("f_re"), g("f_im"))}
    k = g("ratios").astype(int)
    return ManifoldResult(tuple(int(q) for q in g("masters")), g("omega").astype(float), g("phi").astype(float), M,
                          int(g("order")), dict(zip(keys, W)), dict(zip(keys, V)), f, k if k.any() else None)


def branches_of(arrays: dict, p: int, block: dict) -> list[Branch]:
    """Master ``p``'s branches from the arrays, named and with the validity of its ``backbone`` ``block``."""
    listed = ([block["branch"]] if block.get("branch") else []) + list(block.get("coupled_branches") or [])
    out = []
    for i, js in enumerate(listed):
        def g(key: str, i: int = i) -> np.ndarray:
            name = f"backbone_{p}_branch{i}_{key}"
            if name not in arrays:
                raise NumericalError(f"verify: the run kept no array {name} (branch {i} of master mode {p})")
            return np.asarray(arrays[name])
        valid = js.get("valid_up_to")
        turned = f"backbone_{p}_branch{i}_rotations"  # the rotations a standing wave of exact twins was traced with
        out.append(Branch(g("Omega").astype(float), g("zeta_re") + 1j * g("zeta_im"), g("A").astype(float),
                          g("stable").astype(bool), str(js["kind"]), tuple(int(q) for q in g("masters")),
                          g("ratios").astype(int), int(g("mode")), eps=g("eps").astype(float),
                          branch_points=[int(b) for b in g("branch_points")],
                          valid_A=None if valid is None else float(valid),
                          valid_reason=str(js.get("valid_reason", "")),
                          rotations=np.asarray(arrays[turned], dtype=float) if turned in arrays else None,
                          closed=bool(js.get("closed", False))))
    return out


class ManifoldChart:
    """The manifold's point with a state's masters' coordinates and rates, and the distance (module docstring).

    ``manifold``: a :class:`~stepnf.dpim.multimode.manifold.ManifoldResult`; ``K``, ``M`` (n, n) for the norm.
    """

    def __init__(self, manifold: ManifoldResult, K: Any, M: Any):
        self.man, self.K, self.M = manifold, K, M
        self.m = len(manifold.masters)
        self.MPhi = np.asarray(M @ np.asarray(manifold.phi)).reshape(-1, self.m)
        self.keys = list(manifold.W)
        # the coefficients stacked once (terms, n): a large model's fields are not gathered again at every state
        self.Wm = np.asarray([manifold.W[a] for a in self.keys])
        self.Vm = np.asarray([manifold.V[a] for a in self.keys])
        self.Pq = self.MPhi.T @ self.Wm.T  # (m, terms)
        self.Pv = self.MPhi.T @ self.Vm.T

    def coordinates(self, zeta: np.ndarray) -> np.ndarray:
        """``(phi^T M W(z), phi^T M V(z))`` (2m,) real at ``z = (zeta, conj zeta)``."""
        z = np.concatenate([zeta, np.conj(zeta)])[None, :]
        P = powers(z, self.keys)[0]
        return np.concatenate([(self.Pq @ P).real, (self.Pv @ P).real])

    def locate(self, q: np.ndarray, qd: np.ndarray, guess: np.ndarray) -> np.ndarray:
        """``zeta`` (m,) with the masters' coordinates ``q`` and rates ``qd`` (m,), Newton from ``guess``."""
        m = self.m
        target = np.concatenate([q, qd])
        scale = max(float(np.abs(target).max()), 1e-300)
        u = np.concatenate([guess.real, guess.imag])
        zeta = lambda s: s[:m] + 1j * s[m:]  # noqa: E731
        for _ in range(40):
            r = self.coordinates(zeta(u)) - target
            if np.abs(r).max() <= 1e-13 * scale:
                return zeta(u)
            h = 1e-7 * max(float(np.abs(u).max()), 1e-300)
            J = np.column_stack([(self.coordinates(zeta(u + h * e)) - self.coordinates(zeta(u - h * e))) / (2 * h)
                                 for e in np.eye(2 * m)])
            try:
                u = u - np.linalg.solve(J, r)
            except np.linalg.LinAlgError:
                break
        raise NumericalError(f"verify: no point of the manifold of modes {list(self.man.masters)} has the masters' "
                             f"coordinates {np.round(q, 6).tolist()} and rates {np.round(qd, 6).tolist()} (the orbit "
                             "left the parametrisation's range)")

    def distance(self, x: np.ndarray, v: np.ndarray, guess: np.ndarray) -> tuple[float, np.ndarray]:
        """``(relative energy-norm distance, zeta)`` of the state ``(x, v)`` from the manifold (module docstring);
        ``guess``: a ``zeta`` near the answer (the reduced orbit's point at the same time)."""
        zeta = self.locate(self.MPhi.T @ x, self.MPhi.T @ v, guess)
        P = powers(np.concatenate([zeta, np.conj(zeta)])[None, :], self.keys)[0]
        dx, dv = x - (P @ self.Wm).real, v - (P @ self.Vm).real
        num = float(dx @ (self.K @ dx)) + float(dv @ (self.M @ dv))
        den = float(x @ (self.K @ x)) + float(v @ (self.M @ v))
        return (float(np.sqrt(max(num, 0.0) / den)) if den > 0 else 0.0), zeta
