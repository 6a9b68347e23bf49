"""Calls from numba kernels to C functions given by address: DAQP's ``daqp_quadprog``
(``_daqp_kernels.py``) and numpy's BLAS ``ddot``/``dgemv`` (``_numpy_blas.py``).

A kernel could take the ctypes function objects as arguments (numba's first-class functions), but each
such argument costs ~4.5 us of dispatch per call (measured: 13.6 us for three, against 0.36 us for a
float), more than DAQP's solve of a small QP. An address is a plain integer argument, and the compiled
code stays cacheable (no address is baked into it). Pointers are passed as integers too (``a.ctypes.data``):
the same registers on the 64-bit ABIs numba targets. ``index`` is the width of the BLAS's integers: 64
bits for numpy's wheels (ILP64), 32 for a distribution's LP64 build.
"""
from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["quadprog_at", "ddot_at", "dgemv_at"]

_I64, _I32, _F64 = ir.IntType(64), ir.IntType(32), ir.DoubleType()


def _function(builder, address, result, arguments):
    """The C function at the integer ``address`` with the given LLVM ``result`` and ``arguments`` types."""
    return builder.inttoptr(address, ir.FunctionType(result, arguments).as_pointer())


@intrinsic
def quadprog_at(typingctx, address, result, problem, settings):
    """``daqp_quadprog(result, problem, settings)`` at ``address`` (struct pointers as integers)."""
    def codegen(context, builder, signature, args):
        builder.call(_function(builder, args[0], ir.VoidType(), [_I64] * 3), args[1:])
        return context.get_dummy_value()
    return types.none(types.int64, types.int64, types.int64, types.int64), codegen


@intrinsic
def ddot_at(typingctx, address, wide, n, x, y):
    """``cblas_ddot(n, x, 1, y, 1)`` at ``address``; ``wide`` (a literal bool): 64-bit BLAS integers."""
    if not isinstance(wide, types.BooleanLiteral):
        return None
    index = _I64 if wide.literal_value else _I32

    def codegen(context, builder, signature, args):
        _, _, n, x, y = args
        one = ir.Constant(index, 1)
        fn = _function(builder, args[0], _F64, [index, _I64, index, _I64, index])
        return builder.call(fn, [builder.trunc(n, index) if index is _I32 else n, x, one, y, one])
    return types.float64(types.int64, wide, types.int64, types.int64, types.int64), codegen


@intrinsic
def dgemv_at(typingctx, address, wide, m, n, a, x, y):
    """``cblas_dgemv(RowMajor, NoTrans, m, n, 1.0, a, n, x, 1, 0.0, y, 1)`` at ``address``: ``y = a x``
    for a C-contiguous (m, n) ``a``; ``wide`` as in :func:`ddot_at`."""
    if not isinstance(wide, types.BooleanLiteral):
        return None
    index = _I64 if wide.literal_value else _I32

    def codegen(context, builder, signature, args):
        _, _, m, n, a, x, y = args
        if index is _I32:
            m, n = builder.trunc(m, index), builder.trunc(n, index)
        one = ir.Constant(index, 1)
        fn = _function(builder, args[0], ir.VoidType(),
                       [_I32, _I32, index, index, _F64, _I64, index, _I64, index, _F64, _I64, index])
        builder.call(fn, [ir.Constant(_I32, 101), ir.Constant(_I32, 111), m, n, ir.Constant(_F64, 1.0), a, n, x,
                          one, ir.Constant(_F64, 0.0), y, one])
        return context.get_dummy_value()
    return types.none(types.int64, wide, types.int64, types.int64, types.int64, types.int64, types.int64), codegen
