"""Computing the curves: every mode and method on the kappa grid, and the flags of each value.

See :mod:`stepnf.report.curves` for the quantities, the flags and when a flag makes a gap.
"""
from __future__ import annotations

import math
import time
from typing import Any, Callable, Sequence

import numpy as np

from stepnf.errors import allowed
from stepnf.methods import MD, NF, TABLE
from stepnf.report.curves.data import FLAG_BITS, HUGE, INCOMPLETE, METHODS, NEAR_RESONANCE, NON_FINITE, CurveOptions, Curves, CurvesError


def compute_curves(options: CurveOptions = CurveOptions(),
                   progress: Callable[[int, int], None] | None = None) -> Curves:
    """Evaluate every mode and method on the kappa grid (one model per kappa, ~0.07 s each)."""
    from stepnf.nf.diagnostics import slow_fast_ratio
    from stepnf.models import VonKarmanShell

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
    evaluate = {name: TABLE[TABLE[name].modal].function() for name in METHODS}  # nf_modal, md_modal, smd_modal
    for j, kappa in enumerate(kap):
        model = VonKarmanShell(kappa=float(kappa), nu=options.nu, edge=options.edge, **options.model)
        om, labels, comps = model.omegas(), model.labels(), model.companions()
        S = np.arange(len(om))
        if j == 0:
            describe = model.describe()
            _check_modes(model, modes)
            freq_labels = _first_labels(om, labels, options.omega_max, model.k_max,
                                        1 if options.edge == "clamped" else 0)
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
            for name in METHODS:
                res = evaluate[name](p, om, g, h, S, tol=tol, labels=labels)
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
    if method == NF:
        num, den = -6 * g2 * (ws2 - 2 * w2) + 4 * g2 * w2, ws2 * (ws2 - 4 * w2)
    elif method == MD:
        num, den = -6 * g2 * (ws2 - 2 * w2) - 8 * g2 * w2, (ws2 - w2) ** 2
    else:
        raise CurvesError(f"resonant_contribution: method {method!r} has no resonant terms; "
                          f"allowed {allowed([NF, MD])}")
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


def _first_labels(om: np.ndarray, labels: Sequence[Any], omega_max: float, k_max: int,
                  n_first: int = 0) -> list[tuple[int, int]]:
    """Distinct (k, n) labels with frequency below omega_max, by increasing frequency (``n_first``: n of
    the lowest mode with k_max nodal diameters, 1 for the clamped edge, which counts as a circle)."""
    top = min((w for w, lab in zip(om, labels) if tuple(lab) == (k_max, n_first)), default=math.inf)
    if omega_max > top:
        raise CurvesError(f"omega_max = {omega_max:g} is above the frequency {top:.4g} of mode ({k_max}, {n_first}): "
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


def _label_text(lab: Any, comp: str = "cos") -> str:
    k, n = lab
    return f"({k},{n})" + ("" if k == 0 or comp == "cos" else " sin")
