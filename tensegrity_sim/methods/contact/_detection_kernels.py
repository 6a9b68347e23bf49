"""Compiled continuous member-contact detection: the arithmetic of
:mod:`tensegrity_sim.methods.contact.detection`'s numpy detector (the reference, which tests require these to
match: the same events, times to 1e-12), with numba, for a whole run's chunk of steps in one call and ``B``
copies (batch axis last, as the other kernels).

**Narrow phase.** :func:`_closest`, :func:`_reaches` and :func:`_transitions` are ``contact._closest``,
``contact._reaches``, ``contact.transitions`` and ``contact._search`` for one capsule pair, operation for
operation in the same order (the same samples of the step, the same certified intervals, the same
interpolation), so that a pair examined over a step gives the numpy detector's events.

**Broad phase: what a far pair costs.** A pair's gap does not change under a rigid motion of its four
ends, and changes by at most the largest displacement of an end of one member plus that of the other
(a segment's points move by a mix of its ends' displacements). Two bounds follow:

- an *odometer* per copy, the sum over steps of the largest step displacement of a watched node
  relative to their mean displacement (a common translation, a thrown robot's flight, moves no gap):
  a pair whose gap (in contact: penetration) is at least ``g`` keeps its state until the odometer has
  grown by ``g / 2`` (its *due* value), steps' insides included (the motion within a step is linear);
  a step below every pair's due value costs one pass over the watched nodes and a comparison;
- at its due value a pair is *measured*: its ends a1, b0, b1 in its own frame (origin a0, axes along a
  and towards b's midpoint), which a tumbling robot's rotation leaves alone, against those when the narrow
  phase last examined it and found its gap. If they moved less than that gap (less twice the step's
  displacement, for the step's inside), the gap at the step's end is at least what is left and the pair
  waits for its next due value; otherwise the step is examined by the narrow phase. The shape is held
  against the examined one, not the last measured one: a vibrating robot's pair moves back and forth by
  more, summed, than it strays.

Examining a pair at a step where the numpy detector would not (or the reverse) changes no event:
either knows the pair cannot change state there.

Shapes: ``P`` listed pairs (``pair_nodes`` (P, 4): a's ends then b's), ``W`` watched nodes, ``B`` copies.
"""
from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.typed import List

__all__ = ["detection_state", "no_detection", "new_events", "event_arrays", "new_work", "moved_on", "measure",
           "examine", "detect_steps"]

_MAX_ROUNDS = 100   # contact.MAX_ROUNDS (checked equal by the tests)
_EVENT = types.Tuple((types.int64, types.int64, types.int64, types.float64, types.boolean))


@njit(cache=True, error_model="numpy", _nrt=False)
def _closest(e, out, s, t):
    """``contact._closest`` of segments ``e[0]-e[1]`` and ``e[2]-e[3]`` (e (4, 3) m): writes the distance,
    ``s``, ``t`` and the vector from the first closest point to the second into ``out`` (6,); ``s``, ``t``
    (5,) are scratch (the five candidates)."""
    d10 = e[1, 0] - e[0, 0]
    d11 = e[1, 1] - e[0, 1]
    d12 = e[1, 2] - e[0, 2]
    d20 = e[3, 0] - e[2, 0]
    d21 = e[3, 1] - e[2, 1]
    d22 = e[3, 2] - e[2, 2]
    r0 = e[0, 0] - e[2, 0]
    r1 = e[0, 1] - e[2, 1]
    r2 = e[0, 2] - e[2, 2]
    a = d10 * d10 + d11 * d11 + d12 * d12
    ee = d20 * d20 + d21 * d21 + d22 * d22
    b = d10 * d20 + d11 * d21 + d12 * d22
    c = d10 * r0 + d11 * r1 + d12 * r2
    f = d20 * r0 + d21 * r1 + d22 * r2
    inv_a = 1.0 / (a if a > 0 else np.inf)
    inv_e = 1.0 / (ee if ee > 0 else np.inf)
    beta = b * inv_a
    gamma = c * inv_a
    p0 = d20 - beta * d10
    p1 = d21 - beta * d11
    p2 = d22 - beta * d12
    q0 = r0 - gamma * d10
    q1 = r1 - gamma * d11
    q2 = r2 - gamma * d12
    perp2 = p0 * p0 + p1 * p1 + p2 * p2
    t[0] = (q0 * p0 + q1 * p1 + q2 * p2) / (perp2 if perp2 > 0 else np.inf)
    t[1] = f * inv_e
    t[2] = (f + b) * inv_e
    t[3] = 0.0
    t[4] = 1.0
    s[0] = 0.0
    s[1] = 0.0
    s[2] = 1.0
    s[3] = -gamma
    s[4] = beta - gamma
    for k in range(5):
        t[k] = min(max(t[k], 0.0), 1.0) if not np.isnan(t[k]) else t[k]
    s[0] = t[0] * beta - gamma
    best = -1
    best_d2 = 0.0
    w0 = w1 = w2 = 0.0
    for k in range(5):
        sk = min(max(s[k], 0.0), 1.0) if not np.isnan(s[k]) else s[k]
        s[k] = sk
        x0 = r0 + sk * d10 - t[k] * d20
        x1 = r1 + sk * d11 - t[k] * d21
        x2 = r2 + sk * d12 - t[k] * d22
        d2 = x0 * x0 + x1 * x1 + x2 * x2
        # np.argmin: the first smallest, or the first NaN
        if best < 0 or (not np.isnan(best_d2) and (d2 < best_d2 or np.isnan(d2))):
            best, best_d2, w0, w1, w2 = k, d2, x0, x1, x2
    out[0] = np.sqrt(best_d2)
    out[1] = s[best]
    out[2] = t[best]
    out[3] = -w0
    out[4] = -w1
    out[5] = -w2


@njit(cache=True, error_model="numpy", _nrt=False)
def _over(num, den):
    """``num / den`` where ``den > 0``, inf elsewhere (``contact._over``)."""
    return num / den if den > 0 else np.inf


@njit(cache=True, error_model="numpy", _nrt=False)
def _line_reach(e, d, r, out):
    """``contact._line_reach`` of one configuration ``e`` (4, 3) m moving by ``d`` (4, 3) per step fraction,
    the same sums in the same order: its forward and backward reaches into ``out`` (2,)."""
    da0, da1, da2 = e[1, 0] - e[0, 0], e[1, 1] - e[0, 1], e[1, 2] - e[0, 2]
    db0, db1, db2 = e[3, 0] - e[2, 0], e[3, 1] - e[2, 1], e[3, 2] - e[2, 2]
    w0, w1, w2 = e[2, 0] - e[0, 0], e[2, 1] - e[0, 1], e[2, 2] - e[0, 2]
    ea0, ea1, ea2 = d[1, 0] - d[0, 0], d[1, 1] - d[0, 1], d[1, 2] - d[0, 2]
    eb0, eb1, eb2 = d[3, 0] - d[2, 0], d[3, 1] - d[2, 1], d[3, 2] - d[2, 2]
    v0, v1, v2 = d[2, 0] - d[0, 0], d[2, 1] - d[0, 1], d[2, 2] - d[0, 2]
    c00, c01, c02 = da1 * db2 - da2 * db1, da2 * db0 - da0 * db2, da0 * db1 - da1 * db0
    c20, c21, c22 = ea1 * eb2 - ea2 * eb1, ea2 * eb0 - ea0 * eb2, ea0 * eb1 - ea1 * eb0
    c10 = (ea1 * db2 - ea2 * db1) + (da1 * eb2 - da2 * eb1)
    c11 = (ea2 * db0 - ea0 * db2) + (da2 * eb0 - da0 * eb2)
    c12 = (ea0 * db1 - ea1 * db0) + (da0 * eb1 - da1 * eb0)
    n0 = w0 * c00 + w1 * c01 + w2 * c02
    sign = -1.0 if n0 < 0.0 else 1.0
    n1 = sign * ((w0 * c10 + w1 * c11 + w2 * c12) + (v0 * c00 + v1 * c01 + v2 * c02))
    n2 = (w0 * c20 + w1 * c21 + w2 * c22) + (v0 * c10 + v1 * c11 + v2 * c12)
    n3 = v0 * c20 + v1 * c21 + v2 * c22
    size0 = np.sqrt(c00 * c00 + c01 * c01 + c02 * c02)
    size1 = np.sqrt(c10 * c10 + c11 * c11 + c12 * c12)
    size2 = np.sqrt(c20 * c20 + c21 * c21 + c22 * c22)
    f0 = sign * n0 - r * size0
    out[0] = 0.0
    out[1] = 0.0
    if not (f0 > 0.0 and size0 > 0.0):
        return
    inv = 1.0 / size0
    f1 = n1 - r * ((c00 * c10 + c01 * c11 + c02 * c12) * inv)
    q2 = abs(n2) + r * (abs(c00 * c20 + c01 * c21 + c02 * c22) * inv) + r * (size1 * size1 * (0.5 * inv))
    q3 = abs(n3) + r * (size1 * size2 * inv)
    q4 = r * (size2 * size2 * (0.5 * inv))
    quarter = f0 / 4.0
    rest = min(min(np.sqrt(_over(quarter, q2)), _over(quarter, q3) ** (1.0 / 3.0)),
               np.sqrt(np.sqrt(_over(quarter, q4))))
    out[0] = min(_over(quarter, -f1), rest)
    out[1] = min(_over(quarter, f1), rest)


@njit(cache=True, error_model="numpy", _nrt=False)
def _reaches(e, disp, radii_sum, inside, scratch, out):
    """``contact._reaches`` of one configuration ``e`` (4, 3) m moving by ``disp`` (4, 3) per step
    fraction; ``inside``: 1 in contact, 0 not, -1 as the gap says. Writes gap, forward, backward into
    ``out`` (3,); ``scratch`` (16,). Returns the state used (True: in contact)."""
    _closest(e, scratch, scratch[6:11], scratch[11:16])
    dist = scratch[0]
    gap = dist - radii_sum
    ins = gap < 0 if inside < 0 else inside == 1
    w0, w1, w2 = scratch[3], scratch[4], scratch[5]
    if not ins:
        scale = dist if dist > 0 else np.inf
        n0 = w0 / scale
        n1 = w1 / scale
        n2 = w2 / scale
        forward = np.inf
        backward = np.inf
        for i in range(2):
            hi = e[i, 0] * n0 + e[i, 1] * n1 + e[i, 2] * n2
            ri = disp[i, 0] * n0 + disp[i, 1] * n1 + disp[i, 2] * n2
            for j in range(2, 4):
                hj = e[j, 0] * n0 + e[j, 1] * n1 + e[j, 2] * n2
                rj = disp[j, 0] * n0 + disp[j, 1] * n1 + disp[j, 2] * n2
                c = max(hj - hi - radii_sum, 0.0)
                v = rj - ri
                forward = min(forward, _over(c, -v))
                backward = min(backward, _over(c, v))
        if forward < 1.0 or backward < 1.0:   # (a step's reaches are compared with at most 1)
            _line_reach(e, disp, radii_sum, out)
            forward = out[0] if out[0] > forward else forward
            backward = out[1] if out[1] > backward else backward
        if dist == 0:
            forward = 0.0
            backward = 0.0
    else:
        s, t = scratch[1], scratch[2]
        dw0 = (disp[2, 0] + t * (disp[3, 0] - disp[2, 0])) - (disp[0, 0] + s * (disp[1, 0] - disp[0, 0]))
        dw1 = (disp[2, 1] + t * (disp[3, 1] - disp[2, 1])) - (disp[0, 1] + s * (disp[1, 1] - disp[0, 1]))
        dw2 = (disp[2, 2] + t * (disp[3, 2] - disp[2, 2])) - (disp[0, 2] + s * (disp[1, 2] - disp[0, 2]))
        qa = dw0 * dw0 + dw1 * dw1 + dw2 * dw2
        qb = w0 * dw0 + w1 * dw1 + w2 * dw2
        qc = min(w0 * w0 + w1 * w1 + w2 * w2 - radii_sum * radii_sum, 0.0)
        root = np.sqrt(qb * qb - qa * qc)
        forward = _over(-qc, qb + root)
        backward = _over(-qc, root - qb)
    out[0] = gap
    out[1] = forward
    out[2] = backward
    return ins


@njit(cache=True, error_model="numpy", _nrt=False)
def _crossed(h, inside, margin):
    """``contact._crossed``: has a sample ``h = ±gap`` crossed over?"""
    return h <= -margin if inside else h < 0


@njit(cache=True, error_model="numpy", _nrt=False)
def _event(tau, begin, ev_tau, ev_begin, n):
    """Record transition ``n`` (step fraction ``tau``, a begin?) of this pair; returns ``n + 1``."""
    if n < ev_tau.shape[0]:
        ev_tau[n] = tau
        ev_begin[n] = begin
    return n + 1


@njit(cache=True, error_model="numpy")
def _transitions(p0, p1, disp, radii_sum, inside, touch, fractions, around, ev_tau, ev_begin, scratch):
    """``contact.transitions`` (and ``_search``) of one pair whose end points (4, 3) m move from ``p0`` to
    ``p1`` over the step (``disp`` (4, 3) is scratch), in contact before it if ``inside``. Writes the
    transitions' step fractions and kinds (True: begin) into ``ev_tau``, ``ev_begin`` in the order found;
    returns (their count, the state at the step's end, the gap there (m)); ``scratch`` (22,)."""
    for i in range(4):
        for j in range(3):
            disp[i, j] = p1[i, j] - p0[i, j]
    big = 0.0
    for i in range(4):
        for j in range(3):
            big = max(big, abs(p0[i, j]), abs(p1[i, j]))
    margin = max(1e-12 * (radii_sum + big), touch)
    r0 = scratch[16:19]
    r1 = scratch[19:22]
    _reaches(p0, disp, radii_sum, -1, scratch, r0)
    _reaches(p1, disp, radii_sum, -1, scratch, r1)
    gap0, gap1 = r0[0], r1[0]
    n = 0
    if not inside and gap0 < 0:
        n = _event(0.0, True, ev_tau, ev_begin, n)
        inside = True
    # (with a response, touch > 0, a pair in contact at both ends is held there: contact.transitions)
    if not _crossed(-gap1 if inside else gap1, inside, margin) and (r0[1] + r1[2] >= 1.0 or (inside and touch > 0.0)):
        return n, inside, gap1
    # the certified search (contact._search) for this pair
    sign = -1.0 if inside else 1.0
    a, b = 0.0, 1.0
    h_a, h_b = sign * gap0, sign * gap1
    crossed_b = _crossed(h_b, inside, margin)
    n_frac = fractions.shape[0] + around.shape[0]
    sample = np.empty(n_frac)
    times = np.empty(n_frac)
    h = np.empty(n_frac)
    fwd = np.empty(n_frac)
    bwd = np.empty(n_frac)
    cr = np.empty(n_frac, dtype=np.bool_)
    config = np.empty((4, 3))
    res = r0
    live = True
    rounds = 0
    while live and rounds < _MAX_ROUNDS:
        rounds += 1
        A, B, ins = a, b, inside
        span = h_a - h_b
        falsi = h_a / span if span > 0 else 0.5
        for k in range(fractions.shape[0]):
            sample[k] = fractions[k]
        for k in range(around.shape[0]):
            sample[fractions.shape[0] + k] = min(max(falsi + around[k], 0.0), 1.0)
        sample.sort()
        for k in range(n_frac):
            times[k] = A + (B - A) * sample[k]
        times[n_frac - 1] = B
        for k in range(n_frac):
            tau = times[k]
            for i in range(4):
                for j in range(3):
                    config[i, j] = (1.0 - tau) * p0[i, j] + tau * p1[i, j]
            _reaches(config, disp, radii_sum, 1 if ins else 0, scratch, res)
            h[k] = sign * res[0]
            fwd[k] = res[1]
            bwd[k] = res[2]
            cr[k] = _crossed(h[k], ins, margin)
        at_a = cr[0]
        j = 0
        for k in range(n_frac):
            if cr[k]:
                j = k
                break
        found = cr[j] and not at_a
        if found:
            b = times[j]
            h_b = h[j]
        else:
            b = B
        crossed_b = crossed_b or found
        c = -1
        for k in range(n_frac - 1):
            if not (not cr[k + 1] and fwd[k] + bwd[k + 1] >= times[k + 1] - times[k]):
                c = k
                break
        if c < 0:   # every interval certified
            a = B
            h_a = h[n_frac - 1]
        else:
            left, right = times[c], times[c + 1]
            if not cr[c + 1] and right - left <= 1e-9:   # a sliver below TAU_TOLERANCE is stepped over
                a = right
                h_a = h[c + 1]
            else:
                a = left
                h_a = h[c]
        if at_a or (crossed_b and b - a <= 1e-9):
            span = h_a - h_b
            share = min(max(h_a / span if span > 0 else 1.0, 0.0), 1.0)
            when = A if at_a else a + (b - a) * share
            n = _event(when, not ins, ev_tau, ev_begin, n)
            inside = not ins
            sign = -sign
            a = min((A if at_a else b) + 1e-7, 1.0)
            h_a = -(h[0] if at_a else h_b)
            b = 1.0
            h_b = sign * gap1
            crossed_b = _crossed(h_b, inside, margin)
        live = a < b or (crossed_b and a == b)
    if live:
        # the round bound was hit: settle the state from the step's end so that begins and ends pair up
        flip = gap1 >= margin if inside else gap1 < 0
        if flip:
            n = _event(1.0, not inside, ev_tau, ev_begin, n)
            inside = not inside
    return n, inside, gap1


def detection_state(pair_nodes, radii_sum, watch, touch, fractions, around, copies):
    """The kernels' detection tuple for ``copies`` copies, started over (no contact known, every pair
    examined at the next step): (pair_nodes (P, 4), radii_sum (P,) m, watch (W,), touch m, the search's
    sample fractions and offsets (``contact._FRACTIONS``, ``_AROUND``), then the state: inside (P, B),
    snap (P, 4, 3, B) m (rows 1-3: the pair's a1, b0, b1 in its own frame when last examined), budget
    (P, B) m, due (P, B) m, min_due (B,) m, odometer (B,) m, the last step's odometer increment (B,) m)."""
    k = pair_nodes.shape[0]
    return (np.ascontiguousarray(pair_nodes, dtype=np.int64), np.ascontiguousarray(radii_sum, dtype=float),
            np.ascontiguousarray(watch, dtype=np.int64), float(touch), np.ascontiguousarray(fractions, dtype=float),
            np.ascontiguousarray(around, dtype=float), np.zeros((k, copies), dtype=np.bool_),
            np.zeros((k, 4, 3, copies)), np.full((k, copies), -np.inf), np.full((k, copies), -np.inf),
            np.full(copies, -np.inf), np.zeros(copies), np.zeros(copies))


def no_detection():
    """The detection tuple of a run without contact detection (no pair: the loops skip it)."""
    return detection_state(np.zeros((0, 4), dtype=np.int64), np.zeros(0), np.zeros(0, dtype=np.int64), 0.0,
                           np.zeros(1), np.zeros(1), 1)


@njit(cache=True, error_model="numpy")
def new_events():
    """Empty event lists: (step, copy, pair, step fraction, begin) per event, and 24 numbers per event
    (the pair's 4 end points (4, 3) m at the step's start, then at its end)."""
    return List.empty_list(_EVENT), List.empty_list(types.float64)


@njit(cache=True, error_model="numpy")
def event_arrays(events, points):
    """The events of :func:`new_events`' lists as arrays, what the kernels return (Python then never
    touches a typed list, whose methods numba compiles at their first use in a process: ~1 s, once a
    node's first contact came): step, copy, pair (n,) int64, step fraction (n,), begin (n,) bool, and the
    pair's end points at the step's start and end (n, 2, 4, 3) m."""
    n = len(events)
    step = np.empty(n, dtype=np.int64)
    copy = np.empty(n, dtype=np.int64)
    pair = np.empty(n, dtype=np.int64)
    tau = np.empty(n)
    begin = np.empty(n, dtype=np.bool_)
    for e in range(n):
        step[e], copy[e], pair[e], tau[e], begin[e] = events[e]
    ends = np.empty(len(points))
    for i in range(ends.shape[0]):
        ends[i] = points[i]
    return step, copy, pair, tau, begin, ends.reshape((n, 2, 4, 3))


@njit(cache=True, error_model="numpy")
def new_work():
    """Scratch of :func:`measure` and :func:`examine`: a pair's end points at the step's start and end and
    their displacements (4, 3), its shape (9,), the narrow phase's numbers (22,) and a pair's transitions
    (step fractions, begins)."""
    return (np.empty((4, 3)), np.empty((4, 3)), np.empty((4, 3)), np.empty(9), np.empty(22),
            np.empty(_MAX_ROUNDS + 2), np.empty(_MAX_ROUNDS + 2, dtype=np.bool_))


@njit(cache=True, error_model="numpy", _nrt=False)
def moved_on(x0, b0, x1, b1, b, det):
    """The broad phase's test of a step of copy ``b`` from ``x0[:, :, b0]`` to ``x1[:, :, b1]`` (N, 3, .) m:
    adds to its odometer the largest step displacement of a watched node relative to their mean's,
    and says whether some pair is due (then :func:`measure` the step). Small, so that a loop inlines it."""
    watch, min_due, odometer, step_moved = det[2], det[10], det[11], det[12]
    # relative to the watched nodes' mean displacement: a common translation moves no gap
    n_watch = watch.shape[0]
    m0 = m1 = m2 = 0.0
    for w in range(n_watch):
        i = watch[w]
        m0 += x1[i, 0, b1] - x0[i, 0, b0]
        m1 += x1[i, 1, b1] - x0[i, 1, b0]
        m2 += x1[i, 2, b1] - x0[i, 2, b0]
    m0 /= n_watch
    m1 /= n_watch
    m2 /= n_watch
    step2 = 0.0
    for w in range(n_watch):
        i = watch[w]
        d0 = (x1[i, 0, b1] - x0[i, 0, b0]) - m0
        d1 = (x1[i, 1, b1] - x0[i, 1, b0]) - m1
        d2 = (x1[i, 2, b1] - x0[i, 2, b0]) - m2
        step2 = max(step2, d0 * d0 + d1 * d1 + d2 * d2)
    step_moved[b] = np.sqrt(step2)
    odometer[b] += step_moved[b]
    return odometer[b] >= min_due[b]   # (False for a NaN odometer: the step failed, and its copy with it)


@njit(cache=True, error_model="numpy", _nrt=False)
def measure(x1, b1, b, det, work, first):
    """The due pairs ``first``, ``first + 1``, ... of copy ``b`` (state column ``b`` of ``det``,
    :func:`detection_state`) at the step's end ``x1[:, :, b1]`` (N, 3, .) m, after :func:`moved_on` said some
    pair is due: each measured, and its due value moved on if it cannot have changed state over the step.
    Returns the first pair that may have (then :func:`examine` it, and measure on from the next), or -1
    once every pair is done (``min_due`` then updated). Allocates nothing and counts no references
    (``_nrt=False``): it runs at most steps of a moving structure, the narrow phase rarely."""
    pair_nodes, snap, budget, due, min_due, odometer, moved = det[0], det[7], det[8], det[9], det[10], det[11], det[12]
    n_pairs = pair_nodes.shape[0]
    odo = odometer[b]
    local = work[3]
    for p in range(first, n_pairs):
        if due[p, b] <= odo:
            # how far the pair's shape moved since it was last examined: its ends in its own frame
            reach = np.inf
            if _pair_frame(x1, b1, pair_nodes[p], local):
                shift_a = _distance(local, 0, snap[p, 1, 0, b], snap[p, 1, 1, b], snap[p, 1, 2, b])
                shift_b = max(_distance(local, 3, snap[p, 2, 0, b], snap[p, 2, 1, b], snap[p, 2, 2, b]),
                              _distance(local, 6, snap[p, 3, 0, b], snap[p, 3, 1, b], snap[p, 3, 2, b]))
                if shift_a + shift_b >= 0:   # (NaN: no shape measured yet)
                    reach = shift_a + shift_b
            # within the step the shape is at most this step's largest displacement (both members: twice)
            # from the end's, where it is at most `reach` from the examined one
            left = budget[p, b] - reach   # the gap at the step's end is at least this
            if left - 2.0 * moved[b] <= 0:
                return p
            due[p, b] = odo + 0.5 * left
    lowest = np.inf
    for p in range(n_pairs):
        lowest = min(lowest, due[p, b])
    min_due[b] = lowest
    return -1


@njit(cache=True, error_model="numpy")
def examine(x0, b0, x1, b1, b, s, det, work, events, points, p, copy):
    """Pair ``p``, which :func:`measure` found may have changed state over step ``s`` (positions from
    ``x0[:, :, b0]`` to ``x1[:, :, b1]`` (N, 3, .) m; state column ``b`` of ``det``), examined over the step by
    the narrow phase, then the due pairs after it measured, and examined where they need it: transitions
    are appended to ``events`` (as copy ``copy``'s) and ``points`` (:func:`new_events`); ``work``:
    :func:`new_work`."""
    pair_nodes, radii_sum, touch, fractions, around, inside, snap, budget, due, odometer = (
        det[0], det[1], det[3], det[4], det[5], det[6], det[7], det[8], det[9], det[11])
    p0, p1, disp, local, scratch, pair_tau, pair_begin = work
    while p >= 0:
        for k in range(4):
            i = pair_nodes[p, k]
            for j in range(3):
                p0[k, j] = x0[i, j, b0]
                p1[k, j] = x1[i, j, b1]
        found, ins, gap = _transitions(p0, p1, disp, radii_sum[p], inside[p, b], touch, fractions, around,
                                       pair_tau, pair_begin, scratch)
        for e in range(found):
            events.append((s, copy, p, pair_tau[e], pair_begin[e]))
            for k in range(4):
                for j in range(3):
                    points.append(p0[k, j])
            for k in range(4):
                for j in range(3):
                    points.append(p1[k, j])
        inside[p, b] = ins
        if not _pair_frame(x1, b1, pair_nodes[p], local):
            local[0] = np.nan   # no frame: the next look examines the pair again
        left = -gap if ins else gap
        budget[p, b] = left
        for k in range(3):
            for j in range(3):
                snap[p, k + 1, j, b] = local[3 * k + j]
        due[p, b] = odometer[b] + 0.5 * left if left > 0 else odometer[b]
        p = measure(x1, b1, b, det, work, p + 1)


@njit(cache=True, error_model="numpy", _nrt=False)
def _distance(local, k, u0, u1, u2):
    """|local[k:k + 3] - u| (m)."""
    e0 = local[k] - u0
    e1 = local[k + 1] - u1
    e2 = local[k + 2] - u2
    return np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)


@njit(cache=True, error_model="numpy", _nrt=False)
def _pair_frame(x, b, nodes, local):
    """The pair's ends a1, b0, b1 in its own frame (origin a0, first axis along a, second towards b's
    midpoint), written into ``local`` (9,) m: a rigid motion of the pair leaves them unchanged, and its
    gap is theirs. False (``local`` undefined) where the frame is degenerate."""
    a0, a1, c0, c1 = nodes[0], nodes[1], nodes[2], nodes[3]
    u0 = x[a1, 0, b] - x[a0, 0, b]
    u1 = x[a1, 1, b] - x[a0, 1, b]
    u2 = x[a1, 2, b] - x[a0, 2, b]
    nu = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    w0 = 0.5 * (x[c0, 0, b] + x[c1, 0, b]) - x[a0, 0, b]
    w1 = 0.5 * (x[c0, 1, b] + x[c1, 1, b]) - x[a0, 1, b]
    w2 = 0.5 * (x[c0, 2, b] + x[c1, 2, b]) - x[a0, 2, b]
    if not nu > 0:
        return False
    u0 /= nu
    u1 /= nu
    u2 /= nu
    along = w0 * u0 + w1 * u1 + w2 * u2
    w0 -= along * u0
    w1 -= along * u1
    w2 -= along * u2
    nw = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if not nw > 1e-6 * nu:
        return False
    w0 /= nw
    w1 /= nw
    w2 /= nw
    z0 = u1 * w2 - u2 * w1
    z1 = u2 * w0 - u0 * w2
    z2 = u0 * w1 - u1 * w0
    for k in range(3):
        i = nodes[k + 1]
        d0 = x[i, 0, b] - x[a0, 0, b]
        d1 = x[i, 1, b] - x[a0, 1, b]
        d2 = x[i, 2, b] - x[a0, 2, b]
        local[3 * k] = d0 * u0 + d1 * u1 + d2 * u2
        local[3 * k + 1] = d0 * w0 + d1 * w1 + d2 * w2
        local[3 * k + 2] = d0 * z0 + d1 * z1 + d2 * z2
    return True


# copies gathered at a time by detect_steps: the copies one cache line of a row holds
_TILE = 8


@njit(cache=True, error_model="numpy")
def _column_state(det):
    """A state of one copy beside ``det`` (:func:`detection_state`): its pairs, its state arrays of one column."""
    k = det[0].shape[0]
    return (det[0], det[1], det[2], det[3], det[4], det[5], np.empty((k, 1), dtype=np.bool_), np.empty((k, 4, 3, 1)),
            np.empty((k, 1)), np.empty((k, 1)), np.empty(1), np.empty(1), np.empty(1))


@njit(cache=True, error_model="numpy", _nrt=False)
def _copy_column(src, bs, dst, bd):
    """Column ``bs`` of the state arrays of ``src`` (:func:`detection_state`) into column ``bd`` of ``dst``'s."""
    for p in range(src[6].shape[0]):
        dst[6][p, bd] = src[6][p, bs]
        dst[8][p, bd] = src[8][p, bs]
        dst[9][p, bd] = src[9][p, bs]
        for k in range(4):
            for j in range(3):
                dst[7][p, k, j, bd] = src[7][p, k, j, bs]
    dst[10][bd] = src[10][bs]
    dst[11][bd] = src[11][bs]
    dst[12][bd] = src[12][bs]


@njit(cache=True, error_model="numpy", nogil=True)   # nogil: blocks of copies on threads (methods/_copy_blocks.py)
def detect_steps(xs, stop, det):
    """Detection over the first ``stop[b]`` steps of a chunk, copy by copy: ``xs`` (K + 1, N, 3, B) m,
    the positions before the chunk's first step, then after each of its steps; ``stop`` (B,) int (a
    failed copy walks fewer, or none). Updates ``det`` (:func:`detection_state`); returns the events
    (:func:`event_arrays`).

    Each copy is walked through the chunk in arrays of its own (its positions gathered ``_TILE`` copies at a
    time, its state column copied in and out): a copy's numbers in ``xs`` and ``det`` lie ``B`` apart, and
    with ``B`` a power of two every row of a step falls in the same cache set (walked in place, 0.72 µs per
    copy-step at B = 512 against 0.29 at B = 500)."""
    n_rows, n_nodes, _, n_copies = xs.shape
    events, points = new_events()
    work = new_work()
    tile = np.empty((_TILE, n_rows, n_nodes, 3, 1))
    one = _column_state(det)
    for first in range(0, n_copies, _TILE):
        last = min(first + _TILE, n_copies)
        for s in range(n_rows):
            for i in range(n_nodes):
                for j in range(3):
                    for b in range(first, last):
                        tile[b - first, s, i, j, 0] = xs[s, i, j, b]
        for b in range(first, last):
            _copy_column(det, b, one, 0)
            x = tile[b - first]
            for s in range(min(stop[b], n_rows - 1)):
                if moved_on(x[s], 0, x[s + 1], 0, 0, one):
                    p = measure(x[s + 1], 0, 0, one, work, 0)
                    if p >= 0:
                        examine(x[s], 0, x[s + 1], 0, 0, s, one, work, events, points, p, b)
            _copy_column(one, 0, det, b)
    return event_arrays(events, points)
