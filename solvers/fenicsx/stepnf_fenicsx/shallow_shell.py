"""The ``fenicsx_shell`` adapter: a Marguerre (von Karman) shallow spherical shell with FEniCSx (serial).

The finite-element counterpart of the paper's analytical model (its
section 2.1), an independent route to the same equations: in-plane
displacements ``(u, v)`` and transverse deflection ``w`` on the plan-view disk
of radius ``a``, mid-surface ``z0 = -(x^2 + y^2) / (2 R)``, free edge (or
clamped, or simply supported: see "Edge conditions" below); strain
energy and discretisation in :mod:`stepnf_fenicsx.shallow_shell_forms`
(membrane strain with the Marguerre term, bending by a C0 interior-penalty
method on continuous P3 (or P2) ``w``). The internal force is an exact cubic.
Mesh: curved 6-node triangles on concentric rings
(:mod:`stepnf_fenicsx.shallow_shell_mesh`, numpy only).

Dofs: one blocked P3 (or P2) space, node-major ``(u, v, w)`` of node 0, node
1, ... (``dof_directions`` = 0, 1, 2 repeated); ``dof_coordinates`` puts each
node on the mid-surface ``(x, y, z0(x, y))``. With these coordinates the six
rigid motions of :func:`stepnf.linalg.modal_analysis.rigid_body_fields` are *exact*
zero-energy fields of the discrete model (a rotation about ``e_y`` is
``w = -x``, ``u = z0`` up to a translation, which makes the linear membrane
strain vanish; the forms use the interpolant of z0 for this), so the model
has exactly six rigid-body modes and the pipeline's rigid detection finds them.

In-plane inertia (``inplane_inertia``): the von Karman equations neglect it
(quasi-static in-plane motion). A zero in-plane mass would make ``M``
singular (no M-normalised in-plane rigid modes), so ``inplane_inertia =
false`` (default) scales the in-plane kinetic energy by
:data:`INPLANE_MASS_FACTOR` = 1e-3 instead: the in-plane modes move up by
``1/sqrt(1e-3) = 32`` (to w_bar > 8000 for a = 50 h), which changes the NF/DNF
denominators ``w_s^2 - 4 w_p^2`` of the in-plane modes by
``4 w_p^2 / w_s^2 < 1e-4`` relative for w_bar_p < 40 (measured: Gamma of the
six test modes moves by < 1e-4 relative between the factors 1e-3, 1e-4 and 1e-6).
``inplane_inertia = true`` is the Marguerre shell with full inertia
``rho h (u'^2 + v'^2 + w'^2)``.

Edge conditions: the scene's ``[[model.boundary]]`` with ``set = "edge"`` (the
rim of the disk: its boundary facets and every dof on them), the only set of
this model. Every dof (the default) clamps the edge: ``u = v = w = 0`` at the
rim's dofs (removed from the model, so ``w`` and its tangential slope vanish
along the whole curved edge) and the normal slope ``dw/dn = 0`` weakly, by the
boundary terms of the interior-penalty method
(:mod:`stepnf_fenicsx.shallow_shell_forms`); the von Karman clamped edge.
``dofs = ["uz"]`` supports the edge simply (``w = 0``; slope and in-plane
displacements free, ``M_nn = 0`` natural), which leaves the three in-plane
rigid motions. Boxes and other dof lists are refused (:class:`SceneError`):
``["ux", "uy"]`` would need the slope fixed without ``w``, which a shell edge
condition does not express.

Units: those of the scene (SI for the examples); frequencies in rad/s.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.boundary import DOF_NAMES, BoundaryCondition, FreeDofs, select_nodes
from stepnf.errors import SceneError

from . import _compat
from ._forms_adapter import FormsAdapter
from .constraints import as_conditions, describe_conditions
from .labels import ModeLabeler, count_edge_circle
from .shallow_shell_config import DEFAULTS, MODEL_KEYS, parse_shell_model
from .shallow_shell_mesh import disk_triangle6

#: In-plane mass factor used when ``inplane_inertia = false`` (see the module docstring). Not
#: smaller: stepnf's coupling floor (``tol.coupling`` times the lumped ``M^-1`` norm of
#: ``G(phi_p, phi_p)``) grows like ``factor^-1/2`` through the in-plane rows and, at 1e-6, hides
#: the 1:2 resonance flags of (2,1) (kappa = 10, 25) and (4,0) (kappa = 25); not larger: the
#: error ``4 w_p^2 / w_s^2`` grows like the factor (1e-2: 8e-4 on Gamma of (2,0) at kappa = 25).
INPLANE_MASS_FACTOR = 1e-3


def _create_disk_mesh(points: np.ndarray, cells: np.ndarray):
    """A serial dolfinx mesh of ``triangle6`` cells (VTK order) with quadratic geometry."""
    return _compat.create_mesh(points, cells, "triangle6")[0]


#: The edge conditions of the shell: the directions fixed on its rim -> the condition's name.
EDGE_CONDITIONS = {(0, 1, 2): "clamped", (2,): "simply supported"}


def shell_edge(bcs: Sequence[BoundaryCondition], points: np.ndarray, a: float, scene_file=None) -> str:
    """``"free"``, ``"clamped"`` or ``"simply supported"``: the edge condition that ``bcs`` give the disk of
    radius ``a`` (mesh ``points``), or a :class:`SceneError` naming the key it cannot honour."""
    if not bcs:
        return "free"
    rim = np.flatnonzero(np.abs(np.hypot(points[:, 0], points[:, 1]) - a) <= 1e-9 * a)
    xyz = np.column_stack([points[:, :2], np.zeros(len(points))])
    dofs: set[int] = set()
    for bc in bcs:
        if bc.box is not None:
            raise SceneError(scene_file, f"{bc.where}.box", 'fenicsx_shell takes set = "edge" only (the rim of '
                             "its disk mesh); select nodes by box on a 3D solid mesh (solver = \"fenicsx\")")
        select_nodes(bc, xyz, {"edge": rim}, scene_file)  # an unknown set: the message lists "edge"
        dofs.update(bc.dofs)
    kind = EDGE_CONDITIONS.get(tuple(sorted(dofs)))
    if kind is None:
        raise SceneError(scene_file, f"{bcs[-1].where}.dofs",
                         'the edge of fenicsx_shell takes dofs = ["ux", "uy", "uz"] (clamped: u = v = w = 0, '
                         'dw/dn = 0) or ["uz"] (simply supported: w = 0), not '
                         + json.dumps([DOF_NAMES[d] for d in sorted(dofs)]))
    return kind


def _lattice(order: int) -> np.ndarray:
    """Points ``(s, t)`` of the reference triangle on a lattice of the given order."""
    i, j = np.meshgrid(np.arange(order + 1), np.arange(order + 1), indexing="ij")
    keep = i + j <= order
    return np.column_stack([i[keep], j[keep]]) / order


class ShallowShellAdapter(FormsAdapter):
    """Free-edge Marguerre shallow shell (flat plate for ``R = inf``) with FEniCSx.

    Parameters
    ----------
    a, R, h : projected outer radius, radius of curvature (``inf``: plate), thickness
    E, nu, rho : Young's modulus, Poisson ratio, density
    n_rings, grading : mesh resolution (:func:`stepnf_fenicsx.shallow_shell_mesh.disk_triangle6`);
        12 rings (11 991 dofs with P3): frequencies of the first 24 modes within 3e-5 of the
        von Karman model, Gamma of the six test modes within 0.02% (0.13% for (0,2))
    inplane_inertia : keep the in-plane kinetic energy (False: von Karman's quasi-static in-plane motion)
    penalty : interior-penalty factor alpha (penalty ``alpha D / h_F`` on the slope jumps, h_F the
        mean diameter of the two cells); see :mod:`stepnf_fenicsx.shallow_shell_forms` for the choice 10
    degree : polynomial degree of ``u, v, w`` (3: P3, frequency errors O(h^4); 2: P2, O(h^2):
        at 5 403 dofs, (4,0) is 7e-3 off with P2 and 3e-5 with P3)
    quadrature_degree : of the cell integrals (default ``2 degree``: exact mass and linear stiffness
        on straight cells; f stays an exact cubic of the dofs whatever the rule)
    boundary : the edge conditions (see the module docstring): :class:`stepnf.plugin.boundary.BoundaryCondition` s
        or ``[[model.boundary]]`` tables (``{"set": "edge"}``: clamped); none: free edge
    scene_file : the scene, named by messages about ``boundary``

    Mode shapes, dofs and forces are in the units of the arguments (SI in the examples).
    """

    name = "fenicsx_shell"
    model_keys = MODEL_KEYS
    provides_intrusive_tensors = True

    def __init__(self, a: float, R: float, h: float, *, E: float, nu: float, rho: float,
                 n_rings: int = DEFAULTS["n_rings"], grading: float = DEFAULTS["grading"],
                 inplane_inertia: bool = DEFAULTS["inplane_inertia"], penalty: float = DEFAULTS["penalty"],
                 degree: int = DEFAULTS["degree"], quadrature_degree: int | None = None,
                 boundary: Sequence[BoundaryCondition | Mapping[str, Any]] = (), scene_file: Path | None = None):
        from .shallow_shell_forms import MarguerreForms

        t0 = time.perf_counter()
        self.geometry = {"a": float(a), "R": float(R), "h": float(h)}
        self.material = {"E": float(E), "nu": float(nu), "rho": float(rho)}
        self.n_rings, self.grading = int(n_rings), float(grading)
        self.inplane_inertia = bool(inplane_inertia)
        self.penalty = float(penalty)
        self.degree = int(degree)
        if self.degree not in (2, 3):
            raise ValueError(f"degree must be 2 or 3, got {degree}")
        self.quadrature_degree = 2 * self.degree if quadrature_degree is None else int(quadrature_degree)
        if not (math.isinf(R) or R >= a):
            raise ValueError(f"radius of curvature must be >= a = {a} or inf, got {R}")
        points, cells = disk_triangle6(float(a), self.n_rings, self.grading)
        self.boundary = as_conditions(boundary, scene_file)
        self.edge = shell_edge(self.boundary, points, float(a), scene_file)
        self.n_cells = len(cells)
        msh = _create_disk_mesh(points, cells)
        self._V = _compat.vector_space(msh, int(degree), dim=3)
        xyz, bs = _compat.dof_layout(self._V)
        assert bs == 3
        self._nodes = xyz[:, :2].copy()
        self._forms = MarguerreForms(self._V, E=E, nu=nu, rho=rho, h=h, R=R, alpha=self.penalty,
                                     inplane_mass=1.0 if self.inplane_inertia else INPLANE_MASS_FACTOR,
                                     quadrature_degree=self.quadrature_degree,
                                     clamped_edge=self.edge == "clamped")
        self._free = self._edge_dofs(msh)
        self._n = 3 * len(self._nodes) if self._free is None else self._free.n_free
        self._K: sp.csr_matrix | None = None
        self._M: sp.csr_matrix | None = None
        self._labeler: ModeLabeler | None = None
        self._samplers = None
        self.timings: dict[str, float] = {"setup": time.perf_counter() - t0}

    def _edge_dofs(self, msh) -> FreeDofs | None:
        """The free dofs once the edge condition's directions are fixed at every dof of the rim's facets."""
        if self.edge == "free":
            return None
        from dolfinx import fem, mesh as dmesh

        tdim = msh.topology.dim
        msh.topology.create_connectivity(tdim - 1, tdim)
        nodes = fem.locate_dofs_topological(self._V, tdim - 1, dmesh.exterior_facet_indices(msh.topology))
        self._rim_nodes = int(len(nodes))
        directions = sorted({d for bc in self.boundary for d in bc.dofs})
        fixed = (3 * np.asarray(nodes, dtype=np.int64)[:, None] + np.asarray(directions)[None, :]).ravel()
        return FreeDofs(3 * len(self._nodes), fixed)

    @classmethod
    def validate_config(cls, config: Mapping[str, Any], *, base_dir: str | Path | None = None,
                        scene_file: str | Path | None = None) -> dict[str, Any]:
        """The ``[model]`` keys (:data:`~stepnf_fenicsx.shallow_shell_config.MODEL_KEYS`), defaults filled in."""
        return parse_shell_model(config, scene_file)

    @classmethod
    def from_config(cls, config: Mapping[str, Any], *, base_dir: Path | None = None,
                    scene_file: Path | None = None) -> "ShallowShellAdapter":
        p = cls.validate_config(config, base_dir=base_dir, scene_file=scene_file)
        try:
            return cls(p.pop("a"), p.pop("R"), p.pop("h"), scene_file=scene_file, **p)
        except ValueError as exc:
            raise SceneError(scene_file, "model.geometry", str(exc)) from exc

    # ------------------------------------------------------------ geometry
    def _z0(self) -> np.ndarray:
        R = self.geometry["R"]
        r2 = np.sum(self._nodes**2, axis=1)
        return np.zeros(len(r2)) if math.isinf(R) else -r2 / (2.0 * R)

    def dof_coordinates(self) -> np.ndarray:
        X = np.column_stack([self._nodes, self._z0()])
        return self._free_rows(np.repeat(X, 3, axis=0))

    def dof_directions(self) -> np.ndarray:
        return self._free_rows(np.tile(np.arange(3), len(self._nodes)))

    def characteristic_length(self) -> float:
        return self.geometry["h"]

    def shell_scales(self):
        from stepnf.plugin.shell_scales import ShellScales

        g, m = self.geometry, self.material
        return ShellScales.from_geometry(a=g["a"], R=g["R"], h=g["h"], E=m["E"], nu=m["nu"], rho=m["rho"])

    def transverse_amplitude(self, phi: np.ndarray) -> float:
        """max |w| of the finite-element deflection of the mode (not only at nodes).

        Sampled on a lattice of order 8 in every cell, then of order 64 in the
        eight cells with the largest samples: the maximum of a smooth mode is
        found to ~1e-5 relative (a node-only maximum of a ``(k, 0)`` mode of
        arbitrary orientation would err by up to ``(k dtheta / 2)^2``).
        """
        if self._samplers is None:
            self._samplers = (self._forms.w_sampler(_lattice(8)), self._forms.w_sampler(_lattice(64)))
        coarse, fine = self._samplers
        u = self._expand(self._check_field(phi))
        vals = np.abs(coarse(u))
        best = np.argsort(vals.max(axis=1))[-8:]
        return float(max(vals.max(), np.abs(fine(u, best)).max()))

    def mode_labels(self, Phi: np.ndarray) -> list[Any]:
        """(k, n) from the transverse deflection ``w`` (:class:`stepnf.geometry.labels.ModeLabeler`,
        normal ``e_z``: ``(u, v)`` is the tangential part), n counting a held edge as a nodal circle
        (:mod:`stepnf_fenicsx.labels`); ``"in-plane"`` for in-plane modes."""
        Phi = np.asarray(Phi, dtype=float)
        if self._labeler is None:
            N = len(self._nodes)
            normals = np.tile([0.0, 0.0, 1.0], (N, 1))
            self._labeler = ModeLabeler(self._nodes, np.arange(N), normals, self.geometry["a"])
        labels = [self._labeler.label(self._expand(Phi[:, j]).reshape(-1, 3)) for j in range(Phi.shape[1])]
        return labels if self.edge == "free" else count_edge_circle(labels)

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d.update({
            "model": "Marguerre shallow shell (von Karman), C0 interior-penalty bending",
            "cell_type": "triangle6", "n_cells": self.n_cells, "degree": self.degree,
            "n_rings": self.n_rings, "grading": self.grading, "penalty": self.penalty,
            "quadrature_degree": self.quadrature_degree, "inplane_inertia": self.inplane_inertia,
            "inplane_mass_factor": 1.0 if self.inplane_inertia else INPLANE_MASS_FACTOR,
            "material": dict(self.material),
            "geometry": {k: (str(v) if math.isinf(v) else v) for k, v in self.geometry.items()},
        })
        if self.boundary:
            d["boundary"] = describe_conditions(self.boundary, [self._rim_nodes] * len(self.boundary), self._free,
                                                edge=self.edge)
        return d
