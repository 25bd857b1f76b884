"""Cantilever strips and the inextensible-cantilever theory they are measured against (issue 31, item 1).

Theory (computed here, independent of stepnf): the planar inextensible Euler-Bernoulli cantilever of
Crespo da Silva & Glynn (J. Struct. Mech. 6, 1978; Nayfeh & Pai, "Linear and Nonlinear Structural
Mechanics", 2004, ch. 5). In units of L (arc length s in [0, 1], w scaled by L, time by
sqrt(rho A L^4 / (E I))), the energies to fourth order in w are

    V = 1/2 int w''^2 (1 + w'^2) ds                (curvature kappa = w'' / sqrt(1 - w'^2))
    K = 1/2 int (w_t^2 + u_t^2) ds,  u = -1/2 int_0^s w'^2   (inextensibility: the axial shortening)

and the one-mode Galerkin w = q(t) phi_r(s) on the exact linear mode (int phi_r^2 = 1) gives, by
Lagrange's equations,

    q'' + w_r^2 q + a q^3 + b (q^2 q'' + q q'^2) = 0,   a = 2 int phi'^2 phi''^2,  b = int psi^2,
    psi(s) = int_0^s phi'^2,  w_r = (beta_r L)^2.

Harmonic balance on q = A cos(w t): q^3 -> 3/4 A^3 cos, q^2 q'' + q q'^2 -> -1/2 w^2 A^3 cos, so
w^2 (1 + b A^2 / 2) = w_r^2 + 3/4 a A^2 and, to first order,

    w_NL / w_r = 1 + kappa A^2,   kappa = 3 a / (8 w_r^2) - b / 4

(checked against a direct integration of the ODE in ``ode_frequency``). The mode's tip amplitude is
W_tip = A |phi_r(1)| = 2 A (every cantilever mode with int phi^2 = 1 has |phi(1)| = 2), so
w_NL / w_r = 1 + c_r (W_tip / L)^2 with c_r = kappa / phi_r(1)^2:

    c_1 = +0.0193835 (hardening),  c_2 = -6.45441 (softening),  c_3 = -55.978.

Published values: a and b above are the curvature and inertia coefficients of the single-mode
cantilever equation tabulated in the literature following Crespo da Silva & Glynn (1978) (Anderson,
Nayfeh & Balachandran, J. Vib. Acoust. 118, 1996; Malatkar & Nayfeh, Nonlinear Dyn. 31, 2003): mode 1
a = 40.44, b = 4.597; mode 2 a = 13 418, b = 144.7 -- reproduced by ``galerkin_coefficients``
(tests/nf/test_cantilever_theory.py), and the sign pattern (first mode hardening, the higher ones
softening) is Crespo da Silva & Glynn's. The inextensible beam is the limit L/h -> infinity of the 3D
solid; at finite L/h the axial field follows w'^2 / 2 dynamically (at 2w) rather than rigidly, which
makes mode 2 more softening by 8.8% at L/h = 30 and 0.74% at L/h = 100 (``axial_inertia_ratio``,
``gamma_theory(..., extensible=True)``; mode 1: -2.4% and -0.22%); shear and rotary inertia add
O((beta_r h/L)^2) (mode 2's frequency: -0.44% at L/h = 30).

stepnf's figure (docs/design.md, "Comparing models"): Gamma = coefficient of (W_max/h)^2 in
w_NL/w = 1 + Gamma (W_max/h)^2, W_max the largest transverse displacement of the mode (the tip), so
Gamma_r = c_r (h/L)^2. In stepnf's M-normalised units (w_NL = w (1 + T A^2), phi^T M phi = 1, so
max|phi_w| = 2 / sqrt(rho A L)): T_r = 4 c_r / (rho A L^3).

Strips: [0, L] x [-b/2, b/2] x [-h/2, h/2] with b = 3h, clamped at x = 0, nu = 0 (so the plate factor
1 - nu^2 and the anticlastic curvature do not blur the comparison with the beam theory: with nu = 0 the
3D strip's bending stiffness is exactly E b h^3 / 12). Steel E = 2.1e11 Pa, rho = 7800 kg/m^3, h = 0.01 m.
Decks are CalculiX (C3D20 bricks, or C3D10 tetrahedra with two layers through the thickness), written
to a folder by ``write_strip_deck``; ``write_strip_scene`` writes the stepnf scene that runs them.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
from scipy.integrate import cumulative_trapezoid, simpson, solve_ivp
from scipy.optimize import brentq

E, NU, RHO = 2.1e11, 0.0, 7800.0  # Pa, -, kg/m^3 (nu = 0: see the module docstring)
H = 0.01  # thickness (m); width b = WIDTH_RATIO * h
WIDTH_RATIO = 3.0
SLENDERNESS = (30, 100, 300, 1000)
#: stepnf's 0-based masters of the strips' first two bending modes (in z): mode 1 (in-plane, 3 w_0) between
STRIP_MASTERS = (0, 2)
_GUESS = (1.8751, 4.6941, 7.8548, 10.9955)
_NS = 40001  # quadrature points on [0, 1] (Simpson; the integrands are smooth: ~1e-12 relative)


def beta_l(r: int) -> float:
    """beta_r L of the r-th cantilever mode (r = 1, 2, ...): root of cos x cosh x + 1 = 0."""
    if r < 1:
        raise ValueError("modes are numbered from 1")
    g = _GUESS[r - 1] if r <= len(_GUESS) else (2 * r - 1) * math.pi / 2
    return brentq(lambda x: math.cos(x) * math.cosh(x) + 1.0, g - 0.1, g + 0.1, xtol=1e-15, rtol=1e-15)


def mode_shape(r: int, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(phi, phi', phi'') of the r-th cantilever mode at s in [0, 1], normalised to int_0^1 phi^2 = 1.

    phi = cosh bs - cos bs - sigma (sinh bs - sin bs), sigma = (cosh b + cos b)/(sinh b + sin b); for this
    form int_0^1 phi^2 = 1 exactly, so phi(1) = 2 (-1)^(r+1).
    """
    b = beta_l(r)
    sig = (math.cosh(b) + math.cos(b)) / (math.sinh(b) + math.sin(b))
    x = b * np.asarray(s, dtype=float)
    ch, c, sh, sn = np.cosh(x), np.cos(x), np.sinh(x), np.sin(x)
    return ch - c - sig * (sh - sn), b * (sh + sn - sig * (ch - c)), b * b * (ch + c - sig * (sh + sn))


def galerkin_coefficients(r: int) -> tuple[float, float, float]:
    """(w_r^2, a, b) of q'' + w_r^2 q + a q^3 + b (q^2 q'' + q q'^2) = 0 (nondimensional, see the module)."""
    s = np.linspace(0.0, 1.0, _NS)
    phi, d1, d2 = mode_shape(r, s)
    norm = simpson(phi**2, x=s)  # = 1 to quadrature accuracy; divided out all the same
    a = 2.0 * simpson(d1**2 * d2**2, x=s) / norm**2
    psi = cumulative_trapezoid(d1**2, s, initial=0.0)
    b = simpson(psi**2, x=s) / norm**2
    return beta_l(r) ** 4, float(a), float(b)


def frequency_correction(omega2: float, a: float, b: float) -> float:
    """kappa of w_NL/w = 1 + kappa A^2 for x'' + w^2 x + a x^3 + b (x^2 x'' + x x'^2) = 0 (first-order
    harmonic balance; equal to the Lindstedt-Poincare first order)."""
    return 3.0 * a / (8.0 * omega2) - b / 4.0


def backbone_coefficient(r: int) -> float:
    """c_r of w_NL/w_r = 1 + c_r (W_tip/L)^2 for the r-th mode of the inextensible cantilever."""
    w2, a, b = galerkin_coefficients(r)
    phi1 = mode_shape(r, np.array([1.0]))[0][0]
    return frequency_correction(w2, a, b) / phi1**2


def gamma_theory(r: int, slenderness: float, extensible: bool = False) -> float:
    """stepnf's Gamma (coefficient of (W_max/h)^2) of mode r of a cantilever with L/h = ``slenderness``.

    ``extensible``: with the first correction of the axial stiffness (``axial_inertia_ratio``): the 3D
    solid's Gamma differs from it only by shear and rotary inertia, O((beta_r h / L)^2)."""
    if not extensible:
        return backbone_coefficient(r) / slenderness**2
    w2, a, b = galerkin_coefficients(r)
    phi1 = mode_shape(r, np.array([1.0]))[0][0]
    return frequency_correction(w2, a, axial_inertia_ratio(r, slenderness) * b) / phi1**2 / slenderness**2


def axial_inertia_ratio(r: int, slenderness: float) -> float:
    """R >= 1: the inertia coefficient b of a beam with a finite axial stiffness, relative to the
    inextensible one, to first order in the amplitude (see ``gamma_theory(..., extensible=True)``).

    Euler-Bernoulli beam with axial strain eps = u' + w'^2/2, N = EA eps, axial equilibrium N' = rho A u_tt,
    N(L) = 0; in the units of the module eps = mu N with mu = I / (A L^2) = (h/L)^2 / 12. For q = A cos(w t),
    w'^2 = q^2 phi'^2 has a mean (eps = 0: the same shortening as the inextensible beam) and a part at
    Omega = 2w, whose axial response U(s) cos(Omega t) (per unit A^2/4) solves the forced rod
    U' = -phi'^2 + mu Omega^2 int_s^1 U, U(0) = 0 (fixed point, converged to 1e-14). The transverse
    generalised force of N is q int u_tt psi ds, so b -> R b with R = int U psi / int U_0 psi, U_0 = -psi.
    R - 1 ~ mu Omega^2 / (pi/2)^2: mode 2 at L/h = 30: R = 1.063 (Gamma 8.8% more softening), L/h = 100:
    1.0053 (0.74%), L/h >= 300: < 0.1%.
    """
    w2 = beta_l(r) ** 4
    lam = (4.0 * w2) / (12.0 * slenderness**2)  # mu Omega^2
    if lam >= (math.pi / 2) ** 2 / 2:
        raise ValueError(f"L/h = {slenderness} too stocky: 2 w_{r} is near the first axial mode")
    s = np.linspace(0.0, 1.0, _NS)
    d1 = mode_shape(r, s)[1]
    U0 = -cumulative_trapezoid(d1**2, s, initial=0.0)
    U = U0
    for _ in range(500):
        tail = cumulative_trapezoid(U, s, initial=0.0)
        new = cumulative_trapezoid(-(d1**2) + lam * (tail[-1] - tail), s, initial=0.0)
        if np.abs(new - U).max() <= 1e-14 * np.abs(U0).max():
            break
        U = new
    return float(simpson(new * U0, x=s) / simpson(U0 * U0, x=s))


def t_theory(r: int, rho: float, area: float, length: float) -> float:
    """stepnf's T (1/(kg m^2) for SI inputs: w_NL = w (1 + T A^2), A the M-normalised modal amplitude)."""
    return 4.0 * backbone_coefficient(r) / (rho * area * length**3)


def linear_frequency(r: int, E: float, I: float, rho: float, area: float, length: float) -> float:
    """w_r = (beta_r L)^2 sqrt(E I / (rho A L^4)) in rad/s."""
    return beta_l(r) ** 2 * math.sqrt(E * I / (rho * area * length**4))


def ode_frequency(omega2: float, a: float, b: float, amplitude: float, rtol: float = 1e-12) -> float:
    """w_NL of x'' + w^2 x + a x^3 + b (x^2 x'' + x x'^2) = 0 released from x = amplitude, x' = 0, by direct
    integration (scipy solve_ivp, DOP853): the half period is the first return of x' to zero."""
    def rhs(_t, y):
        x, v = y
        return [v, -(omega2 * x + a * x**3 + b * x * v * v) / (1.0 + b * x * x)]

    def turn(_t, y):
        return y[1]

    turn.direction = 1.0  # x' goes from negative to positive at x = -amplitude (t = T/2)
    t_lin = math.pi / math.sqrt(omega2)
    sol = solve_ivp(rhs, (0.0, 3.0 * t_lin), [amplitude, 0.0], method="DOP853", rtol=rtol, atol=rtol * amplitude,
                    events=turn)
    half = sol.t_events[0]
    half = half[half > 0.1 * t_lin][0]
    return math.pi / half


# --- meshes ------------------------------------------------------------------------------------------------

def strip_size(slenderness: float, h: float = H) -> tuple[float, float, float]:
    """(L, b, h) in metres of the strip with L/h = ``slenderness``, b = 3h."""
    return slenderness * h, WIDTH_RATIO * h, h


#: C3D20 corners then mid-edge nodes, in half-cell steps (CalculiX order == VTK hexahedron20)
_HEX20 = np.array([(0, 0, 0), (2, 0, 0), (2, 2, 0), (0, 2, 0), (0, 0, 2), (2, 0, 2), (2, 2, 2), (0, 2, 2),
                   (1, 0, 0), (2, 1, 0), (1, 2, 0), (0, 1, 0), (1, 0, 2), (2, 1, 2), (1, 2, 2), (0, 1, 2),
                   (0, 0, 1), (2, 0, 1), (2, 2, 1), (0, 2, 1)])
#: the 6 tetrahedra of a cube sharing the diagonal 0-6 (Kuhn split: conforming on a structured grid)
_KUHN = [(0, 1, 2, 6), (0, 2, 3, 6), (0, 3, 7, 6), (0, 7, 4, 6), (0, 4, 5, 6), (0, 5, 1, 6)]
_TET10_EDGES = [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]  # C3D10 mid-nodes 5..10 (== VTK tetra10)


def strip_hex20(slenderness: float, nx: int, ny: int = 1, nz: int = 1, h: float = H):
    """Points (N, 3) and C3D20 cells (E, 20), 0-based, of the strip: nx x ny x nz bricks."""
    L, b, hh = strip_size(slenderness, h)
    pts, cells = block_hex20(nx, ny, nz, (L, b, hh))
    return pts - [0.0, b / 2, hh / 2], cells


def strip_tet10(slenderness: float, nx: int, ny: int = 3, nz: int = 2, h: float = H):
    """Points and C3D10 cells (0-based) of the strip: nx x ny x nz boxes, each cut into 6 tetrahedra."""
    L, b, hh = strip_size(slenderness, h)
    cube = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)])
    index: dict[tuple, int] = {}
    cells = []
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                base = 2 * np.array([i, j, k])
                for tet in _KUHN:
                    c = [base + 2 * cube[v] for v in tet]
                    nodes = c + [(c[p] + c[q]) // 2 for p, q in _TET10_EDGES]
                    cells.append([index.setdefault(tuple(n), len(index)) for n in nodes])
    grid = np.array(sorted(index, key=index.get), dtype=float)
    pts = grid / (2 * np.array([nx, ny, nz])) * [L, b, hh] - [0.0, b / 2, hh / 2]
    cells = np.array(cells)
    P = pts[cells[:, :4]]
    vol = np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), P[:, 3] - P[:, 0])
    flip = vol < 0  # swap corners 1 and 2 (and the mid-nodes that follow them) where the orientation is negative
    cells[flip] = cells[flip][:, [0, 2, 1, 3, 6, 5, 4, 7, 9, 8]]
    return pts, cells


def deck_text(points: np.ndarray, cells: np.ndarray, element: str, *, E: float = E, nu: float = NU,
              rho: float = RHO, frequency: int | None = None) -> str:
    """A complete CalculiX deck: nodes, elements (``element`` = "C3D20", "C3D20R" or "C3D10"), the clamp
    at x = min(x) as *BOUNDARY 1-3, the material; with ``frequency`` = n a *FREQUENCY step for n modes
    printing U of every node (``ccx_modes`` reads them)."""
    lines = ["*HEADING", "cantilever strip (stepnf issue 31)", "*NODE, NSET=NALL"]
    lines += [f"{i + 1}, {p[0]:.15g}, {p[1]:.15g}, {p[2]:.15g}" for i, p in enumerate(points)]
    lines.append(f"*ELEMENT, TYPE={element}, ELSET=EALL")
    for e, c in enumerate(cells):
        ids = [str(n + 1) for n in c]
        row = [str(e + 1)] + ids
        lines.append(", ".join(row[:16]) + ("," if len(row) > 16 else ""))
        if len(row) > 16:
            lines.append(", ".join(row[16:]))
    clamp = np.flatnonzero(np.isclose(points[:, 0], points[:, 0].min(), atol=1e-12)) + 1
    lines.append("*NSET, NSET=CLAMP")
    lines += [", ".join(str(n) for n in clamp[i:i + 16]) for i in range(0, len(clamp), 16)]
    lines += ["*MATERIAL, NAME=STEEL", "*ELASTIC", f"{E:.15g}, {nu:.15g}", "*DENSITY", f"{rho:.15g}",
              "*SOLID SECTION, ELSET=EALL, MATERIAL=STEEL", "*BOUNDARY", "CLAMP, 1, 3"]
    if frequency:  # ccx's own eigen-solve, the displacements of every mode printed to the .dat
        lines += ["*STEP", "*FREQUENCY", f"{frequency}", "*NODE PRINT, NSET=NALL", "U", "*END STEP"]
    return "\n".join(lines) + "\n"


def write_strip_deck(folder: Path, slenderness: float, mesh: str = "hex20", nx: int | None = None, *,
                     cross: tuple[int, int] | None = None, h: float = H, frequency: int | None = None,
                     name: str | None = None) -> Path:
    """Write the strip's CalculiX deck (``mesh`` = "hex20": C3D20, ``cross`` = (ny, nz) = (1, 1) elements
    through width and thickness by default; "tet10": C3D10, (3, 2) boxes) to ``folder``/``name`` and return
    its path. ``nx``: elements along the length (default ``default_nx``)."""
    nx = nx or default_nx(mesh)
    if mesh == "hex20":
        pts, cells = strip_hex20(slenderness, nx, *(cross or (1, 1)), h=h)
        element = "C3D20"
    elif mesh == "tet10":
        pts, cells = strip_tet10(slenderness, nx, *(cross or (3, 2)), h=h)
        element = "C3D10"
    else:
        raise ValueError(f"mesh is 'hex20' or 'tet10', not {mesh!r}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / (name or f"strip_{mesh}_{int(slenderness)}_{nx}.inp")
    path.write_text(deck_text(pts, cells, element, frequency=frequency))
    return path


def default_nx(mesh: str) -> int:
    """Elements along the length at which mode 2's T has converged (bench/cantilever.py's refinement)."""
    return {"hex20": 40, "tet10": 40}[mesh]


def write_strip_scene(deck: Path, masters=STRIP_MASTERS, *, h: float = H, relative_amplitude: float | None = None,
                      methods=("dnf",), out: str = "results", analysis: str = "") -> Path:
    """The stepnf scene (next to ``deck``) running it by the calculix adapter; Gamma with thickness h, uz.
    ``analysis``: more lines of the ``[analysis]`` table (e.g. "rigid_modes = 0")."""
    step = "" if relative_amplitude is None else f"\n[analysis.step]\nrelative_amplitude = {relative_amplitude}\n"
    text = (f'[model]\nsolver = "calculix"\ndeck = "{deck.name}"\n\n[analysis]\n'
            f"master_modes = {list(masters)}\nmethods = {list(methods)!r}\nthickness = {h!r}\n"
            f'transverse = "uz"\n').replace("'", '"') + analysis + (
            f'{step}\n[output]\ndir = "{out}"\n')
    path = deck.with_suffix(".toml")
    path.write_text(text)
    return path


#: L/h -> elements along the length of the benchmark's strips (bench/cantilever.py): the FEniCSx hex20
#: strips' Gamma of modes 1 and 2 converged there (the lead's measurement, issue 31)
STRIP_NX = {30: 40, 100: 40, 300: 80, 1000: 100}


def strip_nx(slenderness: float) -> int:
    """Elements along the length of the benchmark's strip with L/h = ``slenderness`` (:data:`STRIP_NX`)."""
    return STRIP_NX[int(slenderness)]


def write_mesh_scene(deck: Path, masters=STRIP_MASTERS, *, solver: str = "fenicsx", material=(E, NU, RHO),
                     boundary_set: str = "CLAMP", h: float = H, relative_amplitude: float | None = None,
                     methods=("dnf",), out: str = "results", analysis: str = "") -> Path:
    """The stepnf scene (next to ``deck``, named ``<deck>_<solver>.toml``) running the deck as a *mesh*
    (``mesh = "<deck>"``: the deck's own *BOUNDARY and *MATERIAL are not read) by ``solver``, with
    ``material`` = (E, nu, rho) as ``[model.material]`` and the node set ``boundary_set`` clamped by
    ``[[model.boundary]]``; Gamma with thickness h, uz. ``analysis``: more lines of ``[analysis]``."""
    E_, nu_, rho_ = material
    step = "" if relative_amplitude is None else f"\n[analysis.step]\nrelative_amplitude = {relative_amplitude}\n"
    text = (f'[model]\nsolver = "{solver}"\nmesh = "{deck.name}"\n\n[model.material]\nE = {E_!r}\nnu = {nu_!r}\n'
            f'rho = {rho_!r}\n\n[[model.boundary]]\nset = "{boundary_set}"\n\n[analysis]\n'
            f"master_modes = {list(masters)}\nmethods = {list(methods)!r}\nthickness = {h!r}\n"
            f'transverse = "uz"\n').replace("'", '"') + analysis + f'{step}\n[output]\ndir = "{out}"\n'
    path = deck.with_name(f"{deck.stem}_{solver}.toml")
    path.write_text(text)
    return path


def plate_deck_text(frequency: int | None = 10) -> str:
    """The cantilever plate of issue 31 as CalculiX's test suite has it (test/dloadlin20f.inp: its design,
    our own deck): 300 x 30 x 1 (mm), C3D20, 15 x 1 x 1 elements (one through the thickness), clamped at
    x = 0, steel in N-mm-tonne units (E = 209000 MPa, nu = 0.3, rho = 7.85e-9). ccx's reference .dat for
    that deck gives 59.58324 and 374.3339 rad/s for the first two modes (both bending in z)."""
    pts, cells = block_hex20(15, 1, 1, (300.0, 30.0, 1.0))
    return deck_text(pts, cells, "C3D20", E=209000.0, nu=0.3, rho=7.85e-9, frequency=frequency)


def write_plate_deck(folder: Path, name: str = "plate.inp", frequency: int | None = None) -> Path:
    """Write ``plate_deck_text`` to ``folder``/``name`` (its stepnf masters: 0 and 1; thickness 1 mm)."""
    path = Path(folder) / name
    path.write_text(plate_deck_text(frequency))
    return path


def block_hex20(nx: int, ny: int, nz: int, size) -> tuple[np.ndarray, np.ndarray]:
    """Points and C3D20 cells (0-based) of the box [0, size] in nx x ny x nz bricks."""
    index: dict[tuple, int] = {}
    cells = [[index.setdefault(tuple(np.array([2 * i, 2 * j, 2 * k]) + d), len(index)) for d in _HEX20]
             for i in range(nx) for j in range(ny) for k in range(nz)]
    grid = np.array(sorted(index, key=index.get), dtype=float)
    return grid / (2 * np.array([nx, ny, nz])) * np.asarray(size, dtype=float), np.array(cells)


def ccx_modes(dat: Path) -> tuple[np.ndarray, list[np.ndarray]]:
    """(omega in rad/s, [U (N, 3) per mode]) from the .dat of a ``deck_text(..., frequency=n)`` run."""
    text = Path(dat).read_text()
    head, _, tail = text.partition("E I G E N V A L U E   O U T P U T")
    omega = []
    for line in tail.splitlines():
        f = line.split()
        if len(f) == 5 and f[0].isdigit():
            omega.append(float(f[2]))
        elif omega and "displacements" in line:
            break
    shapes = []
    for block in re.split(r"displacements \(vx,vy,vz\)[^\n]*\n", text)[1:]:
        rows = [r.split() for r in block.strip().split("\n")]
        rows = [r for r in rows if len(r) == 4 and r[0].isdigit()]
        shapes.append(np.array([[float(v) for v in r[1:]] for r in rows]))
    return np.array(omega), shapes


def bending_modes(shapes: list[np.ndarray], n: int = 2, share: float = 0.9) -> list[int]:
    """0-based indices of the first ``n`` modes whose squared displacement is >= ``share`` in uz (bending
    in the thickness direction)."""
    out = [i for i, U in enumerate(shapes) if (U[:, 2] ** 2).sum() >= share * (U**2).sum()]
    return out[:n]
