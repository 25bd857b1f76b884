"""Indicators and flags around the evaluators: coupling, slow/fast ratio, 1:2 check, modal truncation.

Each says something the numbers alone do not: which slave modes the master
really drives (the coupling floor), how far the slow/fast assumption of the
quadratic manifolds holds (rho_p), whether a mode near twice the master's
frequency makes the normal form's denominator small, and how much of the
quadratic force the modal sums can see.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp

from .adapter import SolverAdapter
from .backbone import MethodResult
from .counters import Counters
from .evaluators import FullOrderContext, Tolerances, coupled
from .modal import ModalBasis


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
    dm = np.asarray(M.diagonal()).ravel()
    return tol.coupling * float(np.sqrt(np.sum(st.Gv**2 / np.where(dm > 0, dm, np.inf))))


def one_two_flags(p: int, w: float, st, basis: ModalBasis, ctx: FullOrderContext, floor0: float,
                   tol: Tolerances, adapter: SolverAdapter, counters: Counters) -> list[dict]:
    """DNF's 1:2 check: the modes nearest ``2 w_p``, found with the DNF's own ``K - 4 w^2 M`` factors."""
    top = basis.omega[-1] if basis.n_elastic else 0.0
    if basis.complete or top >= 2.0 * w * (1 + tol.resonance):
        near_w, near_phi = basis.omega, basis.phi  # every mode near 2 w_p is among the computed ones
    else:
        near_w, near_phi = ritz_near(ctx, 4 * w * w, st.Gv, counters)
    g = near_phi.T @ st.Gv
    floor = np.full(len(g), floor0)
    if st.Gv_check is not None:
        floor = np.maximum(floor, 10.0 * np.abs(near_phi.T @ (st.Gv - st.Gv_check)))
    labels = adapter.mode_labels(near_phi) if not basis.complete else list(adapter.mode_labels(near_phi))
    flags = []
    for j in np.nonzero(coupled(g, tol.coupling, floor))[0]:
        r = near_w[j] / w
        if abs(r - 2.0) > 2.0 * tol.resonance:
            continue
        hit = np.nonzero(np.isclose(basis.omega, near_w[j], rtol=1e-9))[0]
        s_idx = int(hit[0]) if len(hit) else None
        name = (f"mode {s_idx}" if s_idx is not None else f"a mode at w = {near_w[j]:.6g}") + \
            (f" {labels[j]}" if labels[j] is not None else "")
        flags.append({"kind": "internal_resonance_1_2", "mode": s_idx, "label": labels[j], "ratio": float(r),
                      "omega": float(near_w[j]),
                      "message": f"DNF: {name} is in 1:2 internal resonance with master mode {p} "
                                 f"(w_s/w_p = {r:.4f}); the normal form has a small denominator there"})
    return flags


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


def captured_fraction(Gv: np.ndarray, g_retained: np.ndarray, M: sp.spmatrix) -> float:
    """Share of ``G(phi_p, phi_p)`` the retained modes carry: ``sum_S g_s^2 / (Gv^T M^-1 Gv)``.

    The modal sums of NF, MD and SMD see only that share; the rest lies on
    modes not retained (in-plane and thickness modes of a 3D solid). M^-1 by
    Jacobi-preconditioned CG (M is well conditioned).
    """
    import scipy.sparse.linalg as spla

    total2 = float(Gv @ Gv)
    if total2 == 0.0:
        return 1.0
    d = np.asarray(M.diagonal()).ravel()
    x, info = spla.cg(M, Gv, M=sp.diags(1.0 / d), tol=1e-10, atol=0.0, maxiter=500)
    full = float(Gv @ x)
    return float(np.sum(g_retained**2) / full) if full > 0 else 1.0


def truncation_flags(r: MethodResult, Gv: np.ndarray, g_retained: np.ndarray, M: sp.spmatrix,
                     n: int, threshold: float = 0.99) -> list[dict]:
    """Flag a modal-sum result whose retained modes miss more than 1% of the quadratic force."""
    frac = captured_fraction(Gv, g_retained, M)
    r.extra["captured_fraction"] = frac
    if frac >= threshold:
        return []
    return [{"kind": "modal_truncation", "value": frac,
             "message": f"{r.method.upper()}: the {n} retained modes carry only {100 * frac:.3g}% of "
                        "G(phi_p, phi_p) (M^-1 norm); the rest lies on modes not retained (in-plane modes, "
                        "and thickness modes of a 3D model). Use dnf, or md/smd with qm_order = \"full\"."}]


def t_error(T: float, T2: float) -> float:
    if not (np.isfinite(T) and np.isfinite(T2)):
        return 0.0 if T == T2 else float("inf")
    return abs(T - T2) / abs(T) if T != 0 else (0.0 if T2 == 0 else float("inf"))


def smooth_eigenvalue(K: sp.spmatrix, M: sp.spmatrix, X: np.ndarray | None, D: np.ndarray | None) -> float | None:
    """An upper bound of the lowest elastic eigenvalue from smooth fields, without an eigen-solve.

    Rayleigh-Ritz on the quadratic displacement fields ``u_d = x_e x_f``
    (centred, scaled coordinates) with the rigid motions projected out: the
    least Ritz value bounds the first bending eigenvalue from above (within a
    small factor for plates and shells). ``None`` without dof geometry.
    """
    if X is None or D is None:
        return None
    from .modal import rigid_body_fields

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
    MR = M @ R
    Q = Q - R @ np.linalg.lstsq(R.T @ MR, MR.T @ Q, rcond=None)[0]  # M-orthogonal to the rigid motions
    q, r = np.linalg.qr(Q)
    keep = np.abs(np.diag(r)) > 1e-10 * np.abs(np.diag(r)).max()
    q = q[:, keep]
    if not q.shape[1]:
        return None
    Kr, Mr = q.T @ (K @ q), q.T @ (M @ q)
    lam = np.linalg.eigvalsh(np.linalg.solve(np.linalg.cholesky(Mr), np.linalg.solve(np.linalg.cholesky(Mr),
                                                                                      Kr).T))
    return float(max(lam.min(), 0.0))


def conditioning_ratio(lam_low: float, K: sp.spmatrix, M: sp.spmatrix) -> float:
    """``lambda_low / lambda_max``, ``lambda_max`` estimated by ``max(diag K / diag M)``."""
    from .modal import lambda_scale

    return float(lam_low / lambda_scale(K, M))


def check_conditioning(r: float, *, flag_at: float = 1e-6, refuse_at: float = 1e-2) -> list[dict]:
    """Flag (or refuse) a model whose stiffness spread exceeds what double precision resolves.

    The lowest elastic eigenvalue is computed with an absolute error of about
    ``eps * lambda_max``, i.e. a relative error ``eps / r`` with
    ``r = lambda_1 / lambda_max``. A 3D solid model of a shell has
    ``r ~ (h/a)^4``: fine at h/a = 0.02 (r ~ 1e-8), hopeless at h/a = 1e-4
    (r ~ 1e-17). Above ``flag_at`` the results carry an ``ill_conditioned``
    flag; above ``refuse_at`` (frequencies wrong by a percent or more) the run
    stops with a :class:`NumericalError`.
    """
    from .errors import NumericalError

    err = np.finfo(float).eps / max(r, 1e-300)
    text = (f"the lowest elastic eigenvalue is {r:.1e} times the largest: double precision resolves it only "
            f"to about {min(err, 1.0):.0e} (relative), and every frequency, mode and T inherits that error. A very "
            "thin structure meshed with solid elements does this (stiffness ratio ~ (a/h)^4); use a shell "
            "model, or fewer through-thickness elements")
    if err > refuse_at:
        raise NumericalError("ill-conditioned model: " + text)
    if err > flag_at:
        return [{"kind": "ill_conditioned", "value": float(err), "message": text}]
    return []


def conditioning_flags(basis: ModalBasis, K: sp.spmatrix, M: sp.spmatrix,
                       smooth: float | None = None) -> list[dict]:
    """:func:`check_conditioning` with the lowest computed eigenvalue (and the smooth-field bound, which
    catches a first eigenvalue that round-off has pushed far too high)."""
    if not basis.n_elastic:
        return []
    lam = float(basis.omega[0] ** 2)
    if smooth is not None:
        lam = min(lam, smooth)
    return check_conditioning(conditioning_ratio(lam, K, M))
