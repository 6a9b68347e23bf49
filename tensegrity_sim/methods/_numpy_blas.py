"""numpy's own BLAS functions ``cblas_ddot`` and ``cblas_dgemv``, for kernels that must reproduce numpy's
products to the last bit.

numpy's ``@`` of a row by a column is its BLAS's ``ddot`` and of a matrix by a vector its ``dgemv``
(measured: equal to the bit on thousands of random shapes), and those sum in the order of the BLAS
kernel the library picked for this CPU, which no loop written out reproduces. The self-stress rule's fit
(``self_stress.SelfStress._fit``) is such a product of multipliers up to 2e10 N*s, whose round-off decides
slack flags (``_self_stress_kernels.py``), so the compiled fit calls the very functions numpy calls: the
library numpy's extension module is linked to (its wheels' ``scipy_openblas64_``/``openblas64_``, or a
distribution's ``libcblas``), found through that module's own symbol lookup.
"""
from __future__ import annotations

import ctypes

__all__ = ["numpy_blas"]

# the symbol names of numpy's BLAS builds (numpy 2 wheels, numpy 1 wheels, LP64 builds) and whether their
# integers are 64-bit
_CANDIDATES = (("scipy_cblas_{}64_", True), ("cblas_{}64_", True), ("scipy_cblas_{}", False), ("cblas_{}", False))


def numpy_blas():
    """``(ddot, dgemv, wide)``: the addresses of numpy's BLAS ``cblas_ddot`` and ``cblas_dgemv`` (what
    ``_c_calls.ddot_at``/``dgemv_at`` call) and whether its integers are 64-bit; None when numpy's
    module does not resolve a CBLAS ``ddot`` (then the kernels' callers keep numpy's products)."""
    try:
        from numpy._core import _multiarray_umath as module
    except ImportError:   # numpy < 2
        from numpy.core import _multiarray_umath as module
    library = ctypes.CDLL(module.__file__)
    for name, wide in _CANDIDATES:
        try:
            ddot, dgemv = getattr(library, name.format("ddot")), getattr(library, name.format("dgemv"))
        except AttributeError:
            continue
        return ctypes.cast(ddot, ctypes.c_void_p).value, ctypes.cast(dgemv, ctypes.c_void_p).value, wide
    return None
