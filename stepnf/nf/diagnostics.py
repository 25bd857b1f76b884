"""Indicators and flags around the evaluators: coupling, slow/fast ratio, 1:2 check, modal truncation,
soft modes counted rigid, and overflow turned into a :class:`~stepnf.errors.NumericalError`.

Each says something the numbers alone do not: which slave modes the master
really drives (the coupling floor), how far the slow/fast assumption of the
quadratic manifolds holds (rho_p), whether a mode near twice the master's
frequency makes the normal form's denominator small, and how much of the
quadratic force the modal sums can see.
"""
from __future__ import annotations

import contextlib
import math
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from stepnf.plugin.adapter import SolverAdapter
from stepnf.nf.coefficient import MethodResult
from stepnf.linalg.block_product import block_product
from stepnf.runtime.counters import Counters
from stepnf.errors import NumericalError
from stepnf.flags import new_flag
from stepnf.nf.evaluators import FullOrderContext, Tolerances, coupled
from stepnf.linalg.factorization import matrix_diagonal
from stepnf.linalg.modal_analysis import ModalBasis
from stepnf.linalg.null_space import abs_energy
from stepnf.nf.roundoff import eigenvalue_roundoff


def slow_fast_ratio(p: int, omega: np.ndarray, g: np.ndarray, tol: Tolerances,
                    twins: Sequence[int], floor: np.ndarray | float | None = None) -> tuple[float | None, int | None]:
    """rho_p = min over coupled slave modes s of w_s / w_p (paper Eq. 8).

    Slaves are the modes that the master drives through ``g^s_pp`` (others
    cannot break the slow/fast assumption); when none couples, every
    non-twin slave counts, as in the paper's literal definition.
    """
    cp = coupled(g, tol.coupling, floor)
    cand = [s for s in range(len(omega)) if s != p and cp[s]]
    if not cand:
        cand = [s for s in range(len(omega)) if s != p and s not in twins]
    if not cand:
        return None, None
    r = omega[cand] / omega[p]
    j = int(np.argmin(r))
    return float(r[j]), int(cand[j])


def floor_scale(st, M: sp.spmatrix, tol: Tolerances) -> float:
    """``tol.coupling * ||G(phi_p, phi_p)||`` in the lumped ``M^-1`` norm (bounds every ``|g^s_pp|``)."""
    dm = matrix_diagonal(M)
    return tol.coupling * float(np.sqrt(np.sum(st.Gv**2 / np.where(dm > 0, dm, np.inf))))


def one_two_flags(p: int, w: float, st, basis: ModalBasis, ctx: FullOrderContext, floor0: float,
                   tol: Tolerances, adapter: SolverAdapter, counters: Counters) -> list[dict]:
    """DNF's 1:2 check: the modes nearest ``2 w_p``, found with the DNF's own ``K - 4 w^2 M`` factors."""
    top = basis.omega[-1] if basis.n_elastic else 0.0
    if basis.complete or top >= 2.0 * w * (1 + tol.resonance):
        near_w, near_phi = basis.omega, basis.phi  # every mode near 2 w_p is among the computed ones
    else:
        try:
            near_w, near_phi = ritz_near(ctx, 4 * w**2, st.Gv, counters)  # as dnf: the slot's shift, bit for bit
        except NumericalError:  # K - 4 w^2 M singular: DNF has flagged the exact resonance already
            return []
    g = near_phi.T @ st.Gv
    floor = np.full(len(g), floor0)
    if st.Gv_check is not None:
        floor = np.maximum(floor, 10.0 * np.abs(near_phi.T @ (st.Gv - st.Gv_check)))
    resonant = [int(j) for j in np.nonzero(coupled(g, tol.coupling, floor))[0]
                if abs(near_w[j] / w - 2.0) <= 2.0 * tol.resonance]
    # only the resonant modes are named: labelling every computed mode for every master cost 0.3 s each at 250k
    labels = dict(zip(resonant, adapter.mode_labels(near_phi[:, resonant]))) if resonant else {}
    flags = []
    for js in _same_frequency(near_w, resonant):  # a degenerate pair at 2 w_p is ONE resonance: one flag
        j = js[0]
        r = near_w[j] / w
        hit = [int(i) for i in np.nonzero(np.isclose(basis.omega, near_w[j], rtol=1e-9))[0]]
        s_idx = hit[0] if hit else None
        who = (f"mode {s_idx}" if len(hit) == 1 else f"modes {', '.join(map(str, hit))}" if hit
               else f"a mode at w = {near_w[j]:.6g}" if len(js) == 1 else f"{len(js)} modes at w = {near_w[j]:.6g}")
        name = who + (f" {labels[j]}" if labels[j] is not None else "")
        flag = new_flag("internal_resonance_1_2", mode=s_idx, label=labels[j], ratio=float(r),
                        omega=float(near_w[j]),
                        message=f"DNF: {name} {'is' if len(js) == 1 and len(hit) <= 1 else 'are'} in 1:2 internal "
                                f"resonance with master mode {p} (w_s/w_p = {r:.4f}); the normal form has a small "
                                "denominator there")
        if len(hit) > 1:
            flag["modes"] = hit
        flags.append(flag)
    return flags


def merge_flags(flags: list[dict], new: list[dict]) -> list[dict]:
    """``flags`` plus those of ``new`` that say something new: one flag per (kind, mode).

    A flag of the same kind without a mode (DNF's "K - 4 w^2 M is singular")
    takes the mode, label, ratio and frequency the 1:2 check found, instead of
    a second flag for the same resonance.
    """
    out = list(flags)
    for f in new:
        same = [e for e in out if e.get("kind") == f.get("kind")]
        if any(e.get("mode") == f.get("mode") and f.get("mode") is not None for e in same):
            continue
        unnamed = [e for e in same if e.get("mode") is None]
        if unnamed:
            unnamed[0].update({k: v for k, v in f.items() if k != "message"})
            continue
        out.append(f)
    return out


def _same_frequency(w: np.ndarray, idx: list[int], rtol: float = 1e-6) -> list[list[int]]:
    """``idx`` grouped by equal ``w[idx]`` (within ``rtol``: the members of a degenerate pair)."""
    groups: list[list[int]] = []
    for j in sorted(idx, key=lambda i: w[i]):
        if groups and abs(w[j] - w[groups[-1][0]]) <= rtol * abs(w[j]):
            groups[-1].append(j)
        else:
            groups.append([j])
    return groups


def ritz_near(ctx: FullOrderContext, sigma: float, Gv: np.ndarray, counters: Counters,
               steps: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Rayleigh-Ritz on ``span{Z^-1 Gv, (Z^-1 M)^2 Gv, ...}``, ``Z = K - sigma M`` (DNF's factors).

    Inverse iteration from ``G(phi_p, phi_p)`` amplifies exactly the modes that
    are both coupled to the master and near ``sqrt(sigma) = 2 w_p``, so three
    solves find the modes a 1:2 resonance could come from.
    """
    Z = ctx.shifted_factorization(sigma, "")
    R = ctx.Kpinv.R
    v = Gv - ctx.M @ (R @ (R.T @ Gv)) if R.shape[1] else Gv
    V = []
    for _ in range(steps):
        v = Z.solve(v, count=False)
        counters.eigensolver_solves += 1
        V.append(v)
        v = ctx.M @ v
    V = np.column_stack(V)
    Mr = V.T @ (ctx.M @ V)
    Kr = V.T @ (ctx.K @ V)
    d = np.sqrt(np.abs(np.diag(Mr)))
    Mr, Kr, V = Mr / np.outer(d, d), Kr / np.outer(d, d), V / d
    lam, y = np.linalg.eigh(Mr)
    keep = lam > 1e-12 * lam.max()  # drop directions the iteration made dependent
    T = y[:, keep] / np.sqrt(lam[keep])
    mu, z = np.linalg.eigh(T.T @ Kr @ T)
    phi = V @ (T @ z)
    return np.sqrt(np.maximum(mu, 0.0)), phi


def coupling_floor(st, Phi: np.ndarray, M: sp.spmatrix, tol: Tolerances) -> np.ndarray:
    """Per-mode threshold under which ``g^s_pp`` counts as zero (uncoupled by symmetry).

    ``tol.coupling`` times ``||G(phi_p, phi_p)||`` in the (lumped) ``M^-1``
    norm, which bounds every ``|g^s_pp|`` of M-normalised modes, and at least
    ten times the change of ``g^s_pp`` between the two STEP amplitudes (the
    noise the solver's forces carry).
    """
    floor = np.full(Phi.shape[1], floor_scale(st, M, tol))
    if st.Gv_check is not None:
        floor = np.maximum(floor, 10.0 * np.abs(Phi.T @ (st.Gv - st.Gv_check)))
    return floor


#: relative accuracy of :func:`inverse_mass_norm2` (its consumers compare shares with 50% and 99%)
INVERSE_MASS_RTOL = 1e-5


def inverse_mass_norm2(M: sp.spmatrix, v: np.ndarray, rtol: float = INVERSE_MASS_RTOL,
                       maxiter: int = 500) -> float:
    """``v^T M^-1 v`` (units of v squared per mass) to a relative accuracy ``rtol``, by Jacobi-preconditioned CG.

    From ``x_0 = 0``, CG's ``v^T x_k = sum_{j<k} alpha_j gamma_j`` increases
    to ``v^T M^-1 v`` and the rest is the energy error ``sum_{j>=k} alpha_j
    gamma_j``: the estimate is a lower bound (a captured share computed with it
    an upper bound). CG stops when that rest, extrapolated geometrically from
    the last increments (ratio q: ``increment / (1 - q)``), is below ``rtol``
    times the sum. Accuracy needed: the share is compared with 50% (the table's
    n/a) and 99% (``modal_truncation`` flag), where 0.989 against 0.991 flips
    the flag: 1e-3 relative would do; the default 1e-5 leaves a factor 100 for
    the extrapolation, and costs about a quarter of the iterations of the
    former residual test at 1e-10 (which resolved the energy to ~1e-20).
    Independent of the scaling of M (shell rotations): the test is on the
    energy itself. A non-positive diagonal or curvature of M, or no
    convergence in ``maxiter`` iterations, raises :class:`NumericalError`.
    """
    v = np.asarray(v, dtype=float)
    if not np.any(v):
        return 0.0
    d = matrix_diagonal(M)
    if np.any(d <= 0):
        raise NumericalError("the mass matrix has non-positive diagonal entries: its M^-1 norm is undefined")
    r, total, last = v.copy(), 0.0, np.inf
    z = r / d
    p, gamma = z.copy(), float(r @ z)
    for _ in range(maxiter):
        Mp = M @ p
        curv = float(p @ Mp)
        if curv <= 1e3 * np.finfo(float).eps * float(p @ (d * p)):
            if curv >= -1e3 * np.finfo(float).eps * float(p @ (d * p)):
                return math.inf  # p is (to round-off) massless: v has a part M does not see (a singular M)
            raise NumericalError("the mass matrix is not positive definite, nor semi-definite (CG met p^T M p < 0)")
        alpha = gamma / curv
        step = alpha * gamma
        total += step
        q = min(step / last, 1.0)
        if q < 1.0 and step / (1.0 - q) <= rtol * total:
            return total
        last = step
        r -= alpha * Mp
        z = r / d
        gamma, gamma_old = float(r @ z), gamma
        if gamma <= 0:  # r = 0: exact (M diagonal, or a vector M maps from a few of its columns)
            return total
        p = z + (gamma / gamma_old) * p
    raise NumericalError(f"v^T M^-1 v: Jacobi-preconditioned CG did not reach {rtol:g} in {maxiter} iterations")


def captured_fraction_of_norm(g_retained: np.ndarray, norm2: float) -> float:
    """``sum_S g_s^2 / norm2`` with ``norm2 = G^T M^-1 G``; 1 when G vanishes."""
    return float(np.sum(g_retained**2) / norm2) if norm2 > 0 else 1.0


def captured_fraction(Gv: np.ndarray, g_retained: np.ndarray, M: sp.spmatrix) -> float:
    """Share of ``G(phi_p, phi_p)`` the retained modes carry: ``sum_S g_s^2 / (Gv^T M^-1 Gv)``.

    The modal sums of NF, MD and SMD see only that share; the rest lies on
    modes not retained (in-plane and thickness modes of a 3D solid).
    """
    return captured_fraction_of_norm(g_retained, inverse_mass_norm2(M, Gv))


def truncation_flags(r: MethodResult, frac: float, n: int, threshold: float = 0.99) -> list[dict]:
    """Flag a modal-sum result whose ``n`` retained modes carry only ``frac`` < 99% of the quadratic force.

    ``frac`` is :func:`captured_fraction` (targeted STEP) or the same share
    from the full STEP plan (:func:`captured_fraction_of_norm`).
    """
    r.extra["captured_fraction"] = frac
    if frac >= threshold:
        return []
    return [new_flag("modal_truncation", value=frac,
                     message=f"{r.method.upper()}: the {n} retained modes carry only {100 * frac:.3g}% of "
                             "G(phi_p, phi_p) (M^-1 norm); the rest lies on modes not retained (in-plane modes, "
                             "and thickness modes of a 3D model). Use dnf, or md/smd with qm_order = \"full\".")]


def t_error(T: float, T2: float) -> float:
    if not (np.isfinite(T) and np.isfinite(T2)):
        return 0.0 if T == T2 else float("inf")
    return abs(T - T2) / abs(T) if T != 0 else (0.0 if T2 == 0 else float("inf"))


def smooth_field(K: sp.spmatrix, M: sp.spmatrix, X: np.ndarray | None,
                 D: np.ndarray | None) -> tuple[float, np.ndarray] | None:
    """The smoothest field's Ritz value and vector ``(lambda, u)`` (u (n,), M-normalised), without an eigen-solve:
    the value bounds the lowest elastic eigenvalue from above.

    Rayleigh-Ritz on the quadratic displacement fields ``u_d = x_e x_f``
    (centred, scaled coordinates) with the rigid motions projected out: the
    least Ritz value bounds the first bending eigenvalue from above (within a
    small factor for plates and shells). ``None`` without dof geometry.
    """
    if X is None or D is None:
        return None
    from stepnf.linalg.modal_analysis import rigid_body_fields

    X = np.asarray(X, dtype=float)
    D = np.asarray(D, dtype=int)
    c = (X - X.mean(axis=0)) / max(float(np.ptp(X)), 1e-300)
    cols = []
    for d in range(3):
        on = (D == d).astype(float)
        for e in range(3):
            for f in range(e, 3):
                cols.append(on * c[:, e] * c[:, f])
    Q = np.column_stack(cols)
    R = rigid_body_fields(X, D)
    Mb = block_product(M)
    MR = Mb @ R
    Q = Q - R @ np.linalg.lstsq(R.T @ MR, MR.T @ Q, rcond=None)[0]  # M-orthogonal to the rigid motions
    q, r = np.linalg.qr(Q)
    keep = np.abs(np.diag(r)) > 1e-10 * np.abs(np.diag(r)).max()
    q = q[:, keep]
    if not q.shape[1]:
        return None
    Kr, Mr = q.T @ (block_product(K) @ q), q.T @ (Mb @ q)
    L = np.linalg.cholesky(Mr)
    lam, y = np.linalg.eigh(np.linalg.solve(L, np.linalg.solve(L, Kr).T))
    u = q @ np.linalg.solve(L.T, y[:, 0])
    return float(max(lam[0], 0.0)), u


#: a mode whose eigenvalue's own rounding bound (:func:`stepnf.nf.roundoff.eigenvalue_roundoff`) exceeds this is
#: flagged (``ill_conditioned``); above :data:`REFUSE_AT` (an eigenvalue wrong by a percent or more) it is refused
FLAG_AT = 1e-6
REFUSE_AT = 1e-2


def _conditioning_text(what: str, err: float) -> str:
    return (f"{what}: double precision resolves it only to about {min(err, 1.0):.0e} (relative: eps |phi|^T |K| "
            "|phi| / lambda, the rounding of K on that mode, or |lambda - phi^T K phi| / lambda), and the frequencies "
            "inherit that error (each T has its own bound, larger where its terms cancel: T_error, and a "
            "t_roundoff flag above the tolerance). A very thin structure meshed with solid elements does this (its "
            "bending modes are locally rigid motions: stiffness ratio ~ (a/h)^4); use a shell model, or fewer "
            "through-thickness elements")


def check_conditioning(err: float, *, what: str = "the smoothest field's eigenvalue", flag_at: float = FLAG_AT,
                       refuse_at: float = REFUSE_AT) -> list[dict]:
    """Flag (or refuse) one field whose eigenvalue's own rounding bound ``err`` (relative,
    :func:`stepnf.nf.roundoff.eigenvalue_roundoff`) exceeds what the run accepts.

    Above ``flag_at`` an ``ill_conditioned`` flag; above ``refuse_at`` (an eigenvalue wrong by a percent or
    more) a :class:`NumericalError` (the model stage: the smoothest field, whose Ritz value bounds the
    fundamental from above, is beyond reach, so the fundamental is too, before any eigen-solve).
    """
    text = _conditioning_text(what, err)
    if err > refuse_at:
        raise NumericalError("ill-conditioned model: " + text)
    if err > flag_at:
        return [new_flag("ill_conditioned", value=float(err), message=text)]
    return []


def mode_bounds(basis: ModalBasis, K: sp.spmatrix, smooth: float | None = None) -> np.ndarray:
    """Each elastic mode's eigenvalue rounding bound (:func:`stepnf.nf.roundoff.eigenvalue_roundoff`), the
    lowest one's relative to ``min(lambda_0, smooth)`` (the smooth-field Ritz value: it catches a first
    eigenvalue that round-off has pushed far too high)."""
    lam = basis.omega ** 2
    if smooth is not None and len(lam):
        lam = lam.copy()
        lam[0] = min(lam[0], smooth)
    return eigenvalue_roundoff(K, basis.phi, lam)


def conditioning_flags(basis: ModalBasis, K: sp.spmatrix, smooth: float | None = None, masters: Sequence[int] = (),
                       *, flag_at: float = FLAG_AT, refuse_at: float = REFUSE_AT) -> list[dict]:
    """The run's ``ill_conditioned`` flag from each elastic mode's own bound (:func:`mode_bounds`), or [].

    The flag's ``value`` is the largest bound among the masters (else among all modes), ``bounds`` the bound of
    every mode above ``flag_at`` (index -> bound), ``refused`` the masters above ``refuse_at``: each of their
    methods gets an ``unresolved_mode`` flag (:func:`unresolved_flags`: T n/a). ``smooth``: the smoothest
    field's Ritz value (:func:`mode_bounds`)."""
    if not basis.n_elastic:
        return []
    err = mode_bounds(basis, K, smooth)
    high = [int(j) for j in np.flatnonzero(err > flag_at)]
    if not high:
        return []
    ms = [int(p) for p in masters if 0 <= int(p) < len(err)]
    worst = max(ms, key=lambda p: err[p]) if ms and max(err[ms]) > flag_at else max(high, key=lambda j: err[j])
    refused = [p for p in ms if err[p] > refuse_at]
    lost = [int(j) for j in np.flatnonzero(err > refuse_at)]
    text = _conditioning_text(f"mode {worst}'s eigenvalue ({float(basis.omega[worst]) ** 2:.3e})", float(err[worst]))
    if lost:
        text += (f". Beyond {refuse_at:g}: mode{'s' if len(lost) > 1 else ''} {', '.join(map(str, lost))}"
                 + (f"; master{'s' if len(refused) > 1 else ''} {', '.join(map(str, refused))} n/a" if refused else
                    " (no master)"))
    return [new_flag("ill_conditioned", value=float(err[worst]), message=text,
                     bounds={int(j): float(err[j]) for j in high}, refused=refused)]


def unresolved_flags(p: int, run_flags: Sequence[dict]) -> list[dict]:
    """The ``unresolved_mode`` flag of master ``p`` when the run's ``ill_conditioned`` flag refused it
    (:func:`conditioning_flags`): every method of that master gets it (T n/a, no backbone validity)."""
    for f in run_flags:
        if f.get("kind") == "ill_conditioned" and p in (f.get("refused") or ()):
            bounds = f.get("bounds") or {}
            err = float(bounds.get(p, bounds.get(str(p), f.get("value", np.inf))))  # str: a stored run's keys
            return [new_flag("unresolved_mode", mode=int(p), value=err,
                             message=f"master mode {p}'s eigenvalue is resolved only to about {err:.0e} (relative; "
                                     "the rounding of K on that mode): beyond the 1% the run accepts, T is n/a")]
    return []


def soft_mode_flags(rigid_eigenvalues: np.ndarray, scale: float, rigid_tolerance: float,
                    refuse_at: float = REFUSE_AT, rigid: np.ndarray | None = None,
                    K: sp.spmatrix | None = None) -> list[dict]:
    """Flag modes counted as rigid (``|w^2| <= rigid_tolerance * scale``) whose eigenvalue is resolved.

    A true rigid-body eigenvalue is zero up to its own round-off, ``eps |x|^T |K| |x|`` for its mode ``x``
    (``rigid`` (n, r), M-normalised, with ``K``; without them ``eps * scale``, ``scale`` the largest eigenvalue).
    An eigenvalue above that round-off divided by ``refuse_at`` is resolved to better than ``refuse_at`` (the
    bound :func:`conditioning_flags` accepts for elastic modes), so it may well be a very soft elastic mode
    (a weak support, a flexible appendage): counted as rigid, it shifts every master index and leaves the
    modal sums. ``rigid_eigenvalues`` in (rad/s)^2.
    """
    lam = np.asarray(rigid_eigenvalues, dtype=float)
    if rigid is not None and K is not None and rigid.shape[1] == len(lam):
        floor = np.finfo(float).eps / refuse_at * abs_energy(K, rigid)
    else:
        floor = np.full(len(lam), np.finfo(float).eps / refuse_at * scale)
    suspects = [int(i) for i in np.nonzero(lam > floor)[0]]
    if not suspects:
        return []
    text = ", ".join(f"w^2 = {lam[i]:.3e}" for i in suspects)
    return [new_flag("soft_modes_counted_rigid", modes=suspects,
                     message=f"{len(suspects)} of the {len(lam)} modes counted as rigid ({text}; rigid modes "
                             f"{suspects} in ascending order) lie below analysis.rigid_tolerance x lambda_max = "
                             f"{rigid_tolerance:g} x {scale:.3e} but above {1 / refuse_at:g} x their round-off "
                             f"({', '.join(f'{floor[i] * refuse_at:.1e}' for i in suspects)}): they may be very soft "
                             "elastic modes. If so, set analysis.rigid_modes to the number of true rigid-body modes "
                             "or lower analysis.rigid_tolerance; elastic mode indices shift with it")]


def captured_share(p: int, st, full, g_all: np.ndarray, S, M: sp.spmatrix) -> float | None:
    """Share of ``G(phi_p, phi_p)`` the retained modes ``S`` carry (targeted or full STEP), or None."""
    if st is not None:
        return captured_fraction(st.Gv, g_all[S], M)
    if full is None:
        return None
    cols = list(full.modes)
    if p not in cols or cols.index(p) not in full.g_norm2:
        return None
    j = cols.index(p)
    g = np.zeros(len(g_all))
    g[full.modes] = full.g[:, j, j]
    return captured_fraction_of_norm(g[S], full.g_norm2[j])


@contextlib.contextmanager
def overflow_is_numerical(where: dict, steps: dict):
    """Floating-point overflow in the evaluators becomes a :class:`NumericalError` naming the stage.

    ``where`` is updated by the caller with the master mode and method being
    evaluated; ``steps`` (master -> :class:`MasterStep`) gives the size of the
    STEP coefficients for the message. Exact resonances are not overflows
    (singular solves and zero denominators are flagged by the evaluators).
    """
    try:
        with np.errstate(over="raise"):
            yield
    except (FloatingPointError, OverflowError) as exc:
        big = max((float(np.abs(st.Gv).max()) for st in steps.values()), default=float("nan"))
        at = ", ".join(f"{k} {v}" for k, v in where.items())
        raise NumericalError(f"{at}: floating-point overflow ({exc}): the STEP coefficients (largest "
                             f"|G(phi_p, phi_p)| entry {big:.1e}) are beyond double precision's range; check "
                             "the model's units and the forces the solver returns") from exc
