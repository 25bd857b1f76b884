"""Factorization.release frees the factors now (MUMPS through petsc4py keeps them until destroyed)."""
import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.linalg import factorize


@pytest.mark.parametrize("backend", ["mumps", "superlu", "dense"])
def test_solve_then_release(backend):
    if backend == "mumps":
        pytest.importorskip("petsc4py")
    n = 50
    A = sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(n, n)).tocsr()
    b = np.arange(1.0, n + 1)
    fac = factorize(A, backend=backend, label="A")
    x = fac.solve(b)
    # a tridiagonal, diagonally dominant matrix (condition < 10): residual at round-off, 1e-12 relative
    assert np.linalg.norm(A @ x - b) <= 1e-12 * np.linalg.norm(b)
    fac.release()
    fac.release()  # idempotent
    with pytest.raises(RuntimeError, match="factorisation of A was released"):
        fac.solve(b)
