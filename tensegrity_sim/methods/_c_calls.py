"""Calls from numba kernels to C functions given by address: DAQP's ``daqp_quadprog``
(``_daqp_kernels.py``) and numpy's BLAS ``ddot``/``dgemv`` (``_numpy_blas.py``).

A kernel could take the ctypes function objects as arguments (numba's first-class functions), but each
such argument costs ~4.5 us of dispatch per call (measured: 13.6 us for three, against 0.36 us for a
float), more than DAQP's solve of a small QP. An address is a plain integer argument, and the compiled
code stays cacheable (no address is baked into it). Arrays are passed as arrays and their data pointers
taken in the call itself, so that numba keeps them alive until the function returns (a pointer taken
earlier, ``a.ctypes.data``, lets numba free an array that is not used afterwards before the call). The
pointers and 64-bit integers travel in the same registers on the 64-bit ABIs numba targets. ``wide`` is
the width of the BLAS's integers: 64 bits for numpy's wheels (ILP64), 32 for a distribution's LP64 build.
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


def _pointer(context, builder, kind, value):
    """An array's data pointer as a 64-bit integer."""
    return builder.ptrtoint(context.make_array(kind)(context, builder, value).data, _I64)


def _arrays(*kinds) -> bool:
    return all(isinstance(kind, types.Array) for kind in kinds)


@intrinsic
def quadprog_at(typingctx, address, result, problem, settings):
    """``daqp_quadprog(result, problem, settings)`` at ``address``, the structs given as arrays."""
    if not _arrays(result, problem, settings):
        return None

    def codegen(context, builder, signature, args):
        pointers = [_pointer(context, builder, kind, value) for kind, value in zip(signature.args[1:], args[1:])]
        builder.call(_function(builder, args[0], ir.VoidType(), [_I64] * 3), pointers)
        return context.get_dummy_value()
    return types.none(types.int64, result, problem, settings), codegen


def _index(wide):
    """The LLVM type of the BLAS integers for the literal bool ``wide`` (None if it is not a literal)."""
    if not isinstance(wide, types.BooleanLiteral):
        return None
    return _I64 if wide.literal_value else _I32


@intrinsic
def ddot_at(typingctx, address, wide, x, y):
    """``cblas_ddot(len(x), x, 1, y, 1)`` at ``address`` for contiguous vectors; ``wide`` (a literal
    bool): 64-bit BLAS integers."""
    index = _index(wide)
    if index is None or not _arrays(x, y):
        return None

    def codegen(context, builder, signature, args):
        n = context.make_array(x)(context, builder, args[2]).nitems
        n = builder.trunc(n, index) if index is _I32 else n
        one = ir.Constant(index, 1)
        fn = _function(builder, args[0], _F64, [index, _I64, index, _I64, index])
        return builder.call(fn, [n, _pointer(context, builder, x, args[2]), one, _pointer(context, builder, y, args[3]),
                                 one])
    return types.float64(types.int64, wide, x, y), codegen


def _shape(context, builder, kind, value):
    """The two extents of a 2-d array, as 64-bit integers."""
    shape = context.make_array(kind)(context, builder, value).shape
    return builder.extract_value(shape, 0), builder.extract_value(shape, 1)


@intrinsic
def dgemv_at(typingctx, address, wide, a, x, y):
    """``cblas_dgemv(RowMajor, NoTrans, m, n, 1.0, a, n, x, 1, 0.0, y, 1)`` at ``address``: ``y = a x``
    for a C-contiguous (m, n) ``a``; ``wide`` as in :func:`ddot_at`."""
    index = _index(wide)
    if index is None or not _arrays(a, x, y):
        return None

    def codegen(context, builder, signature, args):
        m, n = _shape(context, builder, a, args[2])
        if index is _I32:
            m, n = builder.trunc(m, index), builder.trunc(n, index)
        one = ir.Constant(index, 1)
        fn = _function(builder, args[0], ir.VoidType(),
                       [_I32, _I32, index, index, _F64, _I64, index, _I64, index, _F64, _I64, index])
        builder.call(fn, [ir.Constant(_I32, 101), ir.Constant(_I32, 111), m, n, ir.Constant(_F64, 1.0),
                          _pointer(context, builder, a, args[2]), n, _pointer(context, builder, x, args[3]), one,
                          ir.Constant(_F64, 0.0), _pointer(context, builder, y, args[4]), one])
        return context.get_dummy_value()
    return types.none(types.int64, wide, a, x, y), codegen
