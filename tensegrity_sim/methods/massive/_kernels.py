"""Compiled step of the massive method: the same arithmetic as :class:`.method.MassiveMethod` (the plain numpy
reference, which tests require this to match to 1e-12), with numba.

A batch of one (``Simulator``'s; ``BatchSimulator`` steps one simulator per copy for this method). Shapes: ``N``
nodes, ``m`` members (struts first), ``nc`` cables. The system arrays are those of the elastic kernels
(``elastic/_kernels.model_arrays``: ``ends``, ``stiffness``, ``floor``, ``strut_rest``, ``damping``,
``inv_mass`` (N, 2), ``gravity_force``, ``rigid_members``: none, the method takes no rigid strut yet) and
``plates`` (nc,) kg. A step's record at a configuration (``_Forces`` of the
reference) is the tuple ``(acc (N, 3), tension (nc,), dirs (m, 3), slack (nc,) bool, elong (nc,), rates (nc,),
held (nc,) bool)``; a workspace is ``(x (N, 3), v (N, 3)) + record``, stepped in place.

The structure's inverse mass is applied by :func:`inverse_mass` only (``_mass_kernels.solve_forces``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..elastic._composition_kernels import _first_switch, newton_in_bracket
from .._mass_kernels import solve_forces
from ..qp._qp_kernels import cho_solve, cholesky
from ..elastic.composition import _FLOW_ITER, LOCATE_TOL, MAX_SWITCHES

__all__ = ["inverse_mass", "forces", "massive_step", "massive_steps", "plate_impact"]

_PIVOTS = 64   # principal pivots of the snap's complementarity problem at most (a few in practice)


@njit(cache=True, error_model="numpy")
def inverse_mass(inv_mass, ends, rigid_members, f, out):
    """``out = M^-1 f`` for node vectors ``f`` (N, 3): the one place the kernels apply the structure's inverse
    mass (``_mass_kernels.solve_forces``, ``inv_mass`` (N, 2) its kernel form; fixed nodes: 0)."""
    out[:] = f
    solve_forces(out.reshape((out.shape[0], 3, 1)), inv_mass, ends, rigid_members, 0)


@njit(cache=True, error_model="numpy")
def _solve_spd(a, b):
    """``b`` (n,) overwritten by ``a^-1 b`` for a symmetric positive definite ``a`` (n, n), overwritten by its
    Cholesky factor (the QP kernels' ``cholesky``/``cho_solve``)."""
    cholesky(a, 0.0)
    cho_solve(a, b)


@njit(cache=True, error_model="numpy")
def _subtract_columns(coef, count, mb, out):
    """``out -= sum_k coef[k] mb[k]`` over the first ``count`` node vectors ``mb`` (count, N, 3)."""
    for i in range(out.shape[0]):
        for j in range(3):
            s = 0.0
            for k in range(count):
                s += coef[k] * mb[k, i, j]
            out[i, j] -= s


@njit(cache=True, error_model="numpy")
def _delassus(cables, count, dirs, n_struts, ends, inv_mass, rigid_members, plates, g, mb):
    """``G = B M^-1 B^T + diag(1/m_c)`` into ``g[:count, :count]`` over ``cables[:count]`` and ``M^-1 b_c`` into
    ``mb[:count]`` (count, N, 3), the cables' unit vectors in ``dirs`` (m, 3)."""
    b = np.zeros(mb.shape[1:])
    for k in range(count):
        ci = cables[k]
        a, c = ends[n_struts + ci, 0], ends[n_struts + ci, 1]
        for j in range(3):
            b[a, j] -= dirs[n_struts + ci, j]
            b[c, j] += dirs[n_struts + ci, j]
        inverse_mass(inv_mass, ends, rigid_members, b, mb[k])
        for j in range(3):
            b[a, j] = 0.0
            b[c, j] = 0.0
    for i in range(count):
        ci = cables[i]
        a, c = ends[n_struts + ci, 0], ends[n_struts + ci, 1]
        for k in range(count):
            s = 0.0
            for j in range(3):
                s += dirs[n_struts + ci, j] * (mb[k, c, j] - mb[k, a, j])
            g[i, k] = s
        g[i, i] += 1.0 / plates[ci]


@njit(cache=True, error_model="numpy")
def forces(x, v, rest, ext, ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force, rigid_members,
           plates, band, damped, given, rec, f, cables, g, mb, y):
    """The record ``rec`` at ``x``, ``v`` (N, 3) (MassiveMethod.accelerations): the taut cables damped and with
    their plates, or those of ``rec``'s ``held`` as it is when ``given``. Scratch: ``f`` (N, 3), ``cables`` (nc,),
    ``g`` (nc, nc), ``mb`` (nc, N, 3), ``y`` (nc,)."""
    acc, tension, dirs, slack, elong, rates, held = rec
    n_struts = strut_rest.shape[0]
    for i in range(x.shape[0]):
        for j in range(3):
            f[i, j] = gravity_force[i, j] + ext[i, j]
    for i in range(ends.shape[0]):
        a, c = ends[i, 0], ends[i, 1]
        d0, d1, d2 = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        n0, n1, n2 = d0 / length, d1 / length, d2 / length
        dirs[i, 0], dirs[i, 1], dirs[i, 2] = n0, n1, n2
        r = strut_rest[i] if i < n_struts else rest[i - n_struts]
        e = length - r
        t = stiffness[i] * max(e, floor[i])
        if i >= n_struts:
            ci = i - n_struts
            rate = n0 * (v[c, 0] - v[a, 0]) + n1 * (v[c, 1] - v[a, 1]) + n2 * (v[c, 2] - v[a, 2])
            taut = e > band * r or (e >= -band * r and rate > 0.0)
            slack[ci] = not taut
            if not given:
                held[ci] = taut
            if damped:
                t += damping[ci] * rate if held[ci] else 0.0
                t = max(t, 0.0)   # a damped cable never pushes
            tension[ci], elong[ci], rates[ci] = t, e, rate
        f[a, 0] += t * n0
        f[a, 1] += t * n1
        f[a, 2] += t * n2
        f[c, 0] -= t * n0
        f[c, 1] -= t * n1
        f[c, 2] -= t * n2
    inverse_mass(inv_mass, ends, rigid_members, f, acc)
    count = 0
    for ci in range(rest.shape[0]):
        if held[ci] and plates[ci] > 0:
            cables[count] = ci
            count += 1
    if count == 0:
        return
    # the plates' inertial forces y = m_c d2e/dt2: (B M^-1 B^T + diag(1/m_c)) y = B M^-1 f + q
    _delassus(cables, count, dirs, n_struts, ends, inv_mass, rigid_members, plates, g, mb)
    for k in range(count):
        ci = cables[k]
        a, c = ends[n_struts + ci, 0], ends[n_struts + ci, 1]
        dv0, dv1, dv2 = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        d0, d1, d2 = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        q = (dv0 * dv0 + dv1 * dv1 + dv2 * dv2 - rates[ci] ** 2) / length
        s = 0.0
        for j in range(3):
            s += (acc[c, j] - acc[a, j]) * dirs[n_struts + ci, j]
        y[k] = s + q
    _solve_spd(g[:count, :count], y[:count])
    _subtract_columns(y, count, mb, acc)
    for k in range(count):
        tension[cables[k]] += y[k]


@njit(cache=True, error_model="numpy")
def plate_impact(g, rates, snapping, p):
    """The impact's impulses into ``p`` (k,) (method.plate_impact): ``g`` (k, k) over the cables involved (not
    modified), ``rates`` (k,) before it, ``snapping`` (k,) bool. The moving plates' rows are eliminated (Schur
    complement ``H``); the snapping ones' complementarity problem ``0 <= p ⟂ H p - r >= 0`` is solved by
    principal pivoting with the least-index rule (finite for a positive definite ``H``)."""
    k = g.shape[0]
    a_rows = np.empty(k, dtype=np.int64)
    s_rows = np.empty(k, dtype=np.int64)
    na, ns = 0, 0
    for i in range(k):
        if snapping[i]:
            s_rows[ns] = i
            ns += 1
        else:
            a_rows[na] = i
            na += 1
    coupling = np.empty((na, ns))
    for i in range(na):
        for j in range(ns):
            coupling[i, j] = g[a_rows[i], s_rows[j]]
    if na:
        gaa = np.empty((na, na))
        for i in range(na):
            for j in range(na):
                gaa[i, j] = g[a_rows[i], a_rows[j]]
        cholesky(gaa, 0.0)
        column = np.empty(na)
        for j in range(ns):
            column[:] = coupling[:, j]
            cho_solve(gaa, column)
            coupling[:, j] = column
    h = np.empty((ns, ns))
    for i in range(ns):
        for j in range(ns):
            s = g[s_rows[i], s_rows[j]]
            for m in range(na):
                s -= g[s_rows[i], a_rows[m]] * coupling[m, j]
            h[i, j] = s
    r = np.empty(ns)
    for i in range(ns):
        r[i] = rates[s_rows[i]]
    free = np.ones(ns, dtype=np.bool_)
    ps = np.zeros(ns)
    for _ in range(_PIVOTS):
        idx = np.flatnonzero(free)
        sub = np.empty((len(idx), len(idx)))
        rhs = np.empty(len(idx))
        for i in range(len(idx)):
            rhs[i] = r[idx[i]]
            for j in range(len(idx)):
                sub[i, j] = h[idx[i], idx[j]]
        if len(idx):
            _solve_spd(sub, rhs)
        ps[:] = 0.0
        for i in range(len(idx)):
            ps[idx[i]] = rhs[i]
        flip = -1
        for i in range(ns):
            if free[i]:
                bad = ps[i] < 0.0
            else:
                w = -r[i]
                for j in range(ns):
                    w += h[i, j] * ps[j]
                bad = w < 0.0
            if bad:
                flip = i
                break
        if flip < 0:
            break
        free[flip] = not free[flip]
    for j in range(ns):
        p[s_rows[j]] = ps[j]
    for i in range(na):
        s = 0.0
        for j in range(ns):
            s -= coupling[i, j] * ps[j]
        p[a_rows[i]] = s


@njit(cache=True, error_model="numpy")
def _copy(src, dst):
    """Workspace ``src`` into ``dst`` ((x, v) + record)."""
    dst[0][:] = src[0]
    dst[1][:] = src[1]
    dst[2][:] = src[2]
    dst[3][:] = src[3]
    dst[4][:] = src[4]
    dst[5][:] = src[5]
    dst[6][:] = src[6]
    dst[7][:] = src[7]
    dst[8][:] = src[8]


@njit(cache=True, error_model="numpy")
def _flow(ws, h, weights, rest, ext, model, scratch, impulses):
    """The composed Verlet step of ``h`` (s) in place on the workspace ``ws``; ``impulses`` (nc,) set to each
    cable's impulse over it (MassiveMethod.verlet, Stepper.flow)."""
    x, v = ws[0], ws[1]
    rec = ws[2:]
    ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force, rigid_members, plates, band, damped = model
    f, cables, g, mb, y, v_half = scratch
    impulses[:] = 0.0
    for w in weights:
        hw = w * h
        for ci in range(impulses.shape[0]):
            impulses[ci] += (0.5 * hw) * rec[1][ci]
        for i in range(x.shape[0]):
            for j in range(3):
                v_half[i, j] = v[i, j] + (0.5 * hw) * rec[0][i, j]
                x[i, j] = x[i, j] + hw * v_half[i, j]
        # the taut set of the step's start (the record's held, kept): a switch at its end comes after the kick
        forces(x, v_half, rest, ext, ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
               rigid_members, plates, band, damped, True, rec, f, cables, g, mb, y)
        for i in range(x.shape[0]):
            for j in range(3):
                v[i, j] = v_half[i, j] + (0.5 * hw) * rec[0][i, j]
        if damped or _any_plate(rec[6], plates):
            forces(x, v, rest, ext, ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
                   rigid_members, plates, band, damped, True, rec, f, cables, g, mb, y)
            for i in range(x.shape[0]):
                for j in range(3):
                    v[i, j] = v_half[i, j] + (0.5 * hw) * rec[0][i, j]
        for ci in range(impulses.shape[0]):
            impulses[ci] += (0.5 * hw) * rec[1][ci]


@njit(cache=True, error_model="numpy")
def _any_plate(held, plates):
    """Whether a cable of ``held`` carries a plate."""
    for ci in range(held.shape[0]):
        if held[ci] and plates[ci] > 0:
            return True
    return False


@njit(cache=True, error_model="numpy")
def _kinetic(v, masses, free):
    s = 0.0
    for i in range(v.shape[0]):
        if free[i]:
            for j in range(3):
                s += masses[i] * v[i, j] * v[i, j]
    return 0.5 * s


@njit(cache=True, error_model="numpy")
def _events(ws, rest, ext, model, masses, free, scratch, kicks):
    """The snaps and releases between the set of plates the part was stepped with (the record's ``held``) and
    the switch state at its end, resolved there in place on ``ws`` (MassiveMethod._events); ``kicks`` (nc,) set to
    the snap impulses. Returns the energy they removed (J)."""
    x, v = ws[0], ws[1]
    rec = ws[2:]
    acc, tension, dirs, slack, elong, rates, held = rec
    ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force, rigid_members, plates, band, damped = model
    f, cables, g, mb, y, v_half = scratch
    nc = rest.shape[0]
    n_struts = strut_rest.shape[0]
    kicks[:] = 0.0
    changed, snaps = False, False
    loss = 0.0
    for ci in range(nc):
        if held[ci] == slack[ci]:   # the switch state differs from the part's
            changed = True
            if plates[ci] > 0:
                if held[ci]:
                    loss += 0.5 * plates[ci] * rates[ci] ** 2   # a release: the plate stops
                else:
                    snaps = True
    if not changed:
        return loss
    if not snaps:
        forces(x, v, rest, ext, ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force, rigid_members,
               plates, band, damped, False, rec, f, cables, g, mb, y)
        return loss
    involved = np.empty(nc, dtype=np.int64)
    count = 0
    for ci in range(nc):
        if (not slack[ci]) and plates[ci] > 0:
            involved[count] = ci
            count += 1
    snapping = np.empty(count, dtype=np.bool_)
    before_rates = np.empty(count)
    before = 0.0
    for k in range(count):
        ci = involved[k]
        snapping[k] = not held[ci]
        before_rates[k] = rates[ci]
        if not snapping[k]:
            before += 0.5 * plates[ci] * rates[ci] ** 2
    _delassus(involved, count, dirs, n_struts, ends, inv_mass, rigid_members, plates, g, mb)
    p = np.empty(count)
    plate_impact(g[:count, :count].copy(), before_rates, snapping, p)
    kinetic_before = _kinetic(v, masses, free)
    _subtract_columns(p, count, mb, v)
    forces(x, v, rest, ext, ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force, rigid_members,
           plates, band, damped, False, rec, f, cables, g, mb, y)
    kept = 0.0
    for ci in range(nc):
        if held[ci] and plates[ci] > 0:
            kept += 0.5 * plates[ci] * rates[ci] ** 2
    loss += kinetic_before + before - _kinetic(v, masses, free) - kept
    for k in range(count):
        kicks[involved[k]] = p[k]
    return loss


@njit(cache=True, error_model="numpy")
def massive_step(start, trial, h, weights, locate, min_split, rest, ext, model, masses, free, scratch, impulses):
    """One step of ``h`` (s) in place on the workspace ``start`` (its record: the forces at its state), split at
    the switches inside it when ``locate``, the events resolved where each part ends (_PlateStepper.step);
    ``trial`` is a second workspace (scratch). ``impulses`` (nc,) set to each cable's impulse over the step.
    Returns the energy the plates lost in it (J)."""
    ends = model[0]
    n_struts = model[3].shape[0]
    nc = rest.shape[0]
    n = start[0].shape[0]
    part_imp, trial_imp, kicks = np.empty(nc), np.empty(nc), np.empty(nc)
    rest3 = rest.reshape((nc, 1))
    loss = 0.0
    impulses[:] = 0.0
    _copy(start, trial)
    _flow(trial, h, weights, rest, ext, model, scratch, trial_imp)
    remaining = h
    for _ in range(MAX_SWITCHES if locate else 0):
        changed = False
        for ci in range(nc):
            changed = changed or start[5][ci] != trial[5][ci]
        if not changed:
            break
        cable, s = _first_switch(start[0].reshape((n, 3, 1)), start[1].reshape((n, 3, 1)),
                                 start[2].reshape((n, 3, 1)), start[5], trial[0].reshape((n, 3, 1)), trial[5],
                                 remaining, rest3, ends, n_struts, min_split)
        if cable < 0:
            break
        # Newton's method on e_cable(flow(s)) = 0, bracketed by the part (Stepper._locate)
        e0 = start[6][cable]
        a, c = ends[n_struts + cable, 0], ends[n_struts + cable, 1]
        tol = LOCATE_TOL * rest[cable]
        lo, hi = 0.0, remaining
        converged = False
        for _ in range(_FLOW_ITER):
            _copy(start, trial)
            _flow(trial, s, weights, rest, ext, model, scratch, part_imp)
            e = trial[6][cable]
            if abs(e) <= tol:
                converged = True
                break
            tv, dirs = trial[1], trial[4]
            rate = 0.0
            for j in range(3):
                rate += dirs[n_struts + cable, j] * (tv[c, j] - tv[a, j])
            s, lo, hi = newton_in_bracket(s, e, e0, rate, lo, hi)
        if not converged:
            _copy(start, trial)
            _flow(trial, s, weights, rest, ext, model, scratch, part_imp)
        loss += _events(trial, rest, ext, model, masses, free, scratch, kicks)
        _copy(trial, start)
        for ci in range(nc):
            impulses[ci] = impulses[ci] + part_imp[ci] + kicks[ci]
        remaining -= s
        _flow(trial, remaining, weights, rest, ext, model, scratch, trial_imp)
    # a switch not located (none, a graze, one at a part's very end) is resolved at the step's end
    loss += _events(trial, rest, ext, model, masses, free, scratch, kicks)
    for ci in range(nc):
        impulses[ci] = impulses[ci] + trial_imp[ci] + kicks[ci]
    _copy(trial, start)
    return loss


@njit(cache=True, error_model="numpy")
def massive_steps(start, trial, h, n_steps, every, weights, locate, min_split, rest, ext, model, masses, free,
                  scratch, out_x, out_v, out_impulses, out_slack):
    """``n_steps`` steps of :func:`massive_step` in place on ``start``, keeping steps ``every``, ``2 every``, ...
    and the last in ``out_x``, ``out_v`` (K, N, 3), ``out_impulses`` (K, nc; summed over the steps since the last
    kept one) and ``out_slack`` (K, nc: shorter than the rest length), ``K = ceil(n_steps / every)``. Returns the
    energy the plates lost (J)."""
    nc = rest.shape[0]
    imp = np.empty(nc)
    total = np.zeros(nc)
    loss = 0.0
    for s in range(n_steps):
        loss += massive_step(start, trial, h, weights, locate, min_split, rest, ext, model, masses, free, scratch,
                             imp)
        for ci in range(nc):
            total[ci] += imp[ci]
        if (s + 1) % every == 0 or s == n_steps - 1:
            k = s // every
            out_x[k] = start[0]
            out_v[k] = start[1]
            for ci in range(nc):
                out_impulses[k, ci] = total[ci]
                out_slack[k, ci] = start[6][ci] < 0
                total[ci] = 0.0
    return loss
