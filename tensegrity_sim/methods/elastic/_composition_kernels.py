"""Compiled accuracy options of the elastic method: the same arithmetic as :class:`.composition.Stepper`
(the plain numpy reference, which tests require these to match to 1e-12), built on the Verlet step of
``elastic/_kernels.py``.

One kernel, two drivers (style.md rule 8): arrays carry a batch axis LAST, as in ``elastic/_kernels.py``
(whose module docstring lists the system arrays and the carried state). Each copy is stepped in a
workspace of its own (a batch of one), since a located switch splits one copy's step and not another's.
Beyond the plain kernel's carry, these kernels carry each cable's slack state at the step's start:

    slack (nc, B) bool          slack cables at the step's start     (in: start, out: end)

:func:`composed_steps` advances ``n_steps`` steps of ``h`` composed with ``weights`` (Suzuki's for order
4, ``(1,)`` for order 2), split at slack/taut switches when ``locate``, and keeps every ``every``-th.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ._kernels import _step, gather_copies, keep, scatter_copies
from .composition import _FLOW_ITER, _POLY_ITER, LOCATE_TOL, MAX_SWITCHES

__all__ = ["composed_steps", "newton_in_bracket"]


@njit(cache=True, error_model="numpy", _nrt=False)
def _states(x, v, acc, tension, dirs, slack, to_x, to_v, to_acc, to_tension, to_dirs, to_slack):
    """Copy a workspace's state (positions, velocities, accelerations (N, 3, 1), tensions (nc, 1), rigid
    strut directions (nr, 3, 1), slack cables (nc,)) into another's (element loops: no views to make)."""
    for i in range(x.shape[0]):
        for j in range(3):
            to_x[i, j, 0] = x[i, j, 0]
            to_v[i, j, 0] = v[i, j, 0]
            to_acc[i, j, 0] = acc[i, j, 0]
    for ci in range(slack.shape[0]):
        to_tension[ci, 0] = tension[ci, 0]
        to_slack[ci] = slack[ci]
    for k in range(dirs.shape[0]):
        for j in range(3):
            to_dirs[k, j, 0] = dirs[k, j, 0]


@njit(cache=True, error_model="numpy", _nrt=False)
def _elongation(x, ends, n_struts, rest, ci):
    """Cable ``ci``'s ``length - rest`` (m) at ``x`` (N, 3, 1)."""
    a = ends[n_struts + ci, 0]
    c = ends[n_struts + ci, 1]
    d0 = x[c, 0, 0] - x[a, 0, 0]
    d1 = x[c, 1, 0] - x[a, 1, 0]
    d2 = x[c, 2, 0] - x[a, 2, 0]
    return np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) - rest[ci, 0]


@njit(cache=True, error_model="numpy", _nrt=False)
def _flow(x, v, acc, tension, dirs, slack, h, weights, rest, ext, ends, attach, attach_at, stiffness, floor,
          strut_rest, damping, inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, dx, stage,
          impulses):
    """The composed step of ``h`` (s) in place on the workspace ``x``, ``v`` (N, 3, 1), ``acc``,
    ``tension`` (nc, 1), ``dirs`` (nr, 3, 1), ``slack`` (nc,); ``impulses`` (nc,) N*s is set to each
    cable's impulse over it (Stepper.flow)."""
    for ci in range(impulses.shape[0]):
        impulses[ci] = 0.0
    for w in weights:
        _step(x, v, rest, ext, w * h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
              gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, acc, tension, dirs, dx, stage, slack, 0)
        for ci in range(impulses.shape[0]):
            impulses[ci] += stage[ci]


@njit(cache=True, error_model="numpy")
def _first_switch(x, v, acc, slack0, x1, slack1, span, rest, ends, n_struts, min_split):
    """The cable (index, or -1) whose switch comes first among those whose slack state differs between
    the part's start (``x``, ``v``, ``acc``, ``slack0``) and the trial's end (``x1``, ``slack1``), and
    its time (s) on the position polynomial ``x + t v + t^2 acc / 2`` in ``(0, span)``
    (Stepper._first_switch)."""
    best = -1
    best_t = np.inf
    for ci in range(slack0.shape[0]):
        if slack0[ci] == slack1[ci]:
            continue
        a = ends[n_struts + ci, 0]
        c = ends[n_struts + ci, 1]
        d = np.empty(3)
        u = np.empty(3)
        ac = np.empty(3)
        for j in range(3):
            d[j] = x[c, j, 0] - x[a, j, 0]
            u[j] = v[c, j, 0] - v[a, j, 0]
            ac[j] = acc[c, j, 0] - acc[a, j, 0]
        rest2 = rest[ci, 0] ** 2
        e0 = _elongation(x, ends, n_struts, rest, ci)
        e1 = _elongation(x1, ends, n_struts, rest, ci)
        # first guess: the elongation interpolated linearly between the ends of the trial
        t = span * e0 / (e0 - e1)
        g0 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] - rest2
        p = d + span * u + (0.5 * span * span) * ac
        bracketed = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2] - rest2) * g0 <= 0
        lo = 0.0
        hi = span
        for _ in range(_POLY_ITER):
            p = d + t * u + (0.5 * t * t) * ac
            g = p[0] * p[0] + p[1] * p[1] + p[2] * p[2] - rest2
            q = u + t * ac
            slope = 2.0 * (p[0] * q[0] + p[1] * q[1] + p[2] * q[2])
            if g * g0 > 0:
                lo = t
            else:
                hi = t
            t_new = t - g / slope if slope != 0.0 else np.nan
            if bracketed:
                t = t_new if lo < t_new < hi else 0.5 * (lo + hi)
        if min_split < t < span - min_split and t < best_t:
            best = ci
            best_t = t
    return best, best_t


@njit(cache=True, error_model="numpy", _nrt=False)
def newton_in_bracket(s, e, e0, rate, lo, hi):
    """One step of the locating Newton iteration (Stepper._locate): the part of length ``s`` (s) ended at the
    elongation ``e`` (m; ``e0`` at its start) moving at ``rate`` (m/s); the bracket ``(lo, hi)`` narrowed to the
    switch's side, then Newton's next ``s``, or the bracket's midpoint where Newton leaves it. Returns
    ``(s, lo, hi)``."""
    if e * e0 > 0:
        lo = s
    else:
        hi = s
    s_new = s - e / rate if rate != 0.0 else lo
    return (s_new if lo < s_new < hi else 0.5 * (lo + hi)), lo, hi


@njit(cache=True, error_model="numpy")
def _composed_step(x, v, acc, tension, dirs, slack, h, weights, locate, min_split, rest, ext, ends, attach, attach_at,
                   stiffness, floor, strut_rest, damping, inv_mass, gravity_force, rigid_members, rigid_length_sq,
                   rigid_w,
                   coupled, work, impulses):
    """One step of ``h`` (s) of a batch-of-one workspace, in place on ``x``, ``v``, ``acc``,
    ``tension``, ``dirs``, ``slack`` (see :func:`_flow`), split at the switches inside it when
    ``locate`` (Stepper.step); ``impulses`` (nc,) N*s is set to each cable's impulse over the step.
    ``work`` holds the scratch (:func:`composed_steps` makes it): ``dx`` (N, 3), the impulses of a
    stage, a located part and all located parts (nc,), and the trial's state, as the workspace's."""
    (dx, stage, part_imp, located, tx, tv, tacc, tten, tdirs, tslack) = work
    n_struts = strut_rest.shape[0]
    nc = impulses.shape[0]
    # the trial: the whole (remaining) step from the part's start into the t* arrays
    _states(x, v, acc, tension, dirs, slack, tx, tv, tacc, tten, tdirs, tslack)
    _flow(tx, tv, tacc, tten, tdirs, tslack, h, weights, rest, ext, ends, attach, attach_at, stiffness, floor,
          strut_rest, damping, inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, dx, stage,
          impulses)
    if locate:
        for ci in range(nc):
            located[ci] = 0.0
        remaining = h
        for _ in range(MAX_SWITCHES):
            cable, s = _first_switch(x, v, acc, slack, tx, tslack, remaining, rest, ends, n_struts, min_split)
            if cable < 0:
                break
            # Newton's method on e_cable(flow(s)) = 0, bracketed by the part (Stepper._locate)
            e0 = _elongation(x, ends, n_struts, rest, cable)
            a = ends[n_struts + cable, 0]
            c = ends[n_struts + cable, 1]
            tol = LOCATE_TOL * rest[cable, 0]
            lo = 0.0
            hi = remaining
            converged = False
            for _ in range(_FLOW_ITER):
                _states(x, v, acc, tension, dirs, slack, tx, tv, tacc, tten, tdirs, tslack)
                _flow(tx, tv, tacc, tten, tdirs, tslack, s, weights, rest, ext, ends, attach, attach_at, stiffness,
                      floor, strut_rest, damping, inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w,
                      coupled, dx, stage,
                      part_imp)
                e = _elongation(tx, ends, n_struts, rest, cable)
                if abs(e) <= tol:
                    converged = True
                    break
                d0 = tx[c, 0, 0] - tx[a, 0, 0]
                d1 = tx[c, 1, 0] - tx[a, 1, 0]
                d2 = tx[c, 2, 0] - tx[a, 2, 0]
                length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                rate = ((d0 / length) * (tv[c, 0, 0] - tv[a, 0, 0]) + (d1 / length) * (tv[c, 1, 0] - tv[a, 1, 0])
                        + (d2 / length) * (tv[c, 2, 0] - tv[a, 2, 0]))
                s, lo, hi = newton_in_bracket(s, e, e0, rate, lo, hi)
            if not converged:
                _states(x, v, acc, tension, dirs, slack, tx, tv, tacc, tten, tdirs, tslack)
                _flow(tx, tv, tacc, tten, tdirs, tslack, s, weights, rest, ext, ends, attach, attach_at, stiffness,
                      floor, strut_rest, damping, inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w,
                      coupled, dx, stage,
                      part_imp)
            # the part up to the switch is done: it is the new start; the rest of the step is the trial
            _states(tx, tv, tacc, tten, tdirs, tslack, x, v, acc, tension, dirs, slack)
            for ci in range(nc):
                located[ci] += part_imp[ci]
            remaining -= s
            _flow(tx, tv, tacc, tten, tdirs, tslack, remaining, weights, rest, ext, ends, attach, attach_at,
                  stiffness, floor, strut_rest, damping, inv_mass, gravity_force, rigid_members, rigid_length_sq,
                  rigid_w, coupled, dx,
                  stage, impulses)
        for ci in range(nc):
            impulses[ci] += located[ci]
    _states(tx, tv, tacc, tten, tdirs, tslack, x, v, acc, tension, dirs, slack)


@njit(cache=True, error_model="numpy")
def composed_steps(x, v, rest, ext, h, n_steps, every, weights, locate, min_split, ends, attach, attach_at, stiffness,
                   floor, strut_rest, damping, inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w,
                   coupled,
                   acc, tension, rigid_dirs, slack, out_x, out_v, out_impulses, out_slack):
    """``n_steps`` steps of ``h`` (s) of every copy, each composed with ``weights`` (stage fractions of
    the step) and split at its slack/taut switches if ``locate`` (none closer than ``min_split`` s to
    a part's ends), in place on ``x``, ``v`` (N, 3, B), ``acc``, ``tension``, ``rigid_dirs`` and
    ``slack`` (nc, B); keeps steps ``every``, ``2 every``, ... and the last one in ``out_x``, ``out_v``
    (K, N, 3, B), ``out_impulses`` (K, nc, B; summed over the steps since the last kept one) and
    ``out_slack`` (K, nc, B), ``K = ceil(n_steps / every)``, as ``_elastic_kernels.elastic_steps``."""
    n_nodes = x.shape[0]
    nc, n_copies = rest.shape
    nr = rigid_members.shape[0]
    # a copy's workspace (batch of one) and the scratch of its steps
    wx, wv, wacc = np.empty((n_nodes, 3, 1)), np.empty((n_nodes, 3, 1)), np.empty((n_nodes, 3, 1))
    wten, wdirs, wslack = np.empty((nc, 1)), np.empty((nr, 3, 1)), np.empty(nc, dtype=np.bool_)
    wrest, wext = np.empty((nc, 1)), np.empty((n_nodes, 3, 1))
    work = (np.empty((n_nodes, 3)), np.empty(nc), np.empty(nc), np.empty(nc),
            np.empty((n_nodes, 3, 1)), np.empty((n_nodes, 3, 1)), np.empty((n_nodes, 3, 1)), np.empty((nc, 1)),
            np.empty((nr, 3, 1)), np.empty(nc, dtype=np.bool_))
    imp = np.empty(nc)
    total = np.empty(nc)
    for b in range(n_copies):
        gather_copies(x, v, acc, ext, rest, tension, rigid_dirs, b, wx, wv, wacc, wext, wrest, wten, wdirs, 0, 1)
        for ci in range(nc):
            wslack[ci] = slack[ci, b]
            total[ci] = 0.0
        for s in range(n_steps):
            _composed_step(wx, wv, wacc, wten, wdirs, wslack, h, weights, locate, min_split, wrest, wext, ends,
                           attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
                           rigid_members, rigid_length_sq, rigid_w, coupled, work, imp)
            for ci in range(nc):
                total[ci] += imp[ci]
            if (s + 1) % every == 0 or s == n_steps - 1:
                keep(wx, wv, 0, total, wslack, s // every, b, out_x, out_v, out_impulses, out_slack)
        scatter_copies(wx, wv, wacc, wten, wdirs, 0, b, 1, x, v, acc, tension, rigid_dirs)
        for ci in range(nc):
            slack[ci, b] = wslack[ci]
