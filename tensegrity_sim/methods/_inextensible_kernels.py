"""Compiled kernels of the inextensible method's sub-step bookkeeping: which members are QP rows, their
directions and targets (``InextensibleMethod._rows_reference`` and ``_targets`` are the numpy reference
these must match; the QP itself is DAQP's or another backend's).

Members are the method's row table: the ``n_eq`` moving rigid struts first, then every cable, with
``ends`` (n_eq + nc, 2) node indices and ``limits`` (n_eq + nc,) m (strut lengths, cable length limits).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ._qp_kernels import dot3, row_rates

__all__ = ["select_rows", "row_targets", "motor_limits", "first_snap", "landed"]


@njit(cache=True)
def row_targets(v, ends, directions, length, limits, tau, floor_rate, n_eq):
    """Row targets (k,) m/s for node velocities ``v`` (N, 3) at the sub-step's end (see
    ``InextensibleMethod._targets``): a cable's lands it on its limit given the relative velocity of its
    ends across it, never below ``floor_rate``; a rigid strut's (the first ``n_eq``) is ``floor_rate``."""
    k = ends.shape[0]
    half = 0.5 * tau
    targets = floor_rate.copy()
    for i in range(n_eq, k):
        a = ends[i, 0]
        b = ends[i, 1]
        u0 = v[b, 0] - v[a, 0]
        u1 = v[b, 1] - v[a, 1]
        u2 = v[b, 2] - v[a, 2]
        un = dot3(u0, u1, u2, directions[i, 0], directions[i, 1], directions[i, 2])
        across2 = dot3(u0, u1, u2, u0, u1, u2) - un * un
        lim = limits[i]
        land = (np.sqrt(max(lim * lim - half * half * across2, 0.0)) - length[i]) / half
        targets[i] = max(land, floor_rate[i])
    return targets


@njit(cache=True)
def select_rows(x_m, v, v0, tau, ends, n_eq, limits, floor, cables_move, reel, holding):
    """The rows of a sub-step from the midpoint ``x_m`` (N, 3): every moving rigid strut, and each cable
    that can reach its limit by the sub-step's end (``l_m + tau/2 |u0| >= floor``, ``u0`` the relative
    free velocity ``v0`` (N, 3) of its ends). Returns ``cables`` (nc,) bool (the cables that are rows),
    ``sel`` (k,) their rows in the member table, unit vectors (k, 3), lengths (k,) m, limits (k,) m,
    ``floor_rate`` (k,) m/s (the reversal ``-b.v`` of each row's midpoint rate for velocities ``v``, plus
    twice a cable's reel-in rate ``reel`` (nc,) m/s), targets (k,) m/s and the warm-start hint (k,) bool
    (rigid struts, and the cables ``holding`` (nc,) bool)."""
    total = ends.shape[0]
    nc = total - n_eq
    length = np.empty(total)
    n = np.empty((total, 3))
    for i in range(total):
        a = ends[i, 0]
        b = ends[i, 1]
        for j in range(3):
            n[i, j] = x_m[b, j] - x_m[a, j]
        length[i] = np.sqrt(dot3(n[i, 0], n[i, 1], n[i, 2], n[i, 0], n[i, 1], n[i, 2]))
        for j in range(3):
            n[i, j] /= length[i]
    cables = np.zeros(nc, dtype=np.bool_)
    k = n_eq
    for c in range(nc):
        a = ends[n_eq + c, 0]
        b = ends[n_eq + c, 1]
        u0 = v0[b, 0] - v0[a, 0]
        u1 = v0[b, 1] - v0[a, 1]
        u2 = v0[b, 2] - v0[a, 2]
        if length[n_eq + c] + (0.5 * tau) * np.sqrt(dot3(u0, u1, u2, u0, u1, u2)) >= floor[c] and cables_move[c]:
            cables[c] = True
            k += 1
    sel = np.empty(k, dtype=np.int64)
    for i in range(n_eq):
        sel[i] = i
    r = n_eq
    for c in range(nc):
        if cables[c]:
            sel[r] = n_eq + c
            r += 1
    m_ends = np.empty((k, 2), dtype=np.int64)
    m_n = np.empty((k, 3))
    m_length = np.empty(k)
    m_limits = np.empty(k)
    floor_rate = np.empty(k)
    warm = np.empty(k, dtype=np.bool_)
    for r in range(k):
        i = sel[r]
        m_ends[r, 0] = ends[i, 0]
        m_ends[r, 1] = ends[i, 1]
        for j in range(3):
            m_n[r, j] = n[i, j]
        b = ends[i, 1]
        a = ends[i, 0]
        un = dot3(v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2], n[i, 0], n[i, 1], n[i, 2])
        m_length[r] = length[i]
        m_limits[r] = limits[i]
        floor_rate[r] = -un
        if r >= n_eq:
            if reel[i - n_eq] != 0.0:
                floor_rate[r] += 2.0 * reel[i - n_eq]
            warm[r] = holding[i - n_eq]
        else:
            warm[r] = True
    targets = row_targets(v, m_ends, m_n, m_length, m_limits, tau, floor_rate, n_eq)
    return cables, sel, m_n, m_length, m_limits, floor_rate, targets, warm


@njit(cache=True)
def motor_limits(commanded, applied, most, dt, offsets, limit_tol, taut_tol):
    """The step's cable limits (``InextensibleMethod._motor_limits_reference``): the rest lengths in effect
    ``applied`` (n_cables,) m move towards the ``commanded`` ones by at most ``most`` m, landing exactly on
    them. Returns the new rest lengths in effect, the reel-in rates (m/s, <= 0), the length limits (m,
    plus the prestress ``offsets``), the limits' slack floor and taut threshold (relative tolerances
    ``limit_tol``, ``taut_tol``) and whether any cable reels in."""
    nc = commanded.shape[0]
    new = np.empty(nc)
    reel = np.empty(nc)
    limits = np.empty(nc)
    floor = np.empty(nc)
    taut = np.empty(nc)
    reeling = False
    for c in range(nc):
        change = commanded[c] - applied[c]
        new[c] = commanded[c] if abs(change) <= most else applied[c] + np.copysign(most, change)
        reel[c] = min(new[c] - applied[c], 0.0) / dt
        reeling |= reel[c] != 0.0
        limits[c] = new[c] + offsets[c]
        floor[c] = limits[c] * (1.0 - limit_tol)
        taut[c] = limits[c] * (1.0 - taut_tol)
    return new, reel, limits, floor, taut, reeling


@njit(cache=True)
def first_snap(d, limits, v, v0, tau, cable_ends, slack, newton_iter):
    """``InextensibleMethod._first_snap``: the fraction of the sub-step (0, 1] at which the first
    ``slack`` (n_cables,) bool cable reaches its limit (``limits`` (n_cables,) m) on the free path of its
    ends (cable vectors ``d`` (n_cables, 3) m at the start, velocities ``v`` and free velocities ``v0``
    (N, 3) m/s), 1.0 if none does; ``newton_iter`` Newton iterations from the straight path's crossing."""
    first = 1.0
    for c in range(d.shape[0]):
        if not slack[c]:
            continue
        a = cable_ends[c, 0]
        b = cable_ends[c, 1]
        u = np.empty(3)
        um = np.empty(3)
        de = np.empty(3)
        for j in range(3):
            u[j] = v[b, j] - v[a, j]
            um[j] = 0.5 * (u[j] + v0[b, j] - v0[a, j])   # numpy's order: (u + v0_b) - v0_a
            de[j] = d[c, j] + tau * um[j]
        lim = limits[c]
        if not dot3(de[0], de[1], de[2], de[0], de[1], de[2]) > lim * lim:
            continue
        acc = np.empty(3)
        for j in range(3):
            acc[j] = 2.0 * (um[j] - u[j]) / tau
        # start: the crossing of the straight path d + t tau u_mean (exact at t = 1), small root form
        bb = dot3(d[c, 0], d[c, 1], d[c, 2], um[0], um[1], um[2]) * tau
        aa = dot3(um[0], um[1], um[2], um[0], um[1], um[2]) * tau * tau
        cc = dot3(d[c, 0], d[c, 1], d[c, 2], d[c, 0], d[c, 1], d[c, 2]) - lim * lim
        t = min(max(-cc / (bb + np.sqrt(max(bb * bb - aa * cc, 0.0))), 0.0), 1.0)
        p = np.empty(3)
        dp = np.empty(3)
        for _ in range(newton_iter):
            for j in range(3):
                p[j] = d[c, j] + (t * tau) * u[j] + (0.5 * (t * tau) ** 2) * acc[j]
                dp[j] = tau * u[j] + (t * tau * tau) * acc[j]
            g = dot3(p[0], p[1], p[2], p[0], p[1], p[2]) - lim * lim
            slope = 2.0 * dot3(p[0], p[1], p[2], dp[0], dp[1], dp[2])
            t = min(max(t - g / (slope if slope > 0 else np.inf), 0.0), 1.0)
        first = min(first, t)
    return first


@njit(cache=True)
def landed(v_f, v, v_free, y, ends, nodes, directions, length, limits, tau, floor_rate, n_eq, shortest, tol):
    """One check of ``InextensibleMethod._land`` after a solve: whether every binding row landed (the
    velocities ``v_f`` (N, 3) changed too little from ``v`` for the landing error bound to reach ``tol``
    relative, or every row is within ``tol`` of the targets recomputed at ``v_f``). Returns that, the
    recomputed targets (k,) m/s and the new warm start (k,) bool (rows with an impulse, rigid struts),
    both empty when the bound decided. ``v_free`` (n_free, 3): the solution's free-node velocities;
    ``y`` (k,): its multipliers; rows ``nodes``/``directions`` and member ``ends`` (k, 2), lengths and
    limits (k,) m of the sub-step; ``shortest``: the smallest limit, m."""
    change = 0.0
    largest = 0.0
    for i in range(v.shape[0]):
        for j in range(3):
            change = max(change, abs(v_f[i, j] - v[i, j]))
            largest = max(largest, abs(v[i, j]))
    if 0.5 * tau * tau * change * (change + 2.0 * largest) <= tol * shortest ** 2:
        return True, np.empty(0), np.empty(0, dtype=np.bool_)
    targets = row_targets(v_f, ends, directions, length, limits, tau, floor_rate, n_eq)
    miss = row_rates(v_free, nodes, directions)
    k = targets.shape[0]
    warm = np.empty(k, dtype=np.bool_)
    done = True
    for i in range(k):
        miss[i] -= targets[i]
        warm[i] = i < n_eq or y[i] > 0
        if (abs(miss[i]) if warm[i] else miss[i]) > tol * (2.0 / tau) * limits[i]:
            done = False
    return done, targets, warm
