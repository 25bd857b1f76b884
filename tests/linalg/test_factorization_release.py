"""Factorization.release frees the factors now (MUMPS through petsc4py keeps them until destroyed)."""
import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.linalg.factorization import factorize


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


def test_adapter_solves_get_columns_one_by_one_unless_they_take_blocks():
    """:func:`stepnf.linalg.factorization.apply_columns`: an adapter's solve sees (n,) right-hand sides, or the whole (n, k)
    block in one call when it declares ``takes_columns`` (a distributed MUMPS block solve)."""
    from stepnf.linalg.factorization import apply_columns

    seen = []

    def one(b):
        seen.append(b.shape)
        return 2.0 * b

    class Block:
        takes_columns = True

        def __call__(self, b):
            seen.append(b.shape)
            return 2.0 * b

    B = np.arange(12.0).reshape(4, 3)
    assert np.array_equal(apply_columns(one, B), 2.0 * B) and seen == [(4,)] * 3
    seen.clear()
    assert np.array_equal(apply_columns(Block(), B), 2.0 * B) and seen == [(4, 3)]
    seen.clear()
    assert np.array_equal(apply_columns(Block(), B[:, 0]), 2.0 * B[:, 0]) and seen == [(4,)]
