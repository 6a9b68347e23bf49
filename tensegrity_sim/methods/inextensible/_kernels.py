"""Compiled kernels of the inextensible method's sub-step bookkeeping: which members are QP rows, their
directions and targets (``InextensibleMethod._rows_reference`` and ``_targets`` are the numpy reference
these must match; the QP itself is DAQP's or another backend's).

Members are the method's row table: the ``n_eq`` moving rigid struts first, then every cable, with
``ends`` (n_eq + nc, 2) node indices and ``limits`` (n_eq + nc,) m (strut lengths, cable length limits).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from .._c_calls import ddot_at, dgemv_at
from .._mass_kernels import solve_forces
from ..qp._daqp_kernels import quadprog, solve_rows
from ..elastic._kernels import keep
from ..qp._qp_kernels import answer_residuals, dense_rows, dot3, row_rates
from ._self_stress_kernels import locked_space
from ..contact._friction_kernels import arm_step, contact_solve, first_impact, landing, missed

__all__ = ["select_rows", "row_targets", "motor_limits", "first_snap", "landed", "midpoint", "cable_geometry",
           "fit_one", "impact", "step", "steps", "copies_steps"]


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
def _crosses(d, limits, v, v0, tau, cable_ends, c, u, um):
    """Whether cable ``c``'s ends' straight mean path ``d + tau u_mean`` ends beyond its limit (the cables whose
    snap :func:`first_snap` locates; ``InextensibleMethod._snap_times``' test); ``u`` and ``um`` (3,) get the
    relative velocity and mean free velocity of its ends."""
    a = cable_ends[c, 0]
    b = cable_ends[c, 1]
    for j in range(3):
        u[j] = v[b, j] - v[a, j]
        um[j] = 0.5 * (u[j] + v0[b, j] - v0[a, j])   # numpy's order: (u + v0_b) - v0_a
    de0 = d[c, 0] + tau * um[0]   # the end's vector (no array: this runs for every slack cable, every step)
    de1 = d[c, 1] + tau * um[1]
    de2 = d[c, 2] + tau * um[2]
    return dot3(de0, de1, de2, de0, de1, de2) > limits[c] * limits[c]


@njit(cache=True)
def first_snap(d, limits, v, v0, tau, cable_ends, slack, newton_iter):
    """``InextensibleMethod._first_snap``: the fraction of the sub-step (0, 1] at which the first
    ``slack`` (n_cables,) bool cable reaches its limit (``limits`` (n_cables,) m) on the free path of its
    ends (cable vectors ``d`` (n_cables, 3) m at the start, velocities ``v`` and free velocities ``v0``
    (N, 3) m/s), 1.0 if none does; ``newton_iter`` Newton iterations from the straight path's crossing."""
    first = 1.0
    u = np.empty(3)
    um = np.empty(3)
    acc = np.empty(3)   # the crossing cable's scratch, made once a call
    p = np.empty(3)
    dp = np.empty(3)
    for c in range(d.shape[0]):
        if not slack[c] or not _crosses(d, limits, v, v0, tau, cable_ends, c, u, um):
            continue
        lim = limits[c]
        for j in range(3):
            acc[j] = 2.0 * (um[j] - u[j]) / tau
        # start: the crossing of the straight path d + t tau u_mean (exact at t = 1), small root form
        bb = dot3(d[c, 0], d[c, 1], d[c, 2], um[0], um[1], um[2]) * tau
        aa = dot3(um[0], um[1], um[2], um[0], um[1], um[2]) * tau * tau
        cc = dot3(d[c, 0], d[c, 1], d[c, 2], d[c, 0], d[c, 1], d[c, 2]) - lim * lim
        t = min(max(-cc / (bb + np.sqrt(max(bb * bb - aa * cc, 0.0))), 0.0), 1.0)
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


@njit(cache=True)
def _solve_checked(entry, settings, hessian, sqrt_mass, mass, schur, nodes, directions, v0_free, targets, n_eq, warm,
                   feasibility_tol, velocity_floor, guess):
    """``DaqpSolver.solve`` at unit scale with ``QPSolver._check``: ``v`` (n_free, 3) m/s, the multipliers
    (k,) N*s and whether the answer passed (DAQP succeeded, finite, the optimality conditions met to
    ``feasibility_tol`` relative plus ``velocity_floor`` m/s). A failed one goes back to the Python path,
    which raises its error or solves again at another scale. Also the working set's Cholesky factor and
    rows (``solve_rows``, trying the working set ``warm`` first with ``guess``: ``DaqpSolver.working_set``).
    With rigid rods' mass blocks (``schur``: :func:`_solve_blocks`) that solve is ``BlockMassSolver.solve``'s."""
    if schur[0].shape[0]:
        v, y, ok = _solve_blocks(entry, settings, hessian, sqrt_mass, mass, schur, nodes, directions, v0_free,
                                 targets, n_eq, warm, feasibility_tol, velocity_floor)
        return v, y, ok, np.zeros((0, 0)), np.zeros(0, dtype=np.int64)
    n_free = v0_free.shape[0]
    v_flat, y, flag, _, factor, rows = solve_rows(entry, settings, hessian, sqrt_mass, mass, nodes, directions,
                                                  n_free, v0_free.reshape(-1), targets, n_eq, warm, 1.0, guess)
    v = v_flat.reshape((n_free, 3))
    if flag < 1 or not (np.isfinite(v_flat).all() and np.isfinite(y).all()):
        return v, y, False, factor, rows
    scale, violation, impulse, stationarity, smallest, short = answer_residuals(
        v, y, v0_free, nodes, directions, targets, n_eq, mass, feasibility_tol)
    tol = feasibility_tol * scale + velocity_floor
    ok = not (violation > tol or stationarity > feasibility_tol * impulse or smallest < -feasibility_tol * impulse
              or short > tol)
    return v, y, ok, factor, rows


@njit(cache=True)
def _solve_blocks(entry, settings, hessian, sqrt_mass, mass, schur, nodes, directions, v0_free, targets, n_eq, warm,
                  feasibility_tol, velocity_floor):
    """``BlockMassSolver.solve`` by DAQP's C call (no working-set guess: the backend takes none for general rows):
    ``schur`` = (pivot, other (nb,) int, beta (nb,)) its coordinates ``u = T^-1 v`` (``u_p = v_p + beta v_o``),
    in which ``sqrt_mass``, ``mass`` (3 n_free,) are the diagonal (Schur) mass; the rows on ``u`` are ``A T``
    (column ``o`` less ``beta`` times column ``p``), built and scaled to the bit as ``Rows.dense`` builds
    ``BlockMassSolver.inner_rows`` and ``DaqpSolver._solve`` scales them. The answer is checked on ``u`` as the
    backend checks it (``QPSolver._check``). Returns ``v`` (n_free, 3) m/s, the multipliers (k,) N*s and whether
    the answer passed."""
    pivot, other, beta = schur
    n_free = v0_free.shape[0]
    k = targets.shape[0]
    u0 = v0_free.copy()
    for b in range(pivot.shape[0]):
        for j in range(3):
            u0[pivot[b], j] += beta[b] * u0[other[b], j]
    a = dense_rows(nodes, directions, n_free, np.ones(3 * n_free))
    for b in range(pivot.shape[0]):
        for j in range(3):
            p = 3 * pivot[b] + j
            o = 3 * other[b] + j
            for i in range(k):
                a[i, o] -= beta[b] * a[i, p]
    scaled = a / sqrt_mass
    lower = np.full(k, -1e30)
    sense = np.empty(k, dtype=np.int32)
    for i in range(k):
        sense[i] = 5 if i < n_eq else np.int32(warm[i])
        if i < n_eq:
            lower[i] = targets[i]
    z, y, flag, _ = quadprog(entry, settings, hessian, -sqrt_mass * u0.reshape(-1), scaled, targets.copy(), lower,
                             sense)
    u = (z / sqrt_mass).reshape((n_free, 3))
    v = u.copy()
    for b in range(pivot.shape[0]):
        for j in range(3):
            v[pivot[b], j] -= beta[b] * v[other[b], j]
    if flag < 1 or not (np.isfinite(z).all() and np.isfinite(y).all()):
        return v, y, False
    # QPSolver._check on u: rates A T u, stationarity D (u - u0) + (A T)^T y
    scale = max(np.abs(u0).max() if n_free else 0.0, np.abs(targets).max() if k else 0.0)
    res = a @ u.reshape(-1) - targets
    violation = 0.0
    for i in range(k):
        violation = max(violation, abs(res[i]) if i < n_eq else res[i])
    change = mass * (u.reshape(-1) - u0.reshape(-1))
    impulse = max(np.abs(mass * u0.reshape(-1)).max() if n_free else 0.0, np.abs(change).max() if n_free else 0.0,
                  np.abs(y).max() if k else 0.0, 1e-300)
    station = change + a.T @ y
    stationarity = np.abs(station).max() if n_free else 0.0
    smallest = 0.0
    short = 0.0
    for i in range(n_eq, k):
        smallest = min(smallest, y[i])
        if y[i] > feasibility_tol * impulse:
            short = max(short, -res[i])
    tol = feasibility_tol * scale + velocity_floor
    ok = not (violation > tol or stationarity > feasibility_tol * impulse or smallest < -feasibility_tol * impulse
              or short > tol)
    return v, y, ok


@njit(cache=True)
def _solve_mass(f, inv_mass, ends, n_eq):
    """``M^-1 f`` (N, 3) of forces or impulses ``f`` (N, 3) with the rods' blocks: ``MassOperator.solve``'s
    arithmetic (``_mass_kernels.solve_forces`` on ``inv_mass`` (N, 2), the operator's ``kernel_array``; the rigid
    struts are ``ends``' first ``n_eq``)."""
    acc = np.empty((f.shape[0], 3, 1))
    acc[:, :, 0] = f
    solve_forces(acc, inv_mass, ends, np.arange(n_eq), 0)
    return acc[:, :, 0]


@njit(cache=True)
def _pulling_inputs(x_m, v0, limits, reel, pulling, most, cable_ends, schur, inv_mass, ends, n_eq, cable_limits, dt,
                    tau):
    """The sub-step's free velocity, limits and reel with the ``pulling`` motors at their force (:func:`midpoint`)."""
    nc = reel.shape[0]
    push = np.zeros_like(v0)
    pull = np.zeros((nc, 3))
    for c in range(nc):
        if pulling[c]:
            a = cable_ends[c, 0]
            b = cable_ends[c, 1]
            dx = x_m[b, 0] - x_m[a, 0]
            dy = x_m[b, 1] - x_m[a, 1]
            dz = x_m[b, 2] - x_m[a, 2]
            scale = most / np.sqrt(dot3(dx, dy, dz, dx, dy, dz))   # (einsum's order, as the reference's)
            pull[c, 0] = scale * dx
            pull[c, 1] = scale * dy
            pull[c, 2] = scale * dz
    for c in range(nc):   # np.add.at's order: every first end, then every second end
        if pulling[c]:
            for j in range(3):
                push[cable_ends[c, 0], j] += pull[c, j]
    for c in range(nc):
        if pulling[c]:
            for j in range(3):
                push[cable_ends[c, 1], j] += -pull[c, j]
    if schur[0].shape[0]:   # the rods' blocks
        v0p = v0 + _solve_mass(push, inv_mass, ends, n_eq)
    else:
        v0p = v0 + inv_mass[:, :1] * push
    limits_p = limits.copy()
    reel_p = reel.copy()
    for c in range(nc):
        if pulling[c]:
            # (the motor half a step's reel ahead of its cable, as a running one is)
            limits_p[n_eq + c] = cable_limits[c] - (dt + 0.5 * tau) * reel[c]
            reel_p[c] = 0.0
    return v0p, limits_p, reel_p


@njit(cache=True)
def midpoint(x_m, v, v0, tau, ends, n_eq, limits, floor, cables_move, reel, holding, row_nodes, free_nodes,
             cable_ends, taut, entry, settings, hessian, sqrt_mass, mass, schur, feasibility_tol, velocity_floor,
             landing_tol, landing_iter, reel_force, cable_limits, dt, inv_mass, locked, load_basis, load_cables,
             load_largest, refine, rank_tol, exact, weight, shared, ground, memory, carried):
    """``InextensibleMethod._midpoint`` with no contact rows or the ground's alone, its QP solved by DAQP
    (``_solve_checked``, or with armed ground contacts the compiled friction modes,
    ``_friction_kernels.contact_solve``), in one call: the rows (:func:`select_rows`, member table
    ``ends``, ``limits`` with the landing targets' reel already applied), the landing iterations
    (``_land``: up to ``landing_iter`` solves, :func:`landed` to ``landing_tol``), the end of the sub-step
    and, when the structure can lock (``locked``), the self-stress rule's binding rows and basis
    (``_self_stress_kernels.locked_space``, its fit stays numpy). ``row_nodes`` (n_eq + nc, 2): the
    free-node index of each member end; ``free_nodes`` (n_free,) int: the free nodes; ``taut`` (nc,) m: a
    cable's at-limit length.

    ``schur``: the Schur coordinates of the rods' mass blocks (``InextensibleMethod._qp_call``; empty without
    them), in which ``sqrt_mass`` and ``mass`` are the QP's diagonal mass (:func:`_solve_blocks`; no ground then).

    ``ground``: ``(on, nodes, radii, height, mu, touch_tol, free_index, fixed_point_tol, slip_floor,
    max_iter, depth, restitution)`` (``on`` False: no ground, the rest unused; see ``InextensibleMethod._ground_table``)
    and ``memory`` each node's friction mode, ``y_n`` and slip direction (``FrictionalSolver``'s), which
    the contacts' solves read and update in place. The ground's contacts are armed as
    ``ContactSet.arm_step`` arms them; a sub-step with no member row but armed contacts, or whose answer
    carries an unarmed node into the ground (``ContactSet.missed``), is the Python path's.

    Returns ``ok`` (False: a QP answer the Python path must handle, nothing else is meaningful), ``x_f``,
    ``v_f`` (N, 3), the multipliers (k,) N*s, ``cables`` (nc,) bool (the cable rows), the rows' nodes
    (k, 2) and directions (k, 3), the cable vectors (nc, 3) and lengths (nc,) m at ``x_f`` (as
    ``System.geometry``), ``locked_space``'s binding rows, members, ``A_B^T`` and basis (or None:
    the caller's SVD; empty when not ``locked``), the ground's impulses (N, 3) N*s and the motors that pulled at
    their force (nc,) bool.

    A reeling motor whose cable's impulse would exceed ``reel_force * tau`` pulls at that force instead
    (``InextensibleMethod._motor_modes``, the same arithmetic): a known impulse along the cable added to ``v0``
    (``inv_mass`` (N, 2) 1/kg, ``MassOperator.kernel_array``), the cable's limit where the motor stood at the step's
    start (``cable_limits`` (nc,) m: the step's limits without the landing's lag; ``dt``: the step),
    no reel; the multipliers returned include those impulses. The motors ``carried`` (nc,) bool (those at their
    force in the last step) that still reel start pulling, and where one's cable ends shorter than its landing the
    sub-step starts again from every motor following (``InextensibleMethod._motor_modes``)."""
    (on, g_nodes, radii, height, mu, touch_tol, free_index, fixed_point_tol, slip_floor, max_iter,
     depth, _) = ground
    stick, normal, slip = memory
    n_free = free_nodes.shape[0]
    nc = reel.shape[0]
    most = reel_force * tau   # N*s: the most a motor pulls over the sub-step (InextensibleMethod._motor_modes)
    pulling = np.zeros(nc, dtype=np.bool_)
    start_pulling = False
    for c in range(nc):
        pulling[c] = carried[c] and reel[c] < 0.0
        start_pulling |= pulling[c]
    pulls = start_pulling
    v0p = v0
    limits_p = limits
    reel_p = reel
    if start_pulling:
        v0p, limits_p, reel_p = _pulling_inputs(x_m, v0, limits, reel, pulling, most, cable_ends, schur, inv_mass,
                                                ends, n_eq, cable_limits, dt, tau)
    while True:
        cables, sel, m_n, m_length, m_limits, floor_rate, targets, warm = select_rows(
            x_m, v, v0p, tau, ends, n_eq, limits_p, floor, cables_move, reel_p, holding)
        k = sel.shape[0]
        nodes = np.empty((k, 2), dtype=row_nodes.dtype)
        m_ends = np.empty((k, 2), dtype=ends.dtype)
        for r in range(k):
            for j in range(2):
                nodes[r, j] = row_nodes[sel[r], j]
                m_ends[r, j] = ends[sel[r], j]
        y = np.zeros(k)
        ok = True
        factor = np.zeros((0, 0))   # the last QP's working set and its factor, which the rule may refine with
        work = np.zeros(0, dtype=np.int64)
        # without a ground: empty views, no allocation (this runs every step)
        contact = v0[:0]
        armed = g_nodes[:0]
        w = radii[:0]
        touching = stick[:0]
        impulses = v0[:0]
        if on:
            contact = np.zeros((x_m.shape[0], 3))
            armed, w, touching = arm_step(x_m, v, v0p, 0.5 * tau, g_nodes, radii, height, touch_tol, v0[:0])
        if k == 0:   # nothing can be taut: free motion, no QP (a contact's QP alone is the Python path's)
            v_f = v0p.copy()
            ok = armed.shape[0] == 0
        else:
            v0_free = np.empty((n_free, 3))
            for i in range(n_free):
                for j in range(3):
                    v0_free[i, j] = v0p[free_nodes[i], j]
            v_f = np.zeros_like(v0)
            shortest = m_limits.min()
            v_start = v
            first_warm = warm
            for again in range(2):
                for _ in range(landing_iter):
                    if armed.shape[0]:
                        ok, v_free, y, impulses = contact_solve(
                            entry, settings, hessian, sqrt_mass, mass, v0_free, nodes, m_n, targets, n_eq, warm, armed,
                            free_index, w, touching, mu, stick, normal, slip, fixed_point_tol, slip_floor, max_iter,
                            depth, feasibility_tol, velocity_floor)
                    else:   # a ground's backend answers by DAQP alone (DaqpSolver.working_set)
                        v_free, y, ok, factor, work = _solve_checked(entry, settings, hessian, sqrt_mass, mass, schur,
                                                                     nodes, m_n, v0_free, targets, n_eq, warm,
                                                                     feasibility_tol, velocity_floor, not on)
                    if not ok:
                        break
                    for i in range(n_free):
                        for j in range(3):
                            v_f[free_nodes[i], j] = v_free[i, j]
                    done, new_targets, new_warm = landed(v_f, v_start, v_free, y, m_ends, nodes, m_n, m_length,
                                                         m_limits, tau, floor_rate, n_eq, shortest, landing_tol)
                    if done:
                        break
                    targets = new_targets
                    warm = new_warm
                    v_start = v_f.copy()
                if again or not (ok and on and missed(x_m, v_f, 0.5 * tau, g_nodes, armed, radii, height, touch_tol)):
                    break
                # a cable's impulse carried a node its free motion kept clear of the ground into it: the landing
                # again with that node armed too, judged on this answer (InextensibleMethod._solve_sub_step: from
                # the landing's last targets, the first warm start and velocities; the refinement factorises itself)
                armed, w, touching = arm_step(x_m, v, v0p, 0.5 * tau, g_nodes, radii, height, touch_tol, v_f)
                warm = first_warm
                v_start = v
                factor = np.zeros((0, 0))
                work = np.zeros(0, dtype=np.int64)
        if ok and start_pulling and k:
            # the motors carried pulling: where one's cable ends shorter than a following motor would take it, the
            # sub-step again from every motor following
            x_try = _drift(x_m, 0.5 * tau, v_f)
            _, length_try = cable_geometry(x_try, cable_ends)
            release = False
            for c in range(nc):
                release |= pulling[c] and length_try[c] < limits[n_eq + c]
            if release:
                start_pulling = False
                pulls = False
                pulling = np.zeros(nc, dtype=np.bool_)
                v0p = v0
                limits_p = limits
                reel_p = reel
                continue
        # a motor that would pull harder than reel_force pulls at that force, its cable held where it stood
        over = False
        if ok:
            r = n_eq
            for c in range(nc):
                if cables[c]:
                    if reel[c] < 0.0 and not pulling[c] and y[r] > most:
                        pulling[c] = True
                        over = True
                    r += 1
        if not over:
            break
        pulls = True
        v0p, limits_p, reel_p = _pulling_inputs(x_m, v0, limits, reel, pulling, most, cable_ends, schur, inv_mass,
                                                ends, n_eq, cable_limits, dt, tau)
    if ok and k and pulls:   # the pulling motors' impulses are their cables' too
        r = n_eq
        for c in range(nc):
            if cables[c]:
                if pulling[c]:
                    y[r] += most
                r += 1
    if ok and k:
        for c in range(impulses.shape[0]):   # the last solve's, committed (FrictionalSolver.commit)
            for j in range(3):
                contact[armed[c], j] += impulses[c, j]
    x_f = _drift(x_m, 0.5 * tau, v_f)
    d, length = cable_geometry(x_f, cable_ends)
    if not (ok and locked and k):   # no rule: its space empty
        return (ok, x_f, v_f, y, cables, nodes, m_n, d, length, np.zeros(0, dtype=np.bool_),
                np.zeros(0, dtype=load_cables.dtype), np.zeros((3 * n_free, 0)), None, contact, pulling)
    rows_cables = np.flatnonzero(cables)
    at_limit = np.empty(rows_cables.shape[0], dtype=np.bool_)
    for i in range(rows_cables.shape[0]):
        at_limit[i] = length[rows_cables[i]] >= taut[rows_cables[i]]
    binding, members, a_t, basis = locked_space(nodes, m_n, n_free, n_eq, rows_cables, at_limit, y, load_basis,
                                                load_cables, load_largest, refine, rank_tol, exact, weight, shared,
                                                work, factor)
    return ok, x_f, v_f, y, cables, nodes, m_n, d, length, binding, members, a_t, basis, contact, pulling


@njit(cache=True)
def _drift(x, h, v):
    """``x + h v`` (N, 3) m for positions ``x``, velocities ``v`` (N, 3) and a time ``h`` s, numpy's arithmetic
    in one array (no temporary ``h v``: this runs twice a step)."""
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        for j in range(3):
            out[i, j] = x[i, j] + h * v[i, j]
    return out


@njit(cache=True)
def cable_geometry(x, cable_ends):
    """Cable vectors (nc, 3) and lengths (nc,) m at ``x`` (N, 3), as ``System.geometry``."""
    nc = cable_ends.shape[0]
    d = np.empty((nc, 3))
    length = np.empty(nc)
    for c in range(nc):
        for j in range(3):
            d[c, j] = x[cable_ends[c, 1], j] - x[cable_ends[c, 0], j]
        length[c] = np.sqrt(dot3(d[c, 0], d[c, 1], d[c, 2], d[c, 0], d[c, 1], d[c, 2]))
    return d, length


@njit(cache=True)
def _ddot(address, wide, x, y):
    """``x . y`` (contiguous vectors) by the BLAS ``ddot`` at ``address`` (``wide``: 64-bit integers)."""
    if wide:
        return ddot_at(address, True, x, y)
    return ddot_at(address, False, x, y)


@njit(cache=True)
def fit_one(ddot, dgemv, wide, y, binding, basis, a_t, reference, members, tau, n_eq):
    """``SelfStress.locked_impulses`` for a one-dimensional self-stress ``basis`` (k_b, 1), its products
    made by numpy's BLAS functions at ``ddot``/``dgemv`` (``_numpy_blas.py``; ``wide``: 64-bit
    integers), so to numpy's bits: the
    binding rows' multipliers ``y[binding]`` with their self-stress share replaced by the one closest to
    the binding cables' (``members``) ``reference`` tensions (N) times ``tau`` s. Returns whether no cable
    pulls (else the caller's numpy fit, which keeps every impulse >= 0 by a small QP), the binding rows'
    published impulses (k_b,) N*s and the node impulse the share dropped (``SelfStress.residual``, N*s)."""
    kb = basis.shape[0]
    nb = kb - n_eq
    y_b = np.empty(kb)
    column = np.empty(kb)
    r = 0
    for i in range(y.shape[0]):
        if binding[i]:
            y_b[r] = y[i]
            r += 1
    for r in range(kb):
        column[r] = basis[r, 0]
    ref = np.empty(nb)
    for c in range(nb):
        ref[c] = reference[members[c]] * tau
    cable_part = column[n_eq:].copy()
    share = _ddot(ddot, wide, column, y_b)
    alpha = _ddot(ddot, wide, cable_part, ref) / _ddot(ddot, wide, cable_part, cable_part)
    out = np.empty(kb)
    change = np.empty(kb)
    for r in range(kb):
        out[r] = (y_b[r] - column[r] * share) + column[r] * alpha   # products of one term: exact as numpy's
        if r >= n_eq and out[r] < 0.0:
            return False, out, 0.0
        change[r] = out[r] - y_b[r]
    node = np.empty(a_t.shape[0])
    if wide:
        dgemv_at(dgemv, True, a_t, change, node)
    else:
        dgemv_at(dgemv, False, a_t, change, node)
    return True, out, np.abs(node).max()


@njit(cache=True)
def impact(x, v, d, length, at_limit, snapping, holding, ends, n_eq, row_nodes, free_nodes, entry, settings, hessian,
           sqrt_mass, mass, schur, feasibility_tol, velocity_floor, locked, load_basis, load_cables, load_largest,
           refine, rank_tol, exact, weight, shared, ddot, dgemv, wide, reference, dt, ground, memory, lands, contact):
    """``InextensibleMethod._impact`` without a landing in it, and its ``_publish``: Moreau's impact law at
    ``x`` (N, 3) from ``v`` when the cables ``snapping`` (nc,) bool separate, rows every moving rigid strut
    (``ends``' first ``n_eq``) and every cable ``at_limit`` (nc,) bool (cable vectors ``d`` (nc, 3), lengths
    (nc,) m at ``x``), targets 0, warm the rigid struts and the cables snapping or ``holding``; solved by
    ``_solve_checked`` (the working set first without a ``ground``, as the backend does) or, with nodes touching
    the ground (``ground`` and ``memory`` as :func:`midpoint` takes them), by the compiled friction modes with
    those nodes' rows (``ContactSet.arm_impact``: Newton's law with the ground's restitution for a node moving
    into it by more than its tolerance in a step ``dt``, ``v_z+ >= 0`` for the others), whose impulses are
    added to ``contact`` (N, 3) N*s when the impact ``lands`` (the Python path's commit). When the structure can lock
    (``locked``) the impulses published are the self-stress rule's with a one-dimensional self-stress and no
    cable pulling (:func:`fit_one`, tau = 0). Returns ``ok`` (False: an answer refused or a rule's fit the
    kernel leaves to the Python path), ``v+`` (N, 3), the published cable impulses (nc,) N*s and the fit's
    dropped node impulse, N*s."""
    nc = at_limit.shape[0]
    cables = np.flatnonzero(at_limit)
    k = n_eq + cables.shape[0]
    nodes = np.empty((k, 2), dtype=row_nodes.dtype)
    directions = np.empty((k, 3))
    warm = np.empty(k, dtype=np.bool_)
    for i in range(n_eq):   # the rigid struts' directions at x, as System.geometry
        a = ends[i, 0]
        b = ends[i, 1]
        for j in range(3):
            directions[i, j] = x[b, j] - x[a, j]
        size = np.sqrt(dot3(directions[i, 0], directions[i, 1], directions[i, 2], directions[i, 0],
                            directions[i, 1], directions[i, 2]))
        for j in range(3):
            directions[i, j] /= size
        nodes[i, 0] = row_nodes[i, 0]
        nodes[i, 1] = row_nodes[i, 1]
        warm[i] = True
    for r in range(cables.shape[0]):
        c = cables[r]
        i = n_eq + r
        for j in range(3):
            directions[i, j] = d[c, j] / length[c]
        nodes[i, 0] = row_nodes[n_eq + c, 0]
        nodes[i, 1] = row_nodes[n_eq + c, 1]
        warm[i] = snapping[c] or holding[c]
    n_free = free_nodes.shape[0]
    v_in = np.empty((n_free, 3))
    for i in range(n_free):
        for j in range(3):
            v_in[i, j] = v[free_nodes[i], j]
    (on, g_nodes, radii, height, mu, touch_tol, free_index, fixed_point_tol, slip_floor, max_iter, depth,
     restitution) = ground
    touching = np.zeros(g_nodes.shape[0], dtype=np.bool_)
    for i in range(g_nodes.shape[0]):
        touching[i] = on and x[g_nodes[i], 2] - radii[g_nodes[i]] - height <= touch_tol
    armed = g_nodes[touching]
    if armed.shape[0]:
        w = np.empty(armed.shape[0])
        for c in range(armed.shape[0]):
            vz = v[armed[c], 2]
            w[c] = -restitution * vz if vz * dt < -touch_tol else 0.0
        stick, normal, slip = memory
        ok, v_free, y, impulses = contact_solve(entry, settings, hessian, sqrt_mass, mass, v_in, nodes, directions,
                                                np.zeros(k), n_eq, warm, armed, free_index, w,
                                                np.ones(armed.shape[0], dtype=np.bool_), mu, stick, normal, slip,
                                                fixed_point_tol, slip_floor, max_iter, depth, feasibility_tol,
                                                velocity_floor)
        if ok and lands:
            for c in range(armed.shape[0]):
                for j in range(3):
                    contact[armed[c], j] += impulses[c, j]
    else:
        v_free, y, ok, _, _ = _solve_checked(entry, settings, hessian, sqrt_mass, mass, schur, nodes, directions, v_in,
                                             np.zeros(k), n_eq, warm, feasibility_tol, velocity_floor, not on)
    v_plus = np.zeros_like(v)
    for i in range(n_free):
        for j in range(3):
            v_plus[free_nodes[i], j] = v_free[i, j]
    kicked = np.zeros(nc)
    node = 0.0
    if not ok:
        return False, v_plus, kicked, node
    published = y
    if locked:
        binding, members, a_t, basis = locked_space(nodes, directions, n_free, n_eq, cables,
                                                    np.ones(cables.shape[0], dtype=np.bool_), y, load_basis,
                                                    load_cables, load_largest, refine, rank_tol, exact, weight,
                                                    shared, np.zeros(0, dtype=np.int64), np.zeros((0, 0)))
        if basis is None or basis.shape[1] > 1:
            return False, v_plus, kicked, node
        if basis.shape[1] == 1:
            fitted, out, node = fit_one(ddot, dgemv, wide, y, binding, basis, a_t, reference, members, 0.0, n_eq)
            if not fitted:
                return False, v_plus, kicked, node
            published = y.copy()
            b = 0
            for i in range(k):
                if binding[i]:
                    published[i] = out[b]
                    b += 1
    for r in range(cables.shape[0]):
        kicked[cables[r]] = published[n_eq + r]
    return True, v_plus, kicked, node


@njit(cache=True)
def step(x, v, f_ext, commanded, applied, most, dt, offsets, limit_tol, taut_tol, holding, hint, inv_mass, ends,
         n_eq, rigid_lengths, cables_move, row_nodes, free_nodes, cable_ends, min_event, newton_iter, entry,
         settings, hessian, sqrt_mass, mass, schur, feasibility_tol, velocity_floor, landing_tol, landing_iter,
         reel_force, locked, load_basis, load_cables, load_largest, refine, rank_tol, exact, weight, shared, ddot,
         dgemv, wide, reference, ground, memory, carried):
    """``InextensibleMethod._step_impl`` of a step that is one sub-step (no landing located inside it, a snap
    only where the step taken whole does not meet it: ``InextensibleMethod._whole``; an impact at its start
    allowed), without elastic struts or member contact rows, in one call: the motors' limits
    (:func:`motor_limits`), the impact test, the free motion from ``x``, ``v`` (N, 3) under ``f_ext``
    (N, 3) N (``inv_mass`` (N, 2) 1/kg, ``MassOperator.kernel_array``; with ``schur`` non-empty the rods' blocks
    apply), the snap search (:func:`first_snap`) and :func:`midpoint`.
    ``holding``, ``hint`` (nc,) bool: the cables known to hold and the QP's warm start; ``ground`` and
    ``memory`` as :func:`midpoint` takes them (``memory`` itself is not changed: the friction modes after
    the step are returned, for the caller to keep when it takes the step), ``carried`` too (the motors that
    pulled at their force are returned last).

    When the structure can lock (``locked``), the self-stress rule's fit runs here too (:func:`fit_one`
    with numpy's ``ddot``/``dgemv``, ``wide`` as there, the cables' ``reference`` tensions) if its self-stress is one
    dimensional and no cable would pull.

    Returns ``ok`` (False: the step has an event or a QP answer the Python path must handle; nothing else
    is meaningful), ``x``, ``v`` (N, 3) at the end, the cables that hold (nc,) bool, the rest lengths in
    effect (nc,) m, the taut thresholds (nc,) m, ``fitted`` (the step's impulses (nc,) N*s and slack
    flags (nc,) bool that follow are final, and the fit's dropped node impulse, N*s; else the caller
    fits), then :func:`midpoint`'s cable rows (nc,) bool, multipliers (k,) N*s, end geometry,
    self-stress space, ground impulses (N, 3) N*s and friction modes (as ``memory``)."""
    new_applied, reel, limits, floor, taut, reeling = motor_limits(commanded, applied, most, dt, offsets,
                                                                    limit_tol, taut_tol)
    nc = cable_ends.shape[0]
    d, length = cable_geometry(x, cable_ends)
    at_limit = np.empty(nc, dtype=np.bool_)
    maybe = False
    all_at = True
    for c in range(nc):
        at_limit[c] = length[c] >= floor[c] and cables_move[c]
        maybe |= at_limit[c] and not holding[c]
        all_at &= at_limit[c]
    ok = True
    snapping = np.zeros(nc, dtype=np.bool_)
    snaps = False
    if maybe and (v != 0.0).any():   # a cable at its limit that did not hold separating: an impact
        for c in range(nc):
            if at_limit[c] and not holding[c]:
                a = cable_ends[c, 0]
                b = cable_ends[c, 1]
                rate = dot3(v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2], d[c, 0] / length[c],
                            d[c, 1] / length[c], d[c, 2] / length[c])
                if rate * dt > limit_tol * limits[c]:
                    snapping[c] = True
                    snaps = True
    on, g_nodes, radii, height, _, touch_tol = ground[:6]
    # a node landing at the step's start: an impact with the ground's rows, as a snap is
    lands = on and landing(x, v, dt, g_nodes, radii, height, touch_tol) and (v != 0.0).any()
    modes = (memory[0].copy(), memory[1].copy(), memory[2].copy()) if on else memory   # the step's own until taken
    kicked = np.zeros(nc)   # the impact's published impulses
    kick_node = 0.0
    kick_contact = np.zeros_like(x)   # a landing's ground impulses
    if snaps or lands:
        ok, v, kicked, kick_node = impact(x, v, d, length, at_limit, snapping, holding, ends, n_eq, row_nodes,
                                          free_nodes, entry, settings, hessian, sqrt_mass, mass, schur, feasibility_tol,
                                          velocity_floor, locked, load_basis, load_cables, load_largest,
                                          refine, rank_tol, exact, weight, shared, ddot, dgemv, wide, reference, dt,
                                          ground, modes, lands, kick_contact)
    x_m = _drift(x, 0.5 * dt, v)
    v0 = np.empty_like(v)
    if schur[0].shape[0]:   # the rods' blocks: v + dt M^-1 f, M^-1 as MassOperator.solve applies it
        acc = _solve_mass(f_ext, inv_mass, ends, n_eq)
        for i in range(v.shape[0]):
            for j in range(3):
                v0[i, j] = v[i, j] + dt * acc[i, j]
    else:
        for i in range(v.shape[0]):
            scale = dt * inv_mass[i, 0]
            for j in range(3):
                v0[i, j] = v[i, j] + scale * f_ext[i, j]
    theta = 1.0
    slack = np.empty(nc, dtype=np.bool_)
    for c in range(nc):
        slack[c] = not at_limit[c] and cables_move[c]
    if ok and not all_at:
        theta = first_snap(d, limits, v, v0, dt, cable_ends, slack, newton_iter)
    if ok and on:
        theta = min(theta, first_impact(x, v, v0, dt, g_nodes, radii, height, touch_tol))
    # a snap located inside the step of a structure that can lock, without a ground: the step whole where every
    # crossing cable reaches its limit on its free path only by the path's curvature (its rate at the start would not
    # close its gap within the step), kept where the snap does not happen on the constrained path (checked after
    # it); else (a ground, a landing, a cable closing at its rate) the Python path's cut
    whole = min_event * dt < theta * dt < dt - min_event * dt
    ok = ok and (not whole or (locked and not on))
    if ok and whole:
        u = np.empty(3)
        um = np.empty(3)
        for c in range(nc):
            if (slack[c] and _crosses(d, limits, v, v0, dt, cable_ends, c, u, um)
                    and dt * dot3(d[c, 0], d[c, 1], d[c, 2], u[0], u[1], u[2]) >= (limits[c] - length[c]) * length[c]):
                ok = False
    all_limits = np.empty(n_eq + nc)
    all_limits[:n_eq] = rigid_lengths
    for c in range(nc):
        all_limits[n_eq + c] = limits[c] - (0.5 * dt) * reel[c] if reeling else limits[c]
    impulses = np.zeros(nc)
    if not ok:   # the caller's Python path
        return (False, x, v, holding, new_applied, taut, False, impulses, holding, 0.0, holding,
                np.zeros(0), d, length, np.zeros(0, dtype=np.bool_), load_cables[:0],
                np.zeros((3 * free_nodes.shape[0], 0)), None, np.zeros_like(x), memory, 0, carried)
    done, x_f, v_f, y, cables, _, _, d_f, length_f, binding, members, a_t, basis, contact, pulled = midpoint(
        x_m, v, v0, dt, ends, n_eq, all_limits, floor, cables_move, reel, hint, row_nodes, free_nodes, cable_ends,
        taut, entry, settings, hessian, sqrt_mass, mass, schur, feasibility_tol, velocity_floor, landing_tol,
        landing_iter, reel_force, limits, dt, inv_mass, locked, load_basis, load_cables, load_largest, refine,
        rank_tol, exact, weight, shared, ground, modes, carried)
    new_holding = np.zeros(nc, dtype=np.bool_)
    r = n_eq
    for c in range(nc):
        if cables[c]:
            impulses[c] = y[r]
            r += 1
        new_holding[c] = impulses[c] > 0 and at_limit[c]
    if whole:   # every cable crossing its limit on its free path ends the step short of it, pulling nothing
        u = np.empty(3)
        um = np.empty(3)
        for c in range(nc):
            if (slack[c] and _crosses(d, limits, v, v0, dt, cable_ends, c, u, um)
                    and not (impulses[c] == 0.0 and not pulled[c] and length_f[c] < floor[c])):
                done = False
    published = impulses
    fitted = True
    node = 0.0
    if locked and y.shape[0]:
        fitted = basis is not None and basis.shape[1] <= 1
        if fitted and basis.shape[1] == 1:
            fitted, out, node = fit_one(ddot, dgemv, wide, y, binding, basis, a_t, reference, members, dt, n_eq)
            published = np.zeros(nc)
            r = 0   # row
            b = 0   # binding row
            for c in range(-n_eq, nc):
                if c >= 0 and not cables[c]:
                    continue
                if binding[r]:
                    if c >= 0:
                        published[c] = out[b]
                    b += 1
                elif c >= 0:
                    published[c] = y[r]
                r += 1
    # the step's impulses as the Python path sums them (0.0 + the impact's + published: a -0.0 becomes 0.0) and
    # its flags; a step with an impact whose sub-step the caller must fit is the Python path's (the caller's fit
    # publishes the sub-step's impulses alone)
    summed = np.zeros(nc)
    slack = np.empty(nc, dtype=np.bool_)
    for c in range(nc):
        if snaps or lands:
            summed[c] += kicked[c]
        summed[c] += published[c]
        slack[c] = length_f[c] < taut[c] and not summed[c] > 0
    ok = ok and not ((snaps or lands) and not fitted)
    node = max(node, kick_node)
    if lands:   # the landing's ground impulses first, as the Python path sums them
        kick_contact += contact
        contact = kick_contact
    stalls = 0
    for c in range(nc):
        if pulled[c]:
            # a motor at its force reeled in only what its cable gave: it stands where the cable ends, half a
            # step's reel ahead (InextensibleMethod._step_impl)
            ahead = length_f[c] - offsets[c] + (0.5 * dt) * reel[c]
            new_applied[c] = max(new_applied[c], min(applied[c], ahead))
            stalls += 1
    return (ok and done, x_f, v_f, new_holding, new_applied, taut, fitted, summed, slack, node, cables, y, d_f,
            length_f, binding, members, a_t, basis, contact, modes, stalls, pulled)


@njit(cache=True)
def steps(first, n_steps, every, x, v, applied, holding, hint, residual, total, out_x, out_v, out_impulses, out_slack,
          f_ext, commanded, most, dt, offsets, limit_tol, taut_tol, inv_mass, ends, n_eq, rigid_lengths,
          cables_move, row_nodes, free_nodes, cable_ends, min_event, newton_iter, entry, settings, hessian,
          sqrt_mass, mass, schur, feasibility_tol, velocity_floor, landing_tol, landing_iter, reel_force, locked,
          load_basis, load_cables, load_largest, refine, rank_tol, exact, weight, shared, ddot, dgemv, wide,
          reference, ground, memory, contact_total, out_contact, rest_seq, ext_seq, gravity, ext, stall_count,
          carried):
    """Steps ``first``, ``first + 1``, ... of ``n_steps`` from ``x``, ``v`` (N, 3), the inputs held, each
    :func:`step` from the cables known to hold ``holding`` and the warm start ``hint`` (nc,) bool (after a
    step both are the cables that held, as in ``InextensibleMethod._step_impl``), until one needs the
    Python path (an event, a QP answer it must handle, the rule's numpy fit). Sums the impulses into
    ``total`` (nc,) and keeps steps ``every``, ``2 every``, ... and the last in the outputs
    (``_elastic_kernels.keep``: (K, N, 3, 1), (K, nc, 1)); on a ground (``ground[0]``) its impulses are
    summed into ``contact_total`` (N, 3) and kept likewise in ``out_contact`` (K, N, 3), and the friction
    ``memory`` moves on in place with the steps taken.
    Returns the first step not taken (``n_steps``: all), the positions and velocities before it, the
    rest lengths in effect, ``holding`` and ``hint`` then and the rule's largest dropped node impulse, N*s.

    ``rest_seq`` (n_steps, nc), ``ext_seq`` (n_steps, N, 3): each step's commanded rest lengths and external
    forces (a command schedule evaluated ahead; empty: ``commanded`` and the force ``f_ext`` held), the
    force being ``gravity`` (N, 3) N plus the step's; ``commanded`` and ``ext`` are then the inputs in effect
    before step ``first``. A step whose inputs differ from the last step's starts as after
    ``InextensibleMethod.invalidate`` (no cable known to hold, the warm start kept): the very arithmetic of
    setting them before stepping it, as ``Simulator`` does. The cables that hold are returned after that.
    ``stall_count`` (1,) int: the motor steps at their force (``InextensibleMethod.stalls``) are added to it;
    ``carried`` (nc,) bool: the motors at their force in the last step, updated in place with each step taken."""
    n = x.shape[0]
    nc = cable_ends.shape[0]
    scheduled = rest_seq.shape[0] > 0
    for i in range(first, n_steps):
        if scheduled:
            changed = False
            for c in range(nc):
                changed |= rest_seq[i, c] != commanded[c]
            for p in range(n):
                for j in range(3):
                    changed |= ext_seq[i, p, j] != ext[p, j]
            commanded = rest_seq[i]
            ext = ext_seq[i]
            f_ext = gravity + ext
            if changed:
                holding = np.zeros(nc, dtype=np.bool_)
        (ok, x_f, v_f, new_holding, new_applied, _, fitted, impulses, slack, node, _, _, _, _, _, _, _,
         _, contact, modes, stalls, pulled) = step(
            x, v, f_ext, commanded, applied, most, dt, offsets, limit_tol, taut_tol, holding, hint, inv_mass, ends,
            n_eq, rigid_lengths, cables_move, row_nodes, free_nodes, cable_ends, min_event, newton_iter, entry,
            settings, hessian, sqrt_mass, mass, schur, feasibility_tol, velocity_floor, landing_tol, landing_iter,
            reel_force, locked, load_basis, load_cables, load_largest, refine, rank_tol, exact, weight, shared, ddot,
            dgemv, wide, reference, ground, memory, carried)
        if not (ok and fitted):
            return i, x, v, applied, holding, hint, residual
        carried[:] = pulled
        x, v, applied, holding, hint = x_f, v_f, new_applied, new_holding, new_holding
        stall_count[0] += stalls
        residual = max(residual, node)
        for c in range(nc):
            total[c] += impulses[c]
        kept = (i + 1) % every == 0 or i + 1 == n_steps
        if ground[0]:
            memory[0][:] = modes[0]
            memory[1][:] = modes[1]
            memory[2][:] = modes[2]
            for p in range(n):
                for j in range(3):
                    contact_total[p, j] += contact[p, j]
                    if kept:
                        out_contact[i // every, p, j] = contact_total[p, j]
                        contact_total[p, j] = 0.0
        if kept:
            keep(x.reshape((n, 3, 1)), v.reshape((n, 3, 1)), 0, total, slack, i // every, 0, out_x, out_v,
                 out_impulses, out_slack)
    return n_steps, x, v, applied, holding, hint, residual


@njit(cache=True, parallel=True)
def copies_steps(n_steps, x, v, applied, holding, hint, residual, total, out_x, out_v, out_impulses, out_slack, f_ext,
                 commanded, most, dt, offsets, limit_tol, taut_tol, inv_mass, ends, n_eq, rigid_lengths, cables_move,
                 row_nodes, free_nodes, cable_ends, min_event, newton_iter, entry, settings, hessian, sqrt_mass, mass,
                 schur, feasibility_tol, velocity_floor, landing_tol, landing_iter, reel_force, locked, load_basis,
                 load_cables, load_largest, refine, rank_tol, exact, weight, shared, ddot, dgemv, wide, reference,
                 ground, stick, normal, slip, contact_total, out_contact, done, stall_count, carried, cycling):
    """:func:`steps` of B copies of one structure on every core (``prange`` over the copies), each in arrays of
    its own: the leading axis of ``x``, ``v`` (B, N, 3), the carry ``applied``, ``holding``, ``hint`` (B, nc),
    ``residual`` (B,), the inputs ``f_ext`` (B, N, 3), ``commanded`` and ``offsets`` (B, nc), the friction
    memory ``stick``, ``normal`` (B, N), ``slip`` (B, N, 2), the sums ``total`` (B, nc), ``contact_total``
    (B, N, 3) and the outputs (``out_x`` (B, K, N, 3, 1) ..., every step kept); the tables after ``offsets`` are
    the structure's, shared (each copy steps with copies of them and of its rows of the batch's arrays). A copy's
    steps are the very arithmetic of its own :func:`steps` call from step 0;
    each stops where its :func:`steps` stops (a step for the Python path): ``done`` (B,) gets that step, the
    carry arrays the copy's carry before it; ``stall_count`` (B,) int gets each copy's motor steps at their
    force; ``carried`` (B, nc) bool: each copy's motors at their force, as :func:`steps` keeps them. A copy whose
    last step's friction modes cycled (``cycling`` (B,) bool: ``InextensibleMethod._cycling``) takes no step here
    (``done`` 0): its next step is the Python path's."""
    for b in prange(x.shape[0]):
        if cycling[b]:
            done[b] = 0
            continue
        # each copy steps in arrays of its own, its tables too (copies, the same numbers), its outputs written back
        # after: the steps count references to the arrays they take, and a count the threads share (a table's, or
        # the batch array's behind a copy's view of it) would move between their cores at every step. With shared
        # arrays two threads stepped 256 thrown icosahedra 1.2-1.6 times as fast as one, with copies 1.4-2.3 times
        # (eight runs on a two-core machine that its host shares: bench_batch.py --inextensible).
        no_rest = np.empty((0, commanded.shape[1]))   # the inputs held: no schedule
        no_ext = np.empty((0, x.shape[1], 3))
        own_schur = (schur[0].copy(), schur[1].copy(), schur[2].copy())
        own_ground = (ground[0], ground[1].copy(), ground[2].copy(), ground[3], ground[4], ground[5], ground[6].copy(),
                      ground[7], ground[8], ground[9], ground[10], ground[11])
        own_x, own_v = out_x[b].copy(), out_v[b].copy()
        own_impulses, own_slack, own_contact = out_impulses[b].copy(), out_slack[b].copy(), out_contact[b].copy()
        own_f = f_ext[b].copy()
        own_stalls = np.zeros(1, dtype=stall_count.dtype)
        own_total = total[b].copy()
        own_contact_total = contact_total[b].copy()
        own_stick, own_normal, own_slip = stick[b].copy(), normal[b].copy(), slip[b].copy()
        own_carried = carried[b].copy()
        i, xb, vb, ab, hb, hib, rb = steps(
            0, n_steps, 1, x[b].copy(), v[b].copy(), applied[b].copy(), holding[b].copy(), hint[b].copy(), residual[b],
            own_total, own_x, own_v, own_impulses, own_slack, own_f, commanded[b].copy(), most, dt, offsets[b].copy(),
            limit_tol, taut_tol, inv_mass.copy(), ends.copy(), n_eq, rigid_lengths.copy(), cables_move.copy(),
            row_nodes.copy(), free_nodes.copy(), cable_ends.copy(), min_event, newton_iter, entry, settings.copy(),
            hessian.copy(), sqrt_mass.copy(), mass.copy(), own_schur, feasibility_tol, velocity_floor, landing_tol,
            landing_iter, reel_force, locked, load_basis.copy(), load_cables.copy(), load_largest, refine, rank_tol,
            exact, weight.copy(), shared, ddot, dgemv, wide, reference.copy(), own_ground,
            (own_stick, own_normal, own_slip), own_contact_total, own_contact, no_rest, no_ext, own_f, own_f,
            own_stalls, own_carried)
        done[b] = i
        x[b] = xb
        v[b] = vb
        applied[b] = ab
        holding[b] = hb
        hint[b] = hib
        residual[b] = rb
        out_x[b] = own_x
        out_v[b] = own_v
        out_impulses[b] = own_impulses
        out_slack[b] = own_slack
        out_contact[b] = own_contact
        total[b] = own_total
        contact_total[b] = own_contact_total
        stick[b] = own_stick
        normal[b] = own_normal
        slip[b] = own_slip
        stall_count[b] = own_stalls[0]
        carried[b] = own_carried
