"""Evaluators of T for one master mode: NF, DNF, MD, SMD (docs/design.md section 1).

Modal versions sum over retained elastic modes ``S`` (Table 1, with the
erratum: NF denominators ``w_s^2 (w_s^2 - 4 w^2)``). Full-order versions need
no modal truncation: DNF two linear solves, SMD the ``K^+`` solve of DNF, MD
a bordered solve with ``K - w^2 M``.

Conventions: ``omega`` angular frequencies (m,) of the elastic modes,
``g[s] = g^s_pp = phi_s^T G(phi_p, phi_p)``, ``h = h^p_ppp``; everything in the
model's own units. A term whose ``|g_s|`` is below a *coupling floor* is
treated as zero by symmetry, so that a degenerate twin that does not couple
cannot blow MD up: the floor is ``coupling_tolerance`` (default 1e-5) times
the largest ``|g_s|`` for modal models, and for FE models (set by the
pipeline) the same fraction of ``||G(phi_p, phi_p)||`` in the ``M^-1`` norm, or
ten times the STEP noise of ``g_s``, whichever is larger: couplings that a
mesh's imperfect symmetry creates (measured ~1e-6 on the O-grid caps) stay
below it, physical ones (1e-2 and more) far above. A coupled mode within
``resonance_tolerance`` of the resonance (``w_s/w_p`` near 2 for NF/DNF, near
1 for MD) is flagged, naming the mode; exact resonance gives ``+-inf``.

Fields (for ParaView, :mod:`stepnf.io.fields`): the full-order evaluators put
their displacement vectors in :attr:`MethodResult.fields <stepnf.nf.coefficient.
MethodResult.fields>`, each (n,) in the model's dof order (constrained dofs
removed, as every vector of the adapter protocol), for a mass-normalised
``phi`` (``phi^T M phi = 1``; ``a`` is the modal amplitude, ``q_p = phi^T M x``):

* :func:`dnf`: ``"a_bar"`` = a_bar of docs/design.md (Eq. 9-10) and
  ``"w2_b_bar"`` = ``w_p^2 b_bar`` (b_bar multiplies the squared velocity;
  times ``w_p^2`` it is a displacement per squared amplitude like a_bar).
  On the backbone, ``R = a cos(w t)``, ``R' = -a w sin(w t)``:
  ``x(t) = a cos(wt) phi + a^2 [cos^2(wt) a_bar + sin^2(wt) w2_b_bar] + O(a^3)``,
  so ``a_bar`` is the second-order displacement at the turning point (wt = 0,
  largest ``phi`` amplitude) and ``w2_b_bar`` a quarter period later (where
  ``phi`` passes through zero). Equivalently the second-order motion is a
  mean drift ``(a^2/2)(a_bar + w2_b_bar) = -(a^2/2) K^+ Gv`` plus a second
  harmonic ``(a^2/2)(a_bar - w2_b_bar) cos(2wt)``, ``a_bar - w2_b_bar =
  -(K - 4 w^2 M)^-1 Gv``. A free structure: both are M-orthogonal to the
  rigid-body modes ``R`` (and ``Gv`` above reads ``Gv - M R R^T Gv``).
* :func:`md_full`, :func:`smd_full`: ``"theta"``, the (static) modal
  derivative of the manifold ``u = phi R + theta R^2 / 2``:
  ``x(t) = a cos(wt) phi + (a^2 / 2) cos^2(wt) theta + O(a^3)``.
  MD: ``(K - w^2 M) theta = -2 Gv + M D l`` with ``theta`` M-orthogonal to
  ``D`` = phi and its twins (``l`` the bordered system's multipliers); SMD: ``theta = -2 K^+ Gv``.

``FullOrderContext.keep_fields = False`` keeps none (large models, no
output). A diverging evaluation (flagged, ``T = +-inf``) has no fields.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.nf.coefficient import MethodResult, backbone_T, qm_coefficients
from stepnf.runtime.counters import Counters
from stepnf.errors import NumericalError
from stepnf.flags import new_flag
from stepnf.linalg.deflation import DeflatedSolver
from stepnf.linalg.factorization import Factorization, PseudoInverse, factorize
from stepnf.nf.linearised import Spectrum, qm_T_error, resolvent_mass
from stepnf.nf.roundoff import Rounding, cancellation, dnf_roundoff, dnf_slope, with_qm_roundoff
from stepnf.linalg.shifted import ShiftedFactorizer, Slot
from stepnf import methods


@dataclass(frozen=True)
class Tolerances:
    """Thresholds of the evaluators (scene table ``[analysis]``)."""

    coupling: float = 1e-5
    resonance: float = 0.05


def coupled(g: np.ndarray, tol: float, floor: np.ndarray | float | None = None) -> np.ndarray:
    """Mask of the modes that the master drives: ``|g_s|`` above a threshold, and not exactly zero.

    The threshold is ``floor`` when given (per mode or one number: the
    pipeline sets it from the size of ``G(phi_p, phi_p)`` and from the STEP
    noise seen at the check amplitude), else ``tol * max|g|`` (modal models,
    whose coefficients carry no noise).
    """
    a = np.abs(np.asarray(g, dtype=float))
    if floor is None:
        top = a.max() if a.size else 0.0
        floor = tol * top
    return (a > floor) & (a > 0)


def resonance_flags(method: str, p: int, omega: np.ndarray, g: np.ndarray, S: Sequence[int],
                    ratio: float, tol: Tolerances, labels: Sequence[Any] | None,
                    floor: np.ndarray | float | None = None) -> list[dict]:
    """Flags of the modes of ``S`` in internal resonance ``ratio`` (2.0 for 1:2, 1.0 for 1:1) with master ``p``.

    A mode ``s != p`` of ``S`` is flagged when the master drives it (``|g[s]|``
    above the coupling floor, :func:`coupled` with ``tol.coupling`` and
    ``floor``) and ``|omega[s] / omega[p] - ratio| <= tol.resonance * ratio``
    (a relative window). ``omega`` are angular frequencies in any one unit
    (only their ratios count), ``g[s] = g^s_pp`` in the model's units, ``S``
    and ``p`` indices into them, ``labels`` (optional) the modes' labels.
    ``method`` names the evaluator in the message (``"nf"``, ``"dnf"``, ``"md"``).

    Returns one dict per flagged mode, in the order of ``S``: ``kind``
    (``"internal_resonance_1_2"`` or ``"internal_resonance_1_1"``), ``mode``
    (index ``s``), ``label`` (``labels[s]`` or ``None``), ``ratio``
    (``omega[s] / omega[p]``) and ``message``.
    """
    flags = []
    cp = coupled(g, tol.coupling, floor)
    for s in S:
        if s == p or not cp[s]:
            continue
        r = omega[s] / omega[p]
        if abs(r - ratio) <= tol.resonance * ratio:
            kind = "internal_resonance_1_2" if ratio == 2 else "internal_resonance_1_1"
            lab = labels[s] if labels is not None else None
            flags.append(new_flag(
                kind, mode=int(s), label=lab, ratio=float(r),
                message=f"{method.upper()}: mode {s}{'' if lab is None else ' ' + str(lab)} is in "
                        f"{'1:2' if ratio == 2 else '1:1'} internal resonance with master mode {p} "
                        f"(w_s/w_p = {r:.4f}); the {'normal form' if ratio == 2 else 'modal derivative'} "
                        "has a small denominator there",
            ))
    return flags


def _sum_terms(num: np.ndarray, den: np.ndarray) -> tuple[float, bool]:
    """Sum of num/den; True when some denominator is exactly zero with a non-zero numerator."""
    zero = (den == 0) & (num != 0)
    safe = np.where(den == 0, 1.0, den)
    return float(np.sum(np.where(den == 0, 0.0, num / safe))), bool(zero.any())


def retained_set(p: int, n_retained: int | None, m: int) -> np.ndarray:
    """Indices of the retained elastic modes: the first ``n_retained`` (all when None), plus ``p``."""
    n = m if n_retained is None else min(int(n_retained), m)
    S = list(range(n))
    if p not in S:
        S.append(p)
    return np.asarray(sorted(S))


def nf_modal(p: int, omega: np.ndarray, g: np.ndarray, h: float, S: np.ndarray, *,
             tol: Tolerances = Tolerances(), labels: Sequence[Any] | None = None,
             method: str = methods.NF, floor: np.ndarray | float | None = None) -> MethodResult:
    """Normal form, modal sums over ``S`` (Table 1, NF row, corrected denominators)."""
    w2 = omega[p] ** 2
    cp = coupled(g, tol.coupling, floor)
    Sc = np.asarray([s for s in S if cp[s]], dtype=int)
    ws2, gs2 = omega[Sc] ** 2, g[Sc] ** 2
    den = ws2 * (ws2 - 4 * w2)
    a4, d4 = _sum_terms(2 * gs2 * (ws2 - 2 * w2), den)
    c5, d5 = _sum_terms(4 * gs2 * w2, den)
    C = (0.0, 0.0, 0.0, h - a4, c5, 0.0)
    flags = resonance_flags(method, p, omega, g, S, 2.0, tol, labels, floor)
    T = -np.inf if (d4 or d5) else backbone_T(C, omega[p])
    if d4 or d5:
        C = (0.0, 0.0, 0.0, -np.inf, np.inf, 0.0)
    return MethodResult(method, float(T), C, flags, order=methods.MODAL, retained_modes=len(S))


def md_modal(p: int, omega: np.ndarray, g: np.ndarray, h: float, S: np.ndarray, *,
             tol: Tolerances = Tolerances(), labels: Sequence[Any] | None = None,
             floor: np.ndarray | float | None = None) -> MethodResult:
    """Quadratic manifold with modal derivatives, modal sums over ``S \\ {p}`` (Table 1, MD row)."""
    w2 = omega[p] ** 2
    cp = coupled(g, tol.coupling, floor)
    Sc = np.asarray([s for s in S if s != p and cp[s]], dtype=int)
    ws2, gs2 = omega[Sc] ** 2, g[Sc] ** 2
    den = (ws2 - w2) ** 2
    a4, d4 = _sum_terms(2 * gs2 * (ws2 - 2 * w2), den)
    c5, d5 = _sum_terms(4 * gs2 * w2, den)
    flags = resonance_flags(methods.MD, p, omega, g, S, 1.0, tol, labels, floor)
    if d4 or d5:  # exact 1:1 with a coupled mode: T -> -inf (3 C4 + C5 - 3 C6 ~ -2 g^2 w^2 / 0)
        return MethodResult(methods.MD, -np.inf, (float(g[p]), 0.0, 0.0, np.inf, np.inf, np.inf), flags,
                            order=methods.MODAL, retained_modes=len(S))
    C = (float(g[p]), 0.0, 0.0, h - a4, c5, c5)
    return MethodResult(methods.MD, backbone_T(C, omega[p]), C, flags, order=methods.MODAL, retained_modes=len(S))


def smd_modal(p: int, omega: np.ndarray, g: np.ndarray, h: float, S: np.ndarray, *,
              tol: Tolerances = Tolerances(), labels: Sequence[Any] | None = None,
              floor: np.ndarray | float | None = None) -> MethodResult:
    """Quadratic manifold with static modal derivatives, modal sums over ``S`` (Table 1, SMD row)."""
    w2 = omega[p] ** 2
    cp = coupled(g, tol.coupling, floor)
    Sc = np.asarray([s for s in S if cp[s]], dtype=int)
    ws2, gs2 = omega[Sc] ** 2, g[Sc] ** 2
    gp = float(g[p])
    C = (-2 * gp, -2 * gp, -4 * gp, h - float(np.sum(2 * gs2 / ws2)),
         float(np.sum(4 * gs2 * w2 / ws2**2)), float(np.sum(4 * gs2 * w2 / ws2**2)))
    return MethodResult(methods.SMD, backbone_T(C, omega[p]), C, [], order=methods.MODAL, retained_modes=len(S))


# ---------------------------------------------------------------- full order
@dataclass
class FullOrderContext:
    """What the full-order evaluators share: matrices, the supported-K pseudo-inverse, counters."""

    K: sp.spmatrix
    M: sp.spmatrix
    Kpinv: PseudoInverse
    counters: Counters
    backend: str = "auto"
    #: ``shifted(sigma, label)``: a factorisation of K - sigma M (an adapter's); None: stepnf's own
    #: :class:`~stepnf.linalg.shifted.ShiftedFactorizer`, made here
    shifted: Callable[[float, str], Factorization] | None = None
    #: solves from the computed modes and the eigen-solver's factorisation (no new factorisation)
    deflated: "DeflatedSolver | None" = None
    #: keep the displacement vectors in ``MethodResult.fields`` (see the module docstring)
    keep_fields: bool = True
    #: the one live factorisation of :meth:`shifted_factorization` (made from ``shifted``)
    slot: Slot = field(init=False)

    def __post_init__(self) -> None:
        if self.shifted is None:  # stepnf's own: K - sigma M on one pattern shared with K and M
            self.shifted = ShiftedFactorizer(self.K, self.M, counters=self.counters, backend=self.backend)
        self.slot = Slot.over(self.shifted)

    def shifted_factorization(self, sigma: float, label: str) -> Factorization:
        """Factorisation of ``K - sigma M``; the latest one is kept, so asking again is free.

        With stepnf's :class:`~stepnf.linalg.shifted.ShiftedFactorizer` the slot is its ``refactor``: the previous
        shift's factors are overwritten in place and MUMPS's analysis is kept; an adapter's factorisations
        are released one by one.
        """
        return self.slot.factorization(sigma, label)

    def holds(self, sigma: float) -> bool:
        """Whether :meth:`shifted_factorization` of ``sigma`` is free now (the slot holds it)."""
        return self.slot.holds(sigma)

    def release_shifted(self) -> None:
        """Free the kept factorisation of :meth:`shifted_factorization` now (none is kept afterwards)."""
        self.slot.release()


def dnf_uses_factorisation(omega_p: float, ctx: FullOrderContext) -> bool:
    """True when :func:`dnf` of a master at ``omega_p`` (rad/s) factorises ``K - 4 w^2 M`` (in the
    context's one slot, :meth:`FullOrderContext.shifted_factorization`) instead of a deflated solve."""
    return not (ctx.deflated is not None and ctx.deflated.admissible(4 * omega_p ** 2))


def dnf_shifted_rhs(Gv: np.ndarray, ctx: FullOrderContext) -> np.ndarray:
    """The right-hand side of DNF's ``(K - 4 w^2 M) z = b``: ``Gv`` without its rigid-body part."""
    R = ctx.Kpinv.R
    return Gv - ctx.M @ (R @ (R.T @ Gv)) if R.shape[1] else Gv


def dnf(p: int, phi: np.ndarray, omega_p: float, Gv: np.ndarray, h: float, ctx: FullOrderContext,
        *, dGv: np.ndarray | None = None, dh: float = 0.0, y: np.ndarray | None = None,
        z: np.ndarray | None = None, rounding: Rounding | None = None) -> tuple[MethodResult, np.ndarray]:
    """Direct normal form, full order (paper Eq. 9-10): two linear solves.

    Returns the result and ``y = K^+ Gv`` (reused by full-order SMD); ``y`` and ``z`` (the solution
    of ``(K - 4 w^2 M) z = b``, :func:`dnf_shifted_rhs`) given are not solved again. The
    result's ``fields`` hold ``a_bar`` and ``w2_b_bar = w^2 b_bar`` (module docstring).
    ``B = 2 b_bar^T Gv = (z - y)^T Gv / w^2`` is computed as ``4 y^T M z`` (equal by the resolvent
    identity ``K^+ - (K - 4 w^2 M)^-1 = -4 w^2 K^+ M (K - 4 w^2 M)^-1`` on the elastic modes), which
    does not cancel when ``z`` is close to ``y`` (a slender structure's membrane modes far above ``2 w``).
    With ``dGv``, ``dh`` (differences at the STEP check amplitude) ``T_error`` is
    the first-order change of T: ``dA = 4 dGv^T a_bar``, ``dB = 4 dGv^T b_bar`` (also in
    ``extra["T_change"]``); with ``rounding`` (the STEP amplitude and the solver's force digits),
    ``extra["roundoff"]`` bounds the error the forces' rounding and the solves leave in T through the
    cancellation of its terms (:mod:`stepnf.nf.roundoff`), and the master's own eigenvalue error through
    ``lambda dT/dlambda`` (``extra["roundoff_dT_lambda"]``; ``dB/dlambda = 16 y^T M (K - 4 w^2 M)^-1 M z``
    is ``4 (z - y)^T M z / w^2`` by the same identity, no solve: ``extra["dB_dlambda"]``),
    ``extra["cancellation"]`` measures that cancellation, and ``T_error`` is the larger of the two.
    """
    w2 = omega_p ** 2
    if y is None:
        y = ctx.Kpinv(Gv)
    b = dnf_shifted_rhs(Gv, ctx)
    try:
        if z is None and not dnf_uses_factorisation(omega_p, ctx):
            z = ctx.deflated.solve(b, 4 * w2)  # 2 w_p inside the computed spectrum: no factorisation
        elif z is None:
            Z = ctx.shifted_factorization(4 * w2, f"K - 4 w^2 M (mode {p})")
            z = Z.solve(b)
    except NumericalError as exc:  # exact 1:2 resonance: the NF diverges (same convention as nf_modal)
        flag = new_flag("internal_resonance_1_2", mode=None,
                        message=f"DNF: K - 4 w^2 M is singular for master mode {p} (a mode at exactly twice "
                                f"its frequency): the normal form diverges ({exc})")
        return MethodResult(methods.DNF, -np.inf, (0.0, 0.0, 0.0, -np.inf, np.inf, 0.0), [flag],
                            order=methods.FULL), y
    a_bar = -0.5 * (y + z)
    b_bar = (z - y) / (2 * w2)
    A = 2 * float(a_bar @ Gv)
    B = 4 * float(y @ (ctx.M @ z))  # = 2 b_bar^T Gv, without its cancellation (docstring)
    T = (3 * (A + h) + w2 * B) / (8 * w2)
    res = MethodResult(methods.DNF, T, (0.0, 0.0, 0.0, A + h, w2 * B, 0.0), [], order=methods.FULL)
    res.extra = {"A": A, "B": B, "h": h, "cancellation": cancellation(A, h, w2 * B),
                 "dB_dlambda": 4.0 * float((z - y) @ (ctx.M @ z)) / w2}
    if ctx.keep_fields:
        res.fields = {"a_bar": a_bar, "w2_b_bar": 0.5 * (z - y)}  # w2_b_bar = w^2 b_bar
    res.extra["T_change"] = None  # no check amplitude: no change measured
    if dGv is not None:
        dA, dB = 4 * float(dGv @ a_bar), 4 * float(dGv @ b_bar)
        dT = (3 * (dA + dh) + w2 * dB) / (8 * w2)
        res.T_error = abs(dT) / abs(T) if T != 0 else (0.0 if dT == 0 else np.inf)
        res.extra["T_change"] = res.T_error
    if rounding is not None:
        rel, parts = dnf_roundoff(phi, rounding.q, omega_p, T, Gv, rounding.Hv, y, z, ctx.K, ctx.M, rounding.digits,
                                  slope=dnf_slope(w2, A + h + w2 * B, res.extra["dB_dlambda"]),
                                  excess=rounding.excess)
        res.extra.update(roundoff=rel, **{f"roundoff_{k}": v for k, v in parts.items()})
        res.T_error = rel if res.T_error is None else max(res.T_error, rel)
    return res, y


def smd_full(p: int, phi: np.ndarray, omega_p: float, Gv: np.ndarray, h: float,
             ctx: FullOrderContext, y: np.ndarray | None = None, *, dGv: np.ndarray | None = None,
             dh: float = 0.0, spectrum: Spectrum | None = None, rounding: Rounding | None = None) -> MethodResult:
    """Static modal derivative quadratic manifold, full order: ``theta = -2 K^+ Gv`` (one solve, or none given y).

    With ``dGv``, ``dh`` (differences at the STEP check amplitude, as for
    :func:`dnf`) ``T_error`` is the first-order change of T, without a solve
    (:func:`~stepnf.nf.linearised.qm_T_error`; ``spectrum``: the computed modes, see there).
    """
    if y is None:
        y = ctx.Kpinv(Gv)
    theta = -2.0 * y
    res, forms = _qm_full(methods.SMD, phi, omega_p, Gv, h, theta, ctx)
    if dGv is not None:
        res.T_error = qm_T_error(res, forms, phi, omega_p, theta, 0.0, ctx.Kpinv.R, dGv, dh, spectrum)
    return with_qm_roundoff(res, phi, omega_p, Gv, theta, ctx.K, rounding, forms=forms, h=h)


def md_full(p: int, phi: np.ndarray, omega_p: float, Gv: np.ndarray, h: float, ctx: FullOrderContext,
            twins: np.ndarray | None = None, *, g: np.ndarray | None = None,
            tol: Tolerances = Tolerances(), floor: np.ndarray | float | None = None,
            exclude: Sequence[int] | None = None, twin_index: Sequence[int] | None = None,
            labels: Sequence[Any] | None = None, dGv: np.ndarray | None = None, dh: float = 0.0,
            spectrum: Spectrum | None = None, theta: np.ndarray | None = None,
            rounding: Rounding | None = None) -> MethodResult:
    """Modal-derivative quadratic manifold, full order.

    ``theta`` solves the bordered system ``[[K - w^2 M, M D], [D^T M, 0]]`` with
    ``D = [phi_p, twins]`` (the degenerate companions of p), so that
    ``theta`` is M-orthogonal to them. A twin that couples (``phi_t^T Gv``
    not zero by symmetry) makes MD diverge: T = -inf, flagged. With
    ``ctx.deflated`` and ``exclude`` (the columns of its modes that are p and
    its twins) the same theta comes from the computed modes and CG, without
    a factorisation. With ``dGv``, ``dh`` (differences at the STEP check
    amplitude) and ``spectrum`` (the computed modes, needed: the resolvent
    ``(K - w^2 M)^-1`` is indefinite) ``T_error`` is the first-order change
    of T, without a solve (:func:`~stepnf.nf.linearised.qm_T_error`); none when T diverges. ``theta``
    given (the deflated solve, done beforehand): not solved again.
    """
    w2 = omega_p ** 2
    D = phi[:, None] if twins is None or len(twins) == 0 else np.column_stack([phi, twins])
    res, theta, forms = _md_theta_result(p, phi, omega_p, Gv, h, ctx, D, g, tol, floor, exclude, twin_index, labels,
                                         theta)
    if dGv is not None and theta is not None:
        res.T_error = qm_T_error(res, forms, phi, omega_p, theta, w2, D, dGv, dh, spectrum)
    s = None  # theta's own dependence on lambda (Z M theta from the computed modes); without them left out
    if rounding is not None and theta is not None and spectrum is not None:
        s = float((ctx.M @ theta) @ resolvent_mass(theta, forms[0], forms[1], w2, D, spectrum))
    return with_qm_roundoff(res, phi, omega_p, Gv, theta, ctx.K, rounding, forms=forms, h=h, s=s)


def md_twin_flag(p: int, phi: np.ndarray, Gv: np.ndarray, D: np.ndarray, g: np.ndarray | None, tol: Tolerances,
                 floor: np.ndarray | float | None, twin_index: Sequence[int] | None,
                 labels: Sequence[Any] | None) -> dict | None:
    """MD's 1:1 flag when a degenerate twin of ``p`` (columns 1: of ``D = [phi_p, twins]``) couples
    (``|phi_t^T Gv|`` above the coupling floor): the modal derivative diverges. None otherwise."""
    if D.shape[1] <= 1:
        return None
    gt = D[:, 1:].T @ Gv
    if floor is None:
        floor = tol.coupling * max(np.abs(g).max() if g is not None and g.size else abs(float(phi @ Gv)), 1e-300)
    if not np.any(np.abs(gt) > (np.max(floor) if np.ndim(floor) else floor)):
        return None
    j = int(np.argmax(np.abs(gt)))
    s_idx = None if twin_index is None else int(twin_index[j])
    lab = None if s_idx is None or labels is None else labels[s_idx]
    name = "a degenerate twin" if s_idx is None else f"mode {s_idx}" + ("" if lab is None else f" {lab}")
    return new_flag("internal_resonance_1_1", mode=s_idx, label=lab, ratio=1.0,
                    message=f"MD: {name}, a degenerate twin of master mode {p}, couples "
                            f"(|g| = {np.abs(gt).max():.3e}): the modal derivative diverges")


def _md_theta_result(p: int, phi: np.ndarray, omega_p: float, Gv: np.ndarray, h: float, ctx: FullOrderContext,
                     D: np.ndarray, g: np.ndarray | None, tol: Tolerances, floor: np.ndarray | float | None,
                     exclude: Sequence[int] | None, twin_index: Sequence[int] | None,
                     labels: Sequence[Any] | None, theta: np.ndarray | None = None
                     ) -> tuple[MethodResult, np.ndarray | None, tuple | None]:
    """:func:`md_full`'s result (T, C, flags, fields), theta and its forms (None when MD diverges)."""
    w2 = omega_p ** 2
    flags: list[dict] = []
    twin = md_twin_flag(p, phi, Gv, D, g, tol, floor, twin_index, labels)
    if twin is not None:
        return MethodResult(methods.MD, -np.inf, (float(phi @ Gv), 0.0, 0.0, np.inf, np.inf, np.inf),
                            [twin], order=methods.FULL), None, None
    if theta is None and ctx.deflated is not None and exclude is not None:
        theta = ctx.deflated.solve(-2.0 * Gv, w2, exclude=exclude)
    elif theta is None:
        MD = ctx.M @ D
        A = sp.bmat([[sp.csr_matrix(ctx.K) - w2 * sp.csr_matrix(ctx.M), sp.csr_matrix(MD)],
                     [sp.csr_matrix(MD.T), None]]).tocsr()
        try:
            fac = factorize(A, counters=ctx.counters, backend=ctx.backend,
                            label=f"bordered K - w^2 M (mode {p})")
            theta = fac.solve(np.concatenate([-2.0 * Gv, np.zeros(D.shape[1])]))[: len(Gv)]
        except NumericalError as exc:  # a mode at exactly w_p that is not among the twins: MD diverges
            flags.append(new_flag("internal_resonance_1_1", mode=None,
                                  message=f"MD: K - w^2 M is singular beyond the twins of master mode {p} (an "
                                          f"undeclared mode at the same frequency): modal derivative diverges ({exc})"))
            return MethodResult(methods.MD, -np.inf, (float(phi @ Gv), 0.0, 0.0, np.inf, np.inf, np.inf),
                                flags, order=methods.FULL), None, None
    res, forms = _qm_full(methods.MD, phi, omega_p, Gv, h, theta, ctx)
    res.flags = flags + res.flags
    return res, theta, forms


def _qm_full(method: str, phi: np.ndarray, omega_p: float, Gv: np.ndarray, h: float,
             theta: np.ndarray, ctx: FullOrderContext) -> tuple[MethodResult, tuple[float, float, float]]:
    """T of the quadratic manifold ``u = phi R + theta R^2 / 2`` (:func:`~stepnf.nf.coefficient.qm_coefficients`),
    and the forms ``(mu2, k2, t) = (theta^T M theta, theta^T K theta, theta^T Gv)``."""
    Mt = ctx.M @ theta
    mu1 = float(phi @ Mt)
    mu2 = float(theta @ Mt)
    k2 = float(theta @ (ctx.K @ theta))
    t = float(theta @ Gv)
    C = qm_coefficients(omega_p, float(phi @ Gv), h, mu1, mu2, k2, t)
    res = MethodResult(method, backbone_T(C, omega_p), C, [], order=methods.FULL)
    if ctx.keep_fields:
        res.fields = {"theta": theta}
    return res, (mu2, k2, t)
