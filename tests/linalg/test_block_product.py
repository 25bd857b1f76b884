"""Block products ``A @ X`` by PETSc (stepnf.linalg.block_product) equal scipy's to round-off, with fallbacks."""
import numpy as np
import pytest
import scipy.sparse as sp

from stepnf.linalg.block_product import PETSC_MIN_ROWS, BlockProduct, block_product

petsc4py = pytest.importorskip("petsc4py")


def random_csr(n: int, seed: int = 0, density: float = 0.05) -> sp.csr_matrix:
    A = sp.random(n, n, density=density, random_state=seed, format="csr")
    A = (A + A.T + sp.eye(n)).tocsr()
    A.sum_duplicates()
    A.sort_indices()
    return A


def rounding_bound(A: sp.csr_matrix, X: np.ndarray) -> np.ndarray:
    """Entry-wise bound of the rounding of a row sum of r products: r eps (|A| |X|), r the row's entry count."""
    r = np.diff(A.indptr).max()
    return r * np.finfo(float).eps * (abs(A) @ np.abs(X))


@pytest.mark.parametrize("k", [1, 2, 3, 5, 8, 13])  # 5, 8, 13: several chunks of PETSc products
def test_block_product_equals_scipy(k):
    n = PETSC_MIN_ROWS  # the smallest matrix PETSc multiplies
    A = random_csr(n, density=0.005)
    X = np.random.default_rng(k).standard_normal((n, k))
    P = BlockProduct(A)
    Y = P @ X
    assert Y.shape == (n, k) and Y.flags.c_contiguous
    assert np.all(np.abs(Y - A @ X) <= rounding_bound(A, X))
    assert (P._petsc not in (None, False)) == (k >= 2)  # PETSc is made (and used) for blocks only
    y = P @ X[:, 0]
    assert y.shape == (n,) and np.array_equal(y, A @ X[:, 0])  # one vector: scipy's own product


def test_a_small_matrix_is_multiplied_by_scipy():
    """Below PETSC_MIN_ROWS rows scipy multiplies: no PETSc matrix (petsc4py, so MPI, is not started for it:
    tests/env/test_mpi_tmpdir.py checks a whole run), and the very numbers of scipy."""
    A = random_csr(PETSC_MIN_ROWS - 1, density=0.005)
    X = np.random.default_rng(1).standard_normal((A.shape[0], 8))
    P = BlockProduct(A)
    assert np.array_equal(P @ X, A @ X) and P._petsc is False


def test_block_product_falls_back_to_scipy():
    """Dense matrices, 64-bit indices and unsorted rows are multiplied by scipy, the same numbers."""
    A = random_csr(120)
    X = np.random.default_rng(3).standard_normal((120, 4))
    wide = A.copy()
    wide.indices = wide.indices.astype(np.int64)
    wide.indptr = wide.indptr.astype(np.int64)
    unsorted = A.copy()
    unsorted.indices[:2] = unsorted.indices[:2][::-1].copy()  # row 0 out of order (it has >= 2 entries),
    unsorted.data[:2] = unsorted.data[:2][::-1].copy()  # the same matrix
    unsorted.has_sorted_indices = False
    for B in (A.toarray(), wide, unsorted):
        P = BlockProduct(B)
        # scipy either way; the dense product sums the row in another order (its zeros add exactly)
        assert np.all(np.abs(P @ X - A @ X) <= 2 * rounding_bound(A, X))
        assert P._petsc is False
    assert block_product(P) is P
