"""Rigid-body modes found from the dof geometry: six for a free body, none when clamped."""
import numpy as np
import scipy.sparse as sp

from stepnf.linalg.modal_analysis import modal_analysis, rigid_body_fields, rigid_modes_from, lambda_scale


def free_body(n_nodes=40, seed=0):
    rng = np.random.default_rng(seed)
    X = np.repeat(rng.uniform(-1, 1, (n_nodes, 3)), 3, axis=0)
    D = np.tile([0, 1, 2], n_nodes)
    n = len(D)
    T = rigid_body_fields(X, D)
    A = rng.standard_normal((n, n))
    A = A @ A.T / n + np.eye(n)
    M = np.diag(rng.uniform(1, 2, n))
    P = np.eye(n) - T @ np.linalg.solve(T.T @ M @ T, T.T @ M)  # kills rigid motions
    K = P.T @ A @ P
    return sp.csr_matrix((K + K.T) / 2), sp.csr_matrix(M), X, D, A


def test_rigid_body_fields_are_rigid():
    X = np.repeat(np.random.default_rng(1).uniform(size=(5, 3)), 3, axis=0)
    D = np.tile([0, 1, 2], 5)
    T = rigid_body_fields(X, D)
    u = T[:, 4].reshape(5, 3)  # rotation about y: distances between nodes are preserved to first order
    d0 = X[::3][1] - X[::3][0]
    assert abs(d0 @ (u[1] - u[0])) < 1e-14


def test_free_and_clamped():
    K, M, X, D, A = free_body()
    cands = rigid_body_fields(X, D)
    R = rigid_modes_from(K, M, cands, lambda_scale(K, M), 1e-11)
    assert R.shape[1] == 6
    assert np.allclose(R.T @ (M @ R), np.eye(6), atol=1e-12)  # M-orthonormal
    assert np.abs(K @ R).max() < 1e-10 * abs(K).max()
    Kc = sp.csr_matrix(A)  # no zero-energy motion at all
    assert rigid_modes_from(Kc, M, cands, lambda_scale(Kc, M), 1e-11).shape[1] == 0
    # the sparse Lanczos path with candidates equals the dense solve (same 6 rigid modes set aside)
    b_dense = modal_analysis(K, M, 8)
    b_sparse = modal_analysis(K, M, 8, dense_limit=0, rigid_candidates=cands)
    assert b_sparse.rigid.shape[1] == 6 and b_dense.rigid.shape[1] == 6
    assert np.allclose(b_sparse.omega[:8], b_dense.omega[:8], rtol=1e-10)
