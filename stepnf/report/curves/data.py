"""The curves' vocabulary: methods, quantities, flag bits, options and the result container.

See :mod:`stepnf.report.curves` for what the values, flags and gaps mean.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stepnf.errors import StepnfError, allowed
from stepnf.methods import MD, NF, SMD
from stepnf.nf.evaluators import Tolerances

#: The six master modes of the paper's Fig. 3.
DEFAULT_MODES: tuple[tuple[int, int], ...] = ((2, 0), (3, 0), (4, 0), (0, 1), (0, 2), (2, 1))
#: With ``edge = "clamped"``: its first six modes (labels counting the clamped edge as a nodal circle).
CLAMPED_MODES: tuple[tuple[int, int], ...] = ((0, 1), (1, 1), (2, 1), (0, 2), (3, 1), (1, 2))
#: The edges of :class:`stepnf.models.VonKarmanShell` (its ``edge``; not imported: the model loads lazily).
EDGES: tuple[str, ...] = ("free", "clamped")
#: The methods drawn, each at modal order over every mode of the model (:mod:`stepnf.methods`).
METHODS: tuple[str, ...] = (NF, MD, SMD)
QUANTITIES: tuple[str, ...] = ("T", "gamma")

RES_1_2 = 1          #: NF: a coupled mode within gap_resonance of twice the master frequency (significant)
RES_1_1 = 2          #: MD: a coupled mode within gap_resonance of the master frequency (significant)
NEAR_RESONANCE = 4   #: flagged by the evaluator (tolerances.resonance) but not a gap (see :mod:`stepnf.report.curves`)
NON_FINITE = 8       #: T = +-inf (exact resonance)
HUGE = 16            #: |T| > huge * T_cubic
INCOMPLETE = 32      #: the model lacks modes the master couples to (2 k_p > k_max)
FLAG_BITS: dict[str, int] = {"internal_resonance_1_2": RES_1_2, "internal_resonance_1_1": RES_1_1,
                             "near_resonance": NEAR_RESONANCE, "non_finite": NON_FINITE,
                             "huge": HUGE, "couplings_incomplete": INCOMPLETE}
#: Flags that break the plotted line.
GAP_MASK = RES_1_2 | RES_1_1 | NON_FINITE | HUGE | INCOMPLETE


class CurvesError(StepnfError, ValueError):
    """Bad input to the curves (mode not in the model, bad grid, unknown quantity)."""


@dataclass(frozen=True)
class CurveOptions:
    """What to compute.

    ``kappas`` overrides the grid ``linspace(0, kappa_max, n_kappa)``; ``modes`` are
    ``(k, n)`` labels (cos companion); ``omega_max`` selects the Fig. 2 modes: every
    ``(k, n)`` whose frequency at the first kappa is below it (nondimensional);
    ``model`` holds extra keyword arguments of :class:`VonKarmanShell` (``k_max``,
    ``n_transverse``, ``n_galerkin``, ``n_airy``); ``edge`` is the shell's edge, ``"free"`` (the
    paper) or ``"clamped"`` (immovable), whose default ``modes`` are :data:`CLAMPED_MODES`.
    """

    kappa_max: float = 100.0
    n_kappa: int = 200
    kappas: tuple[float, ...] | None = None
    modes: tuple[tuple[int, int], ...] = DEFAULT_MODES
    nu: float = 0.3
    tolerances: Tolerances = Tolerances()
    gap_resonance: float = 0.02
    significance: float = 0.1
    huge: float = 1e3
    omega_max: float = 80.0
    degeneracy: float = 1e-3
    model: dict[str, int] = field(default_factory=dict)
    edge: str = "free"

    #: 200 kappa values take ~15 s; 10 000 take about 12 minutes, beyond any figure's resolution
    MAX_KAPPAS = 10_000

    def __post_init__(self) -> None:
        """Refuse options no curve can be drawn with (the CLI's arguments arrive here unchecked)."""
        for name, value in (("resonance_tol", self.tolerances.resonance), ("gap_tol", self.gap_resonance)):
            if not (isinstance(value, (int, float)) and 0 < value < 1):
                raise CurvesError(f"{name}: expected a relative window in (0, 1), got {value!r}")
        if not (isinstance(self.omega_max, (int, float)) and math.isfinite(self.omega_max) and self.omega_max > 0):
            raise CurvesError(f"omega_max: expected a finite number > 0, got {self.omega_max!r}")
        if self.kappas is None and not (isinstance(self.n_kappa, int) and self.n_kappa <= self.MAX_KAPPAS):
            raise CurvesError(f"n_kappa: expected an integer in [2, {self.MAX_KAPPAS}], got {self.n_kappa!r}")
        if self.edge not in EDGES:
            raise CurvesError(f"edge: expected one of {allowed(EDGES)}, got {self.edge!r}")
        if self.edge == "clamped" and self.modes == DEFAULT_MODES:  # the free edge's labels: not modes of it
            object.__setattr__(self, "modes", CLAMPED_MODES)

    def grid(self) -> np.ndarray:
        if self.kappas is not None:
            k = np.asarray(self.kappas, dtype=float).ravel()
            if k.size == 0 or not np.all(np.isfinite(k)) or np.any(k < 0):
                raise CurvesError(f"kappas: expected finite values >= 0, got {list(self.kappas)!r}")
            return np.sort(k)
        if not (math.isfinite(self.kappa_max) and self.kappa_max > 0):
            raise CurvesError(f"kappa_max: expected a finite number > 0, got {self.kappa_max!r}")
        if int(self.n_kappa) < 2:
            raise CurvesError(f"n_kappa: expected an integer >= 2, got {self.n_kappa!r}")
        return np.linspace(0.0, float(self.kappa_max), int(self.n_kappa))


@dataclass
class Curves:
    """Results on the kappa grid. Arrays are (n_modes, n_kappa) unless stated."""

    kappa: np.ndarray
    modes: list[tuple[int, int]]
    omega: np.ndarray
    w_max: np.ndarray
    rho: np.ndarray
    rho_mode: np.ndarray          # label text of the mode that sets rho_p (object array)
    T_cubic: np.ndarray
    T: dict[str, np.ndarray]
    gamma: dict[str, np.ndarray]
    flags: dict[str, np.ndarray]  # int bit fields, FLAG_BITS
    notes: dict[str, np.ndarray]  # flag messages (object array, "" when none)
    freq_labels: list[tuple[int, int]]
    frequencies: np.ndarray       # (n_labels, n_kappa)
    options: CurveOptions
    model: dict[str, Any]
    seconds: float = 0.0

    def row(self, mode: tuple[int, int]) -> int:
        """Row of ``mode`` in the arrays."""
        mode = tuple(int(v) for v in mode)  # type: ignore[assignment]
        if mode not in self.modes:
            raise CurvesError(f"mode {mode} not computed; computed: {self.modes}")
        return self.modes.index(mode)  # type: ignore[arg-type]

    def gaps(self, method: str) -> np.ndarray:
        """Boolean mask of the points that break the plotted line of ``method``."""
        return (self.flags[check_method(method)] & GAP_MASK) != 0

    def values(self, method: str, quantity: str = "T") -> np.ndarray:
        """Stored values (``T`` or ``gamma``), flagged points included."""
        q = check_quantity(quantity)
        return (self.T if q == "T" else self.gamma)[check_method(method)]

    def plotted(self, method: str, quantity: str = "T") -> np.ndarray:
        """What the figures draw: the values with NaN at the gaps."""
        v = self.values(method, quantity).copy()
        v[self.gaps(method)] = np.nan
        return v


def check_method(m: str) -> str:
    """``m`` if it is one of :data:`METHODS`, else :class:`CurvesError` naming the allowed ones."""
    if m not in METHODS:
        raise CurvesError(f"unknown method {m!r}; allowed {allowed(METHODS)}")
    return m


def check_quantity(q: str) -> str:
    """``q`` if it is one of :data:`QUANTITIES` (``"T"`` or ``"gamma"``), else :class:`CurvesError`."""
    if q not in QUANTITIES:
        raise CurvesError(f"unknown quantity {q!r}; allowed {allowed(QUANTITIES)}")
    return q


def parse_mode(text: str) -> tuple[int, int]:
    """``"(2,0)"``, ``"2,0"`` or ``"2 0"`` -> ``(2, 0)``."""
    parts = text.replace("(", " ").replace(")", " ").replace(",", " ").split()
    if len(parts) != 2 or not all(p.lstrip("-").isdigit() for p in parts):
        raise CurvesError(f"mode {text!r}: expected two integers such as '(2,0)'")
    return (int(parts[0]), int(parts[1]))
