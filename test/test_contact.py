"""Member contact detection (physics.md section 5): narrow phase against exact rational arithmetic,
continuous time of contact against closed form and dense sampling, the broad phase against a plain
all-pairs reference, and the scene key / simulator override / command line around it."""
import copy
import math
from fractions import Fraction

import numpy as np
import pytest
import yaml

import tensegrity_sim as ts
from tensegrity_sim.cli import main
from tensegrity_sim.methods.contact.detection import ContactDetector, closest_points, make_detector, transitions
from tensegrity_sim.system import System


# --------------------------------------------------------------------------- exact reference
def exact_distance(p0, p1, q0, q1) -> float:
    """Segment distance by exact rational minimisation of |p(s) - q(t)|^2 over the unit square: the
    interior stationary point of the normal equations if it lies inside, else the best of the four
    edges (each a clamped 1-D minimum). Floats are exact rationals, so this is the true distance."""
    P0, P1, Q0, Q1 = ([Fraction(float(v)) for v in p] for p in (p0, p1, q0, q1))
    d1 = [b - a for a, b in zip(P0, P1)]
    d2 = [b - a for a, b in zip(Q0, Q1)]
    r = [a - b for a, b in zip(P0, Q0)]
    dot = lambda u, v: sum(x * y for x, y in zip(u, v))
    a, e, b, c, f = dot(d1, d1), dot(d2, d2), dot(d1, d2), dot(d1, r), dot(d2, r)
    clamp = lambda x: min(max(x, Fraction(0)), Fraction(1))

    def dist2(s, t):
        w = [ri + s * x - t * y for ri, x, y in zip(r, d1, d2)]
        return dot(w, w)

    zero, one = Fraction(0), Fraction(1)
    cands = [(zero, clamp(f / e) if e else zero), (one, clamp((f + b) / e) if e else zero),
             (clamp(-c / a) if a else zero, zero), (clamp((b - c) / a) if a else zero, one)]
    den = a * e - b * b
    if den:
        s, t = (b * f - c * e) / den, (a * f - b * c) / den
        if 0 <= s <= 1 and 0 <= t <= 1:
            cands.append((s, t))
    return math.sqrt(min(dist2(s, t) for s, t in cands))


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


SKEW = 1e-9  # rad
SEGMENTS = {
    "parallel overlapping": ([0, 0, 0], [1, 0, 0], [0.3, 0.2, 0.1], [1.5, 0.2, 0.1]),
    "parallel apart": ([0, 0, 0], [1, 0, 0], [1.5, 0.2, 0], [2.5, 0.2, 0]),
    "antiparallel overlapping": ([0, 0, 0], [1, 0, 0], [0.9, 0, 0.3], [-0.4, 0, 0.3]),
    "skewed 1e-9 above": ([0, 0, 0], [1, 0, 0], [0.2, 1e-3, 0], [1.2, 1e-3 + math.sin(SKEW), 0]),
    "skewed 1e-9 crossing": ([0, 0, 0], [1, 0, 0], [0.2, -0.5 * math.sin(SKEW), 1e-12],
                             [1.2, 0.5 * math.sin(SKEW), 1e-12]),
    "skewed 1e-9 in 3d": ([0.1, 0.2, 0.3], [1.1, 1.2, 1.3], [0.3, 0.4, 0.5 + 1e-7],
                          list(np.array([0.3, 0.4, 0.5 + 1e-7]) + rotation([1, -1, 0], SKEW) @ [1.0, 1.0, 1.0])),
    "collinear overlapping": ([0, 0, 0], [1, 1, 1], [0.5, 0.5, 0.5], [2, 2, 2]),
    "collinear apart": ([0, 0, 0], [1, 1, 1], [1.5, 1.5, 1.5], [2, 2, 2]),
    "touching at an end": ([0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 1, 0]),
    "end on the other's interior": ([0, 0, 0], [1, 0, 0], [0.25, 0, 0], [0.25, 1, 1]),
    "end near the other's interior": ([0, 0, 0], [1, 0, 0], [0.25, 0.3, 0], [0.25, 1, 1]),
    "crossing": ([-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0]),
    "skew perpendicular": ([-1, 0, 0], [1, 0, 0], [0.3, -1, 0.7], [0.3, 1, 0.7]),
    "very short": ([0, 0, 0], [1e-12, 0, 0], [0.5, 0.5, 0], [0.5, 0.5 + 1e-13, 1e-13]),
    "point and segment": ([0.4, 0.3, 0.2], [0.4, 0.3, 0.2], [0, 0, 0], [1, 0, 0]),
    "two points": ([0.4, 0.3, 0.2], [0.4, 0.3, 0.2], [1, 2, 3], [1, 2, 3]),
    "short and long nearly parallel": ([0, 0, 0], [1e-6, 1e-15, 0], [-1, 1e-3, 0], [1, 1e-3, 0]),
}


@pytest.mark.parametrize("name", SEGMENTS)
def test_segment_distance_exact(name):
    p0, p1, q0, q1 = (np.array(v, float) for v in SEGMENTS[name])
    dist, s, t = closest_points(p0, p1, q0, q1)
    exact = exact_distance(p0, p1, q0, q1)
    assert np.isfinite(dist) and 0 <= s <= 1 and 0 <= t <= 1
    assert dist == pytest.approx(exact, rel=1e-14, abs=1e-16)
    # the returned parameters are a pair of points at that distance
    assert np.linalg.norm(p0 + s * (p1 - p0) - q0 - t * (q1 - q0)) == pytest.approx(exact, rel=1e-14, abs=1e-16)


def test_segment_distance_random_and_nearly_parallel():
    """Random segments, and random pairs skewed by 1e-9 rad in random planes (crossing or not): the
    vectorised distance equals the exact one to round-off, and never NaN."""
    rng = np.random.default_rng(7)
    n = 300
    p0, p1, q0 = rng.normal(size=(3, n, 3))
    q1 = rng.normal(size=(n, 3))
    # half of them: q is p's direction turned by 1e-9 rad, started near p (0 to 1e-9 m off its line)
    u = p1[: n // 2] - p0[: n // 2]
    turned = np.einsum("kij,kj->ki", [rotation(rng.normal(size=3), SKEW) for _ in range(n // 2)], u)
    q0[: n // 2] = (p0[: n // 2] + rng.uniform(-0.5, 0.5, (n // 2, 1)) * u
                    + rng.normal(scale=1e-9, size=(n // 2, 3)))
    q1[: n // 2] = q0[: n // 2] + rng.uniform(0.5, 1.5, (n // 2, 1)) * turned
    dist, s, t = closest_points(p0, p1, q0, q1)
    assert np.all(np.isfinite(dist)) and np.all((s >= 0) & (s <= 1) & (t >= 0) & (t <= 1))
    exact = np.array([exact_distance(*args) for args in zip(p0, p1, q0, q1)])
    scale = 1.0 + np.abs(np.stack([p0, p1, q0, q1])).max(axis=(0, 2))
    np.testing.assert_allclose(dist, exact, rtol=1e-13, atol=1e-15 * scale.max())


def test_segment_distance_continuous_through_parallel():
    """Turning one segment through parallel (angles down to 1e-12 rad, and 0): the distance follows the
    exact one, with no jump at the parallel configuration."""
    p0, p1 = np.array([0.0, 0, 0]), np.array([1.0, 0, 0])
    angles = np.concatenate([-np.logspace(-3, -12, 40), [0.0], np.logspace(-12, -3, 40)])
    q0 = np.array([0.5, 0.01, 0.0])
    q1 = q0 + np.array([[math.cos(a), math.sin(a), 0.0] for a in angles])
    dist, _, _ = closest_points(np.tile(p0, (len(angles), 1)), np.tile(p1, (len(angles), 1)),
                                np.tile(q0, (len(angles), 1)), q1)
    exact = [exact_distance(p0, p1, q0, b) for b in q1]
    np.testing.assert_allclose(dist, exact, rtol=1e-14, atol=1e-17)


# --------------------------------------------------------------------------- scenes
def crossing_dict(d0=0.5, speed=100.0, ra=0.01, rb=0.015, extra=None):
    """Strut a along x at the origin; strut b along y at height d0, moving down at ``speed`` m/s:
    nothing acts on them, so both move exactly linearly."""
    d = {
        "name": "crossing",
        "nodes": [
            {"name": "a0", "position": [-1.0, 0.0, 0.0], "mass": 1.0},
            {"name": "a1", "position": [1.0, 0.0, 0.0], "mass": 1.0},
            {"name": "b0", "position": [0.0, -1.0, d0], "mass": 1.0, "velocity": [0.0, 0.0, -speed]},
            {"name": "b1", "position": [0.0, 1.0, d0], "mass": 1.0, "velocity": [0.0, 0.0, -speed]},
        ],
        "struts": [
            {"name": "sa", "nodes": ["a0", "a1"], "stiffness": 1.0e3, "radius": ra},
            {"name": "sb", "nodes": ["b0", "b1"], "stiffness": 1.0e3, "radius": rb},
        ],
    }
    if extra:
        d.update(extra)
    return d


def test_fast_perpendicular_crossing_closed_form():
    """b crosses a at 200 m/s, 8 radii-sums (20 radii of a) per step: the whole contact lies inside one
    step, and detection at the steps' ends would see nothing. Begin at (d0 - ra - rb)/v, end at
    (d0 + ra + rb)/v, exactly."""
    d0, v, ra, rb, dt = 0.5, 200.0, 0.01, 0.015, 1e-3
    assert v * dt > 8 * (ra + rb) - 1e-12
    sim = ts.Simulator(ts.Scene.from_dict(crossing_dict(d0, v, ra, rb)), method="elastic", dt=dt)
    results = [sim.step() for _ in range(8)]
    events = [e for r in results for e in r.contacts]
    assert [(e.kind, e.members) for e in events] == [("begin", ("sa", "sb")), ("end", ("sa", "sb"))]
    begin, end = events
    assert abs(begin.time - (d0 - ra - rb) / v) < 1e-12
    assert abs(end.time - (d0 + ra + rb) / v) < 1e-12
    # both in the step from 2 ms to 3 ms, and no position at a step's end is in contact
    assert [r.time for r in results if r.contacts] == [pytest.approx(3e-3, abs=1e-15)]
    np.testing.assert_allclose(begin.point_a, [0, 0, 0], atol=1e-14)
    np.testing.assert_allclose(begin.point_b, [0, 0, ra + rb], atol=1e-14)
    np.testing.assert_allclose(begin.normal, [0, 0, 1], atol=1e-14)
    np.testing.assert_allclose(end.point_b, [0, 0, -(ra + rb)], atol=1e-14)
    np.testing.assert_allclose(end.normal, [0, 0, -1], atol=1e-14)
    assert abs(begin.distance) < 1e-14 and abs(end.distance) < 1e-14
    assert sim.active_contacts() == ()


def test_slow_crossing_pairs_events_and_reports_penetration():
    """At 1 m/s the crossing lasts many steps: one begin, one end, and in between the active contact's
    gap is |z_b| - ra - rb (negative), with the normal along z."""
    d0, v, ra, rb, dt = 0.05, 1.0, 0.01, 0.015, 1e-3
    sim = ts.Simulator(ts.Scene.from_dict(crossing_dict(d0, v, ra, rb)), method="elastic", dt=dt)
    kinds, checked = [], 0
    for _ in range(100):
        r = sim.step()
        kinds += [e.kind for e in r.contacts]
        active = sim.active_contacts()
        z = sim.positions[2, 2]      # b's height (d0 - v t, to round-off)
        inside = abs(z) < ra + rb
        if abs(abs(z) - ra - rb) > 1e-9:
            assert len(active) == inside
        if active and abs(abs(z) - ra - rb) > 1e-9:
            (c,) = active
            assert c.members == ("sa", "sb") and c.since == pytest.approx((d0 - ra - rb) / v, abs=1e-12)
            assert c.distance == pytest.approx(abs(z) - ra - rb, abs=1e-12) and c.distance < 0
            np.testing.assert_allclose(c.normal, [0, 0, math.copysign(1.0, z)], atol=1e-12)
            checked += 1
    assert kinds == ["begin", "end"] and checked > 30


def test_members_sharing_a_node_never_reported():
    """A V of two struts on one node, a cable along one of them, and a third strut that does get hit:
    only the pairs that share no node are reported."""
    d = {
        "nodes": [
            {"name": "o", "position": [0.0, 0.0, 0.0], "mass": 1.0, "velocity": [0.0, 0.0, -50.0]},
            {"name": "p", "position": [1.0, 0.2, 0.0], "mass": 1.0, "velocity": [0.0, 0.0, -50.0]},
            {"name": "q", "position": [1.0, -0.2, 0.0], "mass": 1.0, "velocity": [0.0, 0.0, -50.0]},
            {"name": "u", "position": [0.5, -1.0, -0.2], "mass": 1.0},
            {"name": "w", "position": [0.5, 1.0, -0.2], "mass": 1.0},
        ],
        "struts": [
            {"name": "s_op", "nodes": ["o", "p"], "stiffness": 1e3, "radius": 0.05},
            {"name": "s_oq", "nodes": ["o", "q"], "stiffness": 1e3, "radius": 0.05},
            {"name": "s_uw", "nodes": ["u", "w"], "stiffness": 1e3, "radius": 0.01},
        ],
        "cables": [{"name": "c_op", "nodes": ["o", "p"], "stiffness": 1e2, "rest_length": 2.0, "radius": 0.01}],
    }
    with pytest.warns(ts.ClassKWarning, match=r"\['o'\] carry more than one strut"):
        scene = ts.Scene.from_dict(d)
    sim = ts.Simulator(scene, method="elastic", dt=1e-3, contacts=["strut_strut", "strut_cable", "cable_cable"])
    events = sim.run(steps=10).contacts
    assert {e.members for e in events} == {("s_op", "s_uw"), ("s_oq", "s_uw"), ("s_uw", "c_op")}
    assert sorted(e.kind for e in events) == ["begin"] * 3 + ["end"] * 3


def test_member_kinds_chosen_by_the_scene_and_the_simulator():
    d = copy.deepcopy(crossing_dict(0.05, 10.0))
    # a cable parallel to a, 0.5 m aside, 2 cm up: b crosses it, a never meets it
    d["nodes"] += [{"name": "c0", "position": [-1.0, 0.5, 0.02], "mass": 1.0},
                   {"name": "c1", "position": [1.0, 0.5, 0.02], "mass": 1.0}]
    d["cables"] = [{"name": "cc", "nodes": ["c0", "c1"], "stiffness": 1.0, "rest_length": 3.0, "radius": 0.005}]
    scene = ts.Scene.from_dict(d)
    assert scene.contact_kinds == ("strut_strut",)

    def pairs(**kw):
        sim = ts.Simulator(scene, method="elastic", dt=1e-3, **kw)
        return {e.members for e in sim.run(steps=20).contacts}

    assert pairs() == {("sa", "sb")}
    assert pairs(contacts=["strut_cable", "strut_strut"]) == {("sa", "sb"), ("sb", "cc")}
    assert pairs(contacts=["strut_cable"]) == {("sb", "cc")}
    assert pairs(contacts=[]) == set()
    d["contact"] = {"kinds": []}
    off = ts.Scene.from_dict(d)
    assert ts.Simulator(off, method="elastic", dt=1e-3).run(steps=20).contacts == []
    assert ts.Simulator(off, method="elastic", dt=1e-3, contacts=["strut_strut"]).run(steps=20).contacts


def test_fixed_pairs_and_zero_radius_never_checked():
    """Two struts whose four nodes are fixed overlap for ever: never reported. A zero-radius strut is a
    line: never reported either."""
    d = crossing_dict(0.0, 0.0)
    for node in d["nodes"]:
        node["fixed"] = True
        node.pop("velocity", None)
    scene = ts.Scene.from_dict(d)
    assert ts.Simulator(scene, dt=1e-3).run(steps=3).contacts == []
    d = crossing_dict(0.05, 10.0, ra=0.0)
    assert ts.Simulator(ts.Scene.from_dict(d), dt=1e-3).run(steps=20).contacts == []
    # nothing left to check, so no detector at all (no cost); likewise when no kind is asked for
    assert make_detector(System(scene), ("strut_strut",)) is None
    assert make_detector(System(ts.Scene.from_dict(d)), ("strut_strut",)) is None
    assert make_detector(System(ts.Scene.from_dict(crossing_dict())), ()) is None
    assert make_detector(System(ts.Scene.from_dict(crossing_dict())), ("strut_strut",)) is not None


def test_initial_overlap_begins_at_time_zero_and_reset_repeats_it():
    d0, v, ra, rb = 0.01, 1.0, 0.01, 0.015
    sim = ts.Simulator(ts.Scene.from_dict(crossing_dict(d0, -v, ra, rb)), method="elastic", dt=1e-3)
    first = sim.run(steps=40).contacts
    assert [e.kind for e in first] == ["begin", "end"]
    assert first[0].time == 0.0 and first[0].distance == pytest.approx(d0 - ra - rb, abs=1e-15)
    assert first[1].time == pytest.approx((ra + rb - d0) / v, abs=1e-12)
    sim.reset()
    again = sim.run(steps=40).contacts
    assert [(e.kind, e.time) for e in again] == [(e.kind, e.time) for e in first]


# --------------------------------------------------------------------------- time of contact
def dense_transitions(p0, p1, radius, samples=20001):
    """Reference for one pair: the gap sampled densely in the step, each sign change refined by
    bisection to 1e-14 of the step. Returns [(tau, 'begin'|'end')]."""
    def gap(tau):
        tau = np.atleast_1d(tau)[:, None, None]
        x = (1 - tau) * p0 + tau * p1
        return closest_points(x[:, 0], x[:, 1], x[:, 2], x[:, 3])[0] - radius

    tau = np.linspace(0, 1, samples)
    g = gap(tau)
    out = []
    for k in np.flatnonzero((g[:-1] < 0) != (g[1:] < 0)):
        lo, hi = tau[k], tau[k + 1]
        while hi - lo > 1e-14:
            mid = 0.5 * (lo + hi)
            if (gap(mid)[0] < 0) == (g[k] < 0):
                lo = mid
            else:
                hi = mid
        out.append((hi, "end" if g[k] < 0 else "begin"))
    return out, g


def test_time_of_contact_against_dense_sampling():
    """Random capsule pairs whose four end points move independently (rotation and stretch, not only
    translation): every begin and end matches a dense-sampling reference; grazes shallower than 1e-6 m,
    which sampling itself cannot resolve, are left out."""
    rng = np.random.default_rng(11)
    n = 300
    p0 = rng.uniform(-0.5, 0.5, (n, 4, 3))
    p1 = p0 + rng.normal(scale=0.5, size=(n, 4, 3))
    radius = rng.uniform(0.05, 0.3, n)
    start = closest_points(p0[:, 0], p0[:, 1], p0[:, 2], p0[:, 3])[0] < radius
    pair, tau, begin, inside_end, _ = transitions(p0, p1, radius, start)
    compared = 0
    for k in range(n):
        ref, g = dense_transitions(p0[k], p1[k], radius[k])
        if np.min(np.abs(g)) < 1e-6:
            continue
        got = sorted((t, "begin" if b else "end") for t, b in zip(tau[pair == k], begin[pair == k]))
        assert [kind for _, kind in got] == [kind for _, kind in ref], k
        np.testing.assert_allclose([t for t, _ in got], [t for t, _ in ref], atol=1e-12)
        assert inside_end[k] == (g[-1] < 0)
        compared += len(ref)
    assert compared > 100  # the sample holds plenty of begins and ends


def test_pass_through_within_one_step_is_caught():
    """Both ends of the step out of contact, the middle deep inside: a begin and an end."""
    p0 = np.array([[[-1.0, 0, 0], [1, 0, 0], [0, -1, 1], [0, 1, 1]]])
    p1 = p0.copy()
    p1[0, 2:, 2] = -1.0
    pair, tau, begin, inside, gap = transitions(p0, p1, np.array([0.05]), np.array([False]))
    order = np.argsort(tau)
    np.testing.assert_allclose(tau[order], [0.475, 0.525], atol=1e-14)
    assert list(begin[order]) == [True, False] and not inside[0] and gap[0] == pytest.approx(0.95, abs=1e-15)


def test_sliding_at_touching_distance_does_not_chatter():
    """Regression: two parallel members sliding along each other exactly at touching distance made
    the gap's sign flip with round-off, a begin and an end every 1e-7 of a step. Now: no event, in
    either state; and non-finite positions give no event and no exception."""
    p0 = np.array([[[0.0, 0, 0], [1, 0, 0], [0.5, 0.5, 0], [1.5, 0.5, 0]]])
    p1 = p0.copy()
    p1[0, 2:, 0] += 0.5
    for inside in (False, True):
        pair, _, _, now, gap = transitions(p0, p1, np.array([0.5]), np.array([inside]))
        assert pair.size == 0 and now[0] == inside and gap[0] == 0.0
    bad = p0.copy()
    bad[0, 0, 0] = np.nan
    pair, _, _, now, _ = transitions(bad, bad, np.array([0.5]), np.array([False]))
    assert pair.size == 0 and not now[0]


def test_the_lines_reach_is_certified_and_the_kernel_s_is_the_numpy_one():
    """``_line_reach`` (how long two capsules surely stay apart by their lines' distance) on random pairs apart,
    moving by random end-point displacements (rotations and translations of a few gaps to many): wherever it
    says they stay apart, dense samples of the straight path find the gap non-negative; the compiled twin gives
    the same reaches (to 1e-12); and a strut rocking 0.2 um above another (its end points sweeping 2,000 gaps a step,
    which the end points' plane bound certifies for 0.0005 of a step) is certified for the whole step."""
    from tensegrity_sim.methods.contact import _detection_kernels as kernels
    from tensegrity_sim.methods.contact.detection import _line_reach, contact_geometry

    rng = np.random.default_rng(5)
    out = np.empty(2)
    certified = 0
    for _ in range(400):
        a = rng.normal(size=(2, 3))
        b = rng.normal(size=(2, 3)) * rng.uniform(0.2, 1.0)
        radii = rng.uniform(0.0, 0.05)
        gap = contact_geometry(np.concatenate([a, b])[None], np.array([radii]))[3][0]
        if gap <= 1e-6:
            continue
        b = b + (rng.uniform(1e-3, 1.0) * gap) * np.array([0, 0, 1.0])   # some just apart
        ends = np.concatenate([a, b])
        disp = rng.normal(size=(4, 3)) * gap * 10.0 ** rng.uniform(-1, 3)
        ahead, behind = (float(x) for x in _line_reach(ends, disp, np.array(radii)))
        kernels._line_reach(ends, disp, radii, out)
        # the same arithmetic, but for the cube root: numpy's vectorised power (SVML on AVX-512 machines) and
        # libm's, which the kernel calls, differ in the last bit for ~5 % of arguments
        np.testing.assert_allclose(out, (ahead, behind), rtol=1e-12, atol=0.0)
        for reach, sign in ((ahead, 1.0), (behind, -1.0)):
            if reach <= 0.0:
                continue
            certified += 1
            taus = sign * np.linspace(0.0, min(reach, 1e3), 2001)
            path = ends[None] + taus[:, None, None] * disp[None]
            gaps = contact_geometry(path, np.full(len(taus), radii))[3]
            assert gaps.min() >= -1e-12 * (1.0 + np.abs(path).max())
    assert certified >= 200
    # the rocking strut: A along x, B along y crossing it 0.2 um above (radii 1 cm each), turning about x (its
    # ends move 5e-4 m up and down) and sliding along A
    ends = np.array([[-0.5, 0, 0], [0.5, 0, 0], [0.2, -0.5, 0.02 + 2e-7], [0.2, 0.5, 0.02 + 2e-7]])
    disp = np.array([[0, 0, 0], [0, 0, 0], [1e-4, 0, 5e-4], [1e-4, 0, -5e-4]])
    ahead, behind = _line_reach(ends, disp, np.array(0.02))
    assert ahead >= 1.0 and behind >= 1.0


def test_the_compiled_search_has_the_numpy_search_s_round_bound():
    from tensegrity_sim.methods.contact import _detection_kernels as kernels
    from tensegrity_sim.methods.contact import detection

    assert kernels._MAX_ROUNDS == detection.MAX_ROUNDS


def test_a_pair_held_in_contact_by_a_response_stays_in_contact_over_the_step():
    """With a response (``touch`` > 0) a pair in contact at both ends of a step is in contact throughout it: the
    response holds it there, and the straight path between its two resting configurations is not the motion.
    Two nearly parallel struts touching at both ends, whose straight path in between parts them by 1 mm
    (their closest points jump along them): without a response the search finds the end and the new begin;
    with one, none; the compiled detector's kernel gives the numpy detector's answers (certifying the step
    instead cost a strut resting on another up to 2.5 ms a step)."""
    from tensegrity_sim.methods.contact._detection_kernels import _transitions
    from tensegrity_sim.methods.contact.detection import _AROUND, _FRACTIONS

    a = [[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0]]
    p0 = np.array([a + [[-0.7884478542181588, 0.01831776920642238, 0.02962910222063064],
                        [0.21075706481673628, -0.01831776920642238, 0.01390119385144191]]])
    p1 = np.array([a + [[-0.7875639948222979, 0.01008030467765645, 0.04649906714345907],
                        [0.21187320542087534, -0.00808030467765646, 0.01829490011212562]]])
    radii = np.array([0.02])
    for touch, kinds in ((0.0, [False, True]), (1e-9, [])):
        pair, tau, begin, now, gap = transitions(p0, p1, radii, np.array([True]), touch)
        assert list(begin[np.argsort(tau)]) == kinds and now[0] and gap[0] < 0
        ev_tau, ev_begin = np.empty(8), np.empty(8, dtype=bool)
        n, inside, end_gap = _transitions(p0[0], p1[0], np.empty((4, 3)), 0.02, True, touch, _FRACTIONS, _AROUND,
                                          ev_tau, ev_begin, np.empty(22))
        assert list(ev_begin[:n]) == kinds and inside and end_gap == gap[0]
        np.testing.assert_allclose(ev_tau[:n], np.sort(tau), rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- broad phase vs all pairs
def gas_scene(rng, sticks, size, radius):
    """Sticks (struts, and every third one a cable) scattered in a box of ``size`` m, a few cables
    joining neighbouring sticks (so that some members share a node), two fixed nodes, some zero radii."""
    centres = rng.uniform(-size / 2, size / 2, (sticks, 3))
    half = rng.normal(size=(sticks, 3))
    half *= rng.uniform(0.05, 0.25, (sticks, 1)) / np.linalg.norm(half, axis=1, keepdims=True)
    pos = np.concatenate([centres - half, centres + half])
    nodes = [{"name": f"n{k}", "position": list(p), "mass": 1.0} for k, p in enumerate(pos)]
    for k in (0, sticks):
        nodes[k].update(fixed=True, mass=0.0)
    members = [{"nodes": [f"n{k}", f"n{k + sticks}"], "stiffness": 1.0,
                "radius": float(rng.choice([0.0, *rng.uniform(radius / 6, radius, 6)]))} for k in range(sticks)]
    for _ in range(sticks // 4):
        a = int(rng.integers(sticks))
        b = int(np.argsort(np.linalg.norm(pos - pos[a], axis=1))[1])
        members.append({"nodes": [f"n{a}", f"n{b}"], "stiffness": 1.0, "radius": radius / 3})
    struts = [dict(m, name=f"s{k}") for k, m in enumerate(members[:sticks]) if k % 3]
    cables = [dict(m, name=f"c{k}") for k, m in enumerate(members) if k >= sticks or not k % 3]
    return ts.Scene.from_dict({"nodes": nodes, "struts": struts, "cables": cables})


def gas_path(rng, scene, steps, speed):
    """Node positions (steps + 1) of a random drift of about ``speed`` m per step, with a jump of 0.3 m
    rms (far beyond the pair list's skin, and through other members) every 50 steps."""
    free = ~scene.fixed[:, None]
    path = [scene.positions]
    velocity = rng.normal(scale=speed, size=path[0].shape)
    for step in range(steps):
        velocity = 0.9 * velocity + rng.normal(scale=0.2 * speed, size=velocity.shape)
        jump = rng.normal(scale=0.3, size=velocity.shape) if step % 50 == 49 else 0.0
        path.append(path[-1] + free * (velocity + jump))
    return path


def reference_events(scene, kinds, path, dt):
    """Plain all-pairs reference: every eligible pair of members (chosen in plain Python) through
    :func:`transitions` at every step; no pair list, no skipping."""
    names = scene.strut_names + scene.cable_names
    members = [(m, "strut") for m in scene.struts] + [(m, "cable") for m in scene.cables]
    index = {n: i for i, n in enumerate(scene.node_names)}
    fixed = {n.name for n in scene.nodes if n.fixed}
    pairs, nodes, radius = [], [], []
    for i in range(len(members)):
        for j in range(i + 1, len(members)):
            (mi, ki), (mj, kj) = members[i], members[j]
            kind = "strut_strut" if ki == kj == "strut" else "cable_cable" if ki == kj else "strut_cable"
            if (kind in kinds and mi.radius > 0 and mj.radius > 0 and not set(mi.nodes) & set(mj.nodes)
                    and not set(mi.nodes) | set(mj.nodes) <= fixed):
                pairs.append((names[i], names[j]))
                nodes.append([index[v] for v in mi.nodes + mj.nodes])
                radius.append(mi.radius + mj.radius)
    nodes, radius = np.array(nodes), np.array(radius)
    inside = np.zeros(len(pairs), dtype=bool)
    events = []
    for step in range(len(path) - 1):
        p0, p1 = path[step][nodes], path[step + 1][nodes]
        pair, tau, begin, inside, _ = transitions(p0, p1, radius, inside)
        found = []
        for k, t, b in zip(pair, tau, begin):
            x = (1 - t) * p0[k] + t * p1[k]
            dist, s, _ = closest_points(x[0], x[1], x[2], x[3])
            found.append((step * dt + t * dt, k, "begin" if b else "end", pairs[k],
                          x[0] + s * (x[1] - x[0]), dist - radius[k]))
        events += [e[:1] + e[2:] for e in sorted(found, key=lambda e: e[:2])]
    return events


@pytest.mark.parametrize("crowded, seed", [(True, 1), (True, 2), (False, 1), (False, 2), (False, 3)])
def test_broad_phase_matches_all_pairs_reference(crowded, seed):
    """Seeded random scenes with all three kinds, drifting, with jumps far beyond the skin (list
    rebuilds, pass-throughs): exactly the events of the all-pairs reference, simultaneous ones in the
    same order. Crowded scenes are rarely quiet; in sparse ones most steps are, and cost one comparison
    over the nodes."""
    rng = np.random.default_rng(seed)
    scene = gas_scene(rng, 30, 2.0, 0.05) if crowded else gas_scene(rng, 30, 3.0, 0.03)
    path = gas_path(rng, scene, 200, 0.002 if crowded else 0.001)
    kinds = ("strut_strut", "strut_cable", "cable_cable")
    dt = 1e-3
    detector = ContactDetector(System(scene), kinds)
    detector.reset(path[0])
    looked, rebuilt = [0], [0]
    careful, rebuild = detector._careful_step, detector._rebuild

    def count(counter, method):
        def counted(*args, **kwargs):
            counter[0] += 1
            return method(*args, **kwargs)
        return counted

    detector._careful_step, detector._rebuild = count(looked, careful), count(rebuilt, rebuild)
    got = []
    for step in range(len(path) - 1):
        got += detector.step(path[step], path[step + 1], step * dt, dt)
    ref = reference_events(scene, kinds, path, dt)
    assert len(ref) > 10 and rebuilt[0] > 4
    assert crowded or looked[0] < 150
    assert [(e.kind, e.members) for e in got] == [(kind, members) for _, kind, members, _, _ in ref]
    np.testing.assert_allclose([e.time for e in got], [r[0] for r in ref], rtol=0, atol=1e-15)
    np.testing.assert_allclose([e.point_a for e in got], [r[3] for r in ref], rtol=0, atol=1e-12)
    np.testing.assert_allclose([e.distance for e in got], [r[4] for r in ref], rtol=0, atol=1e-12)


def event_rows(events):
    """(kind, members) and the numbers (time, points, normal, distance) of contact events."""
    return ([(e.kind, e.members) for e in events],
            np.array([[e.time, *e.point_a, *e.point_b, *e.normal, e.distance] for e in events]).reshape(-1, 11))


@pytest.mark.parametrize("crowded, seed", [(True, 1), (True, 2), (False, 1), (False, 3)])
def test_compiled_detection_matches_the_numpy_detector(crowded, seed):
    """The compiled kernel (CompiledDetector, which the simulators use) against the numpy ContactDetector,
    on the random scenes and paths above (all three kinds, pass-throughs, jumps far beyond the skin): the
    same events in the same order, times, closest points, normals and distances to 1e-12, the same
    ongoing contacts at the end, whether the path is walked in chunks or two copies together (a batch)."""
    from tensegrity_sim.methods.contact.detection import CompiledDetector
    rng = np.random.default_rng(seed)
    scene = gas_scene(rng, 30, 2.0, 0.05) if crowded else gas_scene(rng, 30, 3.0, 0.03)
    paths = [np.array(gas_path(rng, scene, 200, 0.002 if crowded else 0.001)) for _ in range(2)]
    kinds = ("strut_strut", "strut_cable", "cable_cable")
    dt, system = 1e-3, System(scene)
    batch = CompiledDetector(system, kinds, copies=2)
    found = batch.walk(np.stack(paths, axis=-1), lambda k: k * dt, dt)
    for copy, path in enumerate(paths):
        reference = ContactDetector(system, kinds)
        reference.reset(path[0])
        ref = []
        for step in range(len(path) - 1):
            ref += reference.step(path[step], path[step + 1], step * dt, dt)
        single = CompiledDetector(system, kinds)
        got = []
        for step in range(0, 200, 64):   # a run's chunks
            part = single.walk(path[step:step + 65, ..., None], lambda k, first=step: (first + k) * dt, dt)
            got += [e for key in sorted(part) for e in part[key]]
        walked = [e for key in sorted(k for k in found if k[1] == copy) for e in found[key]]
        ref_kinds, ref_numbers = event_rows(ref)
        assert len(ref) > 10
        for events in (got, walked):
            kinds_got, numbers = event_rows(events)
            assert kinds_got == ref_kinds
            np.testing.assert_allclose(numbers, ref_numbers, rtol=0, atol=1e-12)
        ref_active = reference.active(path[-1])
        for active in (single.active(path[-1]), batch.active(path[-1], copy)):
            assert [a.members for a in active] == [a.members for a in ref_active]
            np.testing.assert_allclose([a.since for a in active], [a.since for a in ref_active], rtol=0, atol=1e-12)


@pytest.mark.parametrize("method, every", [("elastic", 1), ("elastic", 7), ("massive", 7)])
def test_detection_in_the_compiled_run_matches_the_numpy_detector(method, every):
    """The built-in icosahedron with struts thick enough to overlap now and then, thrown: run() detects in
    the method's compiled loop (the elastic one's; the massive one's, with cable plates and elastic struts),
    step() one step at a time; both give the numpy detector's events over the same positions (to 1e-12), and
    the same ongoing contacts."""
    d = ts.load_scene("icosahedron").to_dict()
    rng = np.random.default_rng(4)
    for s in d["struts"]:
        s["radius"] = 0.25
    for node in d["nodes"]:
        node["velocity"] = list(rng.normal(scale=1.0, size=3))
    if method == "massive":   # its kernel takes elastic struts and cables with mass
        x = {n["name"]: np.array(n["position"]) for n in d["nodes"]}
        for s in d["struts"]:
            s["stiffness"], s["rest_length"] = 1e5, float(np.linalg.norm(x[s["nodes"][1]] - x[s["nodes"][0]]))
        for c in d["cables"]:
            c["mass"] = 0.05
    scene = ts.Scene.from_dict(d)
    run = ts.Simulator(scene, method=method, dt=1e-3)
    assert run._method.loop_detects()
    trajectory = run.run(steps=700, every=every)
    stepped = ts.Simulator(scene, method=method, dt=1e-3)
    results = [stepped.step() for _ in range(700)]
    path = [scene.positions] + [r.positions for r in results]
    reference = ContactDetector(stepped.system, scene.contact_kinds)
    events = []
    for k in range(700):
        events += reference.step(path[k], path[k + 1], k * 1e-3, 1e-3)
    assert len(events) > 10
    np.testing.assert_array_equal(trajectory.positions[-1], path[-1])
    ref_kinds, ref_numbers = event_rows(events)
    for got in (trajectory.contacts, [e for r in results for e in r.contacts]):
        kinds, numbers = event_rows(got)
        assert kinds == ref_kinds
        np.testing.assert_allclose(numbers, ref_numbers, rtol=0, atol=1e-12)
    active, ref_active = run.active_contacts(), reference.active(path[-1])
    assert [a.members for a in active] == [a.members for a in ref_active]
    np.testing.assert_allclose([a.since for a in active], [a.since for a in ref_active], rtol=0, atol=1e-12)


def test_scenes_with_very_many_pairs_detect_with_the_numpy_detector(monkeypatch):
    """Beyond COMPILED_PAIRS eligible pairs the simulators detect with the numpy ContactDetector (its
    pair list holds only the near pairs): Simulator.run() and a batch give the compiled detector's events."""
    import tensegrity_sim.methods.contact.detection as contact
    d = ts.load_scene("icosahedron").to_dict()
    for s in d["struts"]:
        s["radius"] = 0.25
    rng = np.random.default_rng(5)
    velocities = rng.normal(scale=1.0, size=(2, len(d["nodes"]), 3))
    scene = ts.Scene.from_dict(d)
    runs = []
    for limit in (contact.COMPILED_PAIRS, 0):
        monkeypatch.setattr(contact, "COMPILED_PAIRS", limit)
        sim = ts.Simulator(scene, method="elastic", dt=1e-3)
        batch = ts.BatchSimulator(scene, 2, method="elastic", velocities=velocities)
        assert isinstance(sim._contacts, contact.CompiledDetector) == (limit > 0)
        runs.append((sim.run(steps=400).contacts, batch.run(steps=400).contacts))
    (single, copies), (single_ref, copies_ref) = runs
    for got, want in [(single, single_ref)] + list(zip(copies, copies_ref)):
        assert len(want) > 4 and event_rows(got)[0] == event_rows(want)[0]
        np.testing.assert_allclose(event_rows(got)[1], event_rows(want)[1], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- scene key, override, CLI
BASE = crossing_dict()


@pytest.mark.parametrize("contact, message", [
    ({"kinds": ["strut_ground"]},
     "contact: kinds: unknown member kind 'strut_ground' (allowed: strut_strut, strut_cable, cable_cable)"),
    ({"kinds": "strut_strut"},
     "contact: kinds must be a list of member kinds (strut_strut, strut_cable, cable_cable), got 'strut_strut'"),
    ({"kinds": ["strut_strut", "strut_strut"]}, "contact: kinds: duplicate member kind 'strut_strut'"),
    ({"types": []}, "contact: unknown key 'types' (allowed: friction, kinds, response, restitution)"),
    (["strut_strut"], "contact: must be a mapping, got list"),
])
def test_contact_key_refused_with_exact_message(contact, message):
    d = copy.deepcopy(BASE)
    d["contact"] = contact
    with pytest.raises(ts.SceneError) as err:
        ts.Scene.from_dict(d, source="bad.yaml")
    assert str(err.value) == f"bad.yaml: {message}"


def test_contact_key_round_trips():
    d = copy.deepcopy(BASE)
    d["contact"] = {"kinds": ["cable_cable", "strut_strut"]}
    scene = ts.Scene.from_dict(d)
    assert scene.contact_kinds == ("strut_strut", "cable_cable")
    assert ts.Scene.from_dict(yaml.safe_load(scene.to_yaml())) == scene
    assert scene != ts.Scene.from_dict(BASE)
    assert "contact" not in ts.Scene.from_dict(BASE).to_dict()  # the default is left implicit
    d["contact"] = {}
    assert ts.Scene.from_dict(d).contact_kinds == ("strut_strut",)


@pytest.mark.parametrize("contacts, message", [
    (["ground"], "contacts: unknown member kind 'ground' (allowed: strut_strut, strut_cable, cable_cable)"),
    ("strut_strut", "contacts must be a list of member kinds (strut_strut, strut_cable, cable_cable), "
                    "got 'strut_strut'"),
])
def test_simulator_override_refused(contacts, message):
    with pytest.raises(ValueError) as err:
        ts.Simulator(ts.Scene.from_dict(BASE), dt=1e-3, contacts=contacts)
    assert str(err.value) == message


def test_cli_summary_counts_contacts(tmp_path, capsys):
    path = tmp_path / "crossing.yaml"
    path.write_text(yaml.safe_dump(crossing_dict(0.05, 10.0)))
    assert main(["run", str(path), "--duration", "0.02", "--quiet"]) == 0
    assert "contacts         2 events (1 begin, 1 end) between 1 member pairs" in capsys.readouterr().out
    assert main(["run", str(path), "--duration", "0.02", "--quiet", "--contacts", "none"]) == 0
    assert "contacts         0 events" in capsys.readouterr().out
    assert main(["run", str(path), "--duration", "0.02", "--quiet", "--contacts", "strut_ground"]) == 2
    assert "contacts: unknown member kind 'strut_ground'" in capsys.readouterr().err


def test_logged_run_with_an_override_replays(tmp_path, capsys):
    """``run --contacts`` overrides the scene's kinds; the log embeds the scene as run, so a replay
    checks the same pairs and reproduces the contact messages (off in the file, on for the run)."""
    from tensegrity_sim.ros.replay import replay

    path, log = tmp_path / "crossing.yaml", tmp_path / "run.mcap"
    path.write_text(yaml.safe_dump(crossing_dict(0.05, 10.0, extra={"contact": {"kinds": []}})))
    assert main(["run", str(path), "--duration", "0.02", "--quiet", "--contacts", "strut_strut",
                 "--log", str(log)]) == 0
    assert "contacts         2 events (1 begin, 1 end) between 1 member pairs" in capsys.readouterr().out
    report = replay(log)
    assert report.ok and report.compared["/tensegrity_sim/contacts"] == 1  # both events, one message

