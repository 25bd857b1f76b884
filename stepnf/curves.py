"""Type of nonlinearity versus the shell aspect ratio kappa: the paper's Figs. 2 and 3.

For the von Karman shell model (:class:`stepnf.models.VonKarmanShell`) on a grid of
``kappa = a^4 / (R^2 h^2)`` this computes, per master mode ``(k, n)`` (cos companion):

* ``T_p`` by NF (normal form, all modes of the model), MD and SMD (Table 1 of the
  paper, :mod:`stepnf.evaluators`), in the model's normalisation (``int phi^2 dS = 1``
  over the unit disk, nondimensional time): ``w_NL = w_p (1 + T_p a^2)``;
* ``Gamma = T_p / max|phi_p|^2`` (``w_NL / w_p = 1 + Gamma (W_max / h)^2``, DESIGN.md);
* ``rho_p`` (paper Eq. 8) and the mode it is attained for, as ``stepnf run`` computes it
  (:func:`stepnf.pipeline.slow_fast_ratio`): over the slave modes the master drives
  (``g^s_pp != 0``), degenerate twins excluded; at kappa = 0 (g = 0) over every non-twin
  mode, hence a jump between the first two grid values for modes such as (3,0);
* flags (bit field, :data:`FLAG_BITS`) naming why a value must not be trusted;

and the nondimensional frequencies of the first modes versus kappa (Fig. 2).

Flags and gaps. A method's value at one kappa is *flagged* when the evaluator reports an
internal resonance with a coupled mode (1:2 for NF, 1:1 for MD) within
``tolerances.resonance`` (the library's 5 % by default), when T is not finite, when
``|T|`` exceeds ``huge`` times the single-mode cubic scale ``T_cubic = 3 h_ppp / (8 w_p^2)``
(> 0 for every mode of the shell), or when the model does not hold every mode the master
couples to. A resonance makes a *gap* only when the frequency ratio is within
``gap_resonance`` (2 % by default) of 1:2 / 1:1 *and* the small-denominator terms change
T by more than ``significance * T_cubic``; otherwise it is recorded with bit
``NEAR_RESONANCE`` and the curve stays drawn. The narrower window is needed because the
shell's frequency ratios drift slowly with kappa: w(0,3)/w(0,2) stays within 5 % of 2 for
kappa in [32, 83], w(4,1)/w(2,1) for kappa in [2.5, 30], so the 5 % window would blank
most of those curves although T is finite and smooth there. Non-finite, huge and
incomplete values are always gaps. At a gap the stored data keep the value and its flag,
the plotted arrays (:meth:`Curves.plotted`) hold NaN, and the figure marks the point
with a tick at the bottom of the panel.

Data go to HDF5 (:func:`write_hdf5`) and CSV (:func:`write_csv`); figures to PNG with
matplotlib's Agg backend (:func:`plot_frequencies`, :func:`plot_nonlinearity`).
"""
from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from .errors import StepnfError, allowed
from .evaluators import Tolerances, md_modal, nf_modal, smd_modal

#: The six master modes of the paper's Fig. 3.
DEFAULT_MODES: tuple[tuple[int, int], ...] = ((2, 0), (3, 0), (4, 0), (0, 1), (0, 2), (2, 1))
METHODS: tuple[str, ...] = ("nf", "md", "smd")
QUANTITIES: tuple[str, ...] = ("T", "gamma")

RES_1_2 = 1          #: NF: a coupled mode within gap_resonance of twice the master frequency (significant)
RES_1_1 = 2          #: MD: a coupled mode within gap_resonance of the master frequency (significant)
NEAR_RESONANCE = 4   #: flagged by the evaluator (tolerances.resonance) but not a gap (see module doc)
NON_FINITE = 8       #: T = +-inf (exact resonance)
HUGE = 16            #: |T| > huge * T_cubic
INCOMPLETE = 32      #: the model lacks modes the master couples to (2 k_p > k_max)
FLAG_BITS: dict[str, int] = {"internal_resonance_1_2": RES_1_2, "internal_resonance_1_1": RES_1_1,
                             "near_resonance": NEAR_RESONANCE, "non_finite": NON_FINITE,
                             "huge": HUGE, "couplings_incomplete": INCOMPLETE}
#: Flags that break the plotted line.
GAP_MASK = RES_1_2 | RES_1_1 | NON_FINITE | HUGE | INCOMPLETE

_COLORS = {"nf": "#d000d0", "md": "#d62728", "smd": "#e0b000"}   # magenta, red, yellow (paper)
_NAMES = {"nf": "NF", "md": "QM MD", "smd": "QM SMD"}


class CurvesError(StepnfError, ValueError):
    """Bad input to the curves (mode not in the model, bad grid, unknown quantity)."""


@dataclass(frozen=True)
class CurveOptions:
    """What to compute.

    ``kappas`` overrides the grid ``linspace(0, kappa_max, n_kappa)``; ``modes`` are
    ``(k, n)`` labels (cos companion); ``omega_max`` selects the Fig. 2 modes: every
    ``(k, n)`` whose frequency at the first kappa is below it (nondimensional);
    ``model`` holds extra keyword arguments of :class:`VonKarmanShell` (``k_max``,
    ``n_transverse``, ``n_galerkin``, ``n_airy``).
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
        return (self.flags[_method(method)] & GAP_MASK) != 0

    def values(self, method: str, quantity: str = "T") -> np.ndarray:
        """Stored values (``T`` or ``gamma``), flagged points included."""
        q = _quantity(quantity)
        return (self.T if q == "T" else self.gamma)[_method(method)]

    def plotted(self, method: str, quantity: str = "T") -> np.ndarray:
        """What the figures draw: the values with NaN at the gaps."""
        v = self.values(method, quantity).copy()
        v[self.gaps(method)] = np.nan
        return v


# ------------------------------------------------------------------ computation
def compute_curves(options: CurveOptions = CurveOptions(),
                   progress: Callable[[int, int], None] | None = None) -> Curves:
    """Evaluate every mode and method on the kappa grid (one model per kappa, ~0.07 s each)."""
    from .models import VonKarmanShell
    from .pipeline import slow_fast_ratio

    kap = options.grid()
    modes = [_mode(m) for m in options.modes]
    if not modes:
        raise CurvesError("modes: give at least one (k, n) label")
    t0 = time.perf_counter()
    nm, nk = len(modes), len(kap)
    omega, w_max, rho, T_cubic = (np.full((nm, nk), np.nan) for _ in range(4))
    rho_mode = np.full((nm, nk), "", dtype=object)
    T = {m: np.full((nm, nk), np.nan) for m in METHODS}
    flags = {m: np.zeros((nm, nk), dtype=np.int64) for m in METHODS}
    notes = {m: np.full((nm, nk), "", dtype=object) for m in METHODS}
    freq_labels: list[tuple[int, int]] = []
    freqs = np.empty((0, nk))
    tol = options.tolerances
    describe: dict[str, Any] = {}
    for j, kappa in enumerate(kap):
        model = VonKarmanShell(kappa=float(kappa), nu=options.nu, **options.model)
        om, labels, comps = model.omegas(), model.labels(), model.companions()
        S = np.arange(len(om))
        if j == 0:
            describe = model.describe()
            _check_modes(model, modes)
            freq_labels = _first_labels(om, labels, options.omega_max, model.k_max)
            freqs = np.full((len(freq_labels), nk), np.nan)
        first = {}
        for i, lab in enumerate(labels):
            first.setdefault(tuple(lab), om[i])
        freqs[:, j] = [first[lab] for lab in freq_labels]
        wm = model.mode_maxima()
        for i, kn in enumerate(modes):
            p = model.index(*kn)
            g, h = model.quadratic_coefficients(p), model.cubic_coefficient(p)
            wp = om[p]
            twins = [s for s in S if s != p and abs(om[s] - wp) <= options.degeneracy * wp]
            r, rm = slow_fast_ratio(p, om, g, tol, twins)
            omega[i, j], w_max[i, j], T_cubic[i, j] = wp, wm[p], 3.0 * h / (8.0 * wp * wp)
            rho[i, j] = np.nan if r is None else r
            rho_mode[i, j] = "" if rm is None else _label_text(labels[rm], comps[rm])
            complete = model.couplings_complete(p)
            for name, ev in (("nf", nf_modal), ("md", md_modal), ("smd", smd_modal)):
                res = ev(p, om, g, h, S, tol=tol, labels=labels)
                T[name][i, j] = res.T
                f, text = _classify(name, res, p, om, g, T_cubic[i, j], complete, options)
                flags[name][i, j], notes[name][i, j] = f, text
        if progress is not None:
            progress(j + 1, nk)
    gamma = {m: T[m] / w_max**2 for m in METHODS}
    return Curves(kappa=kap, modes=modes, omega=omega, w_max=w_max, rho=rho, rho_mode=rho_mode,
                  T_cubic=T_cubic, T=T, gamma=gamma, flags=flags, notes=notes, freq_labels=freq_labels,
                  frequencies=freqs, options=options, model=describe, seconds=time.perf_counter() - t0)


def resonant_contribution(method: str, p: int, s: int, omega: np.ndarray, g: np.ndarray) -> float:
    """Part of T that the term of slave mode ``s`` brings (Table 1 with Eq. 7), NF or MD.

    NF: ``[-6 g^2 (ws^2 - 2w^2) + 4 g^2 w^2] / (ws^2 (ws^2 - 4w^2)) / (8 w^2)``;
    MD: ``[-6 g^2 (ws^2 - 2w^2) - 8 g^2 w^2] / (ws^2 - w^2)^2 / (8 w^2)``; ``+-inf`` at exact resonance.
    """
    w2, ws2, g2 = omega[p] ** 2, omega[s] ** 2, float(g[s]) ** 2
    if method == "nf":
        num, den = -6 * g2 * (ws2 - 2 * w2) + 4 * g2 * w2, ws2 * (ws2 - 4 * w2)
    elif method == "md":
        num, den = -6 * g2 * (ws2 - 2 * w2) - 8 * g2 * w2, (ws2 - w2) ** 2
    else:
        raise CurvesError(f"resonant_contribution: method {method!r} has no resonant terms; "
                          f"allowed {allowed(['nf', 'md'])}")
    if den == 0:
        return math.copysign(math.inf, num) if num != 0 else 0.0
    return num / den / (8 * w2)


def _classify(name: str, res: Any, p: int, om: np.ndarray, g: np.ndarray, t_cubic: float,
              complete: bool, options: CurveOptions) -> tuple[int, str]:
    bits, texts = 0, []
    if res.flags:
        for fl in res.flags:
            s = fl.get("mode")
            dT = math.inf if s is None else resonant_contribution(name, p, int(s), om, g)
            target = 2.0 if fl["kind"] == "internal_resonance_1_2" else 1.0
            ratio = fl.get("ratio", target)
            close = abs(ratio - target) <= options.gap_resonance * target
            strong = not abs(dT) <= options.significance * t_cubic
            bits |= FLAG_BITS[fl["kind"]] if (close and strong) else NEAR_RESONANCE
            texts.append(f"{fl['message']}; its terms change T by {dT:.3g} (T_cubic = {t_cubic:.3g})"
                         + ("" if close and strong else " [near: no gap]"))
    if not math.isfinite(res.T):
        bits |= NON_FINITE
        texts.append(f"{name.upper()}: T = {res.T} (exact resonance)")
    elif abs(res.T) > options.huge * t_cubic:
        bits |= HUGE
        texts.append(f"{name.upper()}: |T| = {abs(res.T):.3g} > {options.huge:g} T_cubic")
    if not complete:
        bits |= INCOMPLETE
        texts.append("the model lacks modes with k = 2 k_p (raise k_max)")
    return bits, "; ".join(texts)


def _first_labels(om: np.ndarray, labels: Sequence[Any], omega_max: float, k_max: int) -> list[tuple[int, int]]:
    """Distinct (k, n) labels with frequency below omega_max, by increasing frequency."""
    top = min((w for w, lab in zip(om, labels) if tuple(lab) == (k_max, 0)), default=math.inf)
    if omega_max > top:
        raise CurvesError(f"omega_max = {omega_max:g} is above the frequency {top:.4g} of mode ({k_max}, 0): "
                          f"modes with k > k_max = {k_max} could lie below it; lower omega_max or raise k_max")
    out: list[tuple[int, int]] = []
    for w, lab in zip(om, labels):
        lab = (int(lab[0]), int(lab[1]))
        if w <= omega_max and lab not in out:
            out.append(lab)
    return out


def _check_modes(model: Any, modes: Sequence[tuple[int, int]]) -> None:
    for kn in modes:
        try:
            p = model.index(*kn)
        except KeyError as exc:
            raise CurvesError(f"modes: {kn} is not in the model: {exc.args[0]}") from None
        if not model.couplings_complete(p):
            raise CurvesError(f"modes: {kn} couples to modes with k = {2 * kn[0]} > k_max = {model.k_max}; "
                              f"use k <= {model.k_max // 2} or raise k_max")


def _mode(m: Any) -> tuple[int, int]:
    try:
        k, n = (int(v) for v in m)
    except (TypeError, ValueError):
        raise CurvesError(f"modes: expected (k, n) pairs of integers, got {m!r}") from None
    return (k, n)


def _method(m: str) -> str:
    if m not in METHODS:
        raise CurvesError(f"unknown method {m!r}; allowed {allowed(METHODS)}")
    return m


def _quantity(q: str) -> str:
    if q not in QUANTITIES:
        raise CurvesError(f"unknown quantity {q!r}; allowed {allowed(QUANTITIES)}")
    return q


def _label_text(lab: Any, comp: str = "cos") -> str:
    k, n = lab
    return f"({k},{n})" + ("" if k == 0 or comp == "cos" else " sin")


def parse_mode(text: str) -> tuple[int, int]:
    """``"(2,0)"``, ``"2,0"`` or ``"2 0"`` -> ``(2, 0)``."""
    parts = text.replace("(", " ").replace(")", " ").replace(",", " ").split()
    if len(parts) != 2 or not all(p.lstrip("-").isdigit() for p in parts):
        raise CurvesError(f"mode {text!r}: expected two integers such as '(2,0)'")
    return (int(parts[0]), int(parts[1]))


# ------------------------------------------------------------------ summary
def sign_disagreements(curves: Curves, method: str, mode: tuple[int, int]) -> list[tuple[float, float]]:
    """kappa ranges (first, last grid value) where ``method`` and NF differ in sign.

    Only points where neither method has a gap count; a gap ends a range. The true
    boundaries lie within one grid step of the reported ones.
    """
    i = curves.row(mode)
    a, b = curves.T[_method(method)][i], curves.T["nf"][i]
    ok = ~curves.gaps(method)[i] & ~curves.gaps("nf")[i] & np.isfinite(a) & np.isfinite(b)
    bad = ok & (np.sign(a) != np.sign(b))
    out, start = [], None
    for j in range(len(bad)):
        if bad[j] and start is None:
            start = j
        if start is not None and (j == len(bad) - 1 or not bad[j + 1]):
            out.append((float(curves.kappa[start]), float(curves.kappa[j])))
            start = None
    return out


def summary(curves: Curves) -> list[dict[str, Any]]:
    """Per mode: sign-disagreement ranges of MD and SMD with NF, and the gap counts."""
    rows = []
    for i, kn in enumerate(curves.modes):
        row: dict[str, Any] = {"mode": kn}
        for m in ("md", "smd"):
            row[f"wrong_sign_{m}"] = sign_disagreements(curves, m, kn)
        for m in METHODS:
            row[f"gaps_{m}"] = int(curves.gaps(m)[i].sum())
        rows.append(row)
    return rows


def format_summary(curves: Curves) -> str:
    """Plain-text table of :func:`summary`."""
    def rng(r: list[tuple[float, float]]) -> str:
        return ", ".join(f"[{a:.4g}, {b:.4g}]" if a != b else f"{{{a:.4g}}}" for a, b in r) or "-"

    lines = [f"kappa in [{curves.kappa[0]:g}, {curves.kappa[-1]:g}] ({len(curves.kappa)} values); "
             "ranges where MD / SMD predict the other sign of T than NF (the wrong type of nonlinearity):",
             f"{'mode':7s} {'gaps NF/MD/SMD':15s} {'MD wrong sign':40s} SMD wrong sign"]
    for row in summary(curves):
        k, n = row["mode"]
        gaps = f"{row['gaps_nf']}/{row['gaps_md']}/{row['gaps_smd']}"
        lines.append(f"({k},{n})   {gaps:15s} {rng(row['wrong_sign_md']):40s} {rng(row['wrong_sign_smd'])}")
    return "\n".join(lines)


# ------------------------------------------------------------------ storage
def _mode_key(kn: tuple[int, int]) -> str:
    return f"{kn[0]}_{kn[1]}"


def _meta(curves: Curves) -> dict[str, Any]:
    opt = asdict(curves.options)
    opt["modes"] = [list(m) for m in curves.options.modes]
    return {"options": opt, "model": curves.model, "flag_bits": FLAG_BITS, "gap_mask": GAP_MASK,
            "seconds": curves.seconds,
            "conventions": "modes normalised by int phi^2 dS = 1 over the unit disk; omega nondimensional; "
                           "w_NL = w_p (1 + T a^2); gamma = T / max|phi|^2; NF over all modes of the model"}


CURVES_FORMAT = "stepnf-curves"
CURVES_FORMAT_VERSION = 1


def write_hdf5(curves: Curves, path: str | Path) -> Path:
    """Store everything: ``/kappa``, ``/frequencies/{omega,labels}``, ``/modes/<k>_<n>/...``.

    Per mode: ``omega``, ``w_max``, ``rho``, ``rho_mode``, ``T_cubic``, ``T_<m>``, ``gamma_<m>``,
    ``flags_<m>`` (bits: root attribute ``flag_bits``), ``gap_<m>``, ``notes_<m>`` for m in nf, md, smd.
    Flagged values are stored as computed (``+-inf`` included). Root attributes ``format =
    "stepnf-curves"``, ``format_version = 1`` (files of earlier stepnf say ``"stepnf-curves-1"``).
    Built in memory and written atomically (:mod:`stepnf.atomic`): a full disk raises
    :class:`stepnf.errors.OutputError` and leaves a previous file untouched.
    """
    import h5py

    from .atomic import write_hdf5 as write_atomic

    st = h5py.string_dtype()

    def fill(f: Any) -> None:
        f.attrs["meta"] = json.dumps(_meta(curves), default=str)
        f.attrs["flag_bits"] = json.dumps(FLAG_BITS)
        f.create_dataset("kappa", data=curves.kappa)
        fr = f.create_group("frequencies")
        fr.create_dataset("omega", data=curves.frequencies)
        fr.create_dataset("labels", data=np.asarray(curves.freq_labels, dtype=np.int64).reshape(-1, 2))
        modes = f.create_group("modes")
        for i, kn in enumerate(curves.modes):
            grp = modes.create_group(_mode_key(kn))
            grp.attrs["label"] = list(kn)
            for key in ("omega", "w_max", "rho", "T_cubic"):
                grp.create_dataset(key, data=getattr(curves, key)[i])
            grp.create_dataset("rho_mode", data=np.asarray(curves.rho_mode[i], dtype=object), dtype=st)
            for m in METHODS:
                grp.create_dataset(f"T_{m}", data=curves.T[m][i])
                grp.create_dataset(f"gamma_{m}", data=curves.gamma[m][i])
                grp.create_dataset(f"flags_{m}", data=curves.flags[m][i])
                grp.create_dataset(f"gap_{m}", data=curves.gaps(m)[i])
                grp.create_dataset(f"notes_{m}", data=np.asarray(curves.notes[m][i], dtype=object), dtype=st)
    return write_atomic(path, fill, format=CURVES_FORMAT, format_version=CURVES_FORMAT_VERSION,
                        what="curves file")


def read_hdf5(path: str | Path) -> dict[str, Any]:
    """Plain dict of a file written by :func:`write_hdf5` (``modes`` keyed by ``(k, n)``)."""
    import h5py

    from .atomic import check_format

    out: dict[str, Any] = {}
    with h5py.File(path, "r") as f:
        check_format(f.attrs, path, format=CURVES_FORMAT, version=CURVES_FORMAT_VERSION, what="curves file",
                     legacy=("stepnf-curves-1",), foreign_error=CurvesError)
        out["meta"] = json.loads(f.attrs["meta"])
        out["kappa"] = f["kappa"][()]
        out["frequencies"] = {"omega": f["frequencies/omega"][()],
                              "labels": [tuple(int(v) for v in r) for r in f["frequencies/labels"][()]]}
        out["modes"] = {}
        for grp in f["modes"].values():
            d = {}
            for key, ds in grp.items():
                v = ds[()]
                if ds.dtype.kind in "OS":
                    v = np.array([x.decode() if isinstance(x, bytes) else x for x in v], dtype=object)
                d[key] = v
            out["modes"][tuple(int(v) for v in grp.attrs["label"])] = d
    return out


def write_csv(curves: Curves, directory: str | Path) -> tuple[Path, Path]:
    """``curves.csv`` (one row per kappa and mode) and ``frequencies.csv`` (one column per label)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    p1, p2 = d / "curves.csv", d / "frequencies.csv"
    cols = (["kappa", "mode", "omega", "w_max", "rho", "rho_mode", "T_cubic"]
            + [f"T_{m}" for m in METHODS] + [f"gamma_{m}" for m in METHODS]
            + [f"flags_{m}" for m in METHODS] + [f"gap_{m}" for m in METHODS] + [f"notes_{m}" for m in METHODS])
    with open(p1, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for i, kn in enumerate(curves.modes):
            gaps = {m: curves.gaps(m)[i] for m in METHODS}
            for j, kappa in enumerate(curves.kappa):
                w.writerow([repr(float(kappa)), f"({kn[0]},{kn[1]})", repr(float(curves.omega[i, j])),
                            repr(float(curves.w_max[i, j])), repr(float(curves.rho[i, j])), curves.rho_mode[i, j],
                            repr(float(curves.T_cubic[i, j]))]
                           + [repr(float(curves.T[m][i, j])) for m in METHODS]
                           + [repr(float(curves.gamma[m][i, j])) for m in METHODS]
                           + [int(curves.flags[m][i, j]) for m in METHODS]
                           + [int(gaps[m][j]) for m in METHODS] + [curves.notes[m][i, j] for m in METHODS])
    with open(p2, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["kappa"] + [f"({k},{n})" for k, n in curves.freq_labels])
        for j, kappa in enumerate(curves.kappa):
            w.writerow([repr(float(kappa))] + [repr(float(v)) for v in curves.frequencies[:, j]])
    return p1, p2


# ------------------------------------------------------------------ figures
def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_frequencies(curves: Curves, path: str | Path) -> Path:
    """Fig. 2: ``omega_kn`` versus kappa, one line per (k, n) label, labelled at the right end."""
    plt = _pyplot()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(7.5, 6.0))
    cmap = plt.get_cmap("tab10")
    ends = curves.frequencies[:, -1]
    ypos = ends.copy()  # label heights at the right end, pushed apart so they do not overlap
    gap = 0.022 * (float(np.nanmax(curves.frequencies)) - float(np.nanmin(curves.frequencies)))
    order = np.argsort(ends)
    for a, b in zip(order[:-1], order[1:]):
        ypos[b] = max(ypos[b], ypos[a] + gap)
    for i, (k, n) in enumerate(curves.freq_labels):
        y = curves.frequencies[i]
        ls = "-" if n == 0 else ("--" if k == 0 else "-.")
        ax.plot(curves.kappa, y, ls, color=cmap(k % 10), lw=1.3)
        ax.annotate(f"({k},{n})", (curves.kappa[-1], ypos[i]), xytext=(3, 0), textcoords="offset points",
                    fontsize=7, va="center", color=cmap(k % 10), annotation_clip=False)
    ax.set_xlabel(r"$\kappa = a^4/(R^2h^2)$")
    ax.set_ylabel(r"$\omega_{kn}$ (nondimensional)")
    ax.set_title(r"Natural frequencies of the free-edge shallow spherical shell"
                 "\n(solid: (k,0); dashed: (0,n); dash-dot: mixed)", fontsize=10)
    ax.set_xlim(curves.kappa[0], curves.kappa[-1] * 1.08 if curves.kappa[-1] > 0 else 1)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def _limits(curves: Curves, i: int, quantity: str) -> tuple[float, float]:
    """y-range: every drawn NF value, and the central 96 % of MD's and SMD's, the latter capped
    at 5 max|NF| (farther out a divergence leaves the axes instead of flattening the reference)."""
    ref = curves.plotted("nf", quantity)[i]
    ref = ref[np.isfinite(ref)]
    vals = [ref, np.zeros(1)]
    cap = 5.0 * float(np.abs(ref).max()) if ref.size else math.inf
    for m in ("md", "smd"):
        v = curves.plotted(m, quantity)[i]
        v = v[np.isfinite(v)]
        if v.size:
            vals.append(np.clip(np.percentile(v, [2, 98]), -cap, cap))
    allv = np.concatenate(vals)
    lo, hi = float(allv.min()), float(allv.max())
    pad = 0.08 * (hi - lo if hi > lo else 1.0)
    return lo - pad, hi + pad


def plot_nonlinearity(curves: Curves, path: str | Path, quantity: str = "T") -> Path:
    """Fig. 3 to a PNG file (see :func:`draw_nonlinearity`)."""
    plt = _pyplot()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig = draw_nonlinearity(curves, quantity)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def draw_nonlinearity(curves: Curves, quantity: str = "T") -> Any:
    """Fig. 3: T_p (or Gamma) by NF, MD, SMD versus kappa, one panel per mode, rho_p on a second axis.

    Returns the matplotlib figure; in each panel ``ax.lines[1:4]`` are the NF, MD, SMD
    curves (:meth:`Curves.plotted`). Gaps (flagged points) break the lines; each is marked
    by a tick at the bottom of the panel in the method's colour (rows: NF, MD, SMD). The
    rho = 3 and rho = 4 lines bound the slow/fast criterion of the paper.
    """
    q = _quantity(quantity)
    plt = _pyplot()
    n = len(curves.modes)
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.0 * ncol, 3.9 * nrow), squeeze=False)
    ylab = r"$T_p$" if q == "T" else r"$\Gamma_p = T_p/\max|\phi_p|^2$"
    rho_top = max(4.6, float(np.nanmax(curves.rho)) * 1.08 if np.isfinite(curves.rho).any() else 4.6)
    handles = []
    for i, kn in enumerate(curves.modes):
        ax = axes.ravel()[i]
        ax.axhline(0.0, color="0.6", lw=0.7)
        for m in METHODS:
            (line,) = ax.plot(curves.kappa, curves.plotted(m, q)[i], color=_COLORS[m], lw=1.6, label=_NAMES[m])
            if i == 0:
                handles.append(line)
        for r, m in enumerate(METHODS):
            gx = curves.kappa[curves.gaps(m)[i]]
            if gx.size:
                ax.plot(gx, np.full(gx.size, 0.03 + 0.035 * r), "|", color=_COLORS[m], ms=7, mew=1.2,
                        transform=ax.get_xaxis_transform(), clip_on=False)
        ax.set_ylim(*_limits(curves, i, q))
        ax.set_xlim(curves.kappa[0], curves.kappa[-1])
        ax.set_xlabel(r"$\kappa$")
        ax.set_ylabel(ylab)
        ax.set_title(f"mode ({kn[0]},{kn[1]})")
        ax.grid(alpha=0.25)
        ax2 = ax.twinx()
        (lr,) = ax2.plot(curves.kappa, curves.rho[i], "k--", lw=1.0, label=r"$\rho_p$")
        for level in (3.0, 4.0):
            ax2.axhline(level, color="0.35", lw=0.8, ls=":")
        ax2.set_ylim(0.0, rho_top)
        ax2.set_ylabel(r"$\rho_p$")
        if i == 0:
            handles.append(lr)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    (tick,) = axes[0, 0].plot([], [], "|", color="0.3", ms=7, label="flagged (gap)")
    handles.append(tick)
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    fig.suptitle("Type of nonlinearity versus kappa ("
                 + ("T_p, modes normalised by int phi^2 dS = 1" if q == "T" else "Gamma = T_p / max|phi_p|^2")
                 + "); dotted: rho = 3 and 4", fontsize=11)
    fig.tight_layout(rect=(0, 0.05, 1, 0.96))
    return fig


# ------------------------------------------------------------------ one call
def write_all(curves: Curves, out_dir: str | Path, quantities: Sequence[str] = QUANTITIES,
              plots: bool = True) -> dict[str, Path]:
    """HDF5, CSV, ``summary.txt`` and (``plots``) the PNGs of Fig. 2 and of Fig. 3 for each quantity."""
    d = Path(out_dir)
    files = {"hdf5": write_hdf5(curves, d / "curves.h5")}
    files["csv"], files["frequencies_csv"] = write_csv(curves, d)
    files["summary"] = d / "summary.txt"
    files["summary"].write_text(format_summary(curves) + "\n")
    if plots:
        files["fig2"] = plot_frequencies(curves, d / "fig2_frequencies.png")
        for q in quantities:
            files[f"fig3_{_quantity(q)}"] = plot_nonlinearity(curves, d / f"fig3_{q}.png", q)
    return files
