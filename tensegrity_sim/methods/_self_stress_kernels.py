"""Compiled kernel of the self-stress publishing rule (``self_stress.py``; ``SelfStress._impulses_reference``
is the numpy reference it must match): the binding rows, the matrix ``A_B^T`` and the load time's
self-stress refined by inverse iteration (two solves and QRs), the part that costs. The rest stays
numpy, for the reference's bits: an SVD, when one is needed (numba's is another LAPACK build, with
other last bits), and the share's removal and fit (``SelfStress._fit``): the solver's multipliers reach
2e10 N*s on a locked structure being reeled in, against published impulses of 1 N*s, so their
difference keeps ~4e-6 N*s of round-off, and a published impulse that is round-off around zero decides
a cable's slack flag (measured on the built-in tower); only numpy's own products (its BLAS's summation
order) give the same bits, which is why the inextensible method's one-call step
(``_inextensible_kernels.fit_one``) makes them with numpy's BLAS functions themselves (``_numpy_blas.py``). The kernel's basis is the reference's to its last bits on the icosahedron and
the rigid prism and to ~1e-14 on the tower (numba's matrix product and LAPACK build against numpy's);
``test_compiled.py`` holds the published impulses to 1e-12.

Rows are generic (``_qp_kernels.py``): ``nodes`` (k, 2) free-node indices (-1: fixed), ``directions`` (k, 3).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ._c_calls import pointers_at
from ._qp_kernels import dense_rows

__all__ = ["locked_space"]


@njit(cache=True)
def _column_norm_max(a_t, basis):
    """The largest Euclidean norm of a column of ``a_t @ basis``."""
    # a row-major copy for the product: the basis itself keeps its layout, which numpy's products of
    # the share's fit see (another layout, another BLAS path, other last bits)
    prod = a_t @ np.ascontiguousarray(basis)
    out = 0.0
    for j in range(prod.shape[1]):
        s = 0.0
        for i in range(prod.shape[0]):
            s += prod[i, j] * prod[i, j]
        out = max(out, np.sqrt(s))
    return out


@njit(cache=True)
def _refined_space(a_t, load_basis, load_largest, rank_tol, exact, getrf, getrs):
    """``SelfStress._space`` when the binding rows are the load time's members: the load basis if it is
    exact, else refined by two inverse iterations on ``A A^T`` and kept if below ``rank_tol``; else
    (an exactly singular ``A A^T``, or a refinement that is not below) None: the caller's SVD.

    ``A A^T`` is factorised once by LAPACK's ``dgetrf`` and both iterations solve with ``dgetrs``
    (scipy's, at the addresses ``getrf``, ``getrs``: ``_c_calls.scipy_lapack``), as the reference's
    ``lu_factor``/``lu_solve`` do: the bits of ``np.linalg.solve``'s ``dgesv`` at half its cost."""
    if _column_norm_max(a_t, load_basis) <= exact * load_largest:
        return load_basis
    lu = np.asfortranarray(a_t.T @ a_t)
    n = lu.shape[0]
    size = np.array([n], dtype=np.int32)
    columns = np.array([load_basis.shape[1]], dtype=np.int32)
    info = np.zeros(1, dtype=np.int32)
    pivots = np.empty(n, dtype=np.int32)
    pointers_at(getrf, (size, size, lu, size, pivots, info))
    if info[0] != 0:   # an exact zero pivot, as scipy's lu_factor warns of: the SVD
        return None
    no_transpose = np.array([78], dtype=np.uint8)   # "N"
    basis = load_basis
    for _ in range(2):
        solved = np.empty((basis.shape[1], n)).T   # column-major, as LAPACK writes (never the basis itself)
        solved[:, :] = basis
        pointers_at(getrs, (no_transpose, size, columns, lu, size, pivots, solved, size, info))
        basis, _ = np.linalg.qr(solved)
    if _column_norm_max(a_t, basis) < rank_tol * load_largest:
        return basis
    return None


@njit(cache=True)
def locked_space(nodes, directions, n_free, n_eq, cables, at_limit, y, load_basis, load_cables, load_largest,
                 refine, rank_tol, exact, getrf, getrs):
    """The binding rows of a QP answer and their self-stress basis: rows ``nodes``, ``directions`` (k
    rows, the first ``n_eq`` rigid struts, then the cables ``cables`` (k - n_eq,) int), multipliers ``y``
    (k,) N*s, ``at_limit`` (k - n_eq,) bool; the load time's basis (k_load, d), its cables
    ``load_cables`` (int) and largest singular value, ``getrf``/``getrs`` as in ``_refined_space``.
    Returns ``binding`` (k,) bool, the binding cables
    (k_b - n_eq,) int, ``A_B^T`` (3 n_free, k_b) and the refined basis (k_b, d), or None when the
    binding rows are not the load time's or the refinement fails: then the caller takes an SVD
    (``self_stress_space``: numba's SVD is another LAPACK build, with other last bits)."""
    k = y.shape[0]
    binding = np.empty(k, dtype=np.bool_)
    kb = 0
    for i in range(k):
        binding[i] = i < n_eq or at_limit[i - n_eq] or y[i] != 0.0
        kb += binding[i]
    b_nodes = np.empty((kb, 2), dtype=nodes.dtype)
    b_dirs = np.empty((kb, 3))
    members = np.empty(kb - n_eq, dtype=cables.dtype)
    r = 0
    for i in range(k):
        if binding[i]:
            b_nodes[r] = nodes[i]
            b_dirs[r] = directions[i]
            if r >= n_eq:
                members[r - n_eq] = cables[i - n_eq]
            r += 1
    a_t = np.ascontiguousarray(dense_rows(b_nodes, b_dirs, n_free, np.ones(3 * n_free)).T)
    same = refine and members.shape[0] == load_cables.shape[0]
    if same:
        for i in range(members.shape[0]):
            if members[i] != load_cables[i]:
                same = False
                break
    basis = _refined_space(a_t, load_basis, load_largest, rank_tol, exact, getrf, getrs) if same else None
    return binding, members, a_t, basis
