"""UFL forms of the Marguerre (shallow-shell von Karman) model: membrane + C0 interior-penalty bending.

Unknowns (one blocked P2 or P3 space of dimension 3 on the plan-view disk):
in-plane displacements ``u, v`` and transverse deflection ``w`` (along ``z``).
Mid-surface ``z0(x, y) = -(x^2 + y^2) / (2 R)`` (its interpolant in the
displacement space; apex at the origin, curving downwards like
:func:`stepnf.geometry.spherical_cap`; ``R = inf``: plate).

Strain energy ``Pi = Pi_m + Pi_b``:

* membrane: ``e = sym(grad u) + 1/2 grad w (x) grad w + sym(grad z0 (x) grad w)``,
  ``N = A ((1 - nu) e + nu tr(e) I)``, ``A = E h / (1 - nu^2)``,
  ``Pi_m = 1/2 int N : e dx`` (a quartic polynomial of the dofs);
* bending (linear): ``kappa = -hess w``, ``M = D ((1 - nu) kappa + nu tr(kappa) I)``,
  ``D = E h^3 / (12 (1 - nu^2))``, discretised with continuous P2/P3 ``w`` by the
  symmetric C0 interior-penalty method (Engel et al. 2002; Brenner & Sung 2005)::

      Pi_b = 1/2 sum_T int_T M(w) : hess w
             - sum_F int_F {M_nn(w)} [d_n w]  +  1/2 sum_F int_F (alpha D / h_F) [d_n w]^2

  over interior facets F (``[d_n w]`` the jump of the normal slope, ``{.}``
  the average, ``h_F`` the mean diameter of the two cells). The free edge needs
  no boundary terms (``M_nn = 0`` and the Kirchhoff shear are natural), nor
  does a simply supported one (``w = 0`` strongly, ``M_nn = 0`` natural). A
  clamped edge (``clamped_edge``: ``w = 0`` strongly by the adapter, so the
  tangential slope vanishes too) gets the normal slope ``d_n w = 0`` weakly, by
  the same terms on the boundary facets, where the slope jump is the slope
  itself (Nitsche's method, as in Engel et al. and Brenner & Sung)::

      - sum_E int_E M_nn(w) d_n w  +  1/2 sum_E int_E (alpha D / h_E) (d_n w)^2

  (``h_E`` the diameter of the boundary cell; the same ``alpha``: measured on
  the clamped plate with P3, the first four distinct frequencies are within
  1.3e-4 of the classical values on 8 rings (3.5e-4 with ``alpha = 40``) and
  3e-5 on 12, converging from above). The
  method is consistent (the exact solution satisfies it), so ``alpha`` only
  has to exceed the trace/inverse-inequality constant of the element
  (coercivity) and the results converge to the Kirchhoff plate/shell whatever
  its value. Choice ``alpha = 10`` (P3, kappa = 25, measured): with 2 and 4
  (10-ring mesh) the higher modes fall *below* the converged frequencies
  ((4,1) by -0.5% at 2) and the (3,0) and (6,0) pairs split more, the
  signature of a penalty too weak for coercivity; from 10 to 40 (8-ring mesh)
  every frequency rises monotonically by small amounts (<= 1.4e-4) and Gamma of
  the six test modes changes by < 0.01%, except the nearly cancelling (0,2)
  (0.9%) and (2,1), near a 1:2 resonance (2.7%); both shrink like h^4.

The internal force ``f(U) . V = D Pi(U)[V]`` is therefore an exact cubic of
the dofs; ``K``, ``G`` and ``H`` are its UFL Gateaux derivatives at 0.
Kinetic energy: ``1/2 int rho h (w'^2 + c (u'^2 + v'^2)) dx`` with ``c = 1``
(in-plane inertia) or ``c = INPLANE_MASS_FACTOR`` (von Karman's quasi-static
in-plane motion, see :mod:`stepnf_fenicsx.shallow_shell`).
"""
from __future__ import annotations

import math

from . import _compat
from .model import CubicForms


def cell_diameters(msh):
    """A DG0 function: each cell's largest vertex-to-vertex distance (straight-sided estimate)."""
    import numpy as np
    from dolfinx import fem

    W = _compat.scalar_space(msh, "DG", 0)
    x = msh.geometry.x
    gdofs = _compat.geometry_dofmap(msh)
    v = x[gdofs[:, :3]]  # the first three geometry nodes of a triangle are its vertices
    diam = np.max(np.stack([np.linalg.norm(v[:, i] - v[:, j], axis=1) for i, j in ((0, 1), (1, 2), (2, 0))]),
                  axis=0)
    fn = fem.Function(W)
    dofs = _compat.cell_dofmap(W)[:len(gdofs), 0]
    fn.x.array[dofs] = diam
    return fn


class MarguerreForms(CubicForms):
    """Compiled forms on a dolfinx mesh of the plan view (see the module docstring).

    Parameters: ``V`` the blocked P2 space of dimension 3 on a 2D mesh; ``E, nu,
    rho, h`` material and thickness; ``R`` curvature radius (``inf``: plate);
    ``alpha`` the interior-penalty factor; ``inplane_mass`` the factor ``c`` of the
    in-plane kinetic energy; ``quadrature_degree`` of the cell integrals; ``clamped_edge`` adds the
    boundary terms of a clamped edge (the adapter fixes ``u, v, w`` on it).
    """

    def __init__(self, V, *, E: float, nu: float, rho: float, h: float, R: float, alpha: float,
                 inplane_mass: float, quadrature_degree: int = 4, clamped_edge: bool = False):
        import ufl
        from dolfinx import fem

        self.V = V
        msh = V.mesh
        A_ = E * h / (1.0 - nu**2)
        D_ = E * h**3 / (12.0 * (1.0 - nu**2))
        A = _compat.constant(msh, A_)
        D = _compat.constant(msh, D_)
        nu_c = _compat.constant(msh, nu)
        pen = _compat.constant(msh, alpha * D_)
        rho_h = _compat.constant(msh, rho * h)
        c_in = _compat.constant(msh, float(inplane_mass))
        dx = ufl.dx(domain=msh, metadata={"quadrature_degree": int(quadrature_degree)})
        dS = ufl.dS(domain=msh, metadata={"quadrature_degree": 4})
        ds = ufl.ds(domain=msh, metadata={"quadrature_degree": 4})
        # z0 interpolated in the scalar space of the displacements (not the exact SpatialCoordinate
        # expression): on curved cells a quadratic of x is not in P_k(reference), and only with the
        # interpolant are the rotations about e_x, e_y (v = -z0, w = y, ...) exact zero-energy fields
        z0 = fem.Function(_compat.scalar_space(msh, "Lagrange", _compat.element_degree(V)))
        c_ = 0.0 if math.isinf(R) else 1.0 / R
        z0.interpolate(lambda x: -0.5 * c_ * (x[0] ** 2 + x[1] ** 2))
        self.z0 = z0
        grad_z0 = ufl.grad(z0)
        I2 = ufl.Identity(2)
        n = ufl.FacetNormal(msh)
        diameters = cell_diameters(msh)  # ffcx 0.5 has no CellDiameter on P2 geometry
        hF = ufl.avg(diameters)

        V_ = ufl.TestFunction(V)
        dU = ufl.TrialFunction(V)
        self.u = fem.Function(V)
        self.a = fem.Function(V)
        self.b = fem.Function(V)
        self.c = fem.Function(V)
        self.zero = fem.Function(V)
        self.sample = fem.Function(V)  # field whose w is sampled by :meth:`w_sampler`

        def parts(U):
            gU = ufl.grad(U)  # (3, 2)
            gu = ufl.as_matrix([[gU[0, 0], gU[0, 1]], [gU[1, 0], gU[1, 1]]])
            gw = ufl.as_vector([gU[2, 0], gU[2, 1]])
            return gu, gw, U[2]

        def energy(U):
            gu, gw, w = parts(U)
            e = ufl.sym(gu) + 0.5 * ufl.outer(gw, gw) + ufl.sym(ufl.outer(grad_z0, gw))
            N = A * ((1 - nu_c) * e + nu_c * ufl.tr(e) * I2)
            Hw = ufl.grad(ufl.grad(w))
            Mw = D * ((1 - nu_c) * Hw + nu_c * ufl.tr(Hw) * I2)
            jump_slope = ufl.jump(ufl.grad(w), n)
            Mnn = ufl.inner(ufl.avg(Mw) * n("+"), n("+"))
            out = (0.5 * ufl.inner(N, e) * dx + 0.5 * ufl.inner(Mw, Hw) * dx
                   - Mnn * jump_slope * dS + 0.5 * pen / hF * jump_slope**2 * dS)
            if clamped_edge:
                slope = ufl.dot(ufl.grad(w), n)
                out += -ufl.inner(Mw * n, n) * slope * ds + 0.5 * pen / diameters * slope**2 * ds
            return out

        def force(U):
            return ufl.derivative(energy(U), U, V_)

        _, _, w_t = parts(V_)
        _, _, w_d = parts(dU)
        mass = rho_h * (w_d * w_t + c_in * (dU[0] * V_[0] + dU[1] * V_[1])) * dx
        self.compile(force(self.u), force(self.zero), dU, mass)

    def w_sampler(self, X):
        """``fn(field) -> (cells, len(X))``: w of a field at reference points ``X`` (k, 2) of every cell."""
        import numpy as np

        expr = _compat.expression(self.sample[2], X)
        msh = self.V.mesh
        cells = np.arange(_compat.num_cells(msh), dtype=np.int32)

        def fn(field, which=None):
            _compat.set_values(self.sample, field)
            return _compat.evaluate(expr, msh, cells if which is None else np.asarray(which, dtype=np.int32))
        return fn
