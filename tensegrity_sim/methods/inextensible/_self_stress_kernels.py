"""Compiled kernel of the self-stress publishing rule (``self_stress.py``; ``SelfStress._impulses_reference``
is the numpy reference it must match): the binding rows, the matrix ``A_B^T`` and the load time's
self-stress refined by inverse iteration (two solves with a Cholesky factor of ``A_B A_B^T``), the part
that costs. The rest stays numpy, for the reference's bits: an SVD, when one is needed (numba's is
another LAPACK build, with other last bits), and the share's removal and fit (``SelfStress._fit``): the
solver's multipliers reach 2e10 N*s on a locked structure being reeled in, against published impulses
of 1 N*s, so their difference keeps ~4e-6 N*s of round-off, and a published impulse that is round-off
around zero decides a cable's slack flag (measured on the built-in tower); only numpy's own products
(its BLAS's summation order) give the same bits, which is why the inextensible method's one-call step
(``_inextensible_kernels.fit_one``) makes them with numpy's BLAS functions themselves
(``_numpy_blas.py``). The kernel's basis is the reference's to round-off (2.2e-16 of 0.32 on the thrown
icosahedron); ``test_compiled.py`` holds the published impulses to 1e-12.

Rows are generic (``_qp_kernels.py``): ``nodes`` (k, 2) free-node indices (-1: fixed), ``directions`` (k, 3).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..qp._qp_kernels import add_row, cho_solve, cholesky, delassus

__all__ = ["locked_space"]


@njit(cache=True)
def _column_norm_max(nodes, directions, n_free, basis):
    """The largest Euclidean norm of a column of ``A^T basis`` (rows ``nodes``, ``directions``; ``basis``
    (k, d)): the node force of each self-stress, scattered row by row (``A`` is never formed)."""
    out = 0.0
    force = np.empty((n_free, 3))
    for c in range(basis.shape[1]):
        force[:, :] = 0.0
        for r in range(basis.shape[0]):
            add_row(force, nodes, directions, r, basis[r, c])
        s = 0.0
        for i in range(n_free):
            for j in range(3):
                s += force[i, j] * force[i, j]
        out = max(out, np.sqrt(s))
    return out


@njit(cache=True)
def _refined_space(nodes, directions, n_free, load_basis, load_largest, rank_tol, exact, weight, factor):
    """``SelfStress._space`` when the binding rows (``nodes``, ``directions``) are the load time's
    members: the load basis if it is exact, else refined by two inverse iterations on ``A A^T`` and kept
    if below ``rank_tol``; else (an ``A A^T`` that is not positive definite in floating point, as a
    tower's at its load geometry with twelve self-stresses, or a refinement that is not below) None:
    the caller's SVD.

    The iterations solve with a Cholesky factor of ``A W A^T`` (``weight`` (n_free, 3): the inverse
    masses when they are all equal, a multiple of ``A A^T`` with the same eigenvectors, else ones),
    built row pair by row pair where two members share a node (``_qp_kernels.delassus``), or given as
    ``factor`` (g, g): the QP's own factor of the same rows (``locked_space``), when it has one. Each
    iteration's columns are orthonormalised (a single column: divided by its norm, signed as LAPACK's QR
    signs it). The reference (scipy's ``cho_factor``, ``cho_solve`` and numpy's QR of the dense product
    ``A A^T``) gets the same basis to round-off (~1e-16 relative on the thrown icosahedron, whose
    self-stress singular value is ~1e-5 of the next), at about half the cost of the dense product and
    LAPACK's LU and QR that it replaces (the thrown icosahedron's 30 rows: 10.1 -> 5.7 us a call from
    Python, on the loaded 2-core machine), and at a third of that with the QP's factor."""
    if _column_norm_max(nodes, directions, n_free, load_basis) <= exact * load_largest:
        return load_basis
    k, d = load_basis.shape
    if factor.shape[0] != k:
        factor = delassus(nodes, directions, np.arange(k), weight)
        if not cholesky(factor, 0.0):
            return None
    basis = load_basis
    column = np.empty(k)   # one column's solve, made once
    for _ in range(2):
        solved = np.empty((k, d))
        for c in range(d):
            column[:] = basis[:, c]
            cho_solve(factor, column)
            solved[:, c] = column
        if d == 1:
            norm = np.sqrt(np.sum(solved[:, 0] * solved[:, 0]))
            basis = solved / -np.copysign(norm, solved[0, 0])
        else:
            basis, _ = np.linalg.qr(solved)
    if _column_norm_max(nodes, directions, n_free, basis) < rank_tol * load_largest:
        return basis
    return None


@njit(cache=True)
def locked_space(nodes, directions, n_free, n_eq, cables, at_limit, y, load_basis, load_cables, load_largest,
                 refine, rank_tol, exact, weight, shared, qp_rows, qp_factor):
    """The binding rows of a QP answer and their self-stress basis: rows ``nodes``, ``directions`` (k
    rows, the first ``n_eq`` rigid struts, then the cables ``cables`` (k - n_eq,) int), multipliers ``y``
    (k,) N*s, ``at_limit`` (k - n_eq,) bool; the load time's basis (k_load, d), its cables
    ``load_cables`` (int) and largest singular value; ``weight`` as in ``_refined_space``, ``shared``
    (the inverse masses are all equal, ``weight`` is them) and the QP's working rows ``qp_rows`` (g,)
    int and Cholesky factor ``qp_factor`` (g, g) of its Delassus matrix (``_qp_kernels.cholesky``;
    (0, 0): none), which the refinement takes when the binding rows are those rows.
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
    a_t = np.zeros((3 * n_free, kb))   # A_B^T built as such (not A_B transposed and copied): -n at end a, +n at b
    for r in range(kb):
        for e in range(2):
            node = b_nodes[r, e]
            if node >= 0:
                for j in range(3):
                    a_t[3 * node + j, r] = (2.0 * e - 1.0) * b_dirs[r, j]
    same = refine and members.shape[0] == load_cables.shape[0]
    if same:
        for i in range(members.shape[0]):
            if members[i] != load_cables[i]:
                same = False
                break
    basis = None
    if same:
        # the QP's factor is that of A W A^T for the same rows when they are the binding rows
        reuse = shared and qp_rows.shape[0] == kb
        r = 0
        for i in range(k):
            if reuse and binding[i]:
                reuse = qp_rows[r] == i
                r += 1
        basis = _refined_space(b_nodes, b_dirs, n_free, load_basis, load_largest, rank_tol, exact, weight,
                               qp_factor if reuse else np.zeros((0, 0)))
    return binding, members, a_t, basis
