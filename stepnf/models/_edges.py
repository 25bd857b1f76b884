"""Edge conditions of the von Karman shell model: the free edge and the clamped, immovable edge.

Units and conventions are those of :mod:`stepnf.models.vonkarman`: lengths in the plane in units
of the radius ``a`` (``r = a r_bar``), ``w`` in units of the thickness ``h``, ``F`` in units of
``E h^3``, membrane forces ``N = Airy(F)`` in units of ``E h^3 / a^2``, membrane strains in
units of ``h^2 / a^2``, in-plane displacements in units of ``h^2 / a``; bars dropped below.

Kinematics behind Eq. (2b) (Marguerre form; the mid-surface rises as ``z0 = -sqrt(kappa) r^2 / 2``
in these units, ``sqrt(kappa) = a^2 / (R h)``)::

    eps = sym grad u - sqrt(kappa) sym(x (x) grad w) + 1/2 grad w (x) grad w
    eps_xx = N_xx - nu N_yy,  eps_yy = N_yy - nu N_xx,  eps_xy = (1 + nu) N_xy
    N_xx = F_yy,  N_yy = F_xx,  N_xy = -F_xy

(the compliance of ``E h`` reads 1 in these units). The incompatibility of ``eps`` is
``Delta Delta F`` for the stress part and ``sqrt(kappa) Delta w - L(w, w) / 2`` for the rest:
Eq. (2b). In polar coordinates the non-displacement part of the strain is
``eps0_rr = -sqrt(kappa) r w_r + w_r^2 / 2``, ``eps0_tt = w_t^2 / (2 r^2)``,
``2 eps0_rt = -sqrt(kappa) w_t + w_r w_t / r``.

**Free edge** (``edge = "free"``, the paper): ``N_rr = N_rt = 0`` at ``r = 1``, i.e. ``F = F_r = 0``
(up to the linear functions, which carry no stress); ``w`` satisfies the free-plate bending
conditions. Airy basis: clamped-plate functions; transverse basis: free-plate modes.

**Clamped, immovable edge** (``edge = "clamped"``): ``w = w_r = 0`` and ``u_r = u_t = 0`` at
``r = 1``. Derivation of the conditions on F: on the edge ``w``, ``w_r`` and every tangential
derivative of them vanish, so there ``eps0 = 0`` and, with ``u_r = u_t = 0`` (hence
``u_r,t = u_t,t = 0``),

    eps_tt = u_r + u_t,t = 0                                                  (a)
    d_r (r eps_tt) - eps_rr - 2 d_t eps_rt = u_t,t - u_r,tt = 0                (b)

(``d_r(r eps_tt) = u_r,r + u_t,rt``, ``eps_rr = u_r,r`` and ``2 eps_rt = u_r,t + u_t,r - u_t`` on the
edge, the ``eps0`` terms and their edge derivatives being zero). Conversely (a) and (b) give
``u_r,tt + u_r = 0`` and ``u_t,t = -u_r``: the edge displacement is an in-plane rigid motion, which
stress cannot see and is removed. For ``F = Phi(r) cos k theta`` (strains through the compliance
above) they read, at ``r = 1``,

    (a)  Phi'' - nu (Phi' - k^2 Phi) = 0
    (b)  Phi''' + Phi'' - Phi' - (2 + nu) k^2 Phi' + (3 + nu) k^2 Phi = 0

which are exactly the free-edge conditions of a *plate of Poisson ratio -nu* (bending moment
``Phi'' + nu' (Phi' - k^2 Phi)`` and Kirchhoff shear ``(Delta Phi)' - (1 - nu') k^2 (Phi' - Phi)``
with ``nu' = -nu``). For k = 0 and 1, (b) follows from (a) and Eq. (2b) (``(Delta F)'(1) = 0`` when
``w_r(1) = 0``); the linear functions (``Phi = 1``, ``Phi = r``) satisfy both and are the gauge.

Why: the in-plane problem at given ``w`` is the stationarity of the complementary energy
``1/2 a(F, F) - int Airy(F) : eps0 dS`` over every F (no essential condition: the displacement
condition ``u = 0`` is its natural condition), with

    a(F, G) = int N(F) : C : N(G) dS = int [Delta F Delta G - (1 + nu) L(F, G)] dS,
    int Airy(G) : eps0 dS = int G [sqrt(kappa) Delta w - L(w, w) / 2] dS   (w = w_r = 0 on the edge).

``a`` is the bending form of a plate of Poisson ratio ``-nu``, so its eigenfunctions, the
*elastic free-plate modes with Poisson ratio -nu* (``Delta Delta Upsilon_b = xi_b^4 Upsilon_b``,
(a) and (b) at ``r = 1``, rigid modes left out: they are the gauge and carry no load), satisfy
``a(Upsilon_b, Upsilon_c) = xi_b^4 delta_bc`` and are complete. The Galerkin solution is then
``f_b = (sqrt(kappa) A_b(w) - B_b(w, w) / 2) / xi_b^4``, the membrane energy
``eps_c / 2 sum_b xi_b^4 f_b^2``: the formulas of :mod:`stepnf.models.vonkarman` hold unchanged,
with this Airy basis. The transverse basis is the clamped-plate modes
(``R(1) = R'(1) = 0``, ``omega = lam^2``: 10.2158, 21.260, 34.877, 39.771 for (0,1), (1,1),
(2,1), (0,2)), independent of ``nu``.

Labels and signs: ``(k, n)``, k nodal diameters, n nodal circles *counting the clamped edge*, so
n starts at 1 for every k ((0,1) is the fundamental; a free-edge (k, n) has n circles inside the
plate, from 0 for k >= 2 and from 1 for k = 0, 1). The radial part of a free-edge mode has
``R(1) > 0``; that of a clamped mode ``R(1) = 0`` and ``R''(1) > 0``.
"""
from __future__ import annotations

from stepnf.models._radial import RadialFamily, clamped_plate_family, free_plate_family

#: The edge conditions of the model (``[model] edge``).
EDGES: tuple[str, ...] = ("free", "clamped")


def plate_family(edge: str, k: int, n: int, nu: float) -> RadialFamily:
    """Transverse Ritz basis: the first ``n`` elastic plate modes of ``edge`` with ``k`` nodal diameters."""
    return free_plate_family(k, n, nu) if edge == "free" else clamped_plate_family(k, n)


#: Smallest Poisson ratio of the clamped edge: as nu -> -1 the lowest Airy function of each k >= 2
#: (nearly the harmonic r^k) has xi ~ 2.6 (1 + nu)^(1/4) -> 0; the root scan starts at xi = 0.02,
#: below the lowest xi of every nu >= NU_MIN_CLAMPED (0.026 there, k = 2; no spurious root from 0.01 on).
NU_MIN_CLAMPED = -1.0 + 1e-8


def airy_family(edge: str, k: int, n: int, nu: float) -> RadialFamily:
    """Airy basis of ``edge``: clamped-plate functions (free edge) or elastic free-plate modes of
    Poisson ratio ``-nu`` (immovable clamped edge, see the module docstring; ``nu >= NU_MIN_CLAMPED``)."""
    return clamped_plate_family(k, n) if edge == "free" else free_plate_family(k, n, -nu, start=0.02)


def first_circle(edge: str, k: int) -> int:
    """``n`` of the lowest mode with ``k`` nodal diameters (see the labels above)."""
    return 1 if edge == "clamped" or k in (0, 1) else 0


def sign_derivative(edge: str) -> int:
    """Which derivative at ``r = 1`` is made positive: 0 (``R(1)``, free) or 2 (``R''(1)``, clamped)."""
    return 0 if edge == "free" else 2

