"""Semi-analytical von Karman model of a shallow spherical shell, free or clamped edge (paper section 2.1).

Nondimensional equations (2a)-(2b) of the paper on the unit disk
(``r = a r_bar``, ``t = a^2 sqrt(rho h / D) t_bar``, ``w = h w_bar``, ``F = E h^3 F_bar``):

    Delta Delta w + eps_q Delta F + w'' = eps_c L(w, F)
    Delta Delta F - sqrt(kappa) Delta w = -1/2 L(w, w)

with ``eps_q = 12 (1 - nu^2) sqrt(kappa)``, ``eps_c = 12 (1 - nu^2)``,
``kappa = a^4 / (R^2 h^2)``; free edge (the default, the paper): ``w`` satisfies the free-plate
bending conditions, ``F = F_r = 0`` (``N_rr = N_rtheta = 0``). ``edge = "clamped"``: ``w = w_r = 0`` and
immovable in-plane displacements; the conditions this puts on F, their derivation and the bases
that replace the two below are in :mod:`stepnf.models._edges` (transverse: clamped-plate modes;
Airy: free-plate modes of Poisson ratio ``-nu``); every formula below holds unchanged.

Discretisation (Galerkin, exact in the limit):

* ``F = sum_b f_b Upsilon_b``: clamped-plate eigenfunctions
  (``Delta Delta Upsilon_b = xi_b^4 Upsilon_b``, ``Upsilon = Upsilon_r = 0`` at r = 1),
  complete for the free in-plane edge; ``n_airy`` of them per nodal-diameter number,
  for every k up to ``2 k_max``. Eliminating F exactly in this basis,
  ``f_b = (sqrt(kappa) A_b(w) - B_b(w, w) / 2) / xi_b^4`` with
  ``A_b(w) = int Upsilon_b Delta w dS`` and ``B_b(u, v) = int Upsilon_b L(u, v) dS``.
* ``w = sum_i X_i phi_i``: the transverse eigenmodes of the *shell*, computed for each
  nodal-diameter number ``k`` by a Ritz/Galerkin projection of the linear shell
  problem on ``n_galerkin`` elastic free-edge plate modes (Bessel ``J_k``, ``I_k``):
  ``K = diag(omega_plate^2) + 12 (1 - nu^2) kappa A^T diag(xi^-4) A``; the first
  ``n_transverse`` eigenvectors per (k, companion) are kept. Modes are normalised by
  ``int phi^2 dS = 1`` over the unit disk (the paper's normalisation).

Projecting (2a) on ``phi_p`` gives ``X_p'' + omega_p^2 X_p + g^p_ij X_i X_j + h^p_ijk X_i X_j X_k = 0``
(derived from the potential ``1/2 sum omega^2 X^2 + eps_c/2 sum_b xi_b^4 f_b^2``) with

    g^s_pp = -eps_c sqrt(kappa) sum_b [A_b(phi_s) B_b(phi_p, phi_p) / 2 + A_b(phi_p) B_b(phi_s, phi_p)] / xi_b^4
    h^p_ppp = eps_c / 2 sum_b B_b(phi_p, phi_p)^2 / xi_b^4       (>= 0: the plate hardens)

Angular selection rules (only these are computed, all others are exactly 0):
``A_b(phi)`` needs Upsilon_b of the same k and companion as phi; ``L(phi_p, phi_p)``
holds the harmonics 0 and ``2 k_p`` (cos) only, so ``h^p_ppp`` needs the Airy
functions of k = 0 and ``2 k_p`` (cos), and ``g^s_pp`` is non-zero only for modes s
with ``k_s = 0`` or ``k_s = 2 k_p`` (cos companion). Hence ``g^s_pp`` is complete
only for ``2 k_p <= k_max`` (see :meth:`VonKarmanShell.couplings_complete`).

Conventions: angular frequencies are nondimensional (``omega_bar``); the cos
companion of a mode is ``R(r) cos k theta``, the sin companion ``R(r) sin k theta``
(k = 0 modes are reported as "cos"); the radial part is signed so that
``R(1) > 0`` (clamped: ``R''(1) > 0``). Labels ``(k, n)``: k nodal diameters, n nodal circles (free
edge: n counted from 0 for k >= 2 and from 1 for k = 0, 1, whose n = 0 modes are the rigid motions
left out of the model; clamped edge: the edge counts as a circle, n from 1 for every k), ordered by
frequency within each k.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from stepnf.errors import SceneError
from stepnf.keys.checks import check_choice, check_number
from stepnf.keys.schema import Key, Schema
from stepnf.plugin.modal_model import ModalModel
from stepnf.plugin.shell_scales import ShellScales
from stepnf.models._couplings import laplacian, trilinear
from stepnf.models._edges import EDGES, NU_MIN_CLAMPED, airy_family, first_circle, plate_family, sign_derivative
from stepnf.models._quadrature import angular_factors, panel_rule, radial_panels
from stepnf.models._radial import RadialFamily, angular_weight

#: Defaults. k_max = 8 makes the couplings of every mode with k <= 4 complete (the paper's six
#: modes); with the other numbers T_NF of those six modes is within 3e-7 of a model with
#: (k_max, n_transverse, n_galerkin, n_airy) = (10, 20, 40, 50) at kappa = 0, 10, 25
#: (bench/vonkarman_convergence.py); n_galerkin defaults to max(20, n_transverse + 12). Clamped edge
#: (``--edge clamped``): T_NF of its first six modes within 5e-11 at kappa = 0 and 5e-6 at kappa = 10,
#: set by n_transverse (the NF sum over the axisymmetric modes kept: 4e-7 with n_transverse = 14).
DEFAULTS: dict[str, Any] = {"nu": 0.3, "k_max": 8, "n_transverse": 8, "n_galerkin": 20, "n_airy": 24,
                            "edge": "free"}

#: Allowed range of each parameter (``nu``: the open interval). kappa = a^4/(R^2 h^2) = (2 H/h)^2
#: with H ~ a^2/(2R) the rise of the cap: 1e6 is a cap rising 500 thicknesses, far beyond shallow-shell
#: theory (and the limit h >= a/1000 of the cap geometry keys, :mod:`stepnf.geometry.keys`, gives
#: kappa <= (a/h)^2 <= 1e6 there too); past ~1e7 the Ritz problem ``diag(omega^2) + 12 (1 - nu^2)
#: kappa A^T A`` loses its digits (the (2,0) frequency drifts by 3% at 1e8, and is wrong at 1e10).
#: The resolution bounds keep one model within about a minute and half a GiB: the cost grows like
#: k_max^2, n_transverse^2 and n_airy^2; the largest allowed (k_max, n_transverse, n_galerkin, n_airy)
#: = (16, 32, 64, 64) builds in 39 s and 0.3 GiB ((24, 60, 100, 100): 200 s and 1 GiB), while
#: (10, 20, 40, 50) already converges T to 3e-7 (bench/vonkarman_convergence.py).
RANGES: dict[str, tuple[float, float]] = {"kappa": (0.0, 1e6), "nu": (-1.0, 0.5), "k_max": (0, 16),
                                          "n_transverse": (1, 32), "n_galerkin": (1, 64), "n_airy": (1, 64)}


@dataclass
class ShellFamily:
    """Shell modes of one nodal-diameter number k (radial parts, shared by both companions)."""

    k: int
    omega: np.ndarray        # (n,)
    Q: np.ndarray            # (n_galerkin, n): plate-mode coefficients of each shell mode
    plate: RadialFamily
    f: tuple[np.ndarray, np.ndarray, np.ndarray]  # R, R', R'' on the radial rule, (n, m)
    A: np.ndarray            # (n_airy, n): int Upsilon_b Delta phi dS (same k, same companion)

    def radial(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        R, dR, d2R = self.plate.evaluate(r)
        return self.Q.T @ R, self.Q.T @ dR, self.Q.T @ d2R


@dataclass(frozen=True)
class GalerkinData:
    """What :meth:`VonKarmanShell.galerkin` gives (nondimensional, the module docstring's notation).

    ``families[k]``: the :class:`ShellFamily` of nodal-diameter number k (``omega``, radial parts ``f`` on
    the rule, ``A[b, j] = A_b(phi_j)``); ``airy_radial[kb]``: the Airy functions' radial parts on the rule
    (as ``_table`` gives them); ``xi4[kb]``: their ``xi_b^4``; ``r``, ``w``: the radial quadrature rule
    (``int_0^1 g(r) dr ~ sum w g(r)``); ``rows[i] = (omega, k, n, companion, j)`` of global mode i (increasing
    omega) and ``index[(k, j, companion)] = i``; ``omega``: the global angular frequencies; ``kappa``,
    ``eps_c``, ``k_max``: the model's.
    """

    families: Mapping[int, ShellFamily]
    airy_radial: Mapping[int, np.ndarray]
    xi4: Mapping[int, np.ndarray]
    r: np.ndarray
    w: np.ndarray
    rows: Sequence[tuple]
    index: Mapping[tuple, int]
    omega: np.ndarray
    kappa: float
    eps_c: float
    k_max: int


class VonKarmanShell(ModalModel):
    """Shallow spherical shell with a free or clamped edge, von Karman model, in modal coordinates.

    Parameters
    ----------
    kappa : aspect ratio ``a^4 / (R^2 h^2)`` (>= 0; 0 is the flat plate)
    nu : Poisson ratio (-1 < nu < 0.5)
    k_max : largest nodal-diameter number of the transverse modes kept
    n_transverse : shell modes kept per nodal-diameter number and companion
    n_galerkin : plate modes (of the same edge) per k in the Ritz basis of the shell modes (>= n_transverse)
    n_airy : Airy functions per k (for every k up to ``2 k_max``)
    edge : ``"free"`` (the paper) or ``"clamped"`` (``w = w_r = 0``, immovable in-plane edge)

    Each parameter must lie in its range of :data:`RANGES` (a :class:`SceneError` otherwise).

    Building costs ~0.07 s per kappa once the kappa-independent Bessel tables are
    cached (~1.5-2 s for the first model of a process).
    """

    name = "vonkarman"
    #: The ``[model]`` keys (``stepnf solvers --keys vonkarman``): ranges :data:`RANGES`, defaults
    #: :data:`DEFAULTS`.
    model_keys = Schema(
        Key("kappa", "number", "aspect ratio a^4/(R^2 h^2) of the shell (0: the flat plate)", required=True,
            lo=RANGES["kappa"][0], hi=RANGES["kappa"][1]),
        Key("nu", "number", "Poisson's ratio", default=DEFAULTS["nu"], lo=RANGES["nu"][0], hi=RANGES["nu"][1],
            lo_open=True, hi_open=True),
        Key("k_max", "integer", "largest nodal-diameter number of the transverse modes", default=DEFAULTS["k_max"],
            lo=RANGES["k_max"][0], hi=RANGES["k_max"][1]),
        Key("n_transverse", "integer", "shell modes kept per nodal-diameter number and companion",
            default=DEFAULTS["n_transverse"], lo=RANGES["n_transverse"][0], hi=RANGES["n_transverse"][1]),
        Key("n_galerkin", "integer", "plate modes per k in the Ritz basis, >= n_transverse (default "
            "max(20, n_transverse + 12))", lo=RANGES["n_galerkin"][0], hi=RANGES["n_galerkin"][1]),
        Key("n_airy", "integer", "Airy functions per k", default=DEFAULTS["n_airy"], lo=RANGES["n_airy"][0],
            hi=RANGES["n_airy"][1]),
        Key("edge", "choice", "edge condition: free, or clamped (w = dw/dr = 0, in-plane displacements 0)",
            default=DEFAULTS["edge"], choices=EDGES),
    )

    def __init__(self, kappa: float = 0.0, nu: float = DEFAULTS["nu"], k_max: int = DEFAULTS["k_max"],
                 n_transverse: int = DEFAULTS["n_transverse"], n_galerkin: int | None = None,
                 n_airy: int = DEFAULTS["n_airy"], edge: str = DEFAULTS["edge"]):
        if n_galerkin is None:
            n_galerkin = max(DEFAULTS["n_galerkin"], n_transverse + 12)
        _check(kappa, nu, k_max, n_transverse, n_galerkin, n_airy, None)
        self.edge = _check_edge(edge, nu, None)
        self.kappa, self.nu = float(kappa), float(nu)
        self.k_max, self.n_transverse = int(k_max), int(n_transverse)
        self.n_galerkin, self.n_airy = int(n_galerkin), int(n_airy)
        self.eps_c = 12.0 * (1.0 - self.nu**2)
        self.eps_q = self.eps_c * math.sqrt(self.kappa)
        t0 = time.perf_counter()
        self._build()
        self.build_seconds = time.perf_counter() - t0

    # ------------------------------------------------------------------ scene
    @classmethod
    def validate_config(cls, config: Mapping[str, Any], *, base_dir: Path | str = ".",
                        scene_file: Path | str | None = None) -> dict[str, Any]:
        """The ``[model]`` keys (:data:`MODEL_KEYS`), and ``n_galerkin >= n_transverse``."""
        kw = super().validate_config(config, base_dir=base_dir, scene_file=scene_file)
        n_tr = kw.get("n_transverse", DEFAULTS["n_transverse"])
        n_gal = kw.get("n_galerkin", max(DEFAULTS["n_galerkin"], n_tr + 12))
        _check(kw["kappa"], kw.get("nu", DEFAULTS["nu"]), kw.get("k_max", DEFAULTS["k_max"]), n_tr, n_gal,
               kw.get("n_airy", DEFAULTS["n_airy"]), scene_file)
        _check_edge(kw.get("edge", DEFAULTS["edge"]), kw.get("nu", DEFAULTS["nu"]), scene_file)
        return kw

    # ------------------------------------------------------------------ build
    def _build(self) -> None:
        nu, kmax, edge = self.nu, self.k_max, self.edge
        self._airy = {k: _family("airy", k, self.n_airy, nu, edge) for k in range(2 * kmax + 1)}
        plates = {k: _family("plate", k, self.n_galerkin, nu, edge) for k in range(kmax + 1)}
        lam_max = max(max(f.lam.max() for f in self._airy.values()), max(f.lam.max() for f in plates.values()))
        panels = radial_panels(lam_max)
        self._r, self._w = panel_rule(panels, 16)
        r, w = self._r, self._w
        self._airy_r = {k: _table("airy", k, self.n_airy, nu, edge, panels)[0] for k in self._airy}
        self._xi4 = {k: f.lam**4 for k, f in self._airy.items()}
        beta = self.eps_c * self.kappa  # eps_q sqrt(kappa)
        self._fam: dict[int, ShellFamily] = {}
        for k, pf in plates.items():
            fr = _table("plate", k, self.n_galerkin, nu, edge, panels)
            A = angular_weight(k) * (self._airy_r[k] * (r * w)) @ laplacian(fr, k, r).T  # (n_airy, n_gal)
            K = np.diag(pf.lam**4) + beta * (A.T / self._xi4[k]) @ A
            lam2, V = np.linalg.eigh(0.5 * (K + K.T))
            V = V[:, : self.n_transverse]
            R1 = pf.evaluate(np.array([1.0]))[sign_derivative(edge)][:, 0] @ V
            V = V * np.where(R1 < 0, -1.0, 1.0)
            f = (V.T @ fr[0], V.T @ fr[1], V.T @ fr[2])
            self._fam[k] = ShellFamily(k, np.sqrt(lam2[: self.n_transverse]), V, pf, f, A @ V)
        # global mode list: (omega, k, n, companion)
        rows = []
        for k, fam in self._fam.items():
            n0 = first_circle(edge, k)
            for j, om in enumerate(fam.omega):
                for comp in (("cos",) if k == 0 else ("cos", "sin")):
                    rows.append((float(om), k, n0 + j, comp, j))
        rows.sort(key=lambda t: (t[0], t[1], t[2], t[3] == "sin"))
        self._rows = rows
        self._omega = np.array([t[0] for t in rows])
        self._index = {(t[1], t[4], t[3]): i for i, t in enumerate(rows)}
        self._maxima: np.ndarray | None = None
        self._couple()

    def _couple(self) -> None:
        """h^p_ppp and g^s_pp from the selection rules (only the non-vanishing k-combinations)."""
        m = len(self._rows)
        r, w = self._r, self._w
        self._g = np.zeros((m, m))  # _g[p, s] = g^s_pp
        self._h = np.zeros(m)
        root = math.sqrt(self.kappa)
        for k, fam in self._fam.items():
            for comp in (("cos",) if k == 0 else ("cos", "sin")):
                P = [self._index[(k, j, comp)] for j in range(len(fam.omega))]
                # B_b(phi_p, phi_p) for Airy classes 0 and 2k (cos)
                Bpp = {}
                for kb in sorted({0, 2 * k}):
                    ang = angular_factors(("cos", kb), (comp, k), (comp, k))
                    Bpp[kb] = trilinear(self._airy_r[kb], fam.f, k, fam.f, k, r, w, ang, diagonal=True)
                    self._h[P] += 0.5 * self.eps_c * np.sum(Bpp[kb] ** 2 / self._xi4[kb][:, None], axis=0)
                if root == 0.0:
                    continue  # the plate: g = 0 exactly
                for kt in sorted({0, 2 * k}):
                    if kt not in self._fam:
                        continue  # 2k > k_max: those modes are not in the model
                    tf = self._fam[kt]
                    S = [self._index[(kt, j, "cos")] for j in range(len(tf.omega))]
                    term1 = 0.5 * (tf.A.T / self._xi4[kt]) @ Bpp[kt]  # (s, p)
                    ang = angular_factors((comp, k), ("cos", kt), (comp, k))
                    Bsp = trilinear(self._airy_r[k], tf.f, kt, fam.f, k, r, w, ang)  # (b, s, p)
                    term2 = np.einsum("bp,bsp->sp", fam.A / self._xi4[k][:, None], Bsp)
                    g = -self.eps_c * root * (term1 + term2)
                    self._g[np.ix_(P, S)] = g.T

    # ------------------------------------------------------------------ API
    def galerkin(self) -> "GalerkinData":
        """The Galerkin data of the model (read-only views), for computations beyond ``g`` and ``h``: the
        whole modal force of :mod:`stepnf.pipeline.modal_forces` (see :class:`GalerkinData`)."""
        return GalerkinData(self._fam, self._airy_r, self._xi4, self._r, self._w, self._rows, self._index,
                            self._omega, self.kappa, self.eps_c, self.k_max)

    def omegas(self) -> np.ndarray:
        """Nondimensional angular frequencies ``omega_bar`` (m,), increasing."""
        return self._omega.copy()

    def labels(self) -> list[tuple[int, int]]:
        """``(k, n)`` of each mode; the two companions of a k >= 1 mode share it (see :meth:`companions`)."""
        return [(t[1], t[2]) for t in self._rows]

    def companions(self) -> list[str]:
        """``"cos"`` (``R(r) cos k theta``; also every k = 0 mode) or ``"sin"`` (``R(r) sin k theta``)."""
        return [t[3] for t in self._rows]

    def index(self, k: int, n: int, companion: str = "cos") -> int:
        """Position of mode ``(k, n)`` (given companion) in :meth:`omegas`."""
        n0 = first_circle(self.edge, k)
        key = (int(k), int(n) - n0, "cos" if k == 0 else companion)
        if key not in self._index:
            raise KeyError(f"mode {(k, n)} ({companion}) is not in the model "
                           f"(k <= {self.k_max}, n from {n0} to {n0 + self.n_transverse - 1})")
        return self._index[key]

    def quadratic_coefficients(self, p: int) -> np.ndarray:
        """``g^s_pp`` for every mode s (m,); exact zeros where the selection rules say so."""
        return self._g[p].copy()

    def cubic_coefficient(self, p: int) -> float:
        """``h^p_ppp`` (>= 0)."""
        return float(self._h[p])

    def couplings_complete(self, p: int) -> bool:
        """True when every mode coupled to p by g^s_pp is in the model (``2 k_p <= k_max``)."""
        return 2 * self._rows[p][1] <= self.k_max

    def radial_shape(self, p: int, r: np.ndarray) -> np.ndarray:
        """Radial part ``R_p(r)`` of mode p (the mode is ``R_p(r) cos`` or ``sin (k theta)``)."""
        k, j = self._rows[p][1], self._rows[p][4]
        return self._fam[k].radial(np.asarray(r, dtype=float))[0][j]

    def mode_shape(self, p: int, r: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Mode p at polar points (broadcast ``r``, ``theta``), ``int phi^2 dS = 1``."""
        r, theta = np.broadcast_arrays(np.asarray(r, float), np.asarray(theta, float))
        k, comp = self._rows[p][1], self._rows[p][3]
        ru, inv = np.unique(r.ravel(), return_inverse=True)
        R = self.radial_shape(p, ru)[inv].reshape(r.shape)
        return R * (np.cos(k * theta) if comp == "cos" else np.sin(k * theta))

    def mode_maxima(self) -> np.ndarray:
        """``max |phi_p|`` over the unit disk (the angular factor peaks at 1): for Gamma = T / max^2.

        From the radial parts on 2001 equispaced radii (tabulated once per plate family),
        refined by a parabola through the largest sample and its neighbours (error ~1e-9).
        """
        if self._maxima is None:
            out = np.empty(len(self._rows))
            for k, fam in self._fam.items():
                R = np.abs(fam.Q.T @ _shape_table(k, self.n_galerkin, self.nu, self.edge))
                for j in range(len(fam.omega)):
                    val = _peak(R[j], 1.0 / (R.shape[1] - 1))
                    for comp in (("cos",) if k == 0 else ("cos", "sin")):
                        out[self._index[(k, j, comp)]] = val
            self._maxima = out
        return self._maxima.copy()

    def shell_scales(self) -> ShellScales:
        return ShellScales(kappa=self.kappa, omega_factor=1.0, thickness=1.0)

    def describe(self) -> dict[str, Any]:
        return {
            "model": type(self).__name__, "solver": self.name, "kappa": self.kappa, "nu": self.nu,
            "k_max": self.k_max, "n_transverse": self.n_transverse, "n_galerkin": self.n_galerkin,
            "n_airy": self.n_airy, "edge": self.edge, "n_modes": int(self.n_modes), "radial_nodes": int(self._r.size),
            "normalisation": "integral of phi^2 over the unit disk = 1; omega nondimensional",
            "couplings_complete_for_k_up_to": self.k_max // 2,
            "build_seconds": round(self.build_seconds, 4),
        }


@lru_cache(maxsize=256)
def _family(kind: str, k: int, n: int, nu: float, edge: str) -> RadialFamily:
    """Plate modes / Airy functions of ``edge``, cached: they do not depend on kappa (a kappa sweep
    reuses them). ``nu`` is passed on only where the family depends on it (no cache entry per nu
    for the free edge's Airy functions or the clamped plate modes)."""
    if (kind == "airy") == (edge == "free"):
        nu = 0.0
    return _cached(kind, k, n, nu, edge)


@lru_cache(maxsize=256)
def _cached(kind: str, k: int, n: int, nu: float, edge: str) -> RadialFamily:
    return (airy_family if kind == "airy" else plate_family)(edge, k, n, nu)


@lru_cache(maxsize=256)
def _table(kind: str, k: int, n: int, nu: float, edge: str, panels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``R, R', R''`` of :func:`_family` on the radial rule with ``panels`` panels (read-only, cached)."""
    out = _family(kind, k, n, nu, edge).evaluate(panel_rule(panels, 16)[0])
    for a in out:
        a.setflags(write=False)
    return out


@lru_cache(maxsize=64)
def _shape_table(k: int, n: int, nu: float, edge: str) -> np.ndarray:
    """Plate radial functions ``R`` on 2001 equispaced radii in [0, 1] (read-only, cached)."""
    R = _family("plate", k, n, nu, edge).evaluate(np.linspace(0.0, 1.0, 2001))[0]
    R.setflags(write=False)
    return R


def _peak(y: np.ndarray, dx: float) -> float:
    """Largest value of a smooth sampled function: the vertex of the parabola through the
    largest sample and its neighbours (the sample itself at an end of the interval)."""
    i = int(np.argmax(y))
    if i == 0 or i == len(y) - 1:
        return float(y[i])
    a, b, c = y[i - 1], y[i], y[i + 1]
    den = a - 2 * b + c
    return float(b) if den >= 0 else float(b - 0.125 * (c - a) ** 2 / den)


def _check(kappa: float, nu: float, k_max: int, n_transverse: int, n_galerkin: int, n_airy: int,
           scene_file: Path | None) -> None:
    """Every parameter within :data:`RANGES`, and ``n_galerkin >= n_transverse``."""
    values = {"kappa": kappa, "nu": nu, "k_max": k_max, "n_transverse": n_transverse, "n_galerkin": n_galerkin,
              "n_airy": n_airy}
    for key, val in values.items():
        lo, hi = RANGES[key]
        check_number(scene_file, f"model.{key}", val, integer=key not in ("kappa", "nu"), lo=lo, hi=hi,
                     lo_open=key == "nu", hi_open=key == "nu")
    if n_galerkin < n_transverse:
        raise SceneError(scene_file, "model.n_galerkin",
                         f"must be >= n_transverse = {n_transverse} (the shell modes are taken from "
                         f"a Ritz basis of n_galerkin plate modes), got {n_galerkin!r}")


def _check_edge(edge: str, nu: float, scene_file: Path | None) -> str:
    """``edge`` one of :data:`EDGES`; with the clamped edge, ``nu >= NU_MIN_CLAMPED`` (see there)."""
    check_choice(scene_file, "model.edge", edge, EDGES)
    if edge == "clamped" and nu < NU_MIN_CLAMPED:
        raise SceneError(scene_file, "model.nu", f"must be >= {NU_MIN_CLAMPED!r} with edge = \"clamped\" (its Airy "
                         f"functions, free-plate modes of Poisson ratio -nu, degenerate as nu -> -1), got {nu!r}")
    return edge
