"""Compiled kernels of the QP path (``qp.py``): the constraint matrix, the rows' rates and the answer
check, without a Python-level pass per row. ``qp.py`` keeps the numpy reference of each (``Rows.dense``,
``Rows.rates``, ``QPSolver._residuals_reference``), which tests require these to match.

Rows are generic two-node constraint rows (a member between two free nodes, or a free node and a fixed
one): ``nodes`` (k, 2) int, the free-node index of each end, -1 for a fixed one; ``directions`` (k, 3)
the unit vectors ``n_i`` from end a to end b, so that row ``i`` of ``A`` is ``-n_i`` at end a and
``+n_i`` at end b.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["dense_rows", "row_rates", "answer_residuals", "dot3"]


@njit(cache=True)
def dot3(a0, a1, a2, b0, b1, b2):
    """``a . b`` of two 3-vectors summed in the order numpy's ``einsum("ij,ij->i")`` uses on contiguous
    rows (measured): the compiled rows are then bitwise those of the reference, which matters on a
    locked structure, where a last-bit change of a row moves DAQP's answer by up to 1e-10."""
    return (a0 * b0 + a2 * b2) + a1 * b1


@njit(cache=True)
def dense_rows(nodes, directions, n_free, column_divisor):
    """The (k, 3 n_free) matrix ``A``, each column divided by ``column_divisor`` (3 n_free,)."""
    k = nodes.shape[0]
    a = np.zeros((k, 3 * n_free))
    for i in range(k):
        na = nodes[i, 0]
        nb = nodes[i, 1]
        for j in range(3):
            if na >= 0:
                a[i, 3 * na + j] = -directions[i, j] / column_divisor[3 * na + j]
            if nb >= 0:
                a[i, 3 * nb + j] = directions[i, j] / column_divisor[3 * nb + j]
    return a


@njit(cache=True)
def row_rates(v, nodes, directions):
    """``A v`` (k,) m/s for free-node velocities ``v`` (n_free, 3)."""
    k = nodes.shape[0]
    out = np.empty(k)
    u = np.zeros(3)
    for i in range(k):
        for j in range(3):
            vb = v[nodes[i, 1], j] if nodes[i, 1] >= 0 else 0.0
            va = v[nodes[i, 0], j] if nodes[i, 0] >= 0 else 0.0
            u[j] = vb - va
        out[i] = dot3(u[0], u[1], u[2], directions[i, 0], directions[i, 1], directions[i, 2])
    return out


@njit(cache=True)
def answer_residuals(v, y, v0, nodes, directions, targets, n_eq, mass, rel_tol):
    """How far an answer ``v`` (n_free, 3), ``y`` (k,) is from the QP's optimality conditions, in one
    pass: returns ``(scale, violation, impulse, stationarity, smallest inequality impulse, acting row
    short of its target)`` as ``QPSolver._residuals_reference`` does (``mass`` (3 n_free,) kg per
    degree of freedom; ``rel_tol``: the relative impulse under which a row is not acting)."""
    n_free = v.shape[0]
    k = targets.shape[0]
    scale = 0.0
    for i in range(n_free):
        for j in range(3):
            scale = max(scale, abs(v0[i, j]))
    for i in range(k):
        scale = max(scale, abs(targets[i]))
    res = row_rates(v, nodes, directions)
    violation = 0.0
    for i in range(k):
        res[i] -= targets[i]
        violation = max(violation, abs(res[i]) if i < n_eq else res[i])
    # stationarity: M (v - v0) + A^T y, scattered row by row (A is never formed)
    station = np.empty((n_free, 3))
    impulse = 1e-300
    for i in range(n_free):
        for j in range(3):
            m = mass[3 * i + j]
            change = m * (v[i, j] - v0[i, j])
            station[i, j] = change
            impulse = max(impulse, abs(m * v0[i, j]), abs(change))
    smallest = 0.0
    for i in range(k):
        impulse = max(impulse, abs(y[i]))
        if i >= n_eq:
            smallest = min(smallest, y[i])
        na = nodes[i, 0]
        nb = nodes[i, 1]
        for j in range(3):
            if na >= 0:
                station[na, j] -= directions[i, j] * y[i]
            if nb >= 0:
                station[nb, j] += directions[i, j] * y[i]
    stationarity = 0.0
    for i in range(n_free):
        for j in range(3):
            stationarity = max(stationarity, abs(station[i, j]))
    short = 0.0
    for i in range(n_eq, k):
        if y[i] > rel_tol * impulse:
            short = max(short, -res[i])
    return scale, violation, impulse, stationarity, smallest, short
