"""STEP for a force that is not an exact cubic: the cubic fit's truncation measured, extrapolated, flagged.

A shell's co-rotational (finite-rotation) internal force is not a polynomial in the nodal unknowns. STEP's
combinations at ``+-a phi`` (:func:`stepnf.step.procedure.targeted_steps`) then carry every even (odd)
term above the cubic::

    Gv(a) = [f(a phi) + f(-a phi)] / (2 a^2)            = G(phi, phi)      + a^2 G_4 + a^4 G_6 + ...
    Hv(a) = [f(a phi) - f(-a phi) - 2 a K phi] / (2 a^3) = H(phi, phi, phi) + a^2 H_5 + a^4 H_7 + ...

(``G_4``, ``H_5``: the quartic and quintic terms at ``phi``), a truncation error O(a^2) relative: measured
on Kratos's DKT plate (issue 32), 6.7e-4 at an amplitude of one thickness, 6.6e-2 at ten. What the rest
of stepnf consumes (``Gv``, ``h = phi^T Hv``) is the cubic truncation ``a -> 0``.

The black box itself says whether it matters. STEP already runs at two amplitudes, ``a0 = q`` and
``a1 = c q`` (``c`` = ``check_ratio``, 1/2 by default); their difference is compared with the rounding
those values carry (:func:`rounding_of_step`, the bound of :mod:`stepnf.nf.roundoff`:
``eps (|K| |u|)_i`` plus the printed digits, or ``eps |f_i|`` without). Within :data:`CUBIC_MARGIN` times
that rounding the force is an exact cubic as far as the forces can tell and nothing changes (no solver
run, values and ``error_G``, ``error_h`` as before). Otherwise a third amplitude ``a2 = c^2 q`` is run (two
force evaluations per such master, one batch for all of them) and, for ``Gv`` and ``h`` apart:

* the observed rate ``log(|X(a0) - X(a1)| / |X(a1) - X(a2)|) / log(1/c)`` (2 for a smooth force whose
  cubic fit is truncated; anything for differences that are rounding);
* if it is within :data:`RATE_TOLERANCE` of 2 and the second difference stands above its rounding, the
  Richardson extrapolations ``E(a) = [X(c a) - c^2 X(a)] / (1 - c^2) = X(0) - c^2 a^4 X_4 + ...`` of
  both pairs, ``E1 = E(a0)`` and ``E2 = E(a1)``, whose difference ``c^2 (1 - c^4) a0^4 X_4`` measures
  their own truncation;
* of the five values ``X(a0), X(a1), X(a2), E1, E2`` the one whose estimate of truncation plus rounding
  is smallest is kept (the amplitude that balances the two: a raw value's truncation from the first
  difference at the cubic fit's rate 2, ``|X(a0) - X(a1)| c^(2i) / (1 - c^2)``; E1's ``|E1 - E2| / (1 - c^4)``,
  E2's ``c^4`` of that; rounding from the bound, through the extrapolation's weights), with as check
  value the next better estimate of the limit (``X(a1)``: E1, ``X(a2)``: E2, E1 and E2: the second
  extrapolation ``E2 + c^4 (E2 - E1) / (1 - c^4)``), whose difference is that truncation, so that
  ``error_G``, ``error_h`` and T's ``T_error`` (the change of T between the values and their check values,
  as for every STEP) report it; the rounding is bounded apart, at the amplitude ``q`` the kept values'
  rounding corresponds to (:mod:`stepnf.nf.roundoff`).

The fit is not converged (flag ``step_unconverged``) when the change is above the tolerance and the rate
is not observed but at least :data:`NOISE_RATE` (a change that does not fall with the amplitude is rounding:
``step_accuracy`` of :func:`stepnf.step.procedure.targeted_steps`, which advises a larger amplitude), or when the kept
value's estimated error still exceeds the tolerance (the extrapolated and raw values disagree by far more than it: the amplitude is too large for the cubic fit). A kept
extrapolation is flagged ``step_extrapolated`` with the rates. Not for the full plan (its check only
flags, :func:`stepnf.step.procedure.full_step`) nor for ``method = "tangent"``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp

from stepnf.flags import new_flag
from stepnf.linalg.null_space import abs_product
from stepnf.nf.roundoff import EPS, step_rounding, weighted_rounding
from stepnf.step.forces import ForceEvaluator

#: the two-amplitude change within this many times its rounding bound: the force is an exact cubic (no third
#: amplitude). The bound exceeded the true rounding by 1.5x to 1000x wherever it was measured
#: (stepnf/nf/roundoff.py); a smooth non-cubic force's change is O(a^2) of G and h (Kratos's DKT: 6.7e-4 at
#: an amplitude of one thickness, issue 32), the rounding of forces in double precision 1e-10 or less of them
#: at STEP's amplitudes (a solver that prints 7 digits: ~1e-6, where a truncation below 1e-4 goes unseen)
CUBIC_MARGIN = 100.0
#: an observed rate within this of 2 is the cubic fit's O(a^2) truncation (a quartic term of relative size
#: r at a0 moves the first rate by about log2(1 + 15 r / 16): 0.5 at r = 0.45)
RATE_TOLERANCE = 0.5
#: an unobserved rate below this is rounding, not truncation (noise does not fall with the amplitude: the
#: changes of forces printed with 7 digits and not declared so, on the kappa = 25 cap, came at q^0.05; its
#: expected rate is -2, G's rounding growing as 1/a^2); a force whose fit is truncated at rate 1 (c u |u|^3,
#: tests/step/test_truncation.py) is above it
NOISE_RATE = 0.5


@dataclass(frozen=True)
class Ladder:
    """One quantity (``Gv`` (n,) or ``Hv`` (n,)) of one master at the amplitudes ``a`` (a0 > a1 > a2), with
    its rounding bounds ``rho`` (absolute, in the metric ``size``: a norm of Gv or |h|)."""

    a: tuple[float, ...]
    X: tuple[np.ndarray, ...]
    rho: tuple[float, ...]


@dataclass(frozen=True)
class Choice:
    """What is kept of a :class:`Ladder`: ``value`` and its ``check`` value, the amplitudes ``q`` and
    ``q_check`` whose rounding they carry, the ``rate`` of its successive differences (None: one of them is
    0), whether that rate is ``observed`` (the cubic fit's 2, above rounding), the kept value's estimated
    ``error`` (truncation plus rounding, in the ladder's metric; the first change when not observed) and
    the ``name`` of the choice (``"raw"``, ``"extrapolated (a1, a2)"``, ...)."""

    value: np.ndarray
    check: np.ndarray
    q: float
    q_check: float
    rate: float | None
    observed: bool
    error: float
    name: str


def rounding_of_step(kp: np.ndarray, Kphi: np.ndarray, phi: np.ndarray, a: float, Gv: np.ndarray,
                     Hv: np.ndarray, digits: int | None) -> tuple[float, float]:
    """Rounding bounds of ``Gv`` (2-norm) and ``h = phi^T Hv`` from the forces at ``+-a phi``: the per-entry
    rounding of :func:`stepnf.nf.roundoff.step_rounding` (the solver's own ``eps a (|K| |phi|)_i``, the printed
    ``eps_f |f_i|``, at least ``eps |f_i|``: the rounding of the nonlinear force itself), from ``kp = |K| |phi|``
    and ``Kphi = K phi`` given (no product with K here: a sparse product per call cost 0.4 s of six masters
    on the 38k-dof cap)."""
    own, printed = step_rounding(kp, None, phi, a, Gv, Hv, digits, Kphi=Kphi, floor=EPS)
    return (float(np.linalg.norm(own + printed)) / a ** 2,
            weighted_rounding(np.abs(phi), own, printed) / a ** 3)


def shows_cubic(change: float, rounding: float) -> bool:
    """Whether a two-amplitude ``change`` is rounding (within :data:`CUBIC_MARGIN` of its bound)."""
    return bool(np.isfinite(change) and change <= CUBIC_MARGIN * rounding)


def choose(ladder: Ladder, size: Callable[[np.ndarray], float], c: float) -> Choice:
    """The kept value of ``ladder`` (module docstring); ``size(x)``: the metric of a difference (a norm)."""
    (a0, a1, a2), (X0, X1, X2), (r0, r1, r2) = ladder.a, ladder.X, ladder.rho
    d1, d2 = size(X0 - X1), size(X1 - X2)
    rate = float(np.log(d1 / d2) / np.log(1.0 / c)) if d1 > 0 and d2 > 0 else None
    observed = rate is not None and abs(rate - 2.0) <= RATE_TOLERANCE and not shows_cubic(d2, r1 + r2)
    if not observed:  # differences that are not a truncation: the first amplitude's values, as before
        return Choice(X0, X1, a0, a1, rate, False, d1, "raw")
    w = 1.0 - c * c
    E1, E2 = (X1 - c * c * X0) / w, (X2 - c * c * X1) / w
    R = E2 + c ** 4 * (E2 - E1) / (1.0 - c ** 4)  # the next extrapolation: the check value of E1 and E2
    e12 = size(E1 - E2) / (1.0 - c ** 4)
    # an extrapolation's rounding amplitude: where a raw STEP's printed rounding of G (~ 1/a^2) is what the
    # extrapolation's weights make of it
    widen = np.sqrt(w / (1.0 + c ** 4))
    # (value, check, rounding amplitude, check's, truncation, rounding, name); the check value of each is the
    # next better estimate of the limit, so that the difference is the value's truncation
    cands = [(X0, X1, a0, a1, d1 / w, r0, "raw"),
             (X1, E1, a1, a1 * widen, c * c * d1 / w, r1, "raw at the check amplitude"),
             (X2, E2, a2, a2 * widen, c ** 4 * d1 / w, r2, "raw at the third amplitude"),
             (E1, R, a1 * widen, a2 * widen, e12, (r1 + c * c * r0) / w, "extrapolated (a0, a1)"),
             (E2, R, a2 * widen, a2 * widen, c ** 4 * e12, (r2 + c * c * r1) / w, "extrapolated (a1, a2)")]
    v, chk, q, q_chk, trunc, rho, name = min(cands, key=lambda t: t[4] + t[5])
    return Choice(v, chk, float(q), float(q_chk), rate, True, float(trunc + rho), name)


def rounding_excess(change: float, ch: Choice, bound: float) -> float:
    """How many times a two-amplitude ``change`` exceeds its rounding ``bound`` (both in the ladder's metric)
    when its ladder shows rounding, else 0. Rounding is a change that GROWS as the amplitude shrinks (a
    negative rate: the force's rounding divided by ``a^2`` or ``a^3``); a rate between 0 and
    :data:`NOISE_RATE` is not taken as rounding here, for a cubic fit that does not converge at too large an
    amplitude shows it too (a trigonometric force at 6 rad: 0.38, tests/step/test_truncation.py). The
    per-entry model of the forces' rounding (:func:`rounding_of_step`) is then shown short by that factor, in
    the very force evaluations T is made of; measured on the paper's plate (hex27, FEniCSx) at 1e-6 h: G's
    change 3e4 times its bound at a rate of -2.3 (a solid whose strain ``(F^T F - I) / 2`` rounds at eps of 1,
    not of the strain), while T's bound came out at 0.94 to 1.0 of T for an actual error of 1.00002
    (tests/nf/test_stability.py). A shortfall below :data:`CUBIC_MARGIN` is not measured (no third amplitude
    runs)."""
    if ch.observed or ch.rate is None or ch.rate >= 0.0 or not bound > 0 or not np.isfinite(change):
        return 0.0
    return float(change / bound)


def step_flags(p: int, amplitudes: tuple[float, ...], g: Choice, h: Choice, error_G: float, error_h: float,
               change_G: float, change_h: float, tolerance: float) -> list[dict]:
    """The flags of a master whose STEP ran at three amplitudes: ``step_extrapolated`` (values kept from a
    Richardson extrapolation), ``step_unconverged`` (module docstring). ``error_*``: the kept values' scaled
    error estimates; ``change_*``: the scaled two-amplitude changes."""
    a = ", ".join(f"{x:.3e}" for x in amplitudes)

    def rate(ch: Choice) -> str:
        return "n/a" if ch.rate is None else f"{ch.rate:.2f}"

    flags = []
    if "extrapolated" in g.name or "extrapolated" in h.name:
        flags.append(new_flag(
            "step_extrapolated", mode=p, value=float(max(error_G, error_h)),
            message=f"STEP of mode {p}: the force is not an exact cubic (G changes as q^{rate(g)}, h as "
                    f"q^{rate(h)} over the amplitudes {a}; 2 is the cubic fit's truncation): kept G {g.name}, "
                    f"h {h.name}; estimated error G {error_G:.1e}, h {error_h:.1e} (relative)"))
    # a change that does not fall with the amplitude (rate below NOISE_RATE) is rounding the bound did not
    # foresee (a solver's printed digits it was not told of), not truncation: left to step_accuracy, whose
    # advice (a larger amplitude) is the right one there
    bad = [(n, ch, err, chg) for n, ch, err, chg in (("G", g, error_G, change_G), ("h", h, error_h, change_h))
           if (not ch.observed and chg > tolerance and ch.rate is not None and ch.rate >= NOISE_RATE)
           or (ch.observed and err > tolerance)]
    for n, ch, err, chg in bad:
        why = (f"changes by {chg:.1e} at the rate q^{rate(ch)}, not the cubic fit's q^2" if not ch.observed else
               f"keeps an estimated error of {err:.1e} after extrapolation (rate q^{rate(ch)})")
        flags.append(new_flag(
            "step_unconverged", mode=p, value=float(max(err, chg)),
            message=f"STEP's cubic fit of mode {p} is not converged: {n} {why} over the amplitudes {a}; "
                    f"tolerance {tolerance:.1e}. Try a smaller [analysis.step] relative_amplitude"))
    return flags


def gh_vectors(fp: np.ndarray, fm: np.ndarray, Kphi: np.ndarray, q: float) -> tuple[np.ndarray, np.ndarray]:
    """``G(phi, phi)`` and ``H(phi, phi, phi)`` from the forces at ``+-q phi``."""
    return (fp + fm) / (2.0 * q * q), (fp - fm - 2.0 * q * Kphi) / (2.0 * q ** 3)


def h_metric(h: float, q: float, w2: float) -> Callable[[float], float]:
    """The scaled size of a change ``d`` of ``h``: ``max(|d| / |h|, q^2 |d| / (phi^T K phi))`` (STEP's
    ``error_h``: relative, and relative to the linear force at the amplitude ``q`` when h vanishes)."""
    def size(d: float) -> float:
        d = abs(float(d))
        rel = d / abs(h) if h != 0 else (0.0 if d == 0 else float("inf"))
        return max(rel, q * q * d / w2)
    return size


def refine(forces: ForceEvaluator, K: sp.spmatrix, Phi: np.ndarray, steps: list, c: float, digits: int | None,
           tolerance: float, plan: str, KPhi: np.ndarray | None = None) -> None:
    """The third amplitude and the choice of the kept values (module docstring) for the masters of ``steps``
    (targeted STEP results at ``q`` and ``c q``, columns of ``Phi``) whose change is not rounding; updated in
    place (``Gv``, ``Hv``, ``h``, their check values, ``q``, ``q_check``, ``amplitudes``, ``rate_G``,
    ``rate_h``, ``flags``). One batch of ``2 x`` (such masters) force evaluations, none when every master
    shows a cubic force. ``KPhi``: ``K Phi`` (n, k) when the caller has it (None: computed here)."""
    todo = []
    KP = abs_product(K, np.abs(Phi))  # |K| |phi| of every master at once
    KPhi = np.asarray(K @ Phi) if KPhi is None else KPhi
    for j, st in enumerate(steps):
        phi, kp, Kphi = Phi[:, j], KP[:, j], KPhi[:, j]
        rG0, rh0 = rounding_of_step(kp, Kphi, phi, st.q, st.Gv, st.Hv, digits)
        rG1, rh1 = rounding_of_step(kp, Kphi, phi, st.q_check, st.Gv_check, st.Hv_check, digits)
        if not (shows_cubic(float(np.linalg.norm(st.Gv - st.Gv_check)), rG0 + rG1)
                and shows_cubic(abs(st.h - st.h_check), rh0 + rh1)):
            todo.append((j, (rG0, rG1), (rh0, rh1)))
    if not todo:
        return
    fields = []
    for j, _, _ in todo:
        a2 = c * c * steps[j].q
        fields += [a2 * Phi[:, j], -a2 * Phi[:, j]]
    F = forces(np.stack(fields), plan=f"{plan}third")
    for i, (j, rG, rh) in enumerate(todo):
        st, phi = steps[j], Phi[:, j]
        a = (st.q, st.q_check, c * c * st.q)
        Kphi = KPhi[:, j]
        Gv2, Hv2 = gh_vectors(F[2 * i], F[2 * i + 1], Kphi, a[2])
        rG2, rh2 = rounding_of_step(KP[:, j], Kphi, phi, a[2], Gv2, Hv2, digits)
        lin, w2 = max(float(np.linalg.norm(Kphi)), 1e-300), max(float(phi @ Kphi), 1e-300)
        sh = h_metric(st.h, st.q, w2)

        def size_G(x: np.ndarray) -> float:
            return a[0] * float(np.linalg.norm(x)) / lin

        def size_h(x: np.ndarray) -> float:
            return sh(float(phi @ x))

        change_G, change_h = size_G(st.Gv - st.Gv_check), sh(st.h - st.h_check)
        g = choose(Ladder(a, (st.Gv, st.Gv_check, Gv2), tuple(a[0] * r / lin for r in (*rG, rG2))), size_G, c)
        h = choose(Ladder(a, (st.Hv, st.Hv_check, Hv2), tuple(sh(r) for r in (*rh, rh2))), size_h, c)
        st.Gv, st.Gv_check, st.Hv, st.Hv_check = g.value, g.check, h.value, h.check
        st.h, st.h_check = float(phi @ h.value), float(phi @ h.check)
        st.q, st.q_check = min(g.q, h.q), min(g.q_check, h.q_check)
        st.amplitudes, st.rate_G, st.rate_h = a, g.rate, h.rate
        st.rounding_excess = max(1.0, rounding_excess(change_G, g, sum(rG) * a[0] / lin),
                                 rounding_excess(change_h, h, sh(rh[0]) + sh(rh[1])))
        st.flags += step_flags(st.p, a, g, h, g.error if g.observed else change_G,
                               h.error if h.observed else change_h, change_G, change_h, tolerance)
