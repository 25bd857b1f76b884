"""The ``truss`` solver adapter: a pin-jointed space truss of St Venant-Kirchhoff bars.

Each bar (nodes ``a`` and ``b``, reference vector ``d0 = X_b - X_a`` of length
``L0``, axial stiffness ``EA``) carries the Green-Lagrange strain of its
displacement difference ``du = u_b - u_a``::

    e = (d0 . du + du . du / 2) / L0^2        N = EA e
    force on node b = N (d0 + du) / L0 = -(force on node a)

The force is the gradient of the energy ``sum EA L0 e^2 / 2``: it is
conservative and *exactly* cubic in the displacements, so STEP recovers its
quadratic and cubic terms to round-off. The mass matrix is the consistent one
of linear bars (``rho A L0 / 6 [[2, 1], [1, 2]]`` per direction). Units are
the scene's: lengths, ``E`` (force per area), ``area`` and ``rho`` (mass per
volume) in any consistent system (SI in the example scene).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.plugin import BOUNDARY_KEY, FreeDofs, Key, Schema, SolverAdapter, boundary_conditions, fixed_dofs

from .geometry import arched_box_truss


# [guide:keys]
#: The ``[model]`` keys (``stepnf solvers --keys truss``); defaults are the constructor's.
MODEL_KEYS = Schema(
    Key("span", "number", "length of the arch (x)", default=10.0, lo=0, lo_open=True),
    Key("rise", "number", "height of the top chord at mid-span above the supports", default=1.0, lo=0),
    Key("depth", "number", "distance between the top and bottom chords (z)", default=0.5, lo=0, lo_open=True),
    Key("width", "number", "distance between the two sides of the box (y)", default=0.5, lo=0, lo_open=True),
    Key("panels", "integer", "number of panels along the span", default=8, lo=1, hi=1000),
    Key("E", "number", "Young's modulus of the bars (force / length^2)", default=2.1e11, lo=0, lo_open=True),
    Key("area", "number", "cross-section area of every bar (length^2)", default=1e-4, lo=0, lo_open=True),
    Key("rho", "number", "density of the bars (mass / length^3)", default=7850.0, lo=0, lo_open=True),
    BOUNDARY_KEY,  # [[model.boundary]]: node sets "left", "right", "ends", or boxes
)
# [/guide:keys]


# [guide:class]
class TrussAdapter(SolverAdapter):
    """A pin-jointed arched box truss (see the module docstring); in-process, numpy and scipy only."""

    name = "truss"
    model_keys = MODEL_KEYS
    provides_tangent_stiffness = True   # tangent_stiffness(u) below
    provides_intrusive_tensors = True   # quadratic_force and cubic_force below: exact G and H
# [/guide:class]

    # [guide:init]
    def __init__(self, span: float = 10.0, rise: float = 1.0, depth: float = 0.5, width: float = 0.5,
                 panels: int = 8, E: float = 2.1e11, area: float = 1e-4, rho: float = 7850.0,
                 boundary: Sequence[Mapping[str, Any]] = (), scene_file: Path | None = None):
        self.truss = arched_box_truss(span, rise, depth, width, panels)
        points, bars = self.truss.points, self.truss.bars
        a, b = bars[:, 0], bars[:, 1]
        self.d0 = points[b] - points[a]                       # reference bar vectors (m, 3)
        self.L0 = np.linalg.norm(self.d0, axis=1)             # reference lengths (m,)
        self.EA = np.full(len(bars), E * area)                # axial stiffness (force)
        self.bar_mass = rho * area * self.L0                  # mass of each bar
        m, nn = len(bars), len(points)
        # incidence C (m, nn): (C @ U)[e] = U[b] - U[a] for nodal fields U (nn, 3)
        self.C = sp.csr_matrix((np.r_[-np.ones(m), np.ones(m)], (np.r_[np.arange(m), np.arange(m)], np.r_[a, b])),
                               shape=(m, nn))
        # zero displacements on node sets or boxes (stepnf.plugin.boundary): those dofs are removed
        bcs = boundary_conditions(boundary, scene_file)
        fixed = fixed_dofs(bcs, points, self.truss.node_sets, scene_file)
        self.free = FreeDofs(3 * nn, fixed)
        self.config = {"span": span, "rise": rise, "depth": depth, "width": width, "panels": panels,
                       "E": E, "area": area, "rho": rho, "boundary": [dict(c) for c in boundary]}
    # [/guide:init]

    # [guide:from_config]
    @classmethod
    def from_config(cls, config: Mapping[str, Any], *, base_dir: Path,
                    scene_file: Path | None = None) -> "TrussAdapter":
        """Build from the scene's ``[model]`` table: the keys are checked first (a SceneError naming
        the key), then the scene file is passed on so that a boundary condition naming an unknown
        node set is reported against it."""
        checked = cls.validate_config(config, base_dir=base_dir, scene_file=scene_file)
        return cls(**checked, scene_file=scene_file)
    # [/guide:from_config]

    # [guide:matrices]
    @property
    def n_dofs(self) -> int:
        return self.free.n_free

    def mass_matrix(self) -> sp.csr_matrix:
        """Consistent mass: per bar ``bar_mass / 6 [[2, 1], [1, 2]]`` in each direction."""
        S = abs(self.C)                                        # +1 at both ends of each bar
        w = self.bar_mass / 6
        Mn = S.T @ sp.diags(w) @ S + sp.diags(S.T @ w)         # node-by-node (nn, nn)
        return self.free.restrict_matrix(sp.kron(Mn, sp.identity(3)))

    def stiffness_matrix(self) -> sp.csr_matrix:
        """``K = df/du(0)``: the tangent at the reference configuration."""
        return self.tangent_stiffness(np.zeros(self.n_dofs))
    # [/guide:matrices]

    # [guide:forces]
    def bar_states(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Deformed bar vectors ``d`` (m, 3) and Green-Lagrange strains ``e`` (m,) for free dofs ``u``."""
        du = self.C @ self.free.expand(u).reshape(-1, 3)
        e = (np.einsum("ij,ij->i", self.d0, du) + 0.5 * np.einsum("ij,ij->i", du, du)) / self.L0**2
        return self.d0 + du, e

    def nodal(self, P: np.ndarray) -> np.ndarray:
        """Free-dof forces from end forces ``P`` (m, 3) acting on node b (and ``-P`` on node a)."""
        return self.free.restrict((self.C.T @ P).ravel())

    def _internal_force(self, u: np.ndarray) -> np.ndarray:
        d, e = self.bar_states(u)
        N = self.EA * e                                        # axial force of each bar
        return self.nodal((N / self.L0)[:, None] * d)          # the sign of K u: M x'' + f(x) = 0
    # [/guide:forces]

    # [guide:geometry]
    def dof_coordinates(self) -> np.ndarray:
        return self.truss.points[self.free.free // 3]          # (n, 3): the node of each free dof

    def dof_directions(self) -> np.ndarray:
        return self.free.free % 3                              # 0, 1, 2 = ux, uy, uz

    def free_dof_map(self) -> FreeDofs | None:
        return None if self.free.all_free else self.free
    # [/guide:geometry]

    # [guide:optional]
    def tangent_stiffness(self, u: np.ndarray) -> sp.csr_matrix:
        """``df/du`` at ``u``: material part ``EA/L0 (d/L0)(d/L0)^T`` plus geometric part ``N/L0 I``."""
        d, e = self.bar_states(u)
        m, nn = self.C.shape
        rows = np.repeat(np.arange(m), 6)
        cols = (3 * self.truss.bars[:, :, None] + np.arange(3)).reshape(m, 6).ravel()
        B = sp.csr_matrix(((np.c_[-d, d] / self.L0[:, None]).ravel(), (rows, cols)), shape=(m, 3 * nn))
        geometric = sp.kron(self.C.T @ sp.diags(self.EA * e / self.L0) @ self.C, sp.identity(3))
        return self.free.restrict_matrix(B.T @ sp.diags(self.EA / self.L0) @ B + geometric)

    def quadratic_force(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Exact ``G(u, v)``: ``EA / (2 L0^3) [(d0.du) dv + (d0.dv) du + (du.dv) d0]`` per bar."""
        du, dv = (self.C @ self.free.expand(x).reshape(-1, 3) for x in (u, v))
        dot = lambda p, q: np.einsum("ij,ij->i", p, q)[:, None]  # noqa: E731
        c = (self.EA / (2 * self.L0**3))[:, None]
        return self.nodal(c * (dot(self.d0, du) * dv + dot(self.d0, dv) * du + dot(du, dv) * self.d0))

    def cubic_force(self, u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Exact ``H(u, v, w)``: ``EA / (6 L0^3) [(du.dv) dw + (du.dw) dv + (dv.dw) du]`` per bar."""
        du, dv, dw = (self.C @ self.free.expand(x).reshape(-1, 3) for x in (u, v, w))
        dot = lambda p, q: np.einsum("ij,ij->i", p, q)[:, None]  # noqa: E731
        c = (self.EA / (6 * self.L0**3))[:, None]
        return self.nodal(c * (dot(du, dv) * dw + dot(du, dw) * dv + dot(dv, dw) * du))
    # [/guide:optional]

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), **self.config, "nodes": len(self.truss.points),
                "bars": len(self.truss.bars), "fixed_dofs": int(self.free.fixed.size)}
