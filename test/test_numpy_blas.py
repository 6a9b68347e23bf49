"""numpy's own BLAS functions found for the kernels (``methods/_numpy_blas.py``) against numpy's ``@``:
the same bits for the products the self-stress rule's fit makes (a row by a column, a matrix by a
vector), where a loop written out differs in the last bits (summation order)."""
import numpy as np
from numba import njit

from tensegrity_sim.methods._c_calls import ddot_at, dgemv_at
from tensegrity_sim.methods._numpy_blas import numpy_blas


@njit
def _products(ddot, dgemv, wide, column, other, matrix, vector):
    """``column . other`` and ``matrix @ vector`` by numpy's BLAS at ``ddot``, ``dgemv`` (``wide``: 64-bit
    integers)."""
    out = np.empty(matrix.shape[0])
    if wide:
        dgemv_at(dgemv, True, matrix, vector, out)
        return ddot_at(ddot, True, column, other), out
    dgemv_at(dgemv, False, matrix, vector, out)
    return ddot_at(ddot, False, column, other), out


def test_numpy_blas_is_numpy_matmul_bitwise():
    blas = numpy_blas()
    assert blas is not None   # numpy's wheels and distributions' numpy both resolve a CBLAS ddot
    rng = np.random.default_rng(3)
    naive_differs = 0
    for _ in range(300):
        k, m = int(rng.integers(1, 60)), int(rng.integers(2, 60))
        basis = np.asfortranarray(rng.normal(size=(k, 1)))    # the rule's basis: a (k, 1) column
        y = rng.normal(size=k) * 10.0 ** rng.integers(-3, 11)   # multipliers up to 1e10 N*s
        matrix, vector = rng.normal(size=(m, k)), rng.normal(size=k)
        dot, product = _products(*blas, np.ascontiguousarray(basis[:, 0]), y, matrix, vector)
        assert dot == (basis.T @ y)[0]
        np.testing.assert_array_equal(product, matrix @ vector)
        naive_differs += dot != sum(float(a) * float(b) for a, b in zip(basis[:, 0], y))
    assert naive_differs > 0   # the order of the sum matters, so the test can tell
