"""Compiled kernel of the sparse backend's dual active-set method (``qp.py``: ``SparseSolver``; its numpy
reference is ``SparseSolver._dual_steps_reference`` with ``_WorkingSet``, which tests require this to
follow): the steps between two factorisations of the working set's base, each a few sparse products,
two solves with the base's SuperLU factor (its ``L``, ``U`` and permutations, applied here) and the
Schur complement of the rows changed since. The factorisation itself stays SuperLU's, in Python.

Matrices are CSR arrays (``indptr``, ``indices``, ``data``): ``A`` (k, 3 n_free) the rows, ``W = A M^-1 A^T``
(k, k); the products are summed in the order of scipy's own (``A v`` row by row, ``A^T x`` scattered row
by row), the dense dot products and the Schur complement's solve are numba's (BLAS and LAPACK through
scipy: other last bits than numpy's, so a near tie between two rows may be broken the other way; the
final working set is solved again from scratch and verified either way).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ._superlu_kernels import lu_solve

__all__ = ["dual_steps", "CONVERGED", "REBASE", "FAILED"]

CONVERGED, REBASE, FAILED = 0, 1, 2


@njit(cache=True)
def _row(ptr, idx, dat, i, n):
    """Row ``i`` of a CSR matrix as a dense (n,) vector (its column indices unique within a row)."""
    out = np.zeros(n)
    for q in range(ptr[i], ptr[i + 1]):
        out[idx[q]] = dat[q]
    return out


@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(cache=True)
def dual_steps(a_ptr, a_idx, a_dat, w_ptr, w_idx, w_dat, inv_mass, r, n_eq, tol, dependent, border, v, y, active,
               p, budget, base, singular, l_ptr, l_idx, l_dat, u_ptr, u_idx, u_dat, u_diag, perm_r, perm_c):
    """Steps of ``SparseSolver._dual_active_set`` from working set ``active`` (k,) bool, whose rows are the
    base ``base`` (sorted; SuperLU's factor of its ``W_BB`` in the arrays after ``singular``, which is
    True if that factorisation failed; ``_superlu_kernels.factor_arrays``), velocities ``v`` (3 n_free,)
    and multipliers ``y`` (k,) (both updated in place, as ``active`` is), the row ``p`` joining the set
    (-1: none yet), at most ``budget`` changes of the set. Returns ``(status, p, changes)``:
    ``CONVERGED`` (no row violated beyond ``tol``), ``REBASE`` (``border`` changes since the base: the
    caller factorises the set again and calls back with ``p``) or ``FAILED`` (a singular base, a
    dependent row with nothing to drop, or no changes left)."""
    k = r.shape[0]
    n3 = v.shape[0]
    nb = base.shape[0]
    where = np.full(k, -1, dtype=np.int64)
    for i in range(nb):
        where[base[i]] = i
    vmat = np.zeros((border, nb))     # V^T, (W_BB^-1 V)^T and the Schur complement, by item (_WorkingSet)
    ymat = np.zeros((border, nb))
    cmat = np.zeros((border, border))
    items = np.zeros(border, dtype=np.int64)
    added = np.zeros(border, dtype=np.bool_)
    m = 0
    a_p = np.zeros(n3)
    m_p = np.zeros(n3)
    w_p = np.zeros(k)
    if p >= 0:
        a_p = _row(a_ptr, a_idx, a_dat, p, n3)
        m_p = inv_mass * a_p
        w_p = _row(w_ptr, w_idx, w_dat, p, k)
    changes = 0
    while changes < budget:
        if p < 0:
            best = -np.inf
            p = 0
            for i in range(k):
                if active[i]:
                    continue
                s = 0.0
                for q in range(a_ptr[i], a_ptr[i + 1]):
                    s += a_dat[q] * v[a_idx[q]]
                if s - r[i] > best:
                    best = s - r[i]
                    p = i
            if best <= tol:
                return CONVERGED, -1, changes
            a_p = _row(a_ptr, a_idx, a_dat, p, n3)
            m_p = inv_mass * a_p
            w_p = _row(w_ptr, w_idx, w_dat, p, k)
        if singular:
            return FAILED, p, changes
        # r_vec: W_AA r_A = W_Ap (zero outside the set), by the base's factor and the Schur complement
        r_vec = np.zeros(k)
        b_base = np.empty(nb)
        whole = True   # b_base is W_Bp itself (no base row out of the set where W_ip != 0): p's own column
        for i in range(nb):
            b_base[i] = w_p[base[i]] if active[base[i]] else 0.0
            whole = whole and (active[base[i]] or w_p[base[i]] == 0.0)
        x_b = lu_solve(b_base, l_ptr, l_idx, l_dat, u_ptr, u_idx, u_dat, u_diag, perm_r, perm_c) if nb else b_base
        solved_p = x_b.copy()   # W_BB^-1 b_base, which p's column needs when it joins (if whole)
        if m:
            rhs = np.empty(m)
            for c in range(m):
                s = (w_p[items[c]] if active[items[c]] else 0.0) if added[c] else 0.0
                for i in range(nb):
                    s -= vmat[c, i] * x_b[i]
                rhs[c] = s
            z = np.linalg.solve(cmat[:m, :m], rhs)
            for c in range(m):
                for i in range(nb):
                    x_b[i] -= ymat[c, i] * z[c]
            for i in range(nb):
                r_vec[base[i]] = x_b[i]
            for c in range(m):
                r_vec[items[c]] = z[c] if added[c] else 0.0
        else:
            for i in range(nb):
                r_vec[base[i]] = x_b[i]
        pivot = w_p[p] - _dot(w_p, r_vec)     # W_pp - W_pA W_AA^-1 W_Ap: 0 for a dependent row
        full = (_dot(a_p, v) - r[p]) / pivot if pivot > dependent * w_p[p] else np.inf
        j, ratio = 0, np.inf
        for i in range(n_eq, k):
            if active[i] and r_vec[i] > 0.0:
                q = y[i] / r_vec[i]
                if q < ratio:
                    j, ratio = i, q
        step = ratio if ratio < full else full
        if not np.isfinite(step):
            return FAILED, p, changes
        if np.isfinite(full):
            back = np.zeros(n3)   # A^T r_vec, scattered row by row
            for i in range(k):
                if r_vec[i] != 0.0:
                    for q in range(a_ptr[i], a_ptr[i + 1]):
                        back[a_idx[q]] += a_dat[q] * r_vec[i]
            for i in range(n3):
                v[i] = v[i] + step * (inv_mass[i] * back[i] - m_p[i])
        for i in range(k):
            y[i] -= step * r_vec[i]
        y[p] += step
        if full <= ratio:
            row, joined = p, True
            active[p] = True
            p = -1
        else:
            row, joined = j, False
            active[j] = False
            y[j] = 0.0
        changes += 1
        undone = -1
        for c in range(m):
            if items[c] == row:
                undone = c
                break
        if undone >= 0:   # a change undone: its item leaves the complement
            for c in range(undone, m - 1):
                items[c], added[c] = items[c + 1], added[c + 1]
                vmat[c] = vmat[c + 1]
                ymat[c] = ymat[c + 1]
            for c in range(undone, m - 1):
                for e in range(m):
                    cmat[c, e] = cmat[c + 1, e]
            for e in range(undone, m - 1):
                for c in range(m - 1):
                    cmat[c, e] = cmat[c, e + 1]
            m -= 1
            continue
        if m >= border:
            return REBASE, p, changes
        col = np.zeros(nb)
        c_new = np.zeros(m)
        w_col = np.zeros(k)
        if joined:
            w_col = _row(w_ptr, w_idx, w_dat, row, k)
            for i in range(nb):
                col[i] = w_col[base[i]]
            for c in range(m):
                c_new[c] = w_col[items[c]] if added[c] else 0.0
        else:
            col[where[row]] = 1.0
        if joined and whole:   # the same solve as r_vec's, of the same vector
            solved = solved_p
        elif nb:
            solved = lu_solve(col, l_ptr, l_idx, l_dat, u_ptr, u_idx, u_dat, u_diag, perm_r, perm_c)
        else:
            solved = col
        for c in range(m):
            s = c_new[c]
            for i in range(nb):
                s -= vmat[c, i] * solved[i]
            cmat[c, m] = s
            cmat[m, c] = s
        vmat[m] = col
        ymat[m] = solved
        cmat[m, m] = (w_col[row] if joined else 0.0) - _dot(col, solved)
        items[m], added[m] = row, joined
        m += 1
    return FAILED, p, changes
