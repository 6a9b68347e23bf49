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

_CANDIDATES = (("scipy_cblas_{}64_", ctypes.c_int64), ("cblas_{}64_", ctypes.c_int64),
               ("scipy_cblas_{}", ctypes.c_int), ("cblas_{}", ctypes.c_int))


def numpy_blas():
    """``(ddot, dgemv)`` of numpy's BLAS as ctypes functions taking pointers as integers (CBLAS argument
    order; ``dgemv``'s layout and transpose as the CBLAS enums), or None when numpy's module does not
    resolve a CBLAS ``ddot`` (then the kernels' callers keep numpy's products)."""
    try:
        from numpy._core import _multiarray_umath as module
    except ImportError:   # numpy < 2
        from numpy.core import _multiarray_umath as module
    library = ctypes.CDLL(module.__file__)
    pointer, real = ctypes.c_size_t, ctypes.c_double
    for name, size in _CANDIDATES:
        try:
            ddot, dgemv = getattr(library, name.format("ddot")), getattr(library, name.format("dgemv"))
        except AttributeError:
            continue
        ddot_type = ctypes.CFUNCTYPE(real, size, pointer, size, pointer, size)
        dgemv_type = ctypes.CFUNCTYPE(None, ctypes.c_int, ctypes.c_int, size, size, real, pointer, size, pointer,
                                      size, real, pointer, size)
        return (ddot_type(ctypes.cast(ddot, ctypes.c_void_p).value),
                dgemv_type(ctypes.cast(dgemv, ctypes.c_void_p).value))
    return None
