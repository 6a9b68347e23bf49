"""Compiled step of the massive method: the same arithmetic as :class:`.method.MassiveMethod` (the plain numpy
reference, which tests require this to match to 1e-12), with numba.

A batch of one (``Simulator``'s; ``BatchSimulator`` steps one simulator per copy for this method). Shapes: ``N``
nodes, ``m`` members (struts first), ``nc`` cables, ``k`` cables that carry a plate. The system arrays are those
of the elastic kernels (``elastic/_kernels.model_arrays``: ``ends``, ``stiffness``, ``floor``, ``strut_rest``,
``damping``, ``inv_mass`` (N, 2), ``gravity_force``, ``rigid_members``: none, the method takes no rigid strut
yet), ``plates`` (nc,) kg and the plates' ``G`` layout (``MassiveMethod._plate_layout``): ``rows`` (nc,) each
cable's row of ``G`` (-1: no plate), ``plated`` (k,) the cable of each row, ``envelope`` (k,) the first column of
each row's lower envelope, ``pairs`` (P, 3) (row, row below it, node: two plated cables coupled at a node they
share) and ``signs`` (P,) (+1 where the node is the same end of both). A step's record at a configuration
(``_Forces`` of the reference) is the tuple ``(acc (N, 3), tension (nc,), dirs (m, 3), slack (nc,) bool, elong
(nc,), rates (nc,), held (nc,) bool)``; a workspace is ``(x (N, 3), v (N, 3)) + record``, stepped in place.

The structure's inverse mass is applied by :func:`inverse_mass` only (``_mass_kernels.solve_forces``).

Cost: ``G`` always has a row for every plated cable, in a reversed Cuthill-McKee order of the cables, so its
envelope (and the Cholesky factor's, which keeps its fill) is set once for the scene; a cable whose plate is at
rest gets an identity row (its ``y`` is exactly 0, and so are its couplings in the factor). :func:`_delassus`
builds it node by node (two cables couple only at a shared node) and :func:`_factor` factors it once a step, the
forward substitution with it, for one solve: while plates move, the forces are evaluated once a step, at the
predicted end velocity (the reference's ``verlet``). The functions a step calls take no reference counts
(``_nrt=False``): the loop runs a step without a switch in :func:`_unswitched` alone, since a call into a function
that counts references counts every array it is given (about 50: 0.3-0.5 us a step), and allocates nothing but at
a snap's impact (:func:`_events`).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..contact._detection_kernels import event_arrays, examine, measure, moved_on, new_events, new_work
from ..elastic._composition_kernels import _first_switch, newton_in_bracket
from .._mass_kernels import solve_forces
from ..qp._qp_kernels import cho_solve, cholesky
from ..elastic.composition import _FLOW_ITER, LOCATE_TOL, MAX_SWITCHES

__all__ = ["inverse_mass", "forces", "make_scratch", "massive_step", "massive_steps", "plate_impact"]

_PIVOTS = 64   # principal pivots of the snap's complementarity problem at most (a few in practice)


def make_scratch(n_nodes: int, n_cables: int, n_plated: int) -> tuple:
    """The kernels' scratch arrays: ``f`` (N, 3), ``g`` (k * k,), ``y`` (k,), ``v_half`` (N, 3), ``acc0`` (N, 3),
    ``pulled`` (N, 3), the impulses of a part, of a trial and of a snap (nc,) each, ``rdiag`` (k,), a step's
    impulses and their sum since the last kept step (nc,) each."""
    n, nc, k = n_nodes, n_cables, max(n_plated, 1)
    return (np.empty((n, 3)), np.empty(k * k), np.empty(k), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
            np.empty(nc), np.empty(nc), np.empty(nc), np.empty(k), np.empty(nc), np.empty(nc))


@njit(cache=True, error_model="numpy", _nrt=False)
def inverse_mass(inv_mass, ends, rigid_members, f, out):
    """``out = M^-1 f`` for node vectors ``f`` (N, 3): the one place the kernels apply the structure's inverse
    mass (``_mass_kernels.solve_forces``, ``inv_mass`` (N, 2) its kernel form; fixed nodes: 0)."""
    for i in range(f.shape[0]):
        for j in range(3):
            out[i, j] = f[i, j]
    solve_forces(out.reshape((out.shape[0], 3, 1)), inv_mass, ends, rigid_members, 0)


@njit(cache=True, error_model="numpy")
def _solve_spd(a, b):
    """``b`` (n,) overwritten by ``a^-1 b`` for a symmetric positive definite ``a`` (n, n), overwritten by its
    Cholesky factor (the QP kernels' ``cholesky``/``cho_solve``)."""
    cholesky(a, 0.0)
    cho_solve(a, b)


@njit(cache=True, error_model="numpy", _nrt=False)
def _pull(coef, cables, mask, dirs, n_struts, ends, out):
    """``out -= B^T coef``: each cable ``cables[k]`` of ``mask`` (nc,) bool pulls its ends together by
    ``coef[k]`` along its unit vector in ``dirs`` (as a tension would: ``+coef n`` at its first end, ``-coef n``
    at its second)."""
    for k in range(cables.shape[0]):
        if not mask[cables[k]]:
            continue
        ci = n_struts + cables[k]
        a, c = ends[ci, 0], ends[ci, 1]
        for j in range(3):
            out[a, j] += coef[k] * dirs[ci, j]
            out[c, j] -= coef[k] * dirs[ci, j]


@njit(cache=True, error_model="numpy", _nrt=False)
def _delassus(mask, dirs, n_struts, ends, inv_mass, plates, plated, envelope, pairs, signs, g):
    """``G = B M^-1 B^T + diag(1/m_c)`` over the plated cables of ``mask`` (nc,) bool, the cables' unit vectors
    in ``dirs`` (m, 3), into the lower envelope of ``g`` (k, k) (the layout's rows; the rest of ``g`` is not
    written), an identity row for every other plated cable. ``M^-1`` is lumped (the method takes no rigid strut,
    so ``inv_mass[:, 1]`` is 0): two cables couple only at a node they share, listed once in ``pairs``. Returns
    how many cables it took."""
    count = 0
    for r in range(plated.shape[0]):
        for p in range(envelope[r], r):
            g[r, p] = 0.0
        ci = plated[r]
        if mask[ci]:
            count += 1
            i = n_struts + ci
            s = dirs[i, 0] * dirs[i, 0] + dirs[i, 1] * dirs[i, 1] + dirs[i, 2] * dirs[i, 2]
            g[r, r] = s * (inv_mass[ends[i, 0], 0] + inv_mass[ends[i, 1], 0]) + 1.0 / plates[ci]
        else:
            g[r, r] = 1.0
    for q in range(pairs.shape[0]):
        r, p = pairs[q, 0], pairs[q, 1]
        if mask[plated[r]] and mask[plated[p]]:
            i, k = n_struts + plated[r], n_struts + plated[p]
            s = dirs[i, 0] * dirs[k, 0] + dirs[i, 1] * dirs[k, 1] + dirs[i, 2] * dirs[k, 2]
            # b_c is -n at the cable's first end, +n at its second
            g[r, p] += signs[q] * s * inv_mass[pairs[q, 2], 0]
    return count


@njit(cache=True, error_model="numpy", _nrt=False)
def _factor(g, first, rdiag, b):
    """The Cholesky factor ``L`` (``G = L L^T``) of the lower envelope of :func:`_delassus` in place (the
    envelope keeps its fill), ``rdiag`` (k,) its diagonal's reciprocals, and the forward substitution: ``b``
    (k,) overwritten by ``L^-1 b``. Row by row, each inside its envelope (a row's entries need only the rows
    above it), the forward substitution's row with it; the cables come in an order of small envelope
    (``MassiveMethod._plate_layout``), so this costs a fraction of the dense factor."""
    for i in range(g.shape[0]):
        fi = first[i]
        for j in range(fi, i):
            s = g[i, j]
            for p in range(max(fi, first[j]), j):
                s -= g[i, p] * g[j, p]
            g[i, j] = s * rdiag[j]
        d = g[i, i]
        s = b[i]
        for p in range(fi, i):
            d -= g[i, p] * g[i, p]
            s -= g[i, p] * b[p]
        g[i, i] = np.sqrt(d)
        rdiag[i] = 1.0 / g[i, i]
        b[i] = s * rdiag[i]


@njit(cache=True, error_model="numpy", _nrt=False)
def _back(g, first, rdiag, b):
    """``b`` (k,) overwritten by ``L^-T b`` with :func:`_factor`'s ``L`` (by columns, inside the envelope): after
    :func:`_factor`, ``G^-1`` of its ``b``."""
    for i in range(g.shape[0] - 1, -1, -1):
        b[i] *= rdiag[i]
        for p in range(first[i], i):
            b[p] -= g[i, p] * b[i]


@njit(cache=True, error_model="numpy", _nrt=False)
def forces(x, v, rest, ext, model, scratch, given, rec):
    """The record ``rec`` at ``x``, ``v`` (N, 3) (MassiveMethod.accelerations): the taut cables damped and with
    their plates, or those of ``rec``'s ``held`` as it is when ``given``. ``scratch`` (:func:`make_scratch`)
    here: ``f`` (N, 3) the structure's forces, ``g`` (k * k,), ``y`` (k,), ``acc0`` (N, 3) ``M^-1 f``,
    ``pulled`` (N, 3), ``rdiag`` (k,) (the factor's diagonal's reciprocals)."""
    (ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force, rigid_members, plates, rows, plated,
     envelope, pairs, signs, band, damped) = model
    f, g, y, _, acc0, pulled = scratch[:6]
    rdiag = scratch[9]
    acc, tension, dirs, slack, elong, rates, held = rec
    n_struts = strut_rest.shape[0]
    _structure_forces(x, v, rest, ext, ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
                      rigid_members, band, damped, given, rec, f, acc0)
    k = plated.shape[0]
    if not _any_plate(held, plates):
        _copy_rows(acc0, acc)
        return
    # the plates' inertial forces y = m_c d2e/dt2: (B M^-1 B^T + diag(1/m_c)) y = B M^-1 f + q
    gk = g[: k * k].reshape((k, k))   # contiguous: the factor's loops run over rows
    _delassus(held, dirs, n_struts, ends, inv_mass, plates, plated, envelope, pairs, signs, gk)
    for r in range(k):
        ci = plated[r]
        if not held[ci]:
            y[r] = 0.0   # an identity row: the plate at rest
            continue
        a, c = ends[n_struts + ci, 0], ends[n_struts + ci, 1]
        dv0, dv1, dv2 = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
        q = (dv0 * dv0 + dv1 * dv1 + dv2 * dv2 - rates[ci] ** 2) / (elong[ci] + rest[ci])
        s = 0.0
        for j in range(3):
            s += (acc0[c, j] - acc0[a, j]) * dirs[n_struts + ci, j]
        y[r] = s + q
    _factor(gk, envelope, rdiag, y)
    _back(gk, envelope, rdiag, y)
    # a = M^-1 (f - B^T y): the plates pull on the nodes as tensions would
    _copy_rows(f, pulled)
    _pull(y, plated, held, dirs, n_struts, ends, pulled)
    inverse_mass(inv_mass, ends, rigid_members, pulled, acc)
    for r in range(k):
        if held[plated[r]]:
            tension[plated[r]] += y[r]


@njit(cache=True, error_model="numpy", _nrt=False)
def _rates_at(v, rest, ends, n_struts, band, rec):
    """The record's elongation rates and switch states at the velocities ``v`` (N, 3), its positions' kept."""
    dirs, slack, elong, rates = rec[2], rec[3], rec[4], rec[5]
    for ci in range(rest.shape[0]):
        i = n_struts + ci
        a, c = ends[i, 0], ends[i, 1]
        rate = dirs[i, 0] * (v[c, 0] - v[a, 0]) + dirs[i, 1] * (v[c, 1] - v[a, 1]) + dirs[i, 2] * (v[c, 2] - v[a, 2])
        e, r = elong[ci], rest[ci]
        slack[ci] = not (e > band * r or (e >= -band * r and rate > 0.0))
        rates[ci] = rate


@njit(cache=True, error_model="numpy", _nrt=False)
def _structure_forces(x, v, rest, ext, ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
                      rigid_members, band, damped, given, rec, f, acc0):
    """The members' part of :func:`forces`: the record's fields but the accelerations, the node forces ``f``
    (N, 3) and ``acc0 = M^-1 f``."""
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
    inverse_mass(inv_mass, ends, rigid_members, f, acc0)


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


@njit(cache=True, error_model="numpy", _nrt=False)
def _copy(src, dst):
    """Workspace ``src`` into ``dst`` ((x, v) + record)."""
    _copy_rows(src[0], dst[0])
    _copy_rows(src[1], dst[1])
    _copy_rows(src[2], dst[2])
    _copy_rows(src[4], dst[4])
    for i in range(src[3].shape[0]):   # the cables' fields
        dst[3][i] = src[3][i]
        dst[5][i] = src[5][i]
        dst[6][i] = src[6][i]
        dst[7][i] = src[7][i]
        dst[8][i] = src[8][i]


@njit(cache=True, error_model="numpy", _nrt=False)
def _copy_rows(src, dst):
    """``dst[:] = src`` for (k, 3) arrays."""
    for i in range(src.shape[0]):
        for j in range(3):
            dst[i, j] = src[i, j]


@njit(cache=True, error_model="numpy", _nrt=False)
def _flow(src, dst, h, weights, rest, ext, model, scratch, impulses):
    """The composed Verlet step of ``h`` (s) from the workspace ``src`` into ``dst`` (the two may be one);
    ``impulses`` (nc,) set to each cable's impulse over it (MassiveMethod.verlet, Stepper.flow)."""
    x, v = dst[0], dst[1]
    rec = dst[2:]
    plates, damped = model[8], model[15]
    v_half = scratch[3]
    for ci in range(impulses.shape[0]):
        impulses[ci] = 0.0
        rec[6][ci] = src[8][ci]   # the taut set of the step's start, kept: a switch at its end comes after the kick
    for k in range(weights.shape[0]):
        hw = weights[k] * h
        start = src if k == 0 else dst
        for ci in range(impulses.shape[0]):
            impulses[ci] += (0.5 * hw) * start[3][ci]
        for i in range(x.shape[0]):
            for j in range(3):
                v_half[i, j] = start[1][i, j] + (0.5 * hw) * start[2][i, j]
                x[i, j] = start[0][i, j] + hw * v_half[i, j]
                # the end velocity the start's acceleration predicts: the plates' forces are evaluated there
                v[i, j] = v_half[i, j] + (0.5 * hw) * start[2][i, j]
        predict = _any_plate(rec[6], plates)
        forces(x, v if predict else v_half, rest, ext, model, scratch, True, rec)
        for i in range(x.shape[0]):
            for j in range(3):
                v[i, j] = v_half[i, j] + (0.5 * hw) * rec[0][i, j]
        if predict:   # the events read the rates at the end velocity
            _rates_at(v, rest, model[0], model[3].shape[0], model[14], rec)
        elif damped:   # the closing kick corrected once (no plate moving)
            forces(x, v, rest, ext, model, scratch, True, rec)
            for i in range(x.shape[0]):
                for j in range(3):
                    v[i, j] = v_half[i, j] + (0.5 * hw) * rec[0][i, j]
        for ci in range(impulses.shape[0]):
            impulses[ci] += (0.5 * hw) * rec[1][ci]


@njit(cache=True, error_model="numpy", _nrt=False)
def _switched(rec):
    """Whether a cable's switch state differs from the set the part was stepped with (the record's)."""
    slack, held = rec[3], rec[6]
    for ci in range(held.shape[0]):
        if held[ci] == slack[ci]:
            return True
    return False


@njit(cache=True, error_model="numpy", _nrt=False)
def _any_plate(held, plates):
    """Whether a cable of ``held`` carries a plate."""
    for ci in range(held.shape[0]):
        if held[ci] and plates[ci] > 0:
            return True
    return False


@njit(cache=True, error_model="numpy", _nrt=False)
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
    ends, strut_rest, inv_mass, rigid_members, plates = model[0], model[3], model[5], model[7], model[8]
    rows, plated, envelope, pairs, signs = model[9:14]
    f, g, _, dv = scratch[:4]
    nc = rest.shape[0]
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
        forces(x, v, rest, ext, model, scratch, False, rec)
        return loss
    # the plates' plastic impact (the step loop's only allocations)
    n_struts = strut_rest.shape[0]
    taut = np.empty(nc, dtype=np.bool_)
    involved = np.empty(nc, dtype=np.int64)
    count = 0
    for ci in range(nc):
        taut[ci] = not slack[ci]
        if taut[ci] and plates[ci] > 0:
            involved[count] = ci
            count += 1
    involved = involved[:count]
    snapping = np.empty(count, dtype=np.bool_)
    before_rates = np.empty(count)
    before = 0.0
    for u in range(count):
        ci = involved[u]
        snapping[u] = not held[ci]
        before_rates[u] = rates[ci]
        if not snapping[u]:
            before += 0.5 * plates[ci] * rates[ci] ** 2
    # G over the cables involved, dense, in their order: read off the layout's envelope (zero outside it)
    k = plated.shape[0]
    gk = g[: k * k].reshape((k, k))
    _delassus(taut, dirs, n_struts, ends, inv_mass, plates, plated, envelope, pairs, signs, gk)
    gc = np.empty((count, count))
    for u in range(count):
        for w in range(u + 1):
            hi, lo = max(rows[involved[u]], rows[involved[w]]), min(rows[involved[u]], rows[involved[w]])
            gc[u, w] = gc[w, u] = gk[hi, lo] if lo >= envelope[hi] else 0.0
    p = np.empty(count)
    plate_impact(gc, before_rates, snapping, p)
    kinetic_before = _kinetic(v, masses, free)
    # v -= M^-1 B^T p
    f[:] = 0.0
    _pull(p, involved, taut, dirs, n_struts, ends, f)
    inverse_mass(inv_mass, ends, rigid_members, f, dv)
    for i in range(v.shape[0]):
        for j in range(3):
            v[i, j] += dv[i, j]
    forces(x, v, rest, ext, model, scratch, False, rec)
    kept = 0.0
    for ci in range(nc):
        if held[ci] and plates[ci] > 0:
            kept += 0.5 * plates[ci] * rates[ci] ** 2
    for u in range(count):
        kicks[involved[u]] = p[u]
    return loss + kinetic_before + before - _kinetic(v, masses, free) - kept


@njit(cache=True, error_model="numpy", _nrt=False)
def _unswitched(start, trial, h, weights, locate, rest, ext, model, scratch, impulses):
    """The step's trial, the whole step of ``h`` (s) from ``start`` into ``trial`` with its impulses in
    ``scratch``; True when it is the step: no switch in it (the common step, ``impulses`` set to the trial's),
    False when one is to be located or resolved (:func:`massive_step`). Apart from it since it takes no reference
    counts (the located steps' kernels do)."""
    trial_imp = scratch[7]
    _flow(start, trial, h, weights, rest, ext, model, scratch, trial_imp)
    if locate:
        slack0, slack1 = start[5], trial[5]
        for ci in range(slack0.shape[0]):
            if slack0[ci] != slack1[ci]:
                return False
    if _switched(trial[2:]):
        return False
    for ci in range(impulses.shape[0]):
        impulses[ci] = trial_imp[ci]
    return True


@njit(cache=True, error_model="numpy")
def massive_step(start, trial, h, weights, locate, min_split, rest, ext, model, masses, free, scratch, impulses):
    """One step of ``h`` (s) from the workspace ``start`` (its record: the forces at its state) into ``trial``,
    split at the switches inside it when ``locate``, the events resolved where each part ends
    (_PlateStepper.step); ``start`` is scratch after it. ``impulses`` (nc,) set to each cable's impulse over the
    step. Returns the energy the plates lost in it (J)."""
    if _unswitched(start, trial, h, weights, locate, rest, ext, model, scratch, impulses):
        return 0.0
    return _switches(start, trial, h, weights, locate, min_split, rest, ext, model, masses, free, scratch, impulses)


@njit(cache=True, error_model="numpy")
def _switches(start, trial, h, weights, locate, min_split, rest, ext, model, masses, free, scratch, impulses):
    """:func:`massive_step` after a trial with a switch in it (:func:`_unswitched`): the switches located and
    the events resolved. Returns the energy the plates lost (J)."""
    ends = model[0]
    n_struts = model[3].shape[0]
    nc = rest.shape[0]
    n = start[0].shape[0]
    part_imp, trial_imp, kicks = scratch[6:9]
    rest3 = rest.reshape((nc, 1))
    loss = 0.0
    impulses[:] = 0.0
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
            _flow(start, trial, s, weights, rest, ext, model, scratch, part_imp)
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
            _flow(start, trial, s, weights, rest, ext, model, scratch, part_imp)
        loss += _events(trial, rest, ext, model, masses, free, scratch, kicks)
        _copy(trial, start)
        for ci in range(nc):
            impulses[ci] = impulses[ci] + part_imp[ci] + kicks[ci]
        remaining -= s
        _flow(start, trial, remaining, weights, rest, ext, model, scratch, trial_imp)
    # a switch not located (none, a graze, one at a part's very end) is resolved at the step's end
    if _switched(trial[2:]):
        loss += _events(trial, rest, ext, model, masses, free, scratch, kicks)
        for ci in range(nc):
            impulses[ci] = impulses[ci] + trial_imp[ci] + kicks[ci]
    else:
        for ci in range(nc):
            impulses[ci] = impulses[ci] + trial_imp[ci]
    return loss


@njit(cache=True, error_model="numpy")
def massive_steps(start, trial, h, n_steps, every, weights, locate, min_split, rest, ext, model, masses, free,
                  scratch, out_x, out_v, out_impulses, out_slack, detection):
    """``n_steps`` steps of :func:`massive_step` in place on ``start`` (``trial`` its scratch), keeping
    steps ``every``, ``2 every``, ... and the last in ``out_x``, ``out_v`` (K, N, 3), ``out_impulses`` (K, nc;
    summed over the steps since the last kept one) and ``out_slack`` (K, nc: shorter than the rest length),
    ``K = ceil(n_steps / every)``. ``detection``: member-contact detection over every step, as the elastic
    method's loop runs it (``_detection_kernels.detection_state``, or ``no_detection()``). Returns the energy
    the plates lost (J) and the detection's events (``_detection_kernels.event_arrays``)."""
    nc = rest.shape[0]
    n = start[0].shape[0]
    imp, total = scratch[10:]
    total[:] = 0.0
    loss = 0.0
    detecting = detection[0].shape[0] > 0
    events, points = new_events()
    work = new_work()
    before = np.empty((n, 3, 1))   # the positions at the step's start, for detection
    for s in range(n_steps):
        if detecting:
            _copy_rows(start[0], before.reshape((n, 3)))
        if not _unswitched(start, trial, h, weights, locate, rest, ext, model, scratch, imp):
            loss += _switches(start, trial, h, weights, locate, min_split, rest, ext, model, masses, free, scratch,
                              imp)
        # the step's end is the next one's start: copied (swapping the two tuples counts their arrays' references,
        # 0.3 us a step; the copy takes 0.13 us)
        _copy(trial, start)
        if detecting:
            x = start[0].reshape((n, 3, 1))
            if moved_on(before, 0, x, 0, 0, detection):
                p = measure(x, 0, 0, detection, work, 0)
                if p >= 0:
                    examine(before, 0, x, 0, 0, s, detection, work, events, points, p, 0)
        for ci in range(nc):
            total[ci] += imp[ci]
        if (s + 1) % every == 0 or s == n_steps - 1:
            k = s // every
            _copy_rows(start[0], out_x[k])
            _copy_rows(start[1], out_v[k])
            for ci in range(nc):
                out_impulses[k, ci] = total[ci]
                out_slack[k, ci] = start[6][ci] < 0
                total[ci] = 0.0
    return loss, event_arrays(events, points)
