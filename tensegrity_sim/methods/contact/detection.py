"""Contact detection between members (physics.md section 5): continuous in time, one event at each
begin and end. Detection only: nothing here pushes members apart.

**Model.** A member is a capsule: the segment between its two nodes, thickened by its radius. Two members
that share no node are in contact while the *gap* ``g = |segment distance| - r_a - r_b`` is negative
(the distance is below the sum of the radii). A contact *begins* when ``g`` becomes negative and *ends*
when it is back at ``>= 0`` (strictly: at ``CHATTER`` times the pair's size, far above round-off, so
that members sliding along each other at touching distance do not chatter). Each is a
:class:`~tensegrity_sim.results.ContactEvent` with the time, the closest points, the unit normal from
member a to member b and the gap (≈ 0 at a begin or an end inside a step; the initial penetration for a
pair that already overlaps when the simulation starts, reported as a begin at that step's start time).
While a contact lasts no further event is emitted; :meth:`ContactDetector.active` gives every ongoing
contact with its current (negative) gap.

**Motion within a step.** The simulator hands over the node positions at the start and at the end of a
step; in between every node moves on the straight line between them, ``x(τ) = (1-τ) x0 + τ x1`` with
``τ = (t - t0)/dt`` in [0, 1]. The gap ``g(τ)`` of two moving segments is neither linear nor convex in
``τ`` (the closest features change), so the first crossing is found by a search that *certifies* every
stretch of the step it leaves behind (:func:`_reaches`): from any configuration, out of contact, the
plane through the closest points separates the segments, every end point's height along its normal moves
linearly, so the capsules cannot touch before one of the four end-point height differences drops to
``r_a + r_b`` (exact for a translation, never weaker than the Lipschitz bound ``|Δg| <= V |Δτ|`` with
``V`` the largest relative end-point displacement), nor, where it reaches further, before the distance of
their lines can (:func:`_line_reach`: exact to first order, so a strut rocking on another a fraction of a µm
away, whose end points sweep thousands of gaps a step, is certified at once); in contact, the two closest *material* points move
linearly, and the contact lasts at least while they stay within ``r_a + r_b`` (a quadratic in ``τ``).
Both bounds hold forwards and backwards in time, so two samples certify the interval between them when
their reaches overlap.

**Time of contact** (:func:`transitions`). A pair whose reaches from the step's two ends overlap needs
nothing more (most pairs). The others are searched together, as arrays, a few rounds each: a round
samples the unexamined part ``[a, b]`` of the step (about 240 times per pair: log-spaced towards both
ends, evenly in between, and around the regula-falsi estimate of a bracketed crossing), moves ``a``
over every certified interval and ``b`` back to the first sample found on the other side. A crossing
is bracketed to ``TAU_TOLERANCE`` of the step and its time interpolated linearly inside that bracket:
exact for a linear gap, second-order otherwise; about four rounds per crossing. The search then goes on
from the other side, ``RESOLUTION`` later, to the step's end, so a strut crossing another at many radii
per step gives its begin and its end in the same step. What may escape, stated as the tolerances: an
uncertified sliver narrower than ``TAU_TOLERANCE`` is stepped over (a graze shallower than about
``V·TAU_TOLERANCE/2``), and a contact or separation lasting less than ``RESOLUTION`` of a step right after
a crossing is not resolved (if the state is back, that is reported where it is seen, at most
``RESOLUTION`` late).

**Narrow phase** (:func:`closest_points`): the distance of two segments is the minimum of a convex
quadratic over the unit square, attained either at the interior critical point or on one of the four
edges (an end point against the other segment, a clamped projection). All five candidates are actual
point pairs on the segments and the smallest wins, so the result is exact for parallel, collinear and
degenerate (zero-length) segments and never NaN; the interior candidate is computed in an orthogonalised
basis (``d_b`` minus its component along ``d_a``) so that nearly parallel segments (1e-9 rad) keep full
accuracy, where the textbook ``ac - b²`` determinant cancels to noise.

**Broad phase and what is skipped.** Only the member kinds a scene asks for (``Scene.contact_kinds``),
only members with a radius > 0, never a cable attached along a strut (physics.md section 4c: its end is not a
node, and the detection's segments, events and the contact response's rows are node-to-node), and never two
members that share a node or whose four nodes are all fixed.
The remaining pairs go through a sort-and-sweep of axis-aligned boxes (along the axis of widest spread)
inflated by the radii and by a *skin* (by default 10 % of the median checked member length); that list is
valid until some node has moved by more than the skin, and is rebuilt then, so its cost is paid rarely and
grows with the number of nearby pairs. Each listed pair keeps how far it was from changing state when
last examined (its gap, or while in contact its penetration) and is examined again only when its members
may have moved by that much since (then together with the pairs past half of theirs: one batch costs
about what one pair does); while no node has moved more than half the smallest such margin since the
last check, a step costs one array comparison over the nodes. When a scene checks nothing, the simulator builds no detector at all.

The simulators step :class:`CompiledDetector`: the same events from compiled code
(``methods/contact/_detection_kernels.py``, with a broad phase of its own), inside the elastic method's compiled
``run()`` loop or over a chunk of steps; :class:`ContactDetector` is the plain reference that tests hold
it to.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...results import ContactEvent
from ...scene import CONTACT_KINDS
from ...system import System
from .._copy_blocks import copy_blocks, on_blocks

__all__ = ["ActiveContact", "ContactDetector", "CompiledDetector", "box_pairs", "closest_points", "contact_geometry",
           "transitions", "make_detector", "TAU_TOLERANCE", "SKIN_FRACTION", "COMPILED_PAIRS"]

TAU_TOLERANCE = 1e-9    # width (fraction of the step) to which a crossing is bracketed before interpolation
RESOLUTION = 1e-7       # after a crossing, the search for the next one starts this much later (step fraction)
CHATTER = 1e-12         # an end needs the gap back at CHATTER x (r_a + r_b + largest end-point |coordinate|)
MAX_ROUNDS = 100        # safety bound on the search loop
# Where a round samples its window, as fractions of it: log-spaced towards both ends (where a crossing
# or a just-crossed one makes the certified reaches short) and evenly in between. The first interval
# is narrower than TAU_TOLERANCE, so a round that cannot certify it steps over it: every round progresses.
_FRACTIONS = np.unique(np.concatenate([[0.0], np.geomspace(1e-12, 1.0, 100),
                                       1.0 - np.geomspace(1e-12, 1.0, 100), np.linspace(0.0, 1.0, 33)]))
_AROUND = np.array([-1e-2, -1e-4, -1e-6, -1e-8, 0.0, 1e-8, 1e-6, 1e-4, 1e-2])
SKIN_FRACTION = 0.1     # default skin of the pair list, as a fraction of the median checked member length
_SQRT3 = float(np.sqrt(3.0))  # |d|_2 <= sqrt(3) |d|_inf for a 3-vector


@dataclass(frozen=True)
class ActiveContact:
    """An ongoing contact. members: (name_a, name_b). since: s, time of its begin event.
    point_a, point_b: closest points (3,) m now. normal: unit (3,), from a to b.
    distance: m, segment distance minus both radii now (negative: penetration).
    normal_impulse: N*s, normal impulse of the last step; tangential_impulse (3,) N*s its friction
    (zero for contacts that are only detected)."""

    members: tuple[str, str]
    since: float
    point_a: np.ndarray
    point_b: np.ndarray
    normal: np.ndarray
    distance: float
    normal_impulse: float = 0.0
    tangential_impulse: np.ndarray = field(default_factory=lambda: np.zeros(3))


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", u, v)


def _over(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """``num / den`` where ``den > 0``, inf elsewhere (a rate that never closes the gap)."""
    out = np.full(np.broadcast(num, den).shape, np.inf)
    return np.divide(num, den, out=out, where=den > 0)


def _cross(u, v):
    """``u x v`` of (..., 3) arrays, written out (``_detection_kernels._line_reach`` does the same sums)."""
    return np.stack([u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1], u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
                     u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]], axis=-1)


def _sum3(u, v):
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1] + u[..., 2] * v[..., 2]


def _line_reach(ends, disp, radii_sum):
    """How long (step fractions, forwards and backwards) two capsules apart surely stay apart by their *lines*:
    the segments' distance is at least the lines', ``s (w . C) / |C|`` with ``C = d_a x d_b``, ``w`` from a's
    first end to b's and ``s`` the sign of ``w . C`` now. Along the step ``w . C = N0 + N1 x + N2 x^2 + N3 x^3``
    and ``C = C0 + C1 x + C2 x^2`` exactly, and ``|C| <= |C0| + u . (C - C0) + |C - C0|^2 / (2 |C0|)`` (``u`` =
    ``C0 / |C0|``), so ``s w . C - r |C| >= f0 + f1 x - q2 x^2 - q3 |x|^3 - q4 x^4`` with ``f0 = s N0 - r |C0|``
    and ``f1 = s N1 - r u . C1`` (the first derivative: a lifting pair's helps forwards); each of the four
    falling terms held to ``f0 / 4`` gives the reach. Exact to first order where the closest points are inside
    both segments: a strut rocking on another 0.2 um away, whose end points' heights (the plane's bound) move
    2,000 times its gap a step, is certified for the whole step. 0 where the lines do not keep the capsules
    apart (parallel lines, closest points at an end beyond the other line)."""
    e, d, r = ends, disp, radii_sum
    da, db, w = e[..., 1, :] - e[..., 0, :], e[..., 3, :] - e[..., 2, :], e[..., 2, :] - e[..., 0, :]
    dda, ddb, dw = d[..., 1, :] - d[..., 0, :], d[..., 3, :] - d[..., 2, :], d[..., 2, :] - d[..., 0, :]
    c0, c2 = _cross(da, db), _cross(dda, ddb)
    c1 = _cross(dda, db) + _cross(da, ddb)
    n0 = _sum3(w, c0)
    sign = np.where(n0 < 0.0, -1.0, 1.0)
    n1 = sign * (_sum3(w, c1) + _sum3(dw, c0))
    n2 = _sum3(w, c2) + _sum3(dw, c1)
    n3 = _sum3(dw, c2)
    size0, size1, size2 = np.sqrt(_sum3(c0, c0)), np.sqrt(_sum3(c1, c1)), np.sqrt(_sum3(c2, c2))
    f0 = sign * n0 - r * size0
    inv = 1.0 / np.where(size0 > 0.0, size0, np.inf)
    f1 = n1 - r * (_sum3(c0, c1) * inv)
    q2 = np.abs(n2) + r * (np.abs(_sum3(c0, c2)) * inv) + r * (size1 * size1 * (0.5 * inv))
    q3 = np.abs(n3) + r * (size1 * size2 * inv)
    q4 = r * (size2 * size2 * (0.5 * inv))
    quarter = np.maximum(f0, 0.0) / 4.0   # (f0 <= 0: no reach, below)
    rest = np.minimum(np.minimum(np.sqrt(_over(quarter, q2)), _over(quarter, q3) ** (1.0 / 3.0)),
                      np.sqrt(np.sqrt(_over(quarter, q4))))
    ahead = np.minimum(_over(quarter, -f1), rest)
    behind = np.minimum(_over(quarter, f1), rest)
    keep = (f0 > 0.0) & (size0 > 0.0)
    return np.where(keep, ahead, 0.0), np.where(keep, behind, 0.0)


def closest_points(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray):
    """Closest points of segments ``p0-p1`` and ``q0-q1``; arrays of shape (..., 3), m.

    Returns ``distance`` (...) m, and ``s``, ``t`` (...) in [0, 1], the closest points being
    ``p0 + s (p1 - p0)`` and ``q0 + t (q1 - q0)``. When they are not unique (parallel overlapping
    segments) one of the pairs is returned, always with an end point of one of the segments.
    """
    return _closest(p0, p1, q0, q1)[:3]


def _closest(p0, p1, q0, q1):
    """:func:`closest_points`, plus the vector (..., 3) m from the first closest point to the second."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, b = _dot(d1, d1), _dot(d2, d2), _dot(d1, d2)
    c, f = _dot(d1, r), _dot(d2, r)
    # 1/a, 1/e; 0 for a zero-length segment, all of whose points are then its first end
    inv_a = 1.0 / np.where(a > 0, a, np.inf)
    inv_e = 1.0 / np.where(e > 0, e, np.inf)
    beta, gamma = b * inv_a, c * inv_a
    # Interior critical point, in the basis (d1, d2p) with d2p = d2 - (b/a) d1 orthogonal to d1:
    # minimising |r + (s - t b/a) d1 - t d2p|^2 gives t = (r.d2p)/|d2p|^2, then s = t b/a - c/a.
    # Both factors of r.d2p are taken perpendicular to d1 first: for nearly parallel segments d2p is
    # tiny and its rounding error along d1, times r's large component along d1, would swamp it.
    d2p = d2 - beta[..., None] * d1
    r_perp = r - gamma[..., None] * d1
    perp2 = _dot(d2p, d2p)
    # candidates (s, t): the interior point; p0 and p1 against segment q; q0 and q1 against segment p
    s, t = np.empty(a.shape + (5,)), np.empty(a.shape + (5,))
    t[..., 0] = _dot(r_perp, d2p) / np.where(perp2 > 0, perp2, np.inf)
    t[..., 1] = f
    t[..., 2] = f + b
    t[..., 1:3] *= inv_e[..., None]
    t[..., 3], t[..., 4] = 0.0, 1.0
    np.clip(t, 0.0, 1.0, out=t)
    s[..., 0] = t[..., 0] * beta - gamma
    s[..., 1], s[..., 2] = 0.0, 1.0
    s[..., 3] = -gamma
    s[..., 4] = beta - gamma
    np.clip(s, 0.0, 1.0, out=s)
    w = r[..., None, :] + s[..., None] * d1[..., None, :] - t[..., None] * d2[..., None, :]
    dist2 = _dot(w, w).reshape(-1, 5)
    best = np.argmin(dist2, axis=1)
    rows = np.arange(best.size)
    return (np.sqrt(dist2[rows, best]).reshape(a.shape), s.reshape(-1, 5)[rows, best].reshape(a.shape),
            t.reshape(-1, 5)[rows, best].reshape(a.shape),
            -w.reshape(-1, 5, 3)[rows, best].reshape(r.shape))


def _interpolate(p0: np.ndarray, p1: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """End points (n, ..., 4, 3) at step fractions ``tau`` (n, ...); exact at tau = 0 and 1."""
    extra = (None,) * (tau.ndim - 1)
    tau = tau[..., None, None]
    return (1.0 - tau) * p0[(slice(None),) + extra] + tau * p1[(slice(None),) + extra]


def contact_geometry(ends: np.ndarray, radii_sum: np.ndarray):
    """Closest points ``pa``, ``pb`` (n, 3) m, unit normals from a to b (n, 3), gaps (n,) m and the closest
    points' parameters ``s``, ``t`` (n,) along a and b of capsule pairs ``ends`` (n, 4, 3).

    Where the segments intersect (no direction between the closest points) the normal is along
    ``d_a x d_b`` (any perpendicular of ``d_a`` for parallel ones), turned towards b's midpoint."""
    a0, a1, b0, b1 = (ends[:, i] for i in range(4))
    dist, s, t = closest_points(a0, a1, b0, b1)
    pa = a0 + s[:, None] * (a1 - a0)
    pb = b0 + t[:, None] * (b1 - b0)
    normal = pb - pa
    degenerate = dist <= 1e-12 * (1.0 + np.abs(ends).max(axis=(1, 2)))
    if degenerate.any():
        da, db = a1 - a0, b1 - b0
        fallback = np.cross(da, db)
        parallel = _dot(fallback, fallback) == 0.0
        # a perpendicular of d_a: cross it with the coordinate axis it is least aligned with
        axis = np.eye(3)[np.argmin(np.abs(da), axis=1)]
        fallback = np.where(parallel[:, None], np.cross(da, axis), fallback)
        towards = 0.5 * (b0 + b1 - a0 - a1)
        fallback = np.where((_dot(fallback, towards) < 0)[:, None], -fallback, fallback)
        normal = np.where(degenerate[:, None], fallback, normal)
    length = np.sqrt(_dot(normal, normal))
    # (only two coincident zero-length members leave no direction at all: then +z)
    normal = np.where((length > 0)[:, None], normal / np.where(length > 0, length, 1.0)[:, None],
                      [0.0, 0.0, 1.0])
    return pa, pb, normal, dist - radii_sum, s, t


def _reaches(ends, disp, radii_sum, inside):
    """Gap and how long the current state surely lasts, forwards and backwards, from configurations
    ``ends`` (..., 4, 3) whose end points move by ``disp`` (..., 4, 3) per unit of step fraction.

    ``inside`` (...) bool, or None: then the state is the one the gap says (in contact if negative).
    Returns ``gap`` (...) m and ``forward``, ``backward`` (...) in step fractions (inf: for ever).
    Out of contact: the closest points define a plane that separates the two segments; along its
    normal each end point's height moves linearly, so the capsules cannot touch before the first of
    the four (end of a, end of b) height differences reaches ``r_a + r_b``; or, where it reaches further,
    before the lines' distance can (:func:`_line_reach`). In contact: the two closest
    *material* points move linearly, and the contact surely lasts while they stay within ``r_a + r_b``.
    Both bounds become exact for a translation, and are never weaker than the Lipschitz bound.
    """
    dist, s, t, w = _closest(ends[..., 0, :], ends[..., 1, :], ends[..., 2, :], ends[..., 3, :])
    gap = dist - radii_sum
    if inside is None:
        inside = gap < 0
    forward, backward = np.empty(gap.shape), np.empty(gap.shape)
    outside = ~inside
    if outside.any():
        normal = w / np.where(dist > 0, dist, np.inf)[..., None]
        # heights of the four end points along the normal and their rates, for each (end of a, end of b)
        height, rise = _dot(ends, normal[..., None, :]), _dot(disp, normal[..., None, :])
        c = np.maximum(height[..., None, 2:] - height[..., :2, None] - radii_sum[..., None, None], 0.0)
        v = rise[..., None, 2:] - rise[..., :2, None]                                  # (..., 2, 2)
        # ... or the lines' bound where it reaches further, wherever the plane's falls short of a step (a step's
        # reaches are compared with at most 1; the compiled twin computes the lines' there only)
        line_ahead, line_behind = _line_reach(ends, disp, radii_sum)
        ahead, behind = _over(c, -v).min(axis=(-2, -1)), _over(c, v).min(axis=(-2, -1))
        short = (ahead < 1.0) | (behind < 1.0)
        ahead = np.where(short & (line_ahead > ahead), line_ahead, ahead)
        behind = np.where(short & (line_behind > behind), line_behind, behind)
        # (a segment distance of 0 leaves no normal: no reach; out of contact it needs zero radii)
        touching = dist == 0
        np.copyto(forward, np.where(touching, 0.0, ahead), where=outside)
        np.copyto(backward, np.where(touching, 0.0, behind), where=outside)
    if inside.any():
        # the closest material points: w(x) = w + x dw stays within r_a + r_b between the roots of
        # qa x^2 + 2 qb x + qc (qc <= 0), written as -qc / (qb +- root) to avoid cancellation
        dw = ((disp[..., 2, :] + t[..., None] * (disp[..., 3, :] - disp[..., 2, :]))
              - (disp[..., 0, :] + s[..., None] * (disp[..., 1, :] - disp[..., 0, :])))
        qa, qb, qc = _dot(dw, dw), _dot(w, dw), np.minimum(_dot(w, w) - radii_sum ** 2, 0.0)
        root = np.sqrt(qb * qb - qa * qc)
        np.copyto(forward, _over(-qc, qb + root), where=inside)
        np.copyto(backward, _over(-qc, root - qb), where=inside)
    return gap, forward, backward


def transitions(p0: np.ndarray, p1: np.ndarray, radii_sum: np.ndarray, inside: np.ndarray, touch: float = 0.0):
    """Every begin and end of contact within one step, for ``n`` capsule pairs moving linearly.

    ``p0``, ``p1``: (n, 4, 3) m, end points [a0, a1, b0, b1] at the step's start and end.
    ``radii_sum``: (n,) m. ``inside``: (n,) bool, in contact just before the step. ``touch``: m, an end
    needs the gap at least at this too (members held in contact by a response rest at a gap of ~0); with
    ``touch`` > 0 (a response) a pair in contact at both ends of the step is in contact throughout it.

    Returns ``(pair, tau, begin, inside_end, gap_end)``: for each transition, in no particular order,
    the pair's index (e,), the step fraction (e,) in [0, 1] and whether it is a begin (e,) bool; then
    the state (n,) and the gap (n,) m at the step's end. A pair not in contact but penetrating at
    ``tau = 0`` begins at 0.
    """
    inside = np.array(inside, dtype=bool)
    disp = p1 - p0
    ends = np.stack([p0, p1])
    # an end needs the gap at CHATTER x the pair's size: above its round-off, so no begin-end chatter
    margin = np.maximum(CHATTER * (radii_sum + np.abs(ends).max(axis=(0, 2, 3))), touch)
    # (2, n): at tau = 0 and 1, each judged by its own gap's sign (a crossing at 1 is caught below)
    gap, forward, backward = _reaches(ends, disp, radii_sum, None)
    found_pair, found_tau, found_begin = [], [], []
    starts = ~inside & (gap[0] < 0)
    if starts.any():
        found_pair.append(np.flatnonzero(starts))
        found_tau.append(np.zeros(int(starts.sum())))
        found_begin.append(np.ones(int(starts.sum()), dtype=bool))
        inside |= starts
    # the whole step at once: the same side at both ends, and their reaches overlap? With a response (touch > 0),
    # a pair in contact at both ends stays in contact: the response holds it there over the step, where the
    # straight path between two resting configurations is not the motion (certifying it to the gap's round-off
    # took rounds of samples: 0.2 ms a step for a strut resting on another)
    held = inside & (touch > 0.0)
    sure = ~_crossed(np.where(inside, -gap[1], gap[1]), inside, margin) & ((forward[0] + backward[1] >= 1.0) | held)
    todo = np.flatnonzero(~sure)
    if todo.size:
        pair, tau, begin, inside_todo = _search(p0[todo], p1[todo], radii_sum[todo], margin[todo],
                                                inside[todo], gap[0, todo], gap[1, todo])
        found_pair.append(todo[pair])
        found_tau.append(tau)
        found_begin.append(begin)
        inside[todo] = inside_todo
    if not found_pair:
        return np.zeros(0, dtype=np.intp), np.zeros(0), np.zeros(0, dtype=bool), inside, gap[1]
    return (np.concatenate(found_pair), np.concatenate(found_tau), np.concatenate(found_begin), inside,
            gap[1])


def _crossed(h: np.ndarray, inside: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """Has a sample ``h = ±gap`` crossed over? A begin is ``gap < 0``; an end is ``gap >= margin``."""
    return np.where(inside, h <= -margin, h < 0)


def _search(p0, p1, radii_sum, margin, inside, gap0, gap1):
    """The certified search of the module docstring, for pairs (n,) that may change state in the step.

    ``p0``, ``p1`` (n, 4, 3) m, ``radii_sum`` (n,) m, ``margin`` (n,) m (an end needs the gap at it),
    ``inside`` (n,) bool at the start, ``gap0``, ``gap1`` (n,) m at the step's start and end. Returns
    ``(pair, tau, begin, inside_end)`` as :func:`transitions` does.

    Per pair: everything before ``a`` is certified to be on the current side, and each round samples
    ``[a, b]``, where ``b`` is the step's end or the first time found on the other side
    (``crossed_b``: then the first crossing lies in ``[a, b]``).
    """
    n = len(radii_sum)
    inside = inside.copy()
    sign = np.where(inside, -1.0, 1.0)
    disp = p1 - p0
    a, b = np.zeros(n), np.ones(n)
    h_a, h_b = sign * gap0, sign * gap1
    crossed_b = _crossed(h_b, inside, margin)
    out_pair, out_tau, out_begin = [], [], []
    live = np.arange(n)
    rounds = 0
    while live.size and rounds < MAX_ROUNDS:
        rounds += 1
        rows = np.arange(live.size)
        A, B, ins = a[live], b[live], inside[live]
        # plus samples around the regula-falsi point, where a bracketed crossing probably is
        span = h_a[live] - h_b[live]
        falsi = np.divide(h_a[live], span, out=np.full(live.size, 0.5), where=span > 0)
        fractions = np.sort(np.concatenate([np.broadcast_to(_FRACTIONS, (live.size, _FRACTIONS.size)),
                                            np.clip(falsi[:, None] + _AROUND, 0.0, 1.0)], axis=1), axis=1)
        times = A[:, None] + (B - A)[:, None] * fractions
        times[:, -1] = B
        g, forward, backward = _reaches(_interpolate(p0[live], p1[live], times), disp[live, None],
                                        radii_sum[live, None], ins[:, None])
        h = sign[live, None] * g
        crossed = _crossed(h, ins[:, None], margin[live, None])
        at_a = crossed[:, 0]
        # the first sample on the other side brackets the first crossing
        j = np.argmax(crossed, axis=1)
        found = crossed[rows, j] & ~at_a
        b[live] = np.where(found, times[rows, j], B)
        h_b[live] = np.where(found, h[rows, j], h_b[live])
        crossed_b[live] |= found
        # and `a` moves over every interval certified by the reaches of its two ends
        certified = ~crossed[:, 1:] & (forward[:, :-1] + backward[:, 1:] >= np.diff(times, axis=1))
        c = np.argmax(~certified, axis=1)
        blocked = ~certified[rows, c]
        left, right = times[rows, c], times[rows, c + 1]
        # an uncertified sliver below the resolution is stepped over (a contact that shallow cannot
        # be told from round-off)
        sliver = blocked & ~crossed[rows, c + 1] & (right - left <= TAU_TOLERANCE)
        a[live] = np.where(~blocked, B, np.where(sliver, right, left))
        h_a[live] = np.where(~blocked, h[:, -1], np.where(sliver, h[rows, c + 1], h[rows, c]))
        event = at_a | (crossed_b[live] & (b[live] - a[live] <= TAU_TOLERANCE))
        if event.any():
            ev, k = np.flatnonzero(event), live[event]
            span = h_a[k] - h_b[k]
            share = np.clip(np.divide(h_a[k], span, out=np.ones(ev.size), where=span > 0), 0.0, 1.0)
            when = np.where(at_a[ev], A[ev], a[k] + (b[k] - a[k]) * share)
            out_pair.append(k)
            out_tau.append(when)
            out_begin.append(~ins[ev])
            # the other side from just after the crossing (RESOLUTION) to the step's end
            inside[k] = ~ins[ev]
            sign[k] = -sign[k]
            a[k] = np.minimum(np.where(at_a[ev], A[ev], b[k]) + RESOLUTION, 1.0)
            h_a[k] = -np.where(at_a[ev], h[ev, 0], h_b[k])
            b[k] = 1.0
            h_b[k] = sign[k] * gap1[k]
            crossed_b[k] = _crossed(h_b[k], inside[k], margin[k])
        live = live[(a[live] < b[live]) | (crossed_b[live] & (a[live] == b[live]))]
    if live.size:
        # The round bound was hit (non-finite positions, or a graze held at the resolution limit):
        # settle the state from the step's end so that begins and ends still pair up.
        flip = np.where(inside[live], gap1[live] >= margin[live], gap1[live] < 0)
        out_pair.append(live[flip])
        out_tau.append(np.ones(int(flip.sum())))
        out_begin.append(~inside[live[flip]])
        inside[live[flip]] = ~inside[live[flip]]
    if not out_pair:
        return np.zeros(0, dtype=np.intp), np.zeros(0), np.zeros(0, dtype=bool), inside
    return np.concatenate(out_pair), np.concatenate(out_tau), np.concatenate(out_begin), inside


def box_pairs(lo: np.ndarray, hi: np.ndarray):
    """Index pairs (i, j), i != j, of overlapping axis-aligned boxes (n, 3): sort and sweep along the axis
    where the boxes spread most. Cost: a sort plus the pairs that overlap along that axis."""
    n = len(lo)
    if n < 2:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    axis = int(np.argmax(np.var(lo + hi, axis=0)))
    order = np.argsort(lo[:, axis], kind="stable")
    lo_sorted = lo[order, axis]
    stop = np.searchsorted(lo_sorted, hi[order, axis], side="right")
    counts = np.maximum(stop - np.arange(n) - 1, 0)
    first = np.repeat(np.arange(n), counts)
    offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    i, j = order[first], order[first + 1 + offset]
    keep = np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
    return i[keep], j[keep]


class ContactDetector:
    """Continuous contact detection for the members of a :class:`System` (see the module docstring).

    ``kinds``: member kinds to check, a subset of :data:`~tensegrity_sim.scene.CONTACT_KINDS`.
    ``skin``: m, margin of the pair list (default ``SKIN_FRACTION`` × the median checked member length).
    It starts at the scene's positions (:meth:`reset` starts over anywhere); then :meth:`step` once per
    step, in order. ``touch``: m, a contact ends only when the gap is back at this (a contact response
    holds members at a gap of about 0, within its own tolerance: 0 would chatter).
    """

    def __init__(self, system: System, kinds, *, skin: float | None = None, touch: float = 0.0):
        self.system = system
        self.touch = float(touch)
        self._impulses = {}   # the last step's contact impulses, {(member i, member j): (normal, friction (3,))}
        self.kinds = tuple(kinds)
        radius = np.concatenate([[s.radius for s in system.scene.struts],
                                 [c.radius for c in system.scene.cables]]).astype(float)
        is_cable = np.arange(system.n_members) >= system.n_struts
        kind_ok = np.zeros((2, 2), dtype=bool)   # [kind of a, kind of b], 0 strut, 1 cable
        for name, (u, v) in zip(CONTACT_KINDS, ((0, 0), (0, 1), (1, 1))):
            kind_ok[u, v] = kind_ok[v, u] = name in self.kinds
        takes_part = kind_ok[is_cable.astype(int)].any(axis=1)
        takes_part[system.n_struts + system.attached] = False   # a cable along a strut: not a node-to-node segment
        self.members = np.flatnonzero((radius > 0) & takes_part)   # checked members (system order)
        self._kind = is_cable.astype(int)
        self._kind_ok = kind_ok
        self.radius = radius   # (n_members,) m, struts first
        self._member_fixed = ~system.free[system.ends].any(axis=1)
        self.names = system.scene.strut_names + system.scene.cable_names
        nodes = np.unique(system.ends[self.members])
        # The nodes whose motion matters. All of them (a slice: no copy in the step) when the others
        # are fixed, since a fixed node never moves.
        self._watch = slice(None) if system.free[nodes].sum() == system.free.sum() else nodes
        if skin is None:
            _, length, _ = system.geometry(system.scene.positions, system.ends[self.members])
            skin = SKIN_FRACTION * float(np.median(length)) if len(length) else 1.0
        self.skin = float(skin)
        if not (np.isfinite(self.skin) and self.skin > 0):
            raise ValueError(f"skin must be a positive finite length in m, got {skin!r}")
        self.reset(system.scene.positions)

    # ------------------------------------------------------------------ pairs
    def eligible(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """(k,) bool: may members ``i`` and ``j`` (system indices, (k,)) ever be reported in contact?"""
        ends = self.system.ends
        share = ((ends[i, 0] == ends[j, 0]) | (ends[i, 0] == ends[j, 1])
                 | (ends[i, 1] == ends[j, 0]) | (ends[i, 1] == ends[j, 1]))
        return (self._kind_ok[self._kind[i], self._kind[j]] & ~share
                & ~(self._member_fixed[i] & self._member_fixed[j]) & (i != j))

    def eligible_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Every eligible pair of checked members ``(i, j)`` (k,), ``i < j`` (system indices), in key order."""
        a, b = np.triu_indices(len(self.members), 1)
        i, j = self.members[a], self.members[b]
        ok = self.eligible(i, j)
        return i[ok], j[ok]

    def _rebuild(self, x0: np.ndarray, x1: np.ndarray, keep_state: bool) -> None:
        """New pair list from boxes holding the members' sweep from ``x0`` to ``x1`` and any later
        position within the skin of ``x1``; pairs already listed keep their state."""
        m = self.members
        ends0, ends1 = x0[self.system.ends[m]], x1[self.system.ends[m]]      # (mc, 2, 3)
        pad = self.radius[m, None]
        lo = np.minimum(ends0.min(axis=1), ends1.min(axis=1) - self.skin) - pad
        hi = np.maximum(ends0.max(axis=1), ends1.max(axis=1) + self.skin) + pad
        bi, bj = box_pairs(lo, hi)
        i, j = np.minimum(m[bi], m[bj]), np.maximum(m[bi], m[bj])
        ok = self.eligible(i, j)
        key = np.unique(i[ok] * self.system.n_members + j[ok])
        k = len(key)
        i, j = key // self.system.n_members, key % self.system.n_members
        inside, since = np.zeros(k, dtype=bool), np.full(k, np.nan)
        snap, budget = np.zeros((k, 4, 3)), np.full(k, -np.inf)  # -inf: evaluate at the next step
        if keep_state and len(self._key):
            where = np.searchsorted(self._key, key)
            where = np.minimum(where, len(self._key) - 1)
            old = self._key[where] == key
            inside[old], since[old] = self._inside[where[old]], self._since[where[old]]
            snap[old], budget[old] = self._snap[where[old]], self._budget[where[old]]
        self._key, self._i, self._j = key, i, j
        self._ends = np.concatenate([self.system.ends[i], self.system.ends[j]], axis=1)  # (k, 4) nodes
        self._radii_sum = self.radius[i] + self.radius[j]
        self._inside, self._since, self._snap, self._budget = inside, since, snap, budget
        self._x_list = x1.copy()

    # ------------------------------------------------------------------ stepping
    def reset(self, positions: np.ndarray) -> None:
        """Start over at ``positions`` (N, 3) m with no contact known: pairs that overlap there are
        reported as beginning at the start of the next step."""
        self._rebuild(positions, positions, keep_state=False)
        self._x_ref = positions.copy()
        self._quiet = -np.inf      # max |x - x_ref|_inf (m) under which a step needs no work at all

    @property
    def pair_count(self) -> int:
        """Number of listed (nearby, eligible) pairs."""
        return len(self._key)

    def step(self, x0: np.ndarray, x1: np.ndarray, t0: float, dt: float,
             impulses: dict | None = None) -> tuple[ContactEvent, ...]:
        """The contact events (time order) of a step from positions ``x0`` to ``x1`` (N, 3) m, starting
        at time ``t0`` s and lasting ``dt`` s. ``x0`` must be the previous step's ``x1`` (or the reset).
        ``impulses``: the step's contact impulses by member pair (a response's ``MethodStep.pair_impulses``),
        carried by the events and :meth:`active`."""
        self._impulses = impulses or {}
        w = self._watch
        if np.abs(x1[w] - self._x_ref[w]).max(initial=0.0) < self._quiet:
            return ()
        return self._careful_step(x0, x1, t0, dt)

    def walk(self, xs: np.ndarray, step_start, dt: float, stop=None, impulses: dict | None = None,
             per_step: dict | None = None) -> dict:
        """:meth:`CompiledDetector.walk` of one copy (``xs`` (K + 1, N, 3, 1)), step after step."""
        steps = len(xs) - 1 if stop is None else int(stop[0])
        start = step_start(np.arange(steps))
        found = {}
        for k in range(steps):
            events = self.step(xs[k, ..., 0], xs[k + 1, ..., 0], float(start[k]), dt,
                               impulses if per_step is None else per_step.get((k, 0)))
            if events:
                found[(k, 0)] = events
        self._impulses = impulses or {}
        return found

    def _careful_step(self, x0, x1, t0, dt):
        w = self._watch
        moved = x1[w] - self._x_list[w]
        if np.sqrt(_dot(moved, moved).max(initial=0.0)) >= self.skin:
            self._rebuild(x0, x1, keep_state=True)
        events: tuple[ContactEvent, ...] = ()
        if len(self._key):
            now = x1[self._ends]                                            # (k, 4, 3)
            shift = now - self._snap
            shift = np.sqrt(_dot(shift, shift))
            reach = np.maximum(shift[:, 0], shift[:, 1]) + np.maximum(shift[:, 2], shift[:, 3])
            left = self._budget - reach
            if np.any(left <= 0):
                # Examine the pairs that must be, and with them those past half their budget: one
                # batch costs about what a single pair does, and it spares the next few steps.
                due = np.flatnonzero((left <= 0) | (left < 0.5 * self._budget))
                events = self._evaluate(due, x0, x1, t0, dt)
                left[due] = self._budget[due]
            margin = 0.5 * float(np.min(left))
        else:
            margin = np.inf
        # From here on: a node may move by `margin` before some listed pair could touch, and by the
        # rest of the skin before the list expires.
        moved = x1[w] - self._x_list[w]
        margin = min(margin, self.skin - np.sqrt(_dot(moved, moved).max(initial=0.0)))
        self._x_ref = x1.copy()
        self._quiet = margin / _SQRT3
        return events

    def _evaluate(self, due, x0, x1, t0, dt):
        """Continuous detection for the listed pairs ``due`` over the step; updates their state."""
        nodes = self._ends[due]
        p0, p1 = x0[nodes], x1[nodes]
        radii = self._radii_sum[due]
        pair, tau, begin, inside, gap_end = transitions(p0, p1, radii, self._inside[due], self.touch)
        # how far from changing state: out of contact the gap, in contact the penetration (an end needs
        # the gap back at >= 0); until the members have moved that much, the pair needs no look
        self._inside[due], self._snap[due] = inside, p1
        self._budget[due] = np.where(inside, -gap_end, gap_end)
        if not pair.size:
            return ()
        time = t0 + tau * dt
        order = np.lexsort((self._key[due[pair]], time))     # time order; simultaneous ones in pair order
        pair, tau, begin, time = pair[order], tau[order], begin[order], time[order]
        pa, pb, normal, gap = contact_geometry(_interpolate(p0[pair], p1[pair], tau), radii[pair])[:4]
        events = []
        for k in range(len(pair)):
            p = due[pair[k]]
            if begin[k]:
                self._since[p] = time[k]
            events.append(ContactEvent("begin" if begin[k] else "end",
                                       (self.names[self._i[p]], self.names[self._j[p]]), float(time[k]),
                                       pa[k], pb[k], normal[k], float(gap[k]), *self._impulse(p)))
        return tuple(events)

    def active(self, positions: np.ndarray) -> tuple[ActiveContact, ...]:
        """Every ongoing contact at ``positions`` (N, 3) m (the last step's end), in pair order."""
        idx = np.flatnonzero(self._inside)
        if not idx.size:
            return ()
        pa, pb, normal, gap = contact_geometry(positions[self._ends[idx]], self._radii_sum[idx])[:4]
        return tuple(ActiveContact((self.names[self._i[p]], self.names[self._j[p]]), float(self._since[p]),
                                   pa[k], pb[k], normal[k], float(gap[k]), *self._impulse(p))
                     for k, p in enumerate(idx))

    def _impulse(self, p: int) -> tuple[float, np.ndarray]:
        """Listed pair ``p``'s normal (N*s) and friction (3,) N*s impulses of the last step (0 without)."""
        normal, friction = self._impulses.get((int(self._i[p]), int(self._j[p])), (0.0, np.zeros(3)))
        return float(normal), np.array(friction, dtype=float)


class CompiledDetector(ContactDetector):
    """:class:`ContactDetector`'s events from the compiled kernel (``methods/contact/_detection_kernels.py``, whose
    docstring gives its broad phase), for ``copies`` copies of the system stepped together (a batch; 1
    for a Simulator). It lists every eligible pair once (no skin: a far pair costs nothing until its due
    value comes) and walks a chunk of steps in one call (:meth:`walk`), or runs inside the elastic
    method's compiled loop (:attr:`state`, :meth:`record`). :meth:`active` is copy 0's unless told."""

    def __init__(self, system: System, kinds, *, touch: float = 0.0, copies: int = 1):
        self.copies = int(copies)
        super().__init__(system, kinds, touch=touch)

    def reset(self, positions: np.ndarray) -> None:
        """Start over with no contact known (every pair is examined at the next step; ``positions`` are
        not needed)."""
        from ._detection_kernels import detection_state   # (methods imports this module)
        if not hasattr(self, "_pair_nodes"):
            n_members = self.system.n_members
            self._i, self._j = self.eligible_pairs()
            self._key = self._i * n_members + self._j
            self._ends = np.concatenate([self.system.ends[self._i], self.system.ends[self._j]], axis=1)
            self._pair_nodes = self._ends
            self._radii_sum = self.radius[self._i] + self.radius[self._j]
        #: the kernels' detection tuple (``_detection_kernels.detection_state``), updated in place
        self.state = detection_state(self._pair_nodes, self._radii_sum, np.unique(self.system.ends[self.members]),
                                     self.touch, _FRACTIONS, _AROUND, self.copies)
        self._inside = self.state[6]
        self._since = np.full((len(self._key), self.copies), np.nan)

    @property
    def pair_count(self) -> int:
        return len(self._key)

    def snapshot(self):
        """A copy of the state, for :meth:`restore` (a run whose steps are taken back)."""
        return tuple(a.copy() for a in self.state[6:]) + (self._since.copy(),)

    def restore(self, saved) -> None:
        for a, b in zip(self.state[6:] + (self._since,), saved):
            a[...] = b

    def step(self, x0: np.ndarray, x1: np.ndarray, t0: float, dt: float,
             impulses: dict | None = None) -> tuple[ContactEvent, ...]:
        """:meth:`ContactDetector.step` (copy 0 of a single-copy detector)."""
        return self.walk(np.stack([x0, x1])[..., None], lambda step: t0 + 0.0 * step, dt,
                         impulses=impulses).get((0, 0), ())

    def walk(self, xs: np.ndarray, step_start, dt: float, stop: np.ndarray | None = None,
             impulses: dict | None = None, per_step: dict | None = None) -> dict:
        """The events of a chunk of ``K`` steps of every copy: ``xs`` (K + 1, N, 3, B) m, the positions
        before the first step and after each; ``step_start(k)``: the times (s) steps ``k`` (array) start; ``stop``
        (B,): steps to walk per copy (default all); ``per_step``: the member contacts' impulses of the steps that
        had any ({(step, copy): impulses}; a step it lacks had none), or None: every step's are ``impulses``
        (:meth:`step`'s); ``impulses`` are also what the active contacts report after the walk (the last step's).
        Returns {(step, copy): events in time order} of the steps that have any."""
        from ._detection_kernels import detect_steps

        xs = np.ascontiguousarray(xs, dtype=float)
        stop = np.full(self.copies, len(xs) - 1, dtype=np.int64) if stop is None else np.asarray(stop, dtype=np.int64)
        blocks = copy_blocks(self.copies)
        if len(blocks) == 1:
            return self.record(*detect_steps(xs, stop, self.state), step_start, dt, impulses, per_step)

        def run(block):   # a block of copies in arrays of its own (methods/_copy_blocks.py)
            state = self.state[:6] + tuple(np.ascontiguousarray(a[..., block]) for a in self.state[6:])
            return state[6:], detect_steps(np.ascontiguousarray(xs[..., block]), np.ascontiguousarray(stop[block]),
                                           state)

        found = []
        for block, (state, events) in zip(blocks, on_blocks(run, blocks)):
            for mine, its in zip(self.state[6:], state):
                mine[..., block] = its
            found.append((events[0], events[1] + block.start) + events[2:])
        return self.record(*(np.concatenate(column) for column in zip(*found)), step_start, dt, impulses, per_step)

    def record(self, step, copy, pair, tau, begin, ends, step_start, dt: float, impulses: dict | None = None,
               per_step: dict | None = None) -> dict:
        """ContactEvents of the kernel's transitions (``_detection_kernels.event_arrays``; steps counted
        from the call's first, step ``k`` starting at ``step_start(k)`` s), as
        :meth:`ContactDetector._evaluate` makes them: {(step, copy): events in time order}; their impulses
        ``per_step``'s and ``impulses`` as :meth:`walk` takes them."""
        self._impulses = impulses or {}
        if not len(step):
            return {}
        time = step_start(step) + tau * dt
        order = np.lexsort((self._key[pair], time, copy, step))   # per step and copy: time, then pair order
        step, copy, pair, tau, begin, time, ends = (a[order] for a in (step, copy, pair, tau, begin, time, ends))
        pa, pb, normal, gap = contact_geometry(_interpolate(ends[:, 0], ends[:, 1], tau), self._radii_sum[pair])[:4]
        out: dict = {}
        for k in range(len(pair)):
            p, b = pair[k], copy[k]
            if begin[k]:
                self._since[p, b] = time[k]
            key = (int(step[k]), int(b))
            self._impulses = (impulses if per_step is None else per_step.get(key)) or {}
            event = ContactEvent("begin" if begin[k] else "end", (self.names[self._i[p]], self.names[self._j[p]]),
                                 float(time[k]), pa[k], pb[k], normal[k], float(gap[k]), *self._impulse(p))
            out[key] = out.get(key, ()) + (event,)
        self._impulses = impulses or {}
        return out

    def active(self, positions: np.ndarray, copy: int = 0) -> tuple[ActiveContact, ...]:
        """:meth:`ContactDetector.active` of copy ``copy`` at its ``positions`` (N, 3) m."""
        idx = np.flatnonzero(self._inside[:, copy])
        if not idx.size:
            return ()
        pa, pb, normal, gap = contact_geometry(positions[self._ends[idx]], self._radii_sum[idx])[:4]
        return tuple(ActiveContact((self.names[self._i[p]], self.names[self._j[p]]), float(self._since[p, copy]),
                                   pa[k], pb[k], normal[k], float(gap[k]), *self._impulse(p))
                     for k, p in enumerate(idx))


# Most eligible member pairs the compiled detector lists (all of them, 16 numbers each per copy, each
# looked at when its due value comes), per scene and over a batch's copies (about 500 MB); beyond, the
# numpy detector, whose pair list holds only the pairs within its skin, is cheaper and smaller (bench_contact:
# compiled 10x faster than numpy with the 30,000 pairs of the 10-stage tower with every member kind, 2x
# slower with the 880,000 of the 50-stage one)
COMPILED_PAIRS = 100_000
COMPILED_PAIR_COPIES = 4_000_000


def make_detector(system: System, kinds, touch: float = 0.0, copies: int = 1):
    """The contact detector for ``kinds`` (``touch`` as :class:`ContactDetector`'s) of ``copies`` copies:
    a :class:`CompiledDetector`, or, beyond :data:`COMPILED_PAIRS` eligible pairs (or
    :data:`COMPILED_PAIR_COPIES` pairs times copies), the numpy :class:`ContactDetector` (a list of
    ``copies`` of them for several copies); None when no pair of
    members could ever be reported (no kind asked for, no member with a radius, or every candidate pair
    shares a node or is fixed)."""
    if not kinds:
        return None
    reference = ContactDetector(system, kinds, touch=touch)
    m = reference.members
    a, b = np.triu_indices(len(m), 1)
    count = int(reference.eligible(m[a], m[b]).sum())
    if not count:
        return None
    if count > COMPILED_PAIRS or count * copies > COMPILED_PAIR_COPIES:
        return reference if copies == 1 else [reference] + [ContactDetector(system, kinds, touch=touch)
                                                            for _ in range(copies - 1)]
    return CompiledDetector(system, kinds, touch=touch, copies=copies)
