"""The friction mode fixed point of ``friction.py`` compiled, for the ground's contacts with DAQP (issue 28):
:meth:`.friction.FrictionalSolver._modes` step for step — the same initial modes, the same one mode change
per QP, the same Anderson acceleration — with each QP built and solved in compiled code
(``_daqp_kernels.solve_rows``: DAQP's own C function, the answer of ``daqp.solve`` to the bit) and checked
by ``_qp_kernels.answer_residuals``, so no Python runs per iteration. ``FrictionalSolver._modes`` stays the
reference (``compiled = False``); ``test/test_throws.py`` holds the two to each other.

The kernel answers only what it can answer exactly as the reference does: a QP that fails or is refused
(infeasible even with its member rows' targets at the velocity level, an inaccurate answer that the backend
would solve again at unit scale), modes that do not
settle in ``MAX_MODE_ITER`` QPs, or an answer that misses the Coulomb check return ``ok = False``, and
the reference then takes the whole solve from its start (its own QPs, its fallbacks, its errors).

The ground's geometry of ``friction.ContactSet`` (:func:`first_impact`, :func:`landing`, :func:`arm_step`,
:func:`missed`) and the solve of a sub-step with its armed contacts (:func:`contact_solve`) are here too, for
the inextensible method's step kernel on a ground (``_inextensible_kernels.step``), in the same arithmetic.
The ground's nodes are ``nodes`` (system indices of the free nodes), each with its radius in ``radii`` (N,)
m, the plane at ``height`` m.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..qp._daqp_kernels import solve_pairs, solve_rows
from ..qp._qp_kernels import answer_residuals

__all__ = ["sticking_rows", "ground_modes", "first_impact", "landing", "arm_step", "missed", "contact_solve"]

_INFEASIBLE = -1   # DAQP's exit flag for infeasible rows (DaqpSolver._STATUS)


@njit(cache=True)
def _rows(row_nodes, row_dirs, row_targets, warm, warm_given, fi, w, stick, loaded):
    """The rows of one QP of the mode fixed point (``FrictionalSolver._with_contacts``, ground contacts):
    the method's rows, a normal row ``-v_z <= -w`` per contact and rows ``x, y, -x, -y`` per sticking
    contact; returns their nodes, directions, targets, the rows to start active (the method's ``warm``,
    the ``loaded`` contacts; none unless ``warm_given``) and their count."""
    n_rows, k = row_targets.shape[0], fi.shape[0]
    s = np.flatnonzero(stick)
    total = n_rows + k + 4 * s.shape[0]
    nodes = np.full((total, 2), -1, dtype=row_nodes.dtype)
    dirs = np.zeros((total, 3))
    targets = np.zeros(total)
    start = np.zeros(total, dtype=np.bool_)
    nodes[:n_rows] = row_nodes
    dirs[:n_rows] = row_dirs
    targets[:n_rows] = row_targets
    start[:n_rows] = warm
    for c in range(k):
        nodes[n_rows + c, 1] = fi[c]
        dirs[n_rows + c, 2] = -1.0
        targets[n_rows + c] = -w[c]
        start[n_rows + c] = loaded[c] and warm_given
    for j in range(s.shape[0]):
        for side in range(4):
            i = n_rows + k + 4 * j + side
            nodes[i, 1] = fi[s[j]]
            dirs[i, side % 2] = 1.0 if side < 2 else -1.0
    return nodes, dirs, targets, start, total


@njit(cache=True)
def sticking_rows(start, first, n_stick):
    """The working set tried before DAQP where contacts stick (``_qp_kernels.sticking_answer``): the rows
    ``start`` (k,) bool to start active (the method's warm rows, the loaded contacts' normal rows) and each
    sticking contact's ``t1`` and ``t2`` rows, its rows ``t1, t2, -t1, -t2`` from row ``first`` on (four per
    contact, ``n_stick`` contacts: :func:`_rows`' layout) paired with their opposites. Returns the set (k,)
    bool and each row's opposite (k,) int (-1: none)."""
    guess = start.copy()
    opposite = np.full(start.shape[0], -1, dtype=np.int64)
    for j in range(n_stick):
        base = first + 4 * j
        for side in range(2):
            guess[base + side] = True
            opposite[base + side] = base + side + 2
            opposite[base + side + 2] = base + side
    return guess, opposite


@njit(cache=True)
def ground_modes(entry, settings, hessian, sqrt_mass, mass, v0, row_nodes, row_dirs, row_targets, n_eq, warm,
                 warm_given, fi, w, touching, mu, old_stick, old_normal, old_slip, fixed_point_tol, slip_floor,
                 max_iter, depth, feasibility_tol, velocity_floor):
    """The mode fixed point for ground contacts (``FrictionalSolver._modes``): free velocities ``v0``
    (n_free, 3) m/s, the method's member rows (``row_nodes`` (r, 2), ``row_dirs`` (r, 3), ``row_targets``
    (r,) m/s, ``n_eq`` equalities, ``warm`` (r,) bool if ``warm_given``), the armed contacts' free nodes
    ``fi`` (k,), normal targets ``w`` (k,) m/s, ``touching`` (k,) bool, Coulomb coefficients ``mu`` (k,) and their last
    solve's modes, ``y_n`` (N*s) and slip directions ((k,), (k,), (k, 2)); DAQP's C call and settings as
    ``DaqpSolver.c_call``. Returns ``ok``, ``v`` (n_free, 3), the rows' multipliers (r,), the contacts'
    impulses (k, 3) N*s (friction x, y; normal), the modes to remember (k,) bool, the slip directions
    (k, 2), the QPs taken (``max_iter + 1``: the modes did not settle in ``max_iter``, every QP answered) and
    the last QP's iterate, ``FrictionalSolver._guess``: its multipliers of the member and normal rows
    (r + k,) N*s and the friction (k, 2) N*s (the semismooth Newton method's start where the modes cycle)."""
    n_free = v0.shape[0]
    n_rows, k = row_targets.shape[0], fi.shape[0]
    node_mass = mass.reshape((n_free, 3))[:, 0]
    meff = node_mass[fi]
    scale_v = max(np.abs(v0).max(), np.abs(w).max())   # k >= 1: the kernel runs for armed contacts
    slip_tol = slip_floor + fixed_point_tol * scale_v
    stick = np.zeros(k, dtype=np.bool_)
    slip = np.zeros((k, 2))
    y_hat = np.zeros(k)
    impulse_u0 = 0.0
    for c in range(k):
        u = v0[fi[c]]
        impulse_u0 = max(impulse_u0, meff[c] * max(abs(u[0]), abs(u[1]), abs(u[2])))
        speed0 = np.sqrt(u[0] * u[0] + u[1] * u[1])
        if old_normal[c] > 0:
            stick[c] = old_stick[c]
            slip[c] = old_slip[c]
            y_hat[c] = old_normal[c]
        else:
            stick[c] = touching[c] and speed0 <= slip_tol
            slip[c, 0] = u[0] / max(speed0, 1e-300)
            slip[c, 1] = u[1] / max(speed0, 1e-300)
        stick[c] = stick[c] and mu[c] > 0
    phi = np.empty((k, 2))
    for c in range(k):
        phi[c] = mu[c] * y_hat[c] * slip[c]
    hist_x = np.zeros((depth + 1, 2 * k))
    hist_g = np.zeros((depth + 1, 2 * k))
    n_hist = 0
    v = v0.copy()
    y = np.zeros(n_rows)
    impulses = np.zeros((k, 3))
    remember = np.zeros(k, dtype=np.bool_)
    guess_y = np.zeros(n_rows + k)
    guess_f = np.zeros((k, 2))
    for it in range(1, max_iter + 1):
        s = np.flatnonzero(stick)
        sliding = ~stick
        friction = np.zeros((k, 3))
        for c in range(k):
            if sliding[c]:
                friction[c, 0] = -phi[c, 0]
                friction[c, 1] = -phi[c, 1]
        nodes, dirs, targets, start, total = _rows(row_nodes, row_dirs, row_targets, warm, warm_given, fi, w, stick,
                                                   y_hat > 0)
        v0c = v0.copy()
        for c in range(k):
            for j in range(3):
                v0c[fi[c], j] += friction[c, j] / meff[c]
        guessed = False
        if warm_given and s.shape[0]:
            # the contacts that stick held by their t and -t rows as sign-free pairs (FrictionalSolver._qp)
            guess, opposite = sticking_rows(start, n_rows + k, s.shape[0])
            guessed, flat, y_all = solve_pairs(settings, mass, nodes, dirs, v0c, targets, n_eq, guess,
                                               opposite)
        if guessed:
            flag = 1
        else:
            flat, y_all, flag, _, _, _ = solve_rows(entry, settings, hessian, sqrt_mass, mass, nodes, dirs, n_free,
                                                    v0c.reshape(-1), targets, n_eq, start, 1.0, False)
        if flag == _INFEASIBLE and s.shape[0]:
            # sticking rows with drift-correcting targets no velocity meets: for this QP the member rows'
            # targets yield to the pure velocity level (FrictionalSolver._qp, friction._velocity_level)
            for i in range(n_rows):
                targets[i] = 0.0 if i < n_eq else max(targets[i], 0.0)
            flat, y_all, flag, _, _, _ = solve_rows(entry, settings, hessian, sqrt_mass, mass, nodes, dirs, n_free,
                                                    v0c.reshape(-1), targets, n_eq, start, 1.0, False)
        if flag < 1:
            return False, v, y, impulses, remember, slip, it, guess_y, guess_f
        v = flat.reshape((n_free, 3))
        # QPSolver._check, as the compiled backend does it
        for i in range(total):
            if not np.isfinite(y_all[i]):
                return False, v, y, impulses, remember, slip, it, guess_y, guess_f
        for i in range(n_free):
            for j in range(3):
                if not np.isfinite(v[i, j]):
                    return False, v, y, impulses, remember, slip, it, guess_y, guess_f
        scale, viol, impulse, stationarity, smallest, short = answer_residuals(
            v, y_all, v0c, nodes, dirs, targets, n_eq, mass, feasibility_tol)
        tol_v = feasibility_tol * scale + velocity_floor
        if (viol > tol_v or stationarity > feasibility_tol * impulse or smallest < -feasibility_tol * impulse
                or short > tol_v):
            return False, v, y, impulses, remember, slip, it, guess_y, guess_f
        yn = y_all[n_rows:n_rows + k].copy()
        stick_f = np.empty((s.shape[0], 2))
        for j in range(s.shape[0]):
            base = n_rows + k + 4 * j
            stick_f[j, 0] = -(y_all[base] - y_all[base + 2])
            stick_f[j, 1] = -(y_all[base + 1] - y_all[base + 3])
        impulse_scale = max(impulse_u0, 1e-300)
        for i in range(total):
            impulse_scale = max(impulse_scale, abs(y_all[i]))
        tol = fixed_point_tol * impulse_scale
        for j in range(s.shape[0]):
            friction[s[j], 0] = stick_f[j, 0]
            friction[s[j], 1] = stick_f[j, 1]
        guess_y = y_all[:n_rows + k].copy()
        guess_f = friction[:, :2].copy()
        vmax = np.abs(v).max()
        speed = np.empty(k)
        vt = np.empty((k, 2))
        for c in range(k):
            vt[c, 0] = v[fi[c], 0]
            vt[c, 1] = v[fi[c], 1]
            speed[c] = np.sqrt(vt[c, 0] * vt[c, 0] + vt[c, 1] * vt[c, 1])
        slip_tol = slip_floor + fixed_point_tol * max(scale_v, vmax)
        y_hat = yn.copy()
        changed = False
        # sticking contacts outside the cone: the worst slides (all tied with it), opposite to its friction
        f_mag = np.empty(s.shape[0])
        excess = np.empty(s.shape[0])
        worst = 0.0
        for j in range(s.shape[0]):
            f_mag[j] = np.sqrt(stick_f[j, 0] * stick_f[j, 0] + stick_f[j, 1] * stick_f[j, 1])
            excess[j] = f_mag[j] - mu[s[j]] * yn[s[j]]
            worst = max(worst, excess[j])
        for j in range(s.shape[0]):
            if excess[j] > tol and excess[j] == worst:
                changed = True
                c = s[j]
                slip[c, 0] = -stick_f[j, 0] / f_mag[j]
                slip[c, 1] = -stick_f[j, 1] / f_mag[j]
                phi[c, 0] = (mu[c] * yn[c]) * slip[c, 0]
                phi[c, 1] = (mu[c] * yn[c]) * slip[c, 1]
                stick[c] = False
        # sliding contacts that carry load and turned back: the one turned back most sticks
        stops = np.zeros(k, dtype=np.bool_)
        if not changed:
            best, best_along = -1, 0.0
            for c in range(k):
                if sliding[c]:
                    along = vt[c, 0] * slip[c, 0] + vt[c, 1] * slip[c, 1]
                    if mu[c] > 0 and yn[c] > tol and speed[c] > slip_tol and along < 0:
                        if best < 0 or along < best_along:
                            best, best_along = c, along
            if best >= 0:
                for c in range(k):
                    if sliding[c]:
                        along = vt[c, 0] * slip[c, 0] + vt[c, 1] * slip[c, 1]
                        stops[c] = (mu[c] > 0 and yn[c] > tol and speed[c] > slip_tol and along < 0
                                    and along == best_along)
                changed = True
                for c in range(k):
                    if stops[c]:
                        stick[c] = True
        drift = 0.0
        new_slip = slip.copy()
        target = np.zeros((k, 2))
        for c in range(k):
            if sliding[c] and not stops[c]:
                if speed[c] > slip_tol:
                    new_slip[c, 0] = vt[c, 0] / max(speed[c], 1e-300)
                    new_slip[c, 1] = vt[c, 1] / max(speed[c], 1e-300)
                target[c, 0] = (mu[c] * yn[c]) * new_slip[c, 0]
                target[c, 1] = (mu[c] * yn[c]) * new_slip[c, 1]
                drift = max(drift, abs(target[c, 0] - phi[c, 0]), abs(target[c, 1] - phi[c, 1]))
        if not changed and drift <= tol:
            # the Coulomb law in its projection form (FrictionalSolver._verify)
            for c in range(k):
                t0 = friction[c, 0] - meff[c] * vt[c, 0]
                t1 = friction[c, 1] - meff[c] * vt[c, 1]
                size = np.sqrt(t0 * t0 + t1 * t1)
                shrink = min(1.0, mu[c] * yn[c] / max(size, 1e-300))
                r0, r1 = friction[c, 0] - t0 * shrink, friction[c, 1] - t1 * shrink
                f_mag = np.sqrt(friction[c, 0] * friction[c, 0] + friction[c, 1] * friction[c, 1])
                if np.sqrt(r0 * r0 + r1 * r1) > 2.0 * tol or not f_mag <= mu[c] * yn[c] + 2.0 * tol:
                    return False, v, y, impulses, remember, slip, it, guess_y, guess_f
            for c in range(k):
                remember[c] = stick[c] or speed[c] <= slip_tol
                impulses[c, 0] = friction[c, 0]
                impulses[c, 1] = friction[c, 1]
                impulses[c, 2] = yn[c]
            return True, v, y_all[:n_rows].copy(), impulses, remember, slip, it, guess_y, guess_f
        for c in range(k):
            if sliding[c] and not stops[c]:
                slip[c] = new_slip[c]
        if changed:
            n_hist = 0
            for c in range(k):
                if sliding[c] and not stops[c]:
                    phi[c] = target[c]
            continue
        # Anderson acceleration of phi -> G(phi) over the moving contacts (the same set since the last change)
        moving = np.flatnonzero(sliding)
        m = 2 * moving.shape[0]
        if n_hist == depth + 1:
            for h in range(depth):
                hist_x[h] = hist_x[h + 1]
                hist_g[h] = hist_g[h + 1]
            n_hist = depth
        for j in range(moving.shape[0]):
            c = moving[j]
            hist_x[n_hist, 2 * j] = phi[c, 0]
            hist_x[n_hist, 2 * j + 1] = phi[c, 1]
            hist_g[n_hist, 2 * j] = target[c, 0]
            hist_g[n_hist, 2 * j + 1] = target[c, 1]
            phi[c] = target[c]
        n_hist += 1
        if n_hist > 1:
            f = hist_g[:n_hist, :m] - hist_x[:n_hist, :m]
            df = f[1:] - f[:-1]
            dg = hist_g[1:n_hist, :m] - hist_g[:n_hist - 1, :m]
            # numpy's default cut-off for small singular values (rcond=None), which numba does not take
            cutoff = 2.220446049250313e-16 * max(m, n_hist - 1)
            gamma = np.linalg.lstsq(np.ascontiguousarray(df.T), f[n_hist - 1].copy(), rcond=cutoff)[0]
            accelerated = hist_g[n_hist - 1, :m] - gamma @ dg
            for j in range(moving.shape[0]):
                phi[moving[j], 0] = accelerated[2 * j]
                phi[moving[j], 1] = accelerated[2 * j + 1]
    return False, v, y, impulses, remember, slip, max_iter + 1, guess_y, guess_f


@njit(cache=True)
def first_impact(x, v, v0, tau, nodes, radii, height, touch_tol):
    """``ContactSet.first_impact`` for the ground alone: the fraction of the sub-step (0, 1] at which the first
    node above the ground reaches it on its free path (1.0 if none does)."""
    first = np.inf
    for p in nodes:
        g = x[p, 2] - radii[p] - height
        vz = v[p, 2]
        az = (v0[p, 2] - v[p, 2]) / tau
        end = g + tau * vz + 0.5 * tau * tau * az
        if g > touch_tol and end < 0.0:
            disc = np.sqrt(max(vz * vz - 2.0 * az * g, 0.0))
            first = min(first, 2.0 * g / (-vz + disc))
    if first == np.inf:
        return 1.0
    return min(max(first / tau, 0.0), 1.0)


@njit(cache=True)
def landing(x, v, dt, nodes, radii, height, touch_tol):
    """Whether ``ContactSet.arm_impact`` finds an impact at ``x``: a node touching the ground and moving into
    it by more than ``touch_tol`` per step."""
    for p in nodes:
        if x[p, 2] - radii[p] - height <= touch_tol and v[p, 2] * dt < -touch_tol:
            return True
    return False


@njit(cache=True)
def arm_step(x_m, v, v0, half, nodes, radii, height, touch_tol, v_f):
    """``ContactSet.arm_step`` for the ground alone: the armed nodes (k,) (system indices), their normal
    targets (k,) m/s and whether each touches the ground (k,) bool; judged on an answer ``v_f`` (N, 3) too
    unless it is empty (a re-arm after :func:`missed`)."""
    armed = np.zeros(nodes.shape[0], dtype=np.bool_)
    answered = v_f.shape[0] > 0
    for i in range(nodes.shape[0]):
        p = nodes[i]
        g = x_m[p, 2] - radii[p] - height
        reach = g - half * abs(v0[p, 2])
        if answered:
            reach = min(reach, g + half * v_f[p, 2])
        armed[i] = reach <= touch_tol
    which = nodes[armed]
    k = which.shape[0]
    w = np.empty(k)
    touching = np.empty(k, dtype=np.bool_)
    for c in range(k):
        p = which[c]
        g = x_m[p, 2] - radii[p] - height
        w[c] = min(-g / half, -v[p, 2])
        touching[c] = g <= touch_tol
    return which, w, touching


@njit(cache=True)
def missed(x_m, v_f, half, nodes, armed, radii, height, touch_tol):
    """``ContactSet.missed``: whether the answer ``v_f`` (N, 3) carries a node that is not among the ``armed``
    ones (system indices) below the ground by the sub-step's end."""
    for p in nodes:
        if x_m[p, 2] - radii[p] - height + half * v_f[p, 2] < -touch_tol and not (armed == p).any():
            return True
    return False


@njit(cache=True)
def contact_solve(entry, settings, hessian, sqrt_mass, mass, v0, row_nodes, row_dirs, row_targets, n_eq, warm,
                  armed, free_index, w, touching, mu, stick, normal, slip, fixed_point_tol, slip_floor, max_iter,
                  depth, feasibility_tol, velocity_floor):
    """``FrictionalSolver.solve`` through its compiled modes (:func:`ground_modes`) for the ``armed`` ground
    nodes (k >= 1, system indices; ``free_index`` (N,) their free-node index) with targets ``w`` and
    ``touching`` (k,): recalls each node's mode, ``y_n`` and slip direction from ``stick``, ``normal``,
    ``slip`` ((N,), (N,), (N, 2)) and, answered, remembers the new ones there (``FrictionalSolver._remember``);
    modes that cycle are solved again with the member rows' targets at the velocity level, as there.
    Returns ``ok`` (False: the reference must take the solve; the memory is then unchanged), ``v``
    (n_free, 3), the rows' multipliers and the contacts' impulses (k, 3) N*s."""
    k = armed.shape[0]
    fi = np.empty(k, dtype=np.int64)
    old_stick = np.empty(k, dtype=np.bool_)
    old_normal = np.empty(k)
    old_slip = np.empty((k, 2))
    for c in range(k):
        p = armed[c]
        fi[c] = free_index[p]
        old_stick[c] = stick[p]
        old_normal[c] = normal[p]
        old_slip[c] = slip[p]
    ok, v, y, impulses, remember, new_slip, taken, _, _ = ground_modes(
        entry, settings, hessian, sqrt_mass, mass, v0, row_nodes, row_dirs, row_targets, n_eq, warm, True, fi, w,
        touching, np.full(k, mu), old_stick, old_normal, old_slip, fixed_point_tol, slip_floor, max_iter, depth,
        feasibility_tol, velocity_floor)
    if not ok and taken > max_iter:
        # the modes cycled (the reference's own fixed point cycles the same way): once more with the member rows'
        # targets at the pure velocity level, as FrictionalSolver.solve does (friction._velocity_level)
        level = row_targets.copy()
        for i in range(level.shape[0]):
            level[i] = 0.0 if i < n_eq else max(level[i], 0.0)
        ok, v, y, impulses, remember, new_slip, _, _, _ = ground_modes(
            entry, settings, hessian, sqrt_mass, mass, v0, row_nodes, row_dirs, level, n_eq, warm, True, fi, w,
            touching, np.full(k, mu), old_stick, old_normal, old_slip, fixed_point_tol, slip_floor, max_iter, depth,
            feasibility_tol, velocity_floor)
    if ok:
        for c in range(k):
            p = armed[c]
            stick[p] = remember[c]
            normal[p] = impulses[c, 2]
            slip[p] = new_slip[c]
    return ok, v, y, impulses
