"""Rigid-body modes and mechanisms from the model (null vectors of K), and eigen-solves with a singular M.

An eigenvalue below ``rigid_tolerance * lambda_scale`` is only a *candidate* rigid-body mode: the
fundamental of a slender cantilever (L/h = 300, one solid element through the thickness) lies at
~1e-11 of the largest eigenvalue, as low as that tolerance, yet the structure is held. What decides is
whether K has a null vector there, measured against the round-off of K itself: a field ``x`` with
``K x = 0`` in exact arithmetic gives, in floating point, ``|K x|`` of the order of ``eps |K| |x|``
(the entries of K carry their own relative round-off, 1e-14 for ccx's stored matrices), whereas an
elastic mode gives ``K x = lambda M x``. The scale-aware residual is therefore

    rho(x) = ||K x|| / || |K| |x| ||      (|K|: entrywise absolute values)

* rigid-body fields (translations and rotations of the dof coordinates, :func:`rigid_body_fields`,
  also exported by :mod:`stepnf.linalg.modal_analysis`): :func:`rigid_field_residuals` gives the
  singular values of ``min ||K R c|| / ||D R c||`` over the span (``D`` the row sums of ``|K|``, which
  is ``|K| |R c|`` for fields smooth on an element). Measured: 3e-15 to 8e-15 for free C3D20 blocks,
  1.5e-7 and 9e-7 for the least-held combination of cantilevers at L/h = 1000 and 300: seven decades
  apart, so :data:`RIGID_FIELD_RESIDUAL` = 1e-10 leaves three on each side.
* any other candidate (a mechanism that is no rigid motion of the whole, or a model without dof
  coordinates, e.g. a polynomial one): :func:`null_mask` calls an eigenvector ``x`` a null vector when its
  Rayleigh quotient is zero within its own rounding: ``|x^T K x| <= NULL_SAFETY eps |x|^T |K| |x|``
  (:func:`energy_ratios`; ``|x|^T |K| |x|`` is what a rounding of K's entries or of the products with K
  by ``eps`` changes ``x^T K x`` by, at most, to first order). Measured ratios ``|x^T K x| / (eps |x|^T |K|
  |x|)``: computed null vectors 0.008 to 0.15 (free bodies, random semi-definite K, massless dofs, a loose
  node: 0); elastic modes: 37 for the fundamental of a tet10 cantilever strip at L/h = 1000 (FEniCSx; its
  eigenvalue is 4e-15 of the largest), 7e3 for a fundamental at 3e-12 of the largest in a random basis,
  4.5e15 for K = diag(1, 1e14). :data:`NULL_SAFETY` = 10 leaves a factor 66 above the null vectors and
  3.7 under that strip's fundamental (whose own bound, 1 / 37 = 2.7e-2, is beyond what the run accepts
  anyway: :func:`stepnf.nf.roundoff.eigenvalue_roundoff`). A dof no element stiffens (a loose node) counts
  in ``|K| |x|`` with the largest row sum (:func:`row_scales`).

A semi-definite M (reduced-integration C3D20R mass matrices, lumped masses with massless dofs) has
infinite eigenvalues: :func:`dense_pencil_modes` solves ``M x = mu (K - sigma M) x`` instead of
``K x = lambda M x`` and drops the directions with ``mu`` at round-off (no mass), saying how many.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from stepnf.errors import NumericalError

#: Residual (relative to the round-off scale of K) below which a rigid-body field is a null vector of K.
RIGID_FIELD_RESIDUAL = 1e-10
#: A vector ``x`` is a null vector of K when ``|x^T K x| <= NULL_SAFETY eps |x|^T |K| |x|`` (module docstring).
NULL_SAFETY = 10.0
#: A diagonal entry of M below this times the largest sends the dense solve to the pencil ``(M, K - sigma M)``:
#: ``eigh(K, M)`` with masses of 1e-14 next to 1 puts the first frequencies 8% off with no error (measured,
#: a 10-dof lumped-mass model; the pencil and static condensation agree to 1e-15).
NEARLY_MASSLESS = 1e-8
#: ``mu / max|mu|`` at or below which a direction of the pencil ``(M, K - sigma M)`` has no mass (infinite
#: eigenvalue): computed ``mu`` carry an absolute error ~eps max|mu|, so 1e3 eps is noise; a real mode lies at
#: ``(lambda_min - sigma) / (lambda - sigma)`` >= ~1e-12 (sigma = -1e-10 lambda_scale or minus the lowest
#: elastic eigenvalue, :func:`dense_modes`; lambda <= ~100 lambda_scale).
MASSLESS_RATIO = 1e3 * np.finfo(float).eps
#: A dense ``eigh(K, M)`` eigenvalue beyond this times lambda_scale comes from a (numerically) singular M.
INFINITE_RATIO = 1e8


#: Entries of K whose absolute values are taken at a time (a row block): |K| is never held whole.
_BLOCK_ENTRIES = 1 << 22


def abs_product(K, X: np.ndarray) -> np.ndarray:
    """``|K| X`` (n, k), ``|K|`` the entrywise absolute values, by row blocks of a sparse K."""
    X = np.asarray(X, dtype=float).reshape(K.shape[0], -1)
    if not sp.issparse(K):
        return np.abs(np.asarray(K)) @ X
    K = K.tocsr()
    n = K.shape[0]
    rows = max(1, int(_BLOCK_ENTRIES * n // max(K.nnz, 1)))
    out = np.empty((n, X.shape[1]))
    for r0 in range(0, n, rows):
        r1 = min(n, r0 + rows)
        a, b = K.indptr[r0], K.indptr[r1]  # the block's entries: views of K's arrays, absolute values copied
        block = sp.csr_matrix((np.abs(K.data[a:b]), K.indices[a:b], K.indptr[r0:r1 + 1] - a), shape=(r1 - r0, n))
        out[r0:r1] = block @ X
    return out


def row_scales(K, d: np.ndarray | None = None) -> np.ndarray:
    """The row sums ``d`` of ``|K|`` (n,; computed when not given), those of dofs no element stiffens (below eps
    of the largest) raised to the largest: an amplitude there is as large, for the round-off of ``K x``, as one
    anywhere else."""
    d = abs_product(K, np.ones(K.shape[0]))[:, 0] if d is None else d
    top = float(d.max()) if len(d) else 0.0
    return np.where(d <= np.finfo(float).eps * top, top, d)


def residuals(K, X: np.ndarray) -> np.ndarray:
    """``rho`` of each column of ``X`` (n, k): ``||K x|| / || |K| |x| ||``, the amplitude on a dof no element
    stiffens counted with the largest row sum (:func:`row_scales`; else a loose node's null vector, whose
    computed copy carries round-off on the other dofs, would compare that round-off with itself)."""
    X = np.asarray(X, dtype=float).reshape(K.shape[0], -1)
    num = np.linalg.norm(np.asarray(K @ X), axis=0)
    d = abs_product(K, np.ones(K.shape[0]))[:, 0]
    s = row_scales(K, d)
    den = np.linalg.norm(abs_product(K, np.abs(X)) + np.where((s != d)[:, None], s[:, None] * np.abs(X), 0.0), axis=0)
    return num / np.maximum(den, np.finfo(float).tiny)


def abs_energy(K, X: np.ndarray) -> np.ndarray:
    """``|x|^T |K| |x|`` of each column of ``X`` (n, k): what the rounding of ``x^T K x``, and of K's entries,
    scales with on ``x`` (:func:`energy_ratios`); the amplitude on a dof no element stiffens counted with the
    largest row sum (:func:`row_scales`), as in :func:`residuals`."""
    A = np.abs(np.asarray(X, dtype=float).reshape(K.shape[0], -1))
    d = abs_product(K, np.ones(K.shape[0]))[:, 0]
    s = row_scales(K, d)
    loose = np.where(s != d, s, 0.0)
    return np.einsum("ij,ij->j", A, abs_product(K, A)) + np.einsum("ij,ij->j", A, loose[:, None] * A)


def energy_ratios(K, X: np.ndarray) -> np.ndarray:
    """``|x^T K x| / (|x|^T |K| |x|)`` of each column of ``X`` (n, k): the Rayleigh quotient's numerator over its
    own rounding scale. ``eps`` over it is the relative error that a rounding of K's entries (or of the products
    with K) by ``eps`` leaves in the eigenvalue of an eigenvector ``x`` (first order: ``d lambda = x^T dK x`` for
    ``|dK| <= eps |K|``); a null vector of K gives a few eps at most (:data:`NULL_SAFETY`)."""
    X = np.asarray(X, dtype=float).reshape(K.shape[0], -1)
    num = np.abs(np.einsum("ij,ij->j", X, np.asarray(K @ X)))
    return num / np.maximum(abs_energy(K, X), np.finfo(float).tiny)


def null_mask(K, X: np.ndarray) -> np.ndarray:
    """Which columns of ``X`` are null vectors of K: ``|x^T K x| <= NULL_SAFETY eps |x|^T |K| |x|`` (the
    Rayleigh quotient is zero within its own rounding, :func:`energy_ratios`)."""
    return energy_ratios(K, X) <= NULL_SAFETY * np.finfo(float).eps


def rigid_field_residuals(K, Q: np.ndarray) -> np.ndarray:
    """Singular values (increasing) of ``c -> K Q c`` against ``c -> D Q c`` over span(Q) (n, k), ``D`` the
    row sums of ``|K|`` (:func:`row_scales`): how close a rigid motion in span(Q) comes to a null vector of K."""
    B = row_scales(K)[:, None] * Q
    _, Rb = np.linalg.qr(B)
    S = np.linalg.solve(Rb.T, np.asarray(K @ Q).T).T
    return np.sort(np.linalg.svd(S, compute_uv=False))


def rigid_field_count(K, Q: np.ndarray) -> int:
    """Number of independent rigid motions in span(Q) that are null vectors of K (0 when held)."""
    if Q.shape[1] == 0:
        return 0
    return int(np.sum(rigid_field_residuals(K, Q) <= RIGID_FIELD_RESIDUAL))


def dense_pencil_modes(Kd: np.ndarray, Md: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Every finite eigenpair of ``(K, M)`` with M only semi-definite, and the number of infinite ones.

    Solves ``M x = mu A x`` with ``A = K - sigma M`` (``sigma < 0``: positive definite when K and M are
    positive semi-definite with no common null vector); ``lambda = sigma + 1 / mu``. Directions with
    ``mu <= MASSLESS_RATIO max|mu|`` carry no mass (infinite eigenvalues) and are dropped. Returns
    ``(lam, vec, dropped)``, ``lam`` increasing, ``vec`` columns not yet M-normalised.
    Raises ``np.linalg.LinAlgError`` when ``A`` is not positive definite.
    """
    A = Kd - sigma * Md
    mu, V = sla.eigh((Md + Md.T) / 2, (A + A.T) / 2)
    keep = mu > MASSLESS_RATIO * np.abs(mu).max()
    lam = sigma + 1.0 / mu[keep]
    order = np.argsort(lam)
    return lam[order], V[:, keep][:, order], int(np.sum(~keep))


def rigid_indices(lam: np.ndarray, vec: np.ndarray, K, scale: float, rigid_tol: float,
                  n_rigid_fields: int | None = None) -> np.ndarray:
    """Which of the eigenpairs (``lam`` increasing) are rigid-body modes or mechanisms of the model.

    Candidates are ``|lam| <= rigid_tol * scale``; of those, the first ``n_rigid_fields`` (rigid motions
    K does not resist, :func:`stepnf.linalg.null_space.rigid_field_count`) and every other one whose
    eigenvector is a null vector of K (:func:`stepnf.linalg.null_space.null_mask`)."""
    small = np.flatnonzero(np.abs(lam) <= rigid_tol * scale)
    if not len(small):
        return small
    null = null_mask(K, vec[:, small])
    null[:min(int(n_rigid_fields or 0), len(small))] = True
    return small[null]


def dense_modes(K, M, scale: float, rigid_tol: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Every eigenpair of the dense pencil: ``eigh(K, M)``, or, when M is not (numerically) positive
    definite, the finite ones of ``(M, K - sigma M)`` (:func:`dense_pencil_modes`) and the number of
    massless directions dropped.

    The pencil's eigenvalues carry an absolute error ~``eps / |sigma|`` in ``mu``, i.e. a relative error
    ~``eps (lambda - sigma) / |sigma|`` when rigid modes (``mu = 1 / |sigma|``) lead the spectrum: with the
    first shift, ``-1e-10 lambda_scale`` (positive definite whatever the rigid modes), that is 1e-6 on a
    compact spectrum. When that solve finds candidate rigid modes (``|lambda| <= rigid_tol * scale``), it
    is done again at minus the lowest eigenvalue above them: every error back to ~eps times the spread."""
    Kd = K.toarray() if sp.issparse(K) else np.asarray(K)
    Md = M.toarray() if sp.issparse(M) else np.asarray(M)
    dm = np.abs(np.diag(Md))
    if dm.size and dm.min() > NEARLY_MASSLESS * dm.max():  # else eigh(K, M) loses the low modes silently
        try:
            lam, vec = sla.eigh(Kd, Md)
            if np.all(np.isfinite(lam)) and lam[-1] <= INFINITE_RATIO * scale:
                return lam, vec, 0
        except np.linalg.LinAlgError:
            pass  # M not positive definite: a semi-definite mass matrix
    # the shift's scale: the stiffness over the LARGEST mass (lambda_scale, max diag K / diag M, is the
    # frequency of the lightest dof: with masses of 1e-14 it would push every low eigenvalue into round-off)
    kscale = float(np.abs(np.diag(Kd)).max()) / float(dm.max()) if dm.size and dm.max() > 0 else scale
    try:
        lam, vec, dropped = dense_pencil_modes(Kd, Md, -1e-10 * kscale if kscale > 0 else -1.0)
        above = lam[np.abs(lam) > rigid_tol * scale]
        if len(above) < len(lam) and len(above) and above.min() > 0:
            lam, vec, dropped = dense_pencil_modes(Kd, Md, -float(above.min()))
        return lam, vec, dropped
    except np.linalg.LinAlgError as exc:
        raise NumericalError(f"dense eigen-solve failed: {exc} (M is not positive semi-definite, or a direction "
                             "has neither mass nor stiffness)") from exc


def moving_dofs(x: np.ndarray, X: np.ndarray | None, D: np.ndarray | None, names=("ux", "uy", "uz", "rx", "ry", "rz"),
                shown: int = 4) -> str:
    """The dofs a mechanism moves: how many carry more than 1% of its largest amplitude, and the largest
    few, named by direction and node position when the dof geometry is known (else by dof index)."""
    a = np.abs(np.asarray(x, dtype=float))
    big = np.flatnonzero(a > 1e-2 * a.max())
    top = big[np.argsort(-a[big], kind="stable")][:shown]
    parts = []
    for i in top:
        if X is not None and D is not None:
            p = ", ".join(f"{v:.4g}" for v in np.asarray(X)[i])
            parts.append(f"{names[int(D[i])]} at ({p})")
        else:
            parts.append(f"dof {int(i)}")
    more = f" and {len(big) - len(top)} more" if len(big) > len(top) else ""
    return f"{len(big)} dofs move: {'; '.join(parts)}{more}"


def rigid_body_fields(X: np.ndarray, D: np.ndarray) -> np.ndarray:
    """The six rigid motions (n, 6) sampled on dofs with coordinates X (n, 3) and direction codes D (n,).

    Translations along x, y, z, then rotations about axes through the
    centroid (``e_a x (x - c)`` on translational dofs, 1 on the rotational dof
    of axis a).
    """
    X = np.asarray(X, dtype=float)
    D = np.asarray(D, dtype=int)
    n = len(D)
    c = X[D < 3].mean(axis=0) if np.any(D < 3) else np.zeros(3)
    Y = X - c
    out = np.zeros((n, 6))
    for a in range(3):
        out[D == a, a] = 1.0
        e = np.zeros(3)
        e[a] = 1.0
        rot = np.cross(e, Y)  # (n, 3) displacement of each node
        t = D < 3
        out[t, 3 + a] = rot[np.nonzero(t)[0], D[t]]
        out[D == 3 + a, 3 + a] = 1.0
    return out


def rigid_span(candidates: np.ndarray) -> np.ndarray:
    """An orthonormal basis (n, k) of span(candidates), dependent fields left out (a flat or a line model)."""
    Q, rr = np.linalg.qr(candidates)
    keep = np.abs(np.diag(rr)) > 1e-12 * np.abs(np.diag(rr)).max()
    return Q[:, keep]


def rigid_modes_from(K, M, candidates: np.ndarray, scale: float, rigid_tolerance: float,
                     count: int | None = None) -> np.ndarray:
    """The M-orthonormal zero-energy motions within span(candidates): ``R`` (n, r), r = 0 when held.

    ``r`` is ``count`` or :func:`rigid_field_count` (null vectors of K, scale-aware); the motions are the ``r``
    lowest of the Rayleigh-Ritz problem on the span (those with ``|lambda| <= rigid_tolerance * scale``
    when that count agrees, as it does for a free body)."""
    Q = rigid_span(candidates)
    if Q.shape[1] == 0:
        return np.zeros((K.shape[0], 0))
    Kr = Q.T @ (K @ Q)
    Mr = Q.T @ (M @ Q)
    lam, v = sla.eigh((Kr + Kr.T) / 2, (Mr + Mr.T) / 2)
    zero = np.abs(lam) <= rigid_tolerance * scale
    r = rigid_field_count(K, Q) if count is None else int(count)
    if int(zero.sum()) != r:
        zero = np.zeros(len(lam), dtype=bool)
        zero[np.argsort(np.abs(lam), kind="stable")[:r]] = True
    return Q @ v[:, zero]  # M-orthonormal since v is Mr-orthonormal
