"""UFL forms of the St Venant-Kirchhoff solid (Green-Lagrange strain, linear elastic stress).

With ``F = I + grad u``, ``E = (F^T F - I) / 2`` and ``S = lambda tr(E) I + 2 mu E``
the internal virtual work is ``f(u) . v = int S : (F^T grad v) dx`` -- a cubic
polynomial in the nodal displacements: ``f(u) = K u + G(u, u) + H(u, u, u)``,
where ``G(u, v) = D^2 f(0)[u, v] / 2`` and ``H(u, v, w) = D^3 f[u, v, w] / 6``
are obtained here as UFL Gateaux derivatives (exact, symmetric).
"""
from __future__ import annotations

from dataclasses import dataclass

from . import _compat


@dataclass(frozen=True)
class Material:
    """Isotropic linear elastic material: Young's modulus E, Poisson ratio nu, density rho."""

    E: float
    nu: float
    rho: float

    @property
    def lame(self) -> tuple[float, float]:
        lam = self.E * self.nu / ((1 + self.nu) * (1 - 2 * self.nu))
        mu = self.E / (2 * (1 + self.nu))
        return lam, mu


class CubicForms:
    """Compiled forms of an exact cubic internal force ``f(u)`` and their use.

    A subclass builds ``f`` at ``self.u`` and at ``self.zero`` (a function that
    stays 0) and calls :meth:`compile`: K, G and H are the first three
    derivatives of f at 0 (G: the second derivative / 2, H: the third / 6),
    so the intrusive tensors are exact.
    """

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
        return _compat.assemble_matrix(self.K_form)

    def mass(self):
        return _compat.assemble_matrix(self.M_form)


class SvkForms(CubicForms):
    """Compiled forms of one mesh: internal force, tangent, mass and intrusive tensors.

    ``quadrature_degree`` fixes the quadrature (4: 3x3x3 Gauss points on
    hexahedra, exact for the mass matrix of affine Q2 cells and the usual full
    integration of the stiffness); f stays an exact cubic in u whatever the rule.
    """

    def __init__(self, V, material: Material, quadrature_degree: int = 4):
        import ufl
        from dolfinx import fem

        self.V = V
        msh = V.mesh
        lam_, mu_ = material.lame
        lam = fem.Constant(msh, lam_)
        mu = fem.Constant(msh, mu_)
        rho = fem.Constant(msh, material.rho)
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
            S = lam * ufl.tr(E) * I + 2 * mu * E
            return ufl.inner(F * S, ufl.grad(v)) * dx

        self.compile(internal(self.u), internal(self.zero), du, rho * ufl.inner(du, v) * dx)
