"""Polynomial test systems built from a potential (fully symmetric G and H)."""
from __future__ import annotations

import itertools

import numpy as np
import scipy.linalg as sla


def full_symmetrize(T: np.ndarray) -> np.ndarray:
    perms = list(itertools.permutations(range(T.ndim)))
    return sum(np.transpose(T, p) for p in perms) / len(perms)


def random_system(n: int, seed: int = 0, *, rigid: int = 0, spread: float = 1.0):
    """(M, K, G, H) with SPD M, K of rank n - rigid, and G, H from a potential.

    With ``rigid`` > 0 the nonlinear terms are built in the elastic subspace
    only (as for a real free structure, forces are self-equilibrated).
    """
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    M = A @ A.T / n + np.eye(n)
    # K = M V diag(lam) V^T M with M-orthonormal V
    L = np.linalg.cholesky(M)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    V = np.linalg.solve(L.T, Q)  # V^T M V = I
    lam = np.sort(rng.uniform(1.0, 10.0 * spread, n))
    lam[:rigid] = 0.0
    Minv_VT = M @ V  # rows of V^T M
    K = Minv_VT @ np.diag(lam) @ Minv_VT.T
    K = (K + K.T) / 2
    G = full_symmetrize(rng.standard_normal((n, n, n)))
    H = full_symmetrize(rng.standard_normal((n, n, n, n)))
    H = H + 3 * full_symmetrize(np.einsum("ij,kl->ijkl", np.eye(n), np.eye(n)))  # keep the cubic stiffening
    if rigid:
        E = Minv_VT[:, rigid:]  # projector onto elastic coordinates: P = V_e (M V_e)^T
        P = V[:, rigid:] @ E.T  # u -> elastic part
        # optimize=True: contract one index at a time (the naive 8-fold loop is O(n^8))
        G = np.einsum("ai,bj,ck,abc->ijk", P, P, P, G, optimize=True)
        H = np.einsum("ai,bj,ck,dl,abcd->ijkl", P, P, P, P, H, optimize=True)
    return M, K, G, H


def modal_to_physical(omega, g, h, seed: int = 0, *, rigid: int = 0, return_transform: bool = False):
    """Physical (M, K, G, H) whose mass-normalised modes have the given modal tensors.

    ``omega`` (m,) elastic frequencies, ``g`` (m, m, m) and ``h`` (m, m, m, m)
    fully symmetric modal tensors (``g[s, i, j] = phi_s^T G(phi_i, phi_j)``).
    With ``x`` the modal coordinates and ``u = P x`` (``P`` random,
    well-conditioned), ``M = P^-T P^-1``, ``K = P^-T diag(0_rigid, omega^2) P^-1``
    and the tensors transform covariantly, so mode ``s`` of the physical
    system is ``P e_s`` (up to sign) and its modal tensors are ``g``, ``h``.
    ``rigid`` zero-frequency modes are put first; they do not enter G or H
    (self-equilibrated nonlinear forces). With ``return_transform`` the
    matrix ``P`` (its columns are the M-normalised modes, rigid ones first)
    is returned as a fifth item.
    """
    omega = np.asarray(omega, dtype=float)
    m = len(omega)
    n = m + rigid
    rng = np.random.default_rng(seed)
    Qo, _ = np.linalg.qr(rng.standard_normal((n, n)))
    P = Qo @ np.diag(rng.uniform(0.5, 2.0, n))  # condition number <= 4
    Q = np.linalg.inv(P)
    lam = np.concatenate([np.zeros(rigid), omega ** 2])
    M = Q.T @ Q
    K = Q.T @ np.diag(lam) @ Q
    gf = np.zeros((n, n, n))
    gf[rigid:, rigid:, rigid:] = g
    hf = np.zeros((n, n, n, n))
    hf[rigid:, rigid:, rigid:, rigid:] = h
    G = np.einsum("sa,sij,ib,jc->abc", Q, gf, Q, Q, optimize=True)
    H = np.einsum("sa,sijk,ib,jc,kd->abcd", Q, hf, Q, Q, Q, optimize=True)
    out = ((M + M.T) / 2, (K + K.T) / 2, G, H)
    return out + (P,) if return_transform else out


def solver_backends() -> list[str]:
    """The linear-solver back ends available here (MUMPS when petsc4py imports)."""
    out = ["dense", "superlu"]
    try:
        import petsc4py  # noqa: F401
        out.append("mumps")
    except Exception:  # pragma: no cover - petsc4py is a Debian package here
        pass
    return out


def use_solver(monkeypatch, get_solver) -> None:
    """Every solver name resolves through ``get_solver(name)`` (an in-test adapter class instead of an
    installed plugin): both where a scene's [model] keys are checked and where the pipeline builds it."""
    from stepnf.pipeline import model as pipeline
    from stepnf.plugin import registry

    monkeypatch.setattr(registry, "get_solver", get_solver)
    monkeypatch.setattr(pipeline, "get_solver", get_solver)


def stiff_two_dof(ratio: float, seed: int = 3):
    """Physical (M, K, G, H) of 2 dofs whose modes' stiffnesses differ by ``1.1025 ratio``: frequencies
    1 (the slow master) and ``1.05 sqrt(ratio)`` (the factor 1.05 keeps ``ratio = 1e2`` off the exact
    1:10 internal resonance), with the quadratic and cubic modal terms of :func:`two_dof`
    (self-coupling of the master 0.1 and 0.5, couplings 0.05, 0.2)."""
    g = np.zeros((2, 2, 2))
    h = np.zeros((2, 2, 2, 2))
    for T, entries in ((g, {(0, 0, 0): 0.1, (1, 0, 0): 0.05, (1, 1, 0): 0.05}),
                       (h, {(0, 0, 0, 0): 0.5, (1, 1, 0, 0): 0.2, (1, 1, 1, 1): 0.3})):
        for idx, val in entries.items():
            for perm in set(itertools.permutations(idx)):
                T[perm] = val
    return modal_to_physical(np.array([1.0, 1.05 * np.sqrt(ratio)]), g, h, seed=seed)


def batch_force(K, G, H):
    """``f(U)`` for fields U (m, n), one per row (the adapters' batch convention)."""
    n = K.shape[0]
    G2, H3 = G.reshape(n, n * n).T, H.reshape(n, n ** 3).T

    def f(U):
        U = np.atleast_2d(U)
        UU = (U[:, :, None] * U[:, None, :]).reshape(len(U), n * n)
        return U @ K.T + UU @ G2 + (UU[:, :, None] * U[:, None, :]).reshape(len(U), n ** 3) @ H3
    return f


def sym(shape, entries):
    """A fully symmetric tensor with the given entries (and their permutations)."""
    T = np.zeros(shape)
    for idx, v in entries.items():
        for perm in set(itertools.permutations(idx)):
            T[perm] = v
    return T


def modes(K, M):
    """Frequencies and mass-normalised mode shapes (columns) of ``(K, M)``, dense."""
    lam, V = sla.eigh(K, M)
    return np.sqrt(np.clip(lam, 0, None)), V / np.sqrt(np.einsum("ij,ik,kj->j", V, M, V))


def two_dof():
    """Modal frequencies 1 and 3.6 (no 1:2, 1:3 resonance), quadratic and cubic terms with coupling,
    mapped to a physical system with full M and K (:func:`modal_to_physical`)."""
    g = sym((2, 2, 2), {(0, 0, 0): 0.1, (1, 0, 0): 0.05, (1, 1, 0): 0.05})
    h = sym((2, 2, 2, 2), {(0, 0, 0, 0): 0.5, (1, 1, 0, 0): 0.2, (1, 1, 1, 1): 0.3})
    return modal_to_physical(np.array([1.0, 3.6]), g, h, seed=3)


def near_one_to_four():
    """(M, K, G, H) of 5 dofs, modal frequencies 1, 1.7, 2.3, 3.1 and 3.954: mode 4 near 4 x mode 0 (1:4 internal
    resonance, detuning 1.15%), mode 0 coupled to modes 1, 2 and 4 by quadratic terms (self-coupling 0.1, to mode 4
    0.1) and weak cubic ones (self-coupling 0.05), mapped to a physical system with full M and K
    (:func:`modal_to_physical`). Mode 0's single-mode DPIM (order 15) is valid to A = 1.28 only (1.96 with mode 4
    moved to 3.6: the 1:4 resonance limits it); its backbone frequency rises by 10% at A = 3."""
    g = sym((5, 5, 5), {(0, 0, 0): 0.1, (1, 0, 0): 0.05, (2, 0, 0): 0.05, (4, 0, 0): 0.1, (4, 4, 0): 0.05,
                        (1, 1, 0): 0.05, (4, 1, 0): 0.05})
    h = sym((5, 5, 5, 5), {(0, 0, 0, 0): 0.05, (4, 0, 0, 0): 0.02, (4, 4, 0, 0): 0.02, (1, 1, 0, 0): 0.02,
                           (2, 2, 0, 0): 0.01, (3, 3, 0, 0): 0.01, (4, 4, 4, 4): 0.03, (1, 1, 1, 1): 0.03})
    return modal_to_physical(np.array([1.0, 1.7, 2.3, 3.1, 3.954]), g, h, seed=7)
