"""Compiled solves with a SuperLU factor (``scipy.sparse.linalg.splu``): its ``L``, ``U`` and
permutations applied in numba, on one right-hand side (the sparse backend's dual active-set method,
``_dual_kernels.py``) or on a block of them (the self-stress rule's block inverse iteration,
``self_stress.sparse_self_stress_space``), where SuperLU's own solve took 26 ms for 300 columns of a
moving 100-stage tower's ``A_B A_B^T + delta I`` (1937 rows, 80,000 entries in ``L`` and ``U``) and
this one 6 ms: its inner loops run along a row of the block, contiguous in memory. The factorisation
stays SuperLU's (:func:`symmetric_lu` for the symmetric matrices of the QP backend and the rule); the solves are the textbook forward and backward substitutions, column by column of
the factors (so the last bits are not SuperLU's: its supernodes sum in another order).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["factor_arrays", "lu_solve", "symmetric_lu"]


def symmetric_lu(m):
    """SuperLU's factor of the symmetric matrix ``m`` (scipy sparse) as ``L D L^T`` (its ``U = D L^T``): a
    symmetric ordering (minimum degree on ``M^T + M``) and no pivoting; None if it meets an exactly zero
    pivot."""
    from scipy.sparse.linalg import splu
    try:
        return splu(m.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError:
        return None


def factor_arrays(lu) -> tuple:
    """What :func:`lu_solve` takes after the right-hand sides, from SuperLU's factor ``lu``: the strictly
    lower part of ``L`` and the strictly upper part of ``U`` as CSC arrays (int64 indices, each column's
    entries in SuperLU's order), ``U``'s diagonal, ``perm_r`` and ``perm_c``."""
    return (*_strict(lu.L, lower=True), *_strict(lu.U, lower=False), lu.U.diagonal(),
            lu.perm_r.astype(np.int64), lu.perm_c.astype(np.int64))


def _strict(m, lower: bool) -> tuple:
    """The CSC arrays of ``m``'s entries below (``lower``) or above its diagonal."""
    n = m.shape[1]
    columns = np.repeat(np.arange(n), np.diff(m.indptr))
    keep = m.indices > columns if lower else m.indices < columns
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(columns[keep], minlength=n), out=ptr[1:])
    return ptr, m.indices[keep].astype(np.int64), m.data[keep]


@njit(cache=True)
def lu_solve(b, l_ptr, l_idx, l_dat, u_ptr, u_idx, u_dat, u_diag, perm_r, perm_c):
    """``x`` with ``B x = b`` for SuperLU's ``Pr B Pc = L U`` (:func:`factor_arrays`: ``L`` unit lower and
    ``U`` upper, their off-diagonal parts CSC, ``u_diag`` ``U``'s diagonal): ``b`` (n,) or a block (n, m),
    numba compiling each on its own. A row of the intermediate result that is zero is skipped (a sparse
    right-hand side costs what its fill does)."""
    n = b.shape[0]
    w = np.empty_like(b)
    for i in range(n):
        _copy(w, perm_r[i], b, i)
    for j in range(n):
        if _zero(w, j):
            continue
        for q in range(l_ptr[j], l_ptr[j + 1]):
            _subtract(w, l_idx[q], l_dat[q], j)
    for j in range(n - 1, -1, -1):
        _divide(w, j, u_diag[j])
        if _zero(w, j):
            continue
        for q in range(u_ptr[j], u_ptr[j + 1]):
            _subtract(w, u_idx[q], u_dat[q], j)
    x = np.empty_like(b)
    for i in range(n):
        _copy(x, i, w, perm_c[i])
    return x


# Row operations of lu_solve on a vector (a row is one number) or a block (numba prunes the other branch)

@njit(cache=True)
def _copy(dst, i, src, j):
    if dst.ndim == 1:
        dst[i] = src[j]
    else:
        for c in range(dst.shape[1]):
            dst[i, c] = src[j, c]


@njit(cache=True)
def _zero(w, j):
    if w.ndim == 1:
        return w[j] == 0.0
    for c in range(w.shape[1]):
        if w[j, c] != 0.0:
            return False
    return True


@njit(cache=True)
def _subtract(w, i, factor, j):
    if w.ndim == 1:
        w[i] -= factor * w[j]
    else:
        for c in range(w.shape[1]):
            w[i, c] -= factor * w[j, c]


@njit(cache=True)
def _divide(w, j, d):
    if w.ndim == 1:
        w[j] /= d
    else:
        for c in range(w.shape[1]):
            w[j, c] /= d
