"""Member-member contact response (issue 11, ``contact: response: true``), both methods (the elastic one
compiled and its numpy reference): closed forms of plastic and elastic impacts between rigid struts,
conservation of momentum, Coulomb friction between members, no energy from a contact and a cable snap in
the same step, and the elastic method's compiled step against its reference and against itself stepped
alone."""
import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.methods.contact.detection import contact_geometry

METHODS = ["inextensible", "elastic", "elastic reference"]
G = 9.81
R = 0.01   # m, both struts' radius


def crossing(xc=0.25, v=1.0, e=0.0, mu=0.0, z=0.05, gravity=0.0, fixed_a=False, vx=0.0, cable=False):
    """Rigid strut A (1 m along x, 1 kg per end) at rest at z = 0 and rigid strut B (1 m along y, 1 kg per
    end) above it at height ``z``, crossing it at x = ``xc``, moving at ``v`` down onto it (and ``vx``
    along x). ``cable``: A is a taut cable (stiff, for the elastic method) instead of a strut."""
    a = {"mass": 1.0, "fixed": True} if fixed_a else {"mass": 1.0}
    members = {"struts": [{"name": "A", "nodes": ["a0", "a1"], "stiffness": "rigid", "radius": R},
                          {"name": "B", "nodes": ["b0", "b1"], "stiffness": "rigid", "radius": R}]}
    if cable:
        members = {"struts": members["struts"][1:],
                   "cables": [{"name": "A", "nodes": ["a0", "a1"], "rest_length": 1.0, "stiffness": 1e4, "radius": R}]}
    return ts.Scene.from_dict({
        "gravity": [0, 0, -gravity],
        "contact": {"kinds": ["strut_cable" if cable else "strut_strut"], "response": True, "friction": mu,
                    "restitution": e},
        "nodes": [{"name": "a0", "position": [-0.5, 0, 0], **a},
                  {"name": "a1", "position": [0.5, 0, 0], **a},
                  {"name": "b0", "position": [xc, -0.5, z], "mass": 1.0, "velocity": [vx, 0, -v]},
                  {"name": "b1", "position": [xc, 0.5, z], "mass": 1.0, "velocity": [vx, 0, -v]}],
        **members})


def simulator(scene, method, dt=1e-3):
    """A Simulator of ``method`` (``METHODS``): "elastic" steps compiled (a step with a member pair armed by
    the reference), "elastic reference" by the numpy reference alone."""
    sim = ts.Simulator(scene, method=method.split()[0], dt=dt)
    if method == "elastic reference":
        sim._method.compiled = False
    assert sim._method.name != "elastic" or sim._method.has_loop() == (method == "elastic")
    return sim


def gap(x):
    return float(contact_geometry(x[None, :4], np.array([2 * R]))[3][0])


def plastic(xc, v=1.0, e=0.0):
    """Closed form of B (translating at v) striking A (at rest) at A's point xc, B's middle: impulse
    P = (1 + e) v / (1/m_A(xc) + 1/m_B) with m_B = 2 kg and 1/m_A = 1/2 + xc^2 / I, I = 0.5 kg m^2. Returns
    the z velocities of a0, a1 (A's centre -P/2, turning at -P xc / I) and of B's ends (-v + P/2)."""
    p = (1.0 + e) * v / (0.5 + xc * xc / 0.5 + 0.5)
    turn = -p * xc / 0.5
    return np.array([-p / 2 - 0.5 * turn, -p / 2 + 0.5 * turn, -v + p / 2, -v + p / 2]), p


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("xc, cable", [(0.0, False), (0.25, False), (0.25, True)])
def test_plastic_impact_of_crossing_struts(method, xc, cable):
    """B falls onto A; the gap closes at t = 30 ms, at a step's end. The impact is plastic (restitution 0):
    right after it the two contact points move together, at the closed form's velocities (to round-off
    when B strikes A's middle, where nothing turns; off the middle A turns during the rest of the step
    and its contact geometry with it, by omega h = 1e-3 rad: 1e-5 m/s), its impulse is the closed form's,
    no strut passes through the other, and linear momentum is conserved to 1e-9 throughout. A taut cable
    in A's place (strut_cable) takes the same impulse: across it, its two end masses respond to a blow at
    s as a rigid strut's do, 1/m = (1 - s)^2 / m_0 + s^2 / m_1 = 1/2 + xc^2 / I."""
    sim = simulator(crossing(xc, cable=cable), method)
    # the pair is (strut, cable) in the cable's case: the normal from B to A, the impulse on A
    members, up = (("B", "A"), -1.0) if cable else (("A", "B"), 1.0)
    expected, impulse = plastic(xc)
    momentum = sim.velocities.sum(axis=0)
    after, lowest, begins = None, np.inf, []
    for i in range(80):
        r = sim.step()
        lowest = min(lowest, gap(r.positions))
        np.testing.assert_allclose(r.velocities.sum(axis=0), momentum, rtol=0, atol=1e-9)
        begins += [c for c in r.contacts if c.kind == "begin"]
        if after is None and r.velocities[0, 2] != 0.0:
            after = r.velocities[:, 2]
            active = sim.active_contacts()
    tol = 1e-12 if xc == 0.0 else 1e-5
    np.testing.assert_allclose(after, expected, rtol=0, atol=tol)
    # the contact carries its impulse (on B, along the normal from A to B, +z) and no friction
    assert [c.members for c in active] == [members]
    assert active[0].normal_impulse == pytest.approx(impulse, abs=2 * tol)
    np.testing.assert_allclose(active[0].normal, [0, 0, up], atol=1e-3)   # A turned by omega h
    assert np.abs(active[0].tangential_impulse).max() <= 1e-12
    assert len(begins) == 1 and begins[0].members == members
    assert begins[0].time == pytest.approx(0.03, abs=1e-12)
    assert lowest >= -3e-9   # TOUCH_TOL and the turning pair's drift (methods/contact/member.py)
    # the struts go on together: B's middle stays on A
    assert abs(gap(r.positions)) <= 3e-9


@pytest.mark.parametrize("method", METHODS)
def test_impact_with_restitution_reverses_the_closing_speed(method):
    """Newton's law at B striking A's middle with e = 0.5: P = (1 + e) v / (1/2 + 1/2) = 1.5 N*s, so B
    leaves at -0.25 m/s and A at -0.75 m/s (separating at e v = 0.5 m/s); kinetic energy lost
    (1 - e^2) v^2 m_red / 2 = 0.375 J of 1 J."""
    sim = simulator(crossing(0.0, e=0.5, z=0.0505), method)
    for _ in range(60):
        r = sim.step()
    np.testing.assert_allclose(r.velocities[:, 2], [-0.75, -0.75, -0.25, -0.25], rtol=0, atol=1e-12)
    assert sim.energy()["kinetic"] == pytest.approx(0.625, abs=1e-12)
    assert gap(r.positions) > 0.0


@pytest.mark.parametrize("method", METHODS)
def test_strut_sliding_across_a_fixed_strut_stops_at_the_closed_form(method):
    """B lies across the fixed strut A (touching it at B's middle, gap 0) under gravity and slides along A
    at v0 = 1 m/s with member friction mu = 0.4: the Coulomb disc in the contact's tangent plane
    decelerates it at mu g, so it stops after v0^2 / (2 mu g) at t = v0 / (mu g), then stays (1 %)."""
    mu, v0 = 0.4, 1.0
    sim = simulator(crossing(0.0, v=0.0, mu=mu, z=2 * R, gravity=G, fixed_a=True, vx=v0), method)
    x0 = sim.positions[2, 0]
    stopped = None
    for i in range(400):
        r = sim.step()
        if stopped is None and abs(r.velocities[2, 0]) < 1e-12:
            stopped = (i + 1) * 1e-3
        assert abs(r.positions[2, 2] - 2 * R) <= 1e-6
    assert stopped == pytest.approx(v0 / (mu * G), rel=0.01)
    assert r.positions[2, 0] - x0 == pytest.approx(v0 ** 2 / (2 * mu * G), rel=0.01)
    assert np.abs(r.velocities).max() <= 1e-9


def test_contact_and_snap_in_the_same_step_create_no_energy():
    """B falls onto the fixed strut A (moved to y = -0.25: it meets B a quarter along it, near b0) while the
    slack cable from b1 to a fixed anchor above goes taut at the same instant (t = 30 ms): one inelastic
    impact with the contact row and the cable row. Its closed form: both rows are needed (the contact alone
    would leave B turning about it, b1 still falling), and their least-energy answer stops B dead: 1 J of
    kinetic energy lost, all at once, none ever gained."""
    raw = crossing(0.0, fixed_a=True).to_dict()
    for node in raw["nodes"][:2]:
        node["position"][1] = -0.25
    raw["nodes"].append({"name": "anchor", "position": [0.0, 0.5, 1.0], "fixed": True})
    raw["cables"] = [{"name": "c", "nodes": ["b1", "anchor"], "rest_length": 1.0 - 0.05 + 0.03}]
    sim = ts.Simulator(ts.Scene.from_dict(raw), method="inextensible", dt=1e-3)
    energy = [sim.energy()["total"]]
    impact = None
    for i in range(60):
        r = sim.step()
        energy.append(sim.energy()["total"])
        if impact is None and r.impulses[0] > 0:
            impact = r
    assert np.diff(energy).max() <= 1e-15
    assert energy[-1] <= 1e-20
    assert np.abs(impact.velocities).max() <= 1e-12
    assert impact.time == pytest.approx(0.031)   # located at 30 ms, resolved at the next step's start
    # stopping both ends: b0 takes 3/4 of the contact's impulse P_c (so P_c = 4/3 N*s), b1 1/4 of it and
    # the cable's P = 1 - P_c / 4 = 2/3 N*s
    assert impact.impulses[0] == pytest.approx(2.0 / 3.0, rel=1e-9)
    assert gap(r.positions) >= -1e-9


def test_scene_round_trips_the_response():
    scene = crossing(0.25, e=0.3, mu=0.2)
    assert scene.contact_response == ts.scene.ContactResponse(True, 0.2, 0.3)
    assert ts.Scene.from_dict(scene.to_dict()) == scene


def test_switching_detection_off_under_a_response_is_refused():
    with pytest.raises(ValueError, match=r"^contacts: the scene's contact response \(contact: response: true\) "
                                         r"needs member kinds to check \(without them members would pass through each other\)$"):
        ts.Simulator(crossing(), contacts=[])


def test_compiled_rows_match_the_reference_with_member_contacts():
    """The inextensible method's compiled row bookkeeping beside general contact rows (which its backend
    builds and checks with the numpy reference) against the numpy reference throughout: a tumbling strut B
    dropped across A under gravity, A's ends hanging from fixed anchors by cables, to 1e-12."""
    raw = crossing(0.2, v=0.3, mu=0.3, gravity=G).to_dict()
    raw["nodes"][2]["velocity"] = [0.1, 0.0, -0.5]
    raw["nodes"] += [{"name": "p0", "position": [-0.5, 0, 0.5], "fixed": True},
                     {"name": "p1", "position": [0.5, 0, 0.5], "fixed": True}]
    raw["cables"] = [{"name": "c0", "nodes": ["a0", "p0"], "rest_length": 0.5},
                     {"name": "c1", "nodes": ["a1", "p1"], "rest_length": 0.5}]
    scene = ts.Scene.from_dict(raw)
    compiled = ts.Simulator(scene, method="inextensible", dt=1e-3)
    reference = ts.Simulator(scene, method="inextensible", dt=1e-3)
    reference._method.compiled = False
    touched = 0
    for k in range(150):
        a, b = compiled.step(), reference.step()
        for name in ("positions", "velocities", "impulses"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, atol=1e-12, err_msg=f"{name} {k}")
        touched += bool(compiled.active_contacts())
    assert touched > 50


def across(mu_ground=0.5, mu=0.3, e=0.3):
    """Strut A (``crossing``'s) lying on a ground (friction ``mu_ground``) and strut B thrown across it from
    0.3 m, tumbling (its ends' velocities differ); member friction ``mu``, restitution ``e``; an elastic cable
    from a1 to b1, slack at first (rest length 1.2 m)."""
    raw = crossing(0.2, v=0.5, mu=mu, e=e, z=0.3, gravity=G, vx=0.3).to_dict()
    for node in raw["nodes"][:2]:
        node["position"][2] = R
    raw["nodes"][3]["velocity"] = [0.3, 0.2, -0.8]
    raw["ground"] = {"height": 0.0, "friction": mu_ground, "restitution": 0.0}
    raw["cables"] = [{"name": "c", "nodes": ["a1", "b1"], "rest_length": 1.2, "stiffness": 200.0, "radius": 0.0}]
    return ts.Scene.from_dict(raw)


def test_step_walks_the_detector_once_over_the_steps_it_computes_ahead():
    """step() walks the compiled detector once over the steps it computes ahead and hands each step its
    events: the same events (members, times, impulses) and active contacts as the numpy detector (the
    reference) stepped with each step, across new inputs mid-way and active_contacts() asked mid-way (the
    detector answers at the state, then goes on from where it was)."""
    from tensegrity_sim.methods.contact.detection import ContactDetector
    from tensegrity_sim.methods.contact.friction import TOUCH_TOL

    scene = across(0.2, 1.0)
    ahead, alone = simulator(scene, "elastic"), simulator(scene, "elastic")
    alone._contacts = ContactDetector(alone.system, scene.contact_kinds, touch=TOUCH_TOL)
    alone._contacts.reset(alone.positions)
    events, chunked = [], 0
    for k in range(900):
        if k in (450, 613):
            for sim in (ahead, alone):
                sim.set_rest_lengths([0.4 if k == 450 else 0.45])
        a, b = ahead.step(), alone.step()
        chunked += ahead._ahead.events is not None
        np.testing.assert_array_equal(a.positions, b.positions)   # detection does not change the motion
        mine, its = ([e for e in r.contacts if "ground" not in e.members] for r in (a, b))
        assert [(e.kind, e.members) for e in mine] == [(e.kind, e.members) for e in its], f"step {k}"
        for e, f in zip(mine, its):
            assert e.time == pytest.approx(f.time, abs=1e-12) and e.normal_impulse == f.normal_impulse
        events += mine
        if k % 7 == 3:
            mine, its = ([c for c in sim.active_contacts() if "ground" not in c.members] for sim in (ahead, alone))
            assert [c.members for c in mine] == [c.members for c in its], f"step {k}"
            for c, d in zip(mine, its):
                assert c.since == pytest.approx(d.since, abs=1e-12)
                assert c.distance == pytest.approx(d.distance, abs=1e-15) and c.normal_impulse == d.normal_impulse
    assert chunked == 900 and len(events) >= 2 and {e.kind for e in events} == {"begin", "end"}


@pytest.mark.parametrize("mu_ground, mu", [(0.2, 1.0), (1.0, 0.3)])
def test_elastic_compiled_response_matches_the_reference(mu_ground, mu):
    """The elastic method compiled (the ground's blocks and the coupled blocks of the touching pairs by the
    block Newton of ``_friction_block_kernels``) against its numpy reference (the QP fixed point of
    ``friction.py`` for every step): B lands on A, rocks on it, its ends landing on the ground in turn, and
    slides over the ground and along A once its cable is reeled in mid-run. Each step of the compiled run
    taken again by the reference from the same state: the two algorithms meet the Coulomb law to their
    tolerances (1e-13 and 1e-10 of the impulse scale), so the velocities agree to 1e-9. The two runs apart
    drift further (1e-8 m/s after 900 steps, a sliding strut's impacts amplifying the per-step difference)
    but have the same member contact events, at the same times, with the same impulses."""
    scene = across(mu_ground, mu)
    compiled, reference = simulator(scene, "elastic"), simulator(scene, "elastic reference")
    probe = simulator(scene, "elastic reference")._method
    steps, touching, sliding = 900, 0, 0
    for k in range(steps):
        if k == 450:
            for sim in (compiled, reference):
                sim.set_rest_lengths([0.4])
        probe.invalidate()
        p = probe.step(compiled._state.copy())
        a, b = compiled.step(), reference.step()
        np.testing.assert_allclose(a.velocities, p.velocities, rtol=0, atol=1e-9, err_msg=f"step {k}")
        np.testing.assert_allclose(a.positions, p.positions, rtol=0, atol=1e-12, err_msg=f"step {k}")
        np.testing.assert_allclose(a.impulses, p.impulses, rtol=0, atol=1e-9, err_msg=f"step {k}")
        # the ground's impulses: a strut's friction along itself can pass from one end to the other through its
        # own impulse (statically indeterminate), so the two algorithms' splits differ; their sum and, where the
        # struts do not touch, the normal impulses (the struts lie flat) do not. (Touching, B lying on A and on
        # the ground has six contact rows for its five degrees of freedom: the split between its contacts is
        # indeterminate too.)
        np.testing.assert_allclose(a.contact_impulses.sum(axis=0), p.contact_impulses.sum(axis=0), rtol=0,
                                   atol=1e-9, err_msg=f"step {k}")
        if not p.pair_impulses:
            np.testing.assert_allclose(a.contact_impulses[:, 2], p.contact_impulses[:, 2], rtol=0, atol=1e-9,
                                       err_msg=f"step {k}")
        np.testing.assert_allclose(a.velocities, b.velocities, rtol=0, atol=1e-7, err_msg=f"step {k}")
        # the member contacts' events (the ground's detector counts a node in contact while its impulse is above
        # 0, and the QP fixed point leaves 1e-25 N*s where the block Newton has 0)
        mine, its = ([e for e in r.contacts if "ground" not in e.members] for r in (a, b))
        assert [(e.kind, e.members) for e in mine] == [(e.kind, e.members) for e in its], f"step {k}"
        for e, f in zip(mine, its):
            assert e.time == pytest.approx(f.time, abs=1e-9)
            assert e.normal_impulse == pytest.approx(f.normal_impulse, abs=1e-7)
        touching += any(c.members == ("A", "B") for c in compiled.active_contacts())
        sliding += any(np.hypot(*a.velocities[n, :2]) > 0.1 and a.contact_impulses[n, 2] > 0 for n in (2, 3))
    method = compiled._method
    # the pair touched for a good part of the run, B slid on the ground, and the kernel took every step
    assert touching >= 60 and sliding >= 30 and method.member_steps == method.fallbacks == 0


@pytest.mark.parametrize("records", [None, 1])
def test_elastic_loop_with_a_response_is_its_step_bitwise(monkeypatch, records):
    """The elastic method's compiled loop on a response scene (steps computed ahead, ``run`` in chunks)
    against each step through the method's compiled step alone: the same positions, velocities, cable and
    ground impulses, slack flags and member contact events (with their impulses) to the last bit; also where
    a compiled call has room for one step's pair impulses only (``records`` 1: it stops before each next step
    with a pair armed, and the loop goes on from its carry)."""
    from tensegrity_sim.methods.elastic import method as elastic_method

    if records is not None:
        monkeypatch.setattr(elastic_method, "_PAIR_RECORDS", records)
    scene = across()
    loop, one = simulator(scene, "elastic"), simulator(scene, "elastic")
    one._method.has_loop = lambda: False   # each step through ElasticMethod._step_impl
    fields = ("positions", "velocities", "impulses", "slack", "contact_impulses")

    def events(contacts):
        return [(e.kind, e.members, e.time, e.normal_impulse, tuple(e.tangential_impulse)) for e in contacts]

    impacts = 0
    for k in range(700):
        a, b = loop.step(), one.step()
        for field in fields:
            assert np.array_equal(getattr(a, field), getattr(b, field)), f"{field}, step {k}"
        assert events(a.contacts) == events(b.contacts), f"step {k}"
        impacts += any(e.members == ("A", "B") and e.kind == "begin" and e.normal_impulse > 0 for e in a.contacts)
    assert impacts >= 2
    for sim in (loop, one):
        sim.reset()
    a, b = (sim.run(steps=700, every=7) for sim in (loop, one))
    for field in fields:
        assert np.array_equal(getattr(a, field), getattr(b, field)), f"run: {field}"
    assert events(a.contacts) == events(b.contacts)
