"""UFL forms of the St Venant-Kirchhoff solid (Green-Lagrange strain, linear elastic stress).

With ``F = I + grad u``, ``E = (F^T F - I) / 2`` and ``S = C : E`` the internal
virtual work is ``f(u) . v = int S : (F^T grad v) dx`` -- a cubic polynomial in
the nodal displacements: ``f(u) = K u + G(u, u) + H(u, u, u)``, where
``G(u, v) = D^2 f(0)[u, v] / 2`` and ``H(u, v, w) = D^3 f[u, v, w] / 6`` are
obtained here as UFL Gateaux derivatives (exact, symmetric). ``C`` may differ
from cell to cell (:class:`MaterialField`): f stays a cubic, since C does not
depend on u. Isotropic materials keep ``S = lambda tr(E) I + 2 mu E``;
orthotropic ones (or any ``C``) use :mod:`stepnf.plugin.materials`' Voigt order
(11, 22, 33, 23, 13, 12) with engineering shear strains ``2 E_ij``.
"""
from __future__ import annotations

import hashlib
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from stepnf.plugin.materials import isotropic_stiffness

from . import _compat
from .regions import CellMaterials


@dataclass(frozen=True)
class Material:
    """Isotropic linear elastic material: Young's modulus E, Poisson ratio nu, density rho.

    It answers like :class:`stepnf.plugin.materials.Material` (``C``, ``rho``, ``constants``, ``isotropic``),
    so the forms take either kind.
    """

    E: float
    nu: float
    rho: float

    @property
    def lame(self) -> tuple[float, float]:
        return lame(self)

    @property
    def isotropic(self) -> bool:
        return True

    @property
    def constants(self) -> dict[str, float]:
        return {"E": self.E, "nu": self.nu, "rho": self.rho}

    @property
    def C(self) -> np.ndarray:
        return isotropic_stiffness(self.E, self.nu)


def lame(material: Any) -> tuple[float, float]:
    """``(lambda, mu)`` of an isotropic material (either kind: its ``constants`` E and nu)."""
    E, nu = float(material.constants["E"]), float(material.constants["nu"])
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


class MaterialField:
    """The materials of a mesh's cells in UFL: :meth:`stress` ``S(E)`` and the density ``rho``.

    ``material``: one material (either kind) for every cell, or :class:`~stepnf_fenicsx.regions.CellMaterials`.
    One material: constants. Several: piecewise-constant (DG0) fields, each local cell set from the material
    of its row in the input mesh (``topology.original_cell_index``: dolfinx reorders the cells and, under
    MPI, distributes them). Isotropic materials only: lambda and mu (the form of an isotropic model is the
    one it always was); else the 36 entries of ``C`` in global axes.
    """

    def __init__(self, msh: Any, material: Any):
        mats, index = material.used() if isinstance(material, CellMaterials) else ([material], None)
        self.isotropic = all(m.isotropic for m in mats)
        values = [np.array(lame(m)) if self.isotropic else np.asarray(m.C, dtype=float) for m in mats]
        rho = [m.rho for m in mats]
        if len(mats) == 1:
            self.rho = _compat.constant(msh, float(rho[0]))
            fields = ([_compat.constant(msh, v) for v in values[0]] if self.isotropic
                      else [_compat.constant(msh, values[0])])
        else:
            self.rho = _compat.cell_function(msh, np.asarray(rho, dtype=float)[index])
            table = np.asarray(values)[index]  # (input cells, 2) or (input cells, 6, 6)
            fields = ([_compat.cell_function(msh, table[:, i]) for i in range(2)] if self.isotropic
                      else [_compat.cell_function(msh, table)])
        self.coefficients = fields  # [lambda, mu] or [C]

    def stress(self, E):
        """The second Piola-Kirchhoff stress ``S = C : E`` of a Green-Lagrange strain ``E`` (UFL)."""
        import ufl

        if self.isotropic:
            lam, mu = self.coefficients
            return lam * ufl.tr(E) * ufl.Identity(3) + 2 * mu * E
        (C,) = self.coefficients
        s = ufl.dot(C, ufl.as_vector([E[0, 0], E[1, 1], E[2, 2], 2 * E[1, 2], 2 * E[0, 2], 2 * E[0, 1]]))
        return ufl.as_matrix([[s[0], s[5], s[4]], [s[5], s[1], s[3]], [s[4], s[3], s[2]]])


def _graph_key(graph: tuple) -> tuple:
    """A key of a sparsity graph ``(bs, offsets, columns)``: its sizes and a BLAKE2 digest of its arrays
    (keeping the graph itself would hold ~70 MB at 1M dofs for the sake of one comparison)."""
    bs, offsets, columns = graph
    h = hashlib.blake2b()
    for a in (offsets, columns):  # the arrays' own bytes (buffer protocol: no copy) and their types
        h.update(str(a.dtype).encode())
        h.update(np.ascontiguousarray(a))
    return bs, len(offsets), len(columns), h.hexdigest()


class CubicForms:
    """Compiled forms of an exact cubic internal force ``f(u)`` and their use.

    A subclass builds ``f`` at ``self.u`` and at ``self.zero`` (a function that
    stays 0) and calls :meth:`compile`: K, G and H are the first three
    derivatives of f at 0 (G: the second derivative / 2, H: the third / 6),
    so the intrusive tensors are exact.
    """

    #: (key of the node graph, weak references to (indptr, indices)) of the last matrix assembled: reused
    #: while a matrix still holds them (not kept alive for nothing, e.g. once boundary conditions copied K)
    _pattern: tuple | None = None

    def compile(self, f_u, f_z, du, mass) -> None:
        import ufl

        self.f_form = _compat.form(f_u)
        self.K_form = _compat.form(ufl.derivative(f_z, self.zero, du))
        self.M_form = _compat.form(mass)
        d2 = ufl.derivative(ufl.derivative(f_z, self.zero, self.a), self.zero, self.b)
        self.G_form = _compat.form(0.5 * d2)
        self.H_form = _compat.form((1.0 / 6.0) * ufl.derivative(d2, self.zero, self.c))

    def internal_force(self, u):
        _compat.set_values(self.u, u)
        return _compat.assemble_vector(self.f_form)

    def quadratic(self, u, v):
        _compat.set_values(self.a, u)
        _compat.set_values(self.b, v)
        return _compat.assemble_vector(self.G_form)

    def cubic(self, u, v, w):
        _compat.set_values(self.a, u)
        _compat.set_values(self.b, v)
        _compat.set_values(self.c, w)
        return _compat.assemble_vector(self.H_form)

    def stiffness(self):
        return self._matrix(self.K_form)

    def mass(self):
        return self._matrix(self.M_form)

    def _matrix(self, compiled):
        """A matrix of the forms assembled on its sparsity pattern; forms of the same node graph (K and M
        of one space) share one copy of the index arrays (:func:`_compat.assemble_matrix`)."""
        graph = _compat.sparsity_graph(compiled)
        if graph is None:
            return _compat.assemble_matrix(compiled)
        key = _graph_key(graph)
        pattern = None
        if self._pattern is not None and self._pattern[0] == key:
            pattern = tuple(ref() for ref in self._pattern[1])
        if pattern is None or any(a is None for a in pattern):
            pattern = _compat.expand_pattern(graph)
        A = _compat.assemble_matrix(compiled, pattern)
        self._pattern = (key, (weakref.ref(A.indptr), weakref.ref(A.indices)))  # the arrays A holds
        return A


class SvkForms(CubicForms):
    """Compiled forms of one mesh: internal force, tangent, mass and intrusive tensors.

    ``material``: one material for every cell or the materials of the cells
    (:class:`MaterialField`). ``quadrature_degree`` fixes the quadrature (4: 3x3x3 Gauss points on
    hexahedra, exact for the mass matrix of affine Q2 cells and the usual full
    integration of the stiffness); f stays an exact cubic in u whatever the rule.
    """

    def __init__(self, V, material: Any, quadrature_degree: int = 4):
        import ufl
        from dolfinx import fem

        self.V = V
        msh = V.mesh
        self.law = law = MaterialField(msh, material)
        dx = ufl.dx(domain=msh, metadata={"quadrature_degree": int(quadrature_degree)})
        v = ufl.TestFunction(V)
        du = ufl.TrialFunction(V)
        self.u = fem.Function(V)  # state of the internal force
        self.a = fem.Function(V)  # directions of the intrusive tensors
        self.b = fem.Function(V)
        self.c = fem.Function(V)
        self.zero = fem.Function(V)  # stays 0: the expansion point of G

        def internal(u):
            I = ufl.Identity(3)
            F = I + ufl.grad(u)
            E = 0.5 * (F.T * F - I)
            return ufl.inner(F * law.stress(E), ufl.grad(v)) * dx

        self.compile(internal(self.u), internal(self.zero), du, law.rho * ufl.inner(du, v) * dx)
