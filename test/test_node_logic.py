"""The node's behaviour without rclpy: real simulator, real (rosbags Jazzy) message objects.

Outputs are checked against a plain Simulator run side by side (bit for bit where the node only copies,
to round-off where it derives); refused inputs against a twin that never saw them.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.results import ContactEvent
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.node_logic import TOPICS, NodeSettings, SimNodeLogic, decode_contacts, encode_contacts
from ros_helpers import (FakeClock, FakeRecorder, ListLogger, make_logic, positions_of, prism, rest_lengths_msg,
                         stamp_of, wrench_msg)


# --------------------------------------------------------------------------- settings
@pytest.mark.parametrize("dt, rate, every", [(1e-3, 100.0, 10), (1e-3, 1000.0, 1), (1e-3, 30.0, 33),
                                             (2e-3, 100.0, 5), (1e-4, 100.0, 100)])
def test_publish_every_rounds_to_whole_steps(dt, rate, every):
    assert NodeSettings(dt=dt, publish_rate=rate).publish_every == every


BAD_SETTINGS = [
    ({"dt": 0.0}, "parameter 'dt': must be > 0, got 0.0"),
    ({"dt": math.nan}, "parameter 'dt': must be a finite number, got nan"),
    ({"dt": "1"}, "parameter 'dt': must be a finite number, got '1'"),
    ({"step_rate": -5.0}, "parameter 'step_rate': must be >= 1e-06, got -5.0"),
    # issue 13: absurd values that made tick() raise or run for seconds, or escaped as another exception
    ({"step_rate": 5e-324}, "parameter 'step_rate': must be >= 1e-06, got 5e-324"),
    ({"publish_rate": 1e-300}, "parameter 'publish_rate': must be >= 1e-06, got 1e-300"),
    ({"real_time_factor": 1e300}, "parameter 'real_time_factor': must be <= 1e+06, got 1e+300"),
    ({"dt": 5e-324}, "parameter 'dt': must be >= 1e-09 s (stamps are integer nanoseconds), got 5e-324"),
    ({"dt": 10 ** 400}, "parameter 'dt': must be a finite number, got an integer of 401 digits"),
    ({"marker_rate": [1.0]}, "parameter 'marker_rate': must be a finite number, got [1.0]"),
    ({"real_time_factor": -1.0}, "parameter 'real_time_factor': must be >= 0, got -1.0"),
    ({"real_time_factor": True}, "parameter 'real_time_factor': must be a finite number, got True"),
    ({"publish_rate": 2000.0}, "parameter 'publish_rate': must be at most 1/dt = 1000 Hz (one publication "
                               "per step), got 2000.0"),
    ({"max_rest_length_rate": math.inf}, "parameter 'max_rest_length_rate': must be a finite number, got inf"),
    ({"frame_id": ""}, "parameter 'frame_id': must be a non-empty string, got ''"),
    ({"log_path": None}, "parameter 'log_path': must be a string, got None"),
    ({"solver": "cplex"}, "parameter 'solver': must be one of daqp, osqp, nnls, sparse, auto or empty, got 'cplex'"),
    ({"solver": None}, "parameter 'solver': must be one of daqp, osqp, nnls, sparse, auto or empty, got None"),
    ({"thread_priority": 100}, "parameter 'thread_priority': must be an integer from 0 to 99, got 100"),
    ({"thread_priority": 50.0}, "parameter 'thread_priority': must be an integer from 0 to 99, got 50.0"),
    ({"thread_priority": True}, "parameter 'thread_priority': must be an integer from 0 to 99, got True"),
    ({"lockstep": "true"}, "parameter 'lockstep': must be true or false, got 'true'"),
    ({"lockstep": 1}, "parameter 'lockstep': must be true or false, got 1"),
    ({"node_name": "tensegrity_sim"}, "parameter 'node_name': must be fully qualified (start with /), got "
                                      "'tensegrity_sim'"),
]


@pytest.mark.parametrize("changes, message", BAD_SETTINGS, ids=[m for _, m in BAD_SETTINGS])
def test_bad_settings_name_the_parameter(changes, message):
    with pytest.raises(ValueError) as err:
        NodeSettings(**changes)
    assert str(err.value) == message


@pytest.mark.filterwarnings("ignore::tensegrity_sim.LengthOffsetWarning")  # the prism is prestressed
@pytest.mark.parametrize("solver, qp_solver", [("auto", None), ("", None), ("daqp", "daqp"), ("osqp", "osqp"),
                                               ("nnls", "nnls")])
def test_solver_parameter_names_the_simulators_backend(solver, qp_solver):
    settings = NodeSettings(method="inextensible", solver=solver)
    assert settings.qp_solver == qp_solver
    sim = ts.Simulator(prism(), method=settings.method, solver=settings.qp_solver)
    assert sim.method_settings["solver"] == (qp_solver or "daqp")


def test_integer_parameters_become_floats():
    s = NodeSettings(dt=1, publish_rate=1, step_rate=1000)
    assert isinstance(s.dt, float) and s.dt == 1.0 and s.publish_every == 1


# --------------------------------------------------------------------------- outputs
def publications(sent):
    """[(key -> message)] per publication, in order (a publication starts with the clock)."""
    out = []
    for key, msg in sent:
        if key == "clock":
            out.append({})
        out[-1][key] = msg
    return out


@pytest.mark.parametrize("publish_rate", [100.0, 1000.0, 30.0])
def test_outputs_match_a_plain_simulator(publish_rate):
    scene = prism(gravity=9.81)
    logic, sent, _ = make_logic(scene, publish_rate=publish_rate)
    every = logic.settings.publish_every
    plain = ts.Simulator(scene, method="elastic", dt=1e-3)
    expected = []
    impulse = np.zeros(len(scene.cables))
    events = []
    for k in range(1, 201):
        logic.step()
        r = plain.step()
        impulse = impulse + r.impulses
        events += r.contacts
        if logic.publication_due:
            logic.publish()
            expected.append((k, r, impulse, events))
            impulse = np.zeros(len(scene.cables))
            events = []
    pubs = publications(sent)
    assert len(pubs) == len(expected) == 200 // every
    names = list(scene.cable_names)
    for pub, (k, r, impulse, events) in zip(pubs, expected):
        ns = round(k * 1e-3 * 1e9)
        clock = pub["clock"].clock
        assert clock.sec * 10**9 + clock.nanosec == ns
        poses, states, impulses = pub["node_poses"], pub["cable_states"], pub["cable_impulses"]
        assert {stamp_of(poses), stamp_of(states), stamp_of(impulses)} == {ns}
        assert poses.header.frame_id == "world"
        np.testing.assert_array_equal(positions_of(poses), r.positions)
        assert all((p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w) == (0, 0, 0, 1)
                   for p in poses.poses)
        assert list(states.name) == names and list(impulses.name) == names
        d = r.positions[plain.system.cable_ends[:, 1]] - r.positions[plain.system.cable_ends[:, 0]]
        length = np.linalg.norm(d, axis=1)
        rate = np.sum((r.velocities[plain.system.cable_ends[:, 1]] - r.velocities[plain.system.cable_ends[:, 0]])
                      * d, axis=1) / length
        np.testing.assert_allclose(states.position, length, rtol=1e-15)
        np.testing.assert_allclose(states.velocity, rate, rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(states.effort, r.tensions)
        # impulses summed over exactly the steps since the previous publication, in step order
        np.testing.assert_array_equal(impulses.effort, impulse)
        assert len(impulses.position) == 0 and len(impulses.velocity) == 0
        # the contact events of exactly those steps (the prism collapses through itself), or no message
        published = decode_contacts(pub["contacts"]) if "contacts" in pub else []
        assert [(e.kind, e.members, e.time, e.distance) for e in published] == \
            [(e.kind, e.members, e.time, e.distance) for e in events]
    assert any("contacts" in pub for pub in pubs)


def test_no_impulse_lost_over_a_run():
    """The published sums add up to the whole run's impulse (round-off only), whatever the decimation."""
    scene = prism()
    totals = []
    for rate in (1000.0, 100.0, 7.0):
        logic, sent, _ = make_logic(scene, publish_rate=rate)
        for _ in range(420):
            logic.step()
            if logic.publication_due:
                logic.publish()
        logic.publish()  # the remainder
        totals.append(sum(np.asarray(m.effort) for k, m in sent if k == "cable_impulses"))
    traj = ts.Simulator(scene, method="elastic", dt=1e-3).run(steps=420)
    for total in totals:
        np.testing.assert_allclose(total, traj.impulses.sum(axis=0), rtol=1e-13)
    assert np.any(traj.slack) and np.any(~traj.slack)  # cables went slack and taut: snaps were summed


def test_nothing_published_before_the_first_step():
    logic, sent, _ = make_logic(prism())
    logic.publish()
    assert sent == []


# --------------------------------------------------------------------------- inputs
def snapshot(sim):
    return (sim.time, sim.positions, sim.velocities, sim.rest_lengths, sim.external_forces)


BAD_INPUTS = [
    ("cable_rest_lengths", rest_lengths_msg([], []), "name is empty: no cable to set"),
    ("cable_rest_lengths", rest_lengths_msg(["c0", "c1"], [0.5]), "position has 1 values for 2 names"),
    ("cable_rest_lengths", rest_lengths_msg(["c0", "zz"], [0.5, 0.5]),
     "unknown cable 'zz' (cables: c0, c1, c2, c3, c4, c5, c6, c7, c8)"),
    ("cable_rest_lengths", rest_lengths_msg(["c0", "c0"], [0.5, 0.6]), "cable 'c0' is named more than once"),
    ("cable_rest_lengths", rest_lengths_msg(["c0", "c1"], [0.5, math.nan]),
     "position[1] ('c1'): a rest length must be finite and > 0 m, got nan"),
    ("cable_rest_lengths", rest_lengths_msg(["c2"], [math.inf]),
     "position[0] ('c2'): a rest length must be finite and > 0 m, got inf"),
    ("cable_rest_lengths", rest_lengths_msg(["c2"], [0.0]),
     "position[0] ('c2'): a rest length must be finite and > 0 m, got 0.0"),
    ("cable_rest_lengths", rest_lengths_msg(["c0", "c2"], [0.5, -0.1]),
     "position[1] ('c2'): a rest length must be finite and > 0 m, got -0.1"),
    ("cable_rest_lengths", rest_lengths_msg(["c0"], [0.5], velocity=[1.0, 2.0]),
     "velocity has 2 values for 1 names (must be empty or match)"),
    ("cable_rest_lengths", rest_lengths_msg(["c0"], [0.5], effort=[1.0, 2.0]),
     "effort has 2 values for 1 names (must be empty or match)"),
    ("external_wrench", wrench_msg("ghost", [0.0, 0.0, 1.0]),
     "header.frame_id 'ghost' is not a node of the scene (nodes: n0, n1, n2, n3, n4, n5)"),
    ("external_wrench", wrench_msg("n1", [0.0, math.nan, 1.0]), "wrench.force must be finite, got [0.0, nan, 1.0]"),
    ("external_wrench", wrench_msg("n1", [math.inf, 0.0, 1.0]), "wrench.force must be finite, got [inf, 0.0, 1.0]"),
    ("external_wrench", wrench_msg("n1", [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]),
     "wrench.torque must be zero (a node is a point and takes no torque), got [0.0, 0.0, 1.0]"),
    ("external_wrench", wrench_msg("n1", [0.0, 0.0, 1.0], [math.nan, 0.0, 0.0]),
     "wrench.torque must be zero (a node is a point and takes no torque), got [nan, 0.0, 0.0]"),
]


@pytest.mark.parametrize("key, message, reason", BAD_INPUTS, ids=[r for _, _, r in BAD_INPUTS])
@pytest.mark.parametrize("rate_limit", [0.0, 1.0])
def test_refused_input_changes_nothing(key, message, reason, rate_limit):
    """Refused whole with the reason logged; the state, and so every later output, is exactly that of a
    twin that never saw the message (15 steps in: the impulse sum of the next publication is open)."""
    scene = prism()
    logic, sent, logger = make_logic(scene, max_rest_length_rate=rate_limit)
    twin, twin_sent, _ = make_logic(scene, max_rest_length_rate=rate_limit)
    for node in (logic, twin):
        node.receive("cable_rest_lengths", rest_lengths_msg(["c4"], [0.5]))
        for _ in range(15):
            node.step()
            if node.publication_due:
                node.publish()
    before = snapshot(logic.sim)
    assert logic.receive(key, message) == reason
    assert logger.warnings == [f"/tensegrity_sim/{key}: refused: {reason}"]
    assert logic.refused[key] == 1 and logic.received[key] == 2 - (key == "external_wrench")
    for a, b in zip(before, snapshot(logic.sim)):
        np.testing.assert_array_equal(a, b)
    for node in (logic, twin):
        for _ in range(25):
            node.step()
            if node.publication_due:
                node.publish()
    assert len(sent) == len(twin_sent) == 20
    for (k1, m1), (k2, m2) in zip(sent, twin_sent):
        assert k1 == k2
        assert M.serialize(m1, TOPICS[k1].typename) == M.serialize(m2, TOPICS[k2].typename)


def test_accepted_inputs_act_from_the_next_step():
    """Rest lengths and a force taken as messages evolve exactly like the same calls on a Simulator;
    the force is held until replaced, and a zero force clears it."""
    scene = prism()
    logic, _, logger = make_logic(scene)
    plain = ts.Simulator(scene, method="elastic", dt=1e-3)
    for _ in range(5):
        logic.step(), plain.step()
    assert logic.receive("cable_rest_lengths", rest_lengths_msg(["c1", "c6"], [0.55, 0.5])) is None
    assert logic.receive("external_wrench", wrench_msg("n4", [1.0, -2.0, 30.0])) is None
    plain.set_rest_lengths({"c1": 0.55, "c6": 0.5})
    plain.set_external_forces({"n4": [1.0, -2.0, 30.0]})
    for _ in range(30):
        np.testing.assert_array_equal(logic.step().positions, plain.step().positions)
    np.testing.assert_array_equal(logic.sim.external_forces[4], [1.0, -2.0, 30.0])
    assert logic.receive("external_wrench", wrench_msg("n4", [0.0, 0.0, 0.0])) is None
    assert not np.any(logic.sim.external_forces)
    assert logger.warnings == []


def test_wrench_impulse_balance():
    """Σ m Δv = dt Σ f over steps with a held force on a free structure (contract §2)."""
    scene = prism()
    logic, _, _ = make_logic(scene)
    logic.receive("external_wrench", wrench_msg("n2", [3.0, 0.0, -4.0]))
    p0 = logic.sim.momentum()[0]
    for _ in range(50):
        logic.step()
    np.testing.assert_allclose(logic.sim.momentum()[0] - p0, [0.15, 0.0, -0.2], rtol=1e-12, atol=1e-14)


def test_rest_length_rate_limit():
    """At 2 m/s and dt = 1 ms a rest length moves 2 mm per step towards its target and lands on it
    exactly; a new command replaces the target."""
    scene = prism()
    logic, _, _ = make_logic(scene, max_rest_length_rate=2.0)
    start = scene.cable_rest_lengths[3]
    logic.receive("cable_rest_lengths", rest_lengths_msg(["c3"], [start - 0.05]))
    assert logic.sim.rest_lengths[3] == start  # not before the next step
    seen = []
    for _ in range(30):
        logic.step()
        seen.append(logic.sim.rest_lengths[3])
    np.testing.assert_allclose(seen[:25], start - 0.002 * np.arange(1, 26), rtol=0, atol=1e-15)
    assert seen[24] == seen[29] == start - 0.05
    others = np.delete(logic.sim.rest_lengths, 3)
    np.testing.assert_array_equal(others, np.delete(scene.cable_rest_lengths, 3))
    logic.receive("cable_rest_lengths", rest_lengths_msg(["c3"], [start]))
    for _ in range(3):
        logic.step()
    assert logic.sim.rest_lengths[3] == pytest.approx(start - 0.05 + 0.006, abs=1e-15)


# --------------------------------------------------------------------------- contacts
def contact(kind, a, b, t, seed):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=3)
    return ContactEvent(kind, (a, b), t, rng.normal(size=3), rng.normal(size=3), n / np.linalg.norm(n),
                        float(rng.normal() * 1e-3))


def test_contact_events_are_never_dropped(monkeypatch):
    """Synthetic events (contact detection is not wired into the step yet) in steps 3 (two), 10 (the step
    of a publication), 11 and 27: every one comes out once, in order, exactly, in the publication after
    its step; the marker shows a contact from its begin to its end."""
    scene = prism()
    logic, sent, _ = make_logic(scene)
    script = {3: [contact("begin", "s0", "c7", 0.0025, 1), contact("begin", "s1", "c8", 0.0027, 2)],
              10: [contact("end", "s1", "c8", 0.0095, 3)], 11: [contact("begin", "s2", "c3", 0.0105, 4)],
              27: [contact("end", "s0", "c7", 0.0261, 5), contact("end", "s2", "c3", 0.0262, 6)]}
    real_step = logic.sim.step

    def step_with_contacts():
        r = real_step()
        return replace(r, contacts=tuple(script.get(logic.sim.step_count, ())))

    monkeypatch.setattr(logic.sim, "step", step_with_contacts)
    for _ in range(40):
        logic.step()
        if logic.publication_due:
            logic.publish()
    got = [(stamp_of(m), e) for k, m in sent if k == "contacts" for e in decode_contacts(m)]
    expected = [e for k in sorted(script) for e in script[k]]
    assert len(got) == len(expected) == 6
    for (stamp, e), x in zip(got, expected):
        assert (e.kind, e.members, e.time, e.distance) == (x.kind, x.members, x.time, x.distance)
        for f in ("point_a", "point_b", "normal"):
            np.testing.assert_array_equal(getattr(e, f), getattr(x, f))
        assert stamp == 10_000_000 * math.ceil(x.time / 0.01 + 1e-9)  # the publication after its step
    markers = [{m.ns: m for m in msg.markers} for k, msg in sent if k == "markers"]
    shown = [len(m["contacts"].points) if "contacts" in m and m["contacts"].action == 0 else None for m in markers]
    deleted = ["contacts" in m and m["contacts"].action == 2 for m in markers]
    assert shown == [2, 4, None, None]  # s0-c7 from step 3, s2-c3 from step 11, both ended in step 27
    assert deleted == [False, False, True, False]


def test_contact_encoding_keeps_every_bit():
    events = [ContactEvent("begin", ("s0", "c1"), 1 / 3, np.array([1e-300, -0.0, 2 / 7]),
                           np.array([np.pi, -np.e, 1e300]), np.array([0.6, 0.8, 0.0]), -1 / 7)]
    msg = M.deserialize(M.serialize(encode_contacts(events, M.header(5, "world")),
                                    "diagnostic_msgs/msg/DiagnosticArray"), "diagnostic_msgs/msg/DiagnosticArray")
    (e,) = decode_contacts(msg)
    x = events[0]
    assert (e.kind, e.members, e.time, e.distance) == (x.kind, x.members, x.time, x.distance)
    for f in ("point_a", "point_b", "normal"):
        assert getattr(e, f).tobytes() == getattr(x, f).tobytes()
    status = msg.status[0]
    assert (status.name, status.message) == ("contact s0 c1", "begin")


# --------------------------------------------------------------------------- bytes for the log
class BytesRecorder:
    """Keeps the (topic, CDR bytes, log time) the node logic records."""

    def __init__(self):
        self.records = []

    def record(self, records, log_time_ns):
        for topic, data in records:
            assert isinstance(data, bytes)
            self.records.append((topic, data, log_time_ns))


def test_a_message_a_transport_decoded_is_taken_as_it_is(monkeypatch):
    """receive(..., decoded=True) (the DDS transport's samples, decoded from the wire's CDR): the same log
    bytes, the same refusals and the same commanded rest lengths as the message taken by an in-process caller,
    without decoding it again from the logged bytes."""
    from tensegrity_sim.ros import node_logic

    scene = prism()
    typename = TOPICS["cable_rest_lengths"].typename
    messages = [rest_lengths_msg(["c0", "c2"], [0.31, 0.27]), rest_lengths_msg(["c9"], [0.3]),
                rest_lengths_msg(["c1"], [float("nan")])]
    runs = []
    for decoded in (False, True):
        logic, _, _ = make_logic(scene)
        logic.recorder = BytesRecorder()
        decodes = []
        real = node_logic.M.deserialize
        monkeypatch.setattr(node_logic.M, "deserialize", lambda data, t: decodes.append(t) or real(data, t))
        reasons = [logic.receive("cable_rest_lengths", real(M.serialize(m, typename), typename) if decoded else m,
                                 decoded=decoded) for m in messages]
        monkeypatch.setattr(node_logic.M, "deserialize", real)
        runs.append((reasons, logic.recorder.records, logic._target.copy(), len(decodes)))
    (reasons, records, target, decodes), (reasons2, records2, target2, decodes2) = runs
    assert reasons == reasons2 and reasons[0] is None and "c9" in reasons[1] and "finite" in reasons[2]
    assert records == records2 and len(records) == 3
    np.testing.assert_array_equal(target, target2)
    assert target[[0, 2]].tolist() == [0.31, 0.27] and (decodes, decodes2) == (3, 0)


@pytest.mark.parametrize("scene, frame_id", [(prism(gravity=9.81), "world"), (ts.load_scene("icosahedron"), "map"),
                                             (ts.load_scene("tower"), "b")])
def test_log_and_raw_transport_get_the_messages_bytes(monkeypatch, scene, frame_id):
    """Every output and input the log records, and every output a raw transport gets, is byte for byte
    the message object the transport gets, serialised by rosbags (clock, poses, cable states and
    impulses, markers of several shapes come from templates; contacts, diagnostics and inputs from the
    objects). With ``idle_outputs`` (the markers and contacts wait for ``send_waiting``, called after some
    publications only: the others' go out before the next publication or diagnostics; an input that arrives
    meanwhile acts at once, its record waits behind them), the transport and the log get the same messages in
    the same order at the same log times."""
    logics = {}
    waited = []   # with idle_outputs: (outputs sent, records) before and after the inputs at step 15
    for raw, idle in ((False, False), (True, False), (False, True)):
        sent = []
        logic = SimNodeLogic(ts.Simulator(scene, method="elastic", dt=1e-3),
                             NodeSettings(scene=scene.name, frame_id=frame_id, marker_rate=100.0),
                             transport=lambda key, msg, sent=sent: sent.append((key, msg)), raw_transport=raw,
                             clock=FakeClock())
        logic.recorder = None if raw else BytesRecorder()
        logic.idle_outputs = idle
        script = {3: [contact("begin", scene.strut_names[0], scene.cable_names[-1], 0.0025, 1)],
                  57: [contact("end", scene.strut_names[0], scene.cable_names[-1], 0.0565, 2)]}
        real_step = logic.sim.step

        def step_with_contacts(real_step=real_step, logic=logic):
            r = real_step()
            return replace(r, contacts=tuple(script.get(logic.sim.step_count, ())))

        monkeypatch.setattr(logic.sim, "step", step_with_contacts)
        for k in range(120):
            if k == 15:
                before = (len(sent), len(logic.recorder.records)) if idle else None
                logic.receive("cable_rest_lengths", rest_lengths_msg([scene.cable_names[1]], [0.3]))
                logic.receive("external_wrench", wrench_msg("nope", [0.0, 0.0, 5.0]))  # refused, still logged
                if idle:
                    waited += [before, (len(sent), len(logic.recorder.records))]
                    np.testing.assert_array_equal(logic._target[1], 0.3)   # the input acts at once
            logic.step()
            if logic.publication_due:
                logic.publish()
                if k % 30 == 19:
                    logic.send_waiting()
        logic.publish_diagnostics()
        logics[raw, idle] = (logic, sent)
    (logic, sent), (_, raw_sent), (idle_logic, idle_sent) = logics.values()
    outputs = [(logic.topic_names[key], M.serialize(msg, TOPICS[key].typename)) for key, msg in sent]
    # all but the diagnostics, whose statistics count the idle sends
    assert [(logic.topic_names[key], M.serialize(msg, TOPICS[key].typename)) for key, msg in idle_sent][:-1] == \
        outputs[:-1] and outputs[-1][0] == "/diagnostics"
    assert idle_logic.recorder.records[:-1] == logic.recorder.records[:-1]
    assert waited[0] == waited[1]   # step 10's markers still waiting: the inputs drew nothing, recorded nothing yet
    assert idle_logic.statistics()["idle_sends"] == 4   # at steps 20, 50, 80 and 110
    assert [k for k, _ in sent].count("contacts") == 2 and [k for k, _ in sent].count("markers") == 12
    shapes = {tuple((m.ns, m.action, len(m.points), len(m.colors)) for m in msg.markers)
              for key, msg in sent if key == "markers"}
    assert len(shapes) >= 3  # with and without contacts, and the one that deletes them
    assert [(logic.topic_names[k], data) for k, data in raw_sent] == outputs
    inputs = [(logic.topic_names["cable_rest_lengths"], M.serialize(rest_lengths_msg([scene.cable_names[1]], [0.3]),
                                                                    TOPICS["cable_rest_lengths"].typename)),
              (logic.topic_names["external_wrench"], M.serialize(wrench_msg("nope", [0.0, 0.0, 5.0]),
                                                                 TOPICS["external_wrench"].typename))]
    records = logic.recorder.records
    assert [(topic, data) for topic, data, _ in records if topic not in dict(inputs)] == outputs
    assert [(topic, data, t) for topic, data, t in records if topic in dict(inputs)] == \
        [(topic, data, 15_000_000) for topic, data in inputs]


# --------------------------------------------------------------------------- markers
def test_the_marker_templates_a_rolling_run_meets_first_are_built_with_the_node(monkeypatch):
    """The markers' templates of a robot landing on the ground (contacts and their forces) with a cable let
    out (slack cables shown, then deleted) are built when the node is (Markers.prepare), not at a
    publication (~2 ms each)."""
    scene = ts.load_scene("icosahedron_ground")
    logic, sent, _ = make_logic(scene)
    logic.recorder = BytesRecorder()   # the log takes the markers' bytes, from their templates
    built = []
    real_base = logic._markers._base
    monkeypatch.setattr(logic._markers, "_base", lambda kinds: built.append(kinds) or real_base(kinds))
    cable, rest = scene.cable_names[0], float(scene.cable_rest_lengths[0])
    for k in range(300):
        if k in (100, 200):
            logic.receive("cable_rest_lengths", rest_lengths_msg([cable], [2.0 * rest if k == 100 else rest]))
        logic.step()
        if logic.publication_due:
            logic.publish()
    kinds = {tuple((m.ns, m.action) for m in msg.markers) for key, msg in sent if key == "markers"}
    assert {("slack_cables", 0) in k for k in kinds} == {True, False} and any(("slack_cables", 2) in k for k in kinds)
    assert all(("contact_forces", 0) in k for k in kinds) and built == []


def test_markers_show_struts_taut_and_slack_cables_and_supports():
    scene = prism(fixed_base=True, gravity=9.81)
    logic, sent, _ = make_logic(scene, publish_rate=1000.0)
    logic.receive("cable_rest_lengths", rest_lengths_msg(["c0"], [5.0]))  # far too long: slack
    r = logic.step()
    logic.publish()
    markers = {m.ns: m for m in sent[-1][1].markers}
    assert set(markers) == {"struts", "cables", "slack_cables", "supports"}
    sys = logic.sim.system
    pts = {ns: np.array([[p.x, p.y, p.z] for p in m.points]) for ns, m in markers.items()}
    np.testing.assert_array_equal(pts["struts"], r.positions[sys.strut_ends].reshape(-1, 3))
    np.testing.assert_array_equal(pts["slack_cables"], r.positions[sys.cable_ends[r.slack]].reshape(-1, 3))
    np.testing.assert_array_equal(pts["cables"], r.positions[sys.cable_ends[~r.slack]].reshape(-1, 3))
    np.testing.assert_array_equal(pts["supports"], r.positions[[0]])
    assert r.slack[0] and markers["slack_cables"].scale.x == pytest.approx(0.002)  # half of 2 x radius
    assert markers["struts"].scale.x == pytest.approx(0.02)
    colors = np.array([[c.r, c.g, c.b] for c in markers["cables"].colors])
    tension = np.repeat(r.tensions[~r.slack], 2)
    i = int(np.argmax(tension))
    assert colors.shape == (len(tension), 3) and colors[i, 0] == 1.0 and colors[i, 2] == 0.0  # red: largest


# --------------------------------------------------------------------------- scheduling
def run_ticks(logic, clock, times):
    counts = []
    for t in times:
        clock.t = t
        logic.tick()
        counts.append(logic.sim.step_count)
    return counts


def test_steps_follow_the_steady_clock_without_drift():
    """Jittered ticks at 1 kHz (±0.3 ms): the step count is always floor(elapsed / dt), so the rate
    never drifts, and no overrun is counted."""
    clock = FakeClock(t=50.0)
    logic, _, _ = make_logic(prism(), clock=clock)
    rng = np.random.default_rng(0)
    times = 50.0 + 1e-3 * (np.arange(1, 3001) + rng.uniform(-0.3, 0.3, 3000))
    counts = run_ticks(logic, clock, times)
    assert counts == [math.floor((t - 50.0) * 1000.0) for t in times]
    assert logic.overruns == 0


def test_late_tick_catches_up_at_twice_the_rate_and_counts_overruns():
    clock = FakeClock(t=0.0)
    logic, _, _ = make_logic(prism(), clock=clock)
    times = [1e-3 * k + 1e-7 for k in (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 15, 16, 17, 18, 19)]
    counts = run_ticks(logic, clock, times)
    assert counts == [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 14, 16, 18, 19]
    assert logic.overruns == 2  # ends 3 and 2 steps behind; 1 step behind is within a tick
    assert logic.max_lag == pytest.approx(3e-3)
    assert logic.burst_ticks == 4 and logic.max_steps_per_tick == 2  # the four ticks of 2 steps catch up


def test_tick_durations_and_catch_up_bursts_in_the_statistics():
    """1000 ticks on time at 1 kHz, the k-th taking k us of the clock (its step costs half, the schedule's
    read at its end the other half): by nearest rank p50 = 500 us, p99 = 990 us, p99.9 = 999 us (each
    reported to within one histogram bin, 1.2 %, never below), the longest 1 ms exactly; one step a tick,
    no burst. Then the clock jumps 3 ms: the next two ticks run 2 steps each (the cap) to catch up, two
    bursts that end within one tick of the schedule, so no overrun."""
    clock = FakeClock(t=0.0)
    logic, _, _ = make_logic(prism(), clock=clock)
    for k in range(1, 1001):
        clock.t, clock.per_read = 1e-3 * k + 1e-7, 0.5e-6 * k
        assert logic.tick() == 1
    stats = logic.statistics()
    assert stats["ticks"] == 1000 and stats["max_steps_per_tick"] == 1 and stats["burst_ticks"] == 0
    bin_ratio = 10.0 ** (1.0 / 200.0)
    for key, true_ms in (("tick_p50_ms", 0.5), ("tick_p99_ms", 0.99), ("tick_p999_ms", 0.999)):
        assert true_ms <= stats[key] <= true_ms * bin_ratio + 5e-4, key  # + 5e-4: rounded to 1 us
    assert stats["tick_max_ms"] == 1.0
    clock.per_read = 0.0
    assert run_ticks(logic, clock, [1e-3 * k + 1e-7 for k in (1003, 1004, 1005)]) == [1002, 1004, 1005]
    stats = logic.statistics()
    assert (stats["ticks"], stats["max_steps_per_tick"], stats["burst_ticks"], stats["overruns"]) == (1003, 2, 2, 0)
    # three ticks of 0 ms joined them: the 502nd shortest of 1003 is the 499th of the first 1000
    assert 0.499 <= stats["tick_p50_ms"] <= 0.499 * bin_ratio + 5e-4 and stats["tick_max_ms"] == 1.0


def test_a_catch_up_tick_is_the_nodes_own_when_its_thread_used_over_a_period_of_cpu_time():
    """A catch-up tick counts as the node's own (own_burst_ticks) when the ticking thread used over a tick
    period of CPU time since the tick before began (or since the loop woke, if it slept after it), else as the
    machine's: at 1 kHz, ticks on time using 0.2 ms each; then a tick 3 ms late after 0.3 ms of CPU time (the
    thread was off its core: the machine's), one after a tick that used 1.5 ms (the node's own), and one after
    0.9 ms of idle work, a sleep, a wake-up 1.2 ms late and 0.2 ms of work (the machine's), all of two steps."""
    clock, cpu = FakeClock(t=0.0), FakeClock(t=5.0)
    logic, _, _ = make_logic(prism(), clock=clock, cpu_clock=cpu)
    for k, used in [(k, 0.2e-3) for k in range(1, 11)] + [(13, 0.3e-3), (14, 1.5e-3), (15, 0.2e-3)]:
        clock.t = 1e-3 * k + 1e-7
        cpu.t += used   # the CPU time of the thread since the tick before began
        logic.tick()
    cpu.t += 0.9e-3
    logic.woke(1.2e-3)
    cpu.t += 0.2e-3
    clock.t = 17.2e-3
    logic.tick()
    stats = logic.statistics()
    assert logic.sim.step_count == 17 and stats["max_steps_per_tick"] == 2 and stats["late_wakeups"] == 1
    assert (stats["burst_ticks"], stats["own_burst_ticks"]) == (3, 1)


def test_the_spinning_node_keeps_what_it_started_with_out_of_the_collector():
    """live.spin freezes the objects that exist when its ticks start (gc.freeze: a full collection over them
    was a tick of tens of ms) and unfreezes them however it ends, here at a SIGINT after three ticks."""
    import gc
    import logging
    import signal

    from tensegrity_sim.ros.live import spin
    from tensegrity_sim.ros.log import SignalLatch

    logic, _, _ = make_logic(prism())
    latch, frozen = SignalLatch(), []

    class Transport:
        def poll(self, logic, log):
            frozen.append(gc.get_freeze_count())
            if len(frozen) == 3:
                latch.signum = signal.SIGINT

        def wait(self, seconds):
            return False

    assert gc.get_freeze_count() == 0
    with pytest.raises(KeyboardInterrupt):
        spin(logic, Transport(), latch=latch, log=logging.getLogger("test"))
    assert len(frozen) == 3 and min(frozen) > 10_000   # the package, numpy, numba, pytest: all frozen
    assert gc.get_freeze_count() == 0


def test_the_spinning_node_wakes_on_the_schedule_so_a_late_wake_up_owes_no_step():
    """live.spin wakes each tick on the logic's grid (SimNodeLogic.next_tick), not on a cadence of its own:
    every wake-up here is late by 0.05 or 0.7 ms in turn, and each such tick runs exactly one step. (A cadence
    of its own, restarted after a long tick, sits at a random phase of the schedule: a 0.7 ms late wake-up then
    owes two steps and the next none.) A turn that runs past the next tick of the grid runs what is due at
    once, without sleeping: 1.3 ms long (the 50th), the one step it owes in a tick of its own (not a period
    late beside the next); 3.6 ms long (the 150th), the 3 steps it owes in ticks of at most 2 (the cap)."""
    import logging
    import signal

    from tensegrity_sim.ros.live import spin
    from tensegrity_sim.ros.log import SignalLatch

    clock = FakeClock(t=10.0)
    logic, _, _ = make_logic(prism(), clock=clock)
    latch, polls, steps, slept, late = SignalLatch(), [], [], [], [0.05e-3, 0.7e-3]

    class Transport:
        def poll(self, logic, log):
            polls.append(clock.t)
            steps.append(logic.sim.step_count)
            if len(polls) == 400:
                latch.signum = signal.SIGINT

        def wait(self, seconds):
            slept.append(len(polls))
            clock.t += seconds + late[len(polls) % 2]
            return False

    tick = logic.tick

    def long_tick():   # the 51st and 151st ticks run long (a costly publication, say)
        done = tick()
        clock.t += {51: 1.3e-3, 151: 3.6e-3}.get(len(polls), 0.0)
        return done

    logic.tick = long_tick

    with pytest.raises(KeyboardInterrupt):
        spin(logic, Transport(), latch=latch, log=logging.getLogger("test"))
    per_tick = np.diff(steps)   # the steps of tick k (poll k + 1), but the last
    assert sorted(set(range(1, 400)) - set(slept)) == [51, 151, 152]   # no sleep after the long ticks ...
    assert polls[51] - polls[50] == pytest.approx(1.3e-3, abs=1e-12)   # ... the next at the long tick's end
    assert polls[151] - polls[150] == pytest.approx(3.6e-3, abs=1e-12)
    assert per_tick[151] == 2 and set(np.delete(per_tick, 151)[2:]) == {1}
    assert logic.burst_ticks == 1 and logic.max_steps_per_tick == 2
    assert logic.late_wakeups == 0 and logic.max_wakeup_delay == pytest.approx(0.7e-3, abs=1e-12)
    assert logic.sim.step_count == math.floor((polls[-1] - polls[0]) * 1e3)   # on time at the end
    # the other wake-ups: a whole number of periods after the schedule's start, and a microsecond, plus their
    # lateness
    start = polls[1] - 1e-3 - 1e-6 - late[1]
    woken = np.array([k for k in range(1, len(polls)) if k not in (51, 151, 152)])
    phase = (np.array(polls)[woken] - start - 1e-6 - np.array([late[k % 2] for k in woken])) * 1e3
    assert np.allclose(phase, np.round(phase), atol=1e-9)


def test_a_wake_up_over_a_period_late_is_counted_and_owes_the_next_tick_a_step():
    """The loop counts the wake-ups that come over a tick period after the time it slept to (the OS's doing:
    late_wakeups, and the latest in max_wakeup_delay): here six, 1.6 ms late (the others 0.1 ms); each
    owes the tick after it one step more, so the ticks of two steps are exactly those."""
    import logging
    import signal

    from tensegrity_sim.ros.live import spin
    from tensegrity_sim.ros.log import SignalLatch

    clock = FakeClock(t=10.0)
    logic, _, _ = make_logic(prism(), clock=clock)
    latch, polls = SignalLatch(), []

    class Transport:
        def poll(self, logic, log):
            polls.append(clock.t)
            if len(polls) == 300:
                latch.signum = signal.SIGINT

        def wait(self, seconds):
            clock.t += seconds + (1.6e-3 if len(polls) % 50 == 25 else 0.1e-3)
            return False

    with pytest.raises(KeyboardInterrupt):
        spin(logic, Transport(), latch=latch, log=logging.getLogger("test"))
    stats = logic.statistics()
    assert stats["late_wakeups"] == 6 and stats["max_wakeup_delay_ms"] == pytest.approx(1.6, abs=1e-9)
    assert stats["burst_ticks"] == 6 and stats["max_steps_per_tick"] == 2


def test_an_input_that_comes_between_ticks_is_taken_at_once_and_the_step_after_it_computed_ahead():
    """live.spin waits for inputs between ticks (the transport's wait): one that comes there is taken at once,
    and the step after it computed ahead in the rest of the idle time, so the tick after it only hands that
    step out. The run is the one that takes each input as its tick starts (the inputs given by the ticks'
    polls instead), bit for bit: the inputs act on the same steps. Here a rest-length command comes 0.3 ms into
    every 10th tick's idle time."""
    import logging
    import signal

    from tensegrity_sim.ros.live import spin
    from tensegrity_sim.ros.log import SignalLatch

    def run(between_ticks: bool):
        clock = FakeClock(t=10.0)
        logic, _, _ = make_logic(prism(), clock=clock, publish_rate=100.0)
        names = logic.sim.scene.cable_names
        start = np.array(logic.sim.scene.cable_rest_lengths)
        latch, ticks, ahead_at_tick, taken_between = SignalLatch(), [0], [], []

        def command():
            k = ticks[0] // 10
            return rest_lengths_msg(names, list(start * (1.0 - 0.01 * (k % 3))))

        class Transport:
            waiting = False   # an input came in the idle time

            def poll(self, logic, log):
                if self.waiting:   # taken in the idle time
                    self.waiting = False
                    taken_between.append(logic.sim.step_count)
                    logic.receive("cable_rest_lengths", command())
                    return
                ticks[0] += 1
                ahead_at_tick.append(logic.sim.steps_ahead)
                if not between_ticks and ticks[0] % 10 == 1 and ticks[0] > 1:
                    logic.receive("cable_rest_lengths", command())
                if ticks[0] == 200:
                    latch.signum = signal.SIGINT

            def wait(self, seconds):
                once = taken_between[-1:] != [logic.sim.step_count]   # one input in a tick's idle time
                if between_ticks and ticks[0] % 10 == 0 < 200 - ticks[0] and once:
                    clock.t += 0.3e-3
                    self.waiting = True
                    return True
                clock.t += seconds + 1e-6
                return False

        with pytest.raises(KeyboardInterrupt):
            spin(logic, Transport(), latch=latch, log=logging.getLogger("test"))
        return logic, ahead_at_tick, taken_between

    logic, ahead_at_tick, taken = run(between_ticks=True)
    reference, _, _ = run(between_ticks=False)
    assert len(taken) == 19 and logic.received["cable_rest_lengths"] == 19
    # every tick after an input hands out a step computed in the idle time after it
    assert all(ahead_at_tick[k] >= 1 for k in range(10, 200, 10))
    assert logic.sim.step_count == reference.sim.step_count
    assert np.array_equal(logic.sim.positions, reference.sim.positions)
    assert np.array_equal(logic.sim.velocities, reference.sim.velocities)


def test_the_spinning_node_sends_markers_and_hands_its_log_the_waiting_messages_between_ticks(tmp_path):
    """live.spin sends a publication's markers and hands the log its waiting messages in the idle time after
    a tick (more than SPARE_FOR_IDLE of a period left), so no tick pays for them: after every quick tick
    nothing waits. Ticks that leave less (each takes 0.6 ms here) leave the markers to the next publication
    and the log's messages until the crash-safety bound (PENDING_SIZE bytes) hands them on in a tick, as
    without the idle time; the finished log holds every message either way, the last markers too (sent as
    SIGINT ends the loop)."""
    import logging
    import signal

    from tensegrity_sim.ros.live import SPARE_FOR_IDLE, spin
    from tensegrity_sim.ros.log import PENDING_SIZE, LogRecorder, SignalLatch
    from tensegrity_sim.ros.log_reader import LogReader

    clock = FakeClock(t=10.0)
    logic, _, _ = make_logic(prism(), clock=clock, publish_rate=1000.0)
    path = tmp_path / "spin.mcap"
    logic.recorder = LogRecorder(path, logic.channels(), logic.run_info())
    # the log's flush period on the fake clock too: on the wall clock a loaded machine's second would flush the
    # waiting messages in the middle of the ticks counted below (CI's run beside a benchmark did)
    writer = logic.recorder._writer
    writer._clock, writer._next_flush = clock, clock() + writer._flush_period
    latch, waiting, markers_waiting, published, tick_length = SignalLatch(), [], [], [], [0.0]
    assert 0.6e-3 > (1.0 - SPARE_FOR_IDLE) * 1e-3   # the long ticks leave less than SPARE_FOR_IDLE of a period

    class Transport:
        def poll(self, logic, log):
            waiting.append(logic.recorder._writer._pending_bytes)   # bytes waiting as the tick starts
            markers_waiting.append(logic._waiting is not None)
            published.append(logic.publications)
            if len(waiting) == 100:
                tick_length[0] = 0.6e-3
            if len(waiting) == 300:
                latch.signum = signal.SIGINT
            clock.t += tick_length[0]

        def wait(self, seconds):
            clock.t += seconds + 1e-7   # waking a little late
            return False

    with logic.recorder, pytest.raises(KeyboardInterrupt):
        spin(logic, Transport(), latch=latch, log=logging.getLogger("test"))
    quick, slow = np.array(waiting[2:100]), np.array(waiting[101:300])
    assert logic.publications >= 290 and not quick.any() and not any(markers_waiting[2:100])
    assert all(markers_waiting[102:300])
    # the markers of every quick tick's publication, none of a slow one's, and the last (as SIGINT ends the loop)
    assert logic.statistics()["idle_sends"] == published[99] + 1
    # with ~2 KiB a publication: one or two publications wait, and every second or third tick hands them on
    assert slow.max() < PENDING_SIZE and (slow > 0).sum() >= len(slow) / 2 and (slow == 0).sum() >= len(slow) / 4
    with LogReader(path) as reader:
        topics = [m.topic for m in reader.messages()]
    assert topics.count("/tensegrity_sim/node_poses") == topics.count("/tensegrity_sim/markers") == logic.publications


def test_the_spinning_node_publishes_diagnostics_in_its_idle_time_or_after_waiting_for_it():
    """live.spin publishes /diagnostics once a second in the loop's idle time: at once while the ticks leave
    more than SPARE_FOR_IDLE of a period (0.1 ms ticks here), DIAGNOSTICS_WAIT late when they leave none (0.6 ms
    ticks, from 1.5 s on): the one due at 2 s goes out at 2.1 s, the next (due a second after it) at 3.2 s."""
    import logging
    import signal

    from tensegrity_sim.ros.live import DIAGNOSTICS_WAIT, spin
    from tensegrity_sim.ros.log import SignalLatch

    clock = FakeClock(t=10.0)
    logic, _, _ = make_logic(prism(), clock=clock)
    latch, published, start = SignalLatch(), [], []
    publish = logic.publish_diagnostics

    def publish_diagnostics():
        published.append(clock.t)
        publish()

    logic.publish_diagnostics = publish_diagnostics

    class Transport:
        def poll(self, logic, log):
            if not start:
                start.append(clock.t)
            late = clock.t - start[0] > 1.5
            clock.t += 0.6e-3 if late else 0.1e-3
            if clock.t - start[0] > 3.5:
                latch.signum = signal.SIGINT

        def wait(self, seconds):
            clock.t += seconds
            return False

    with pytest.raises(KeyboardInterrupt):
        spin(logic, Transport(), latch=latch, log=logging.getLogger("test"))
    since = np.array(published) - start[0]
    assert len(since) == 3 and abs(since[0] - 1.0) < 1e-3
    assert abs(since[1] - (since[0] + 1.0 + DIAGNOSTICS_WAIT)) < 1e-3
    assert abs(since[2] - (since[1] + 1.0 + DIAGNOSTICS_WAIT)) < 1e-3


def test_the_stepping_thread_runs_on_fifo_while_the_node_is_on_a_schedule():
    """thread_priority puts the calling thread (only it) on SCHED_FIFO at that priority while the node runs on
    a schedule and back on the default policy otherwise; where the OS refuses (no privilege), one warning says
    so and the thread stays on the default policy."""
    import os
    import threading

    from tensegrity_sim.ros.live import StepperScheduling

    logger, seen = ListLogger(), []

    def stepper():
        scheduling = StepperScheduling(7, logger)
        for scheduled in (True, False, True):
            scheduling.follow(scheduled)
            seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))
        scheduling.restore()
        seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

    thread = threading.Thread(target=stepper)
    thread.start()
    thread.join()
    fifo, other = (os.SCHED_FIFO, 7), (os.SCHED_OTHER, 0)
    if logger.warnings:   # an unprivileged run
        assert seen == [other] * 4 and len(logger.warnings) == 1
        assert logger.warnings[0].startswith("thread_priority 7: the OS refused SCHED_FIFO")
    else:
        assert seen == [fifo, other, fifo, other]
    assert os.sched_getscheduler(0) == os.SCHED_OTHER   # the test's own thread kept its policy


def test_a_refused_thread_priority_warns_once_and_steps_on(monkeypatch):
    import errno
    import os

    from tensegrity_sim.ros.live import StepperScheduling

    calls = []

    def refuse(pid, policy, param):
        calls.append(policy)
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    logger = ListLogger()
    scheduling = StepperScheduling(50, logger)
    for scheduled in (True, True, False, True):
        scheduling.follow(scheduled)
    scheduling.restore()
    assert calls == [os.SCHED_FIFO] and logger.warnings == [
        "thread_priority 50: the OS refused SCHED_FIFO (Operation not permitted); stepping on the default scheduler "
        "(root, CAP_SYS_NICE or an rtprio limit of at least 50, e.g. ulimit -r 50, grants it)"]
    calls.clear()
    StepperScheduling(0, logger).follow(True)   # 0: the default scheduler, nothing asked of the OS
    assert calls == []


def test_the_steps_computed_ahead_end_at_the_next_publication():
    """The node's Simulator computes its steps ahead in chunks that end at the next publication (at most
    NODE_STEPS_AHEAD): a tick that publishes never computes the next steps too (with a marker array, the two
    were the node's slowest ticks), whatever the commands' cadence."""
    from conftest import record_advances
    from tensegrity_sim.ros.node_logic import NODE_STEPS_AHEAD

    logic, _, _ = make_logic(prism(), publish_rate=100.0)
    chunks = record_advances(logic.sim)
    names = logic._cable_names
    for k in range(300):
        if k % 7 == 3:
            assert logic.receive("cable_rest_lengths", rest_lengths_msg(names[:1], [0.9 + 0.001 * k])) is None
        logic._advance()
    every = logic.settings.publish_every
    assert every == 10 and logic.publications == 30 and len(chunks) >= 60
    for start, steps in chunks:   # steps start + 1 .. start + steps, none past the next publication
        assert 1 <= steps <= NODE_STEPS_AHEAD and start + steps <= every * (start // every + 1), (start, steps)
    assert max(steps for _, steps in chunks) == every   # ... and as many as that between two commands


@pytest.mark.parametrize("rate", [0.0, 0.5])
def test_steps_computed_ahead_in_idle_time_change_no_message(rate):
    """The live loop's idle look-ahead (SimNodeLogic.look_ahead, here after every tick: the steps up to the next
    publication computed before the ticks that take them) leaves every logged message bit for bit as without
    it: a rolling icosahedron commanded after every publication, its rest lengths resent unchanged or moved (at
    once, or at a limited rate: then nothing is computed early while they move), and a wrench. A command that
    moves them drops the steps computed ahead (the loop is rewound over the one taken): the tick after it
    computes its own step alone, the idle time the rest, up to the next publication."""
    from conftest import record_advances

    scene = ts.load_scene("icosahedron_ground")
    runs, early = [], []
    for idle in (False, True):
        logic, _, _ = make_logic(scene, publish_rate=100.0, max_rest_length_rate=rate)
        logic.recorder = BytesRecorder()
        logic.idle_outputs = idle
        chunks = record_advances(logic.sim)
        by = {"input": [], "tick": [], "idle": []}   # the chunks computed by each
        names = logic._cable_names

        def computing(what, call, *args):
            before = len(chunks)
            out = call(*args)
            by[what] += chunks[before:]
            return out

        for k in range(400):   # as the loop: the inputs, a tick (a step, and a publication if due), idle time
            if k % 10 == 1:   # the controller's answer to the publication: the same lengths every other time
                command = scene.cable_rest_lengths * (1.0 + 0.01 * ((k // 20) % 3))
                msg = rest_lengths_msg(names, command.tolist())
                assert computing("input", logic.receive, "cable_rest_lengths", msg) is None
            if k == 155:
                msg = wrench_msg(scene.node_names[0], [0.0, 1.0, 0.0])
                assert computing("input", logic.receive, "external_wrench", msg) is None
            assert computing("tick", logic._advance)
            logic.send_waiting()
            if idle:
                early.append(computing("idle", logic.look_ahead))
        runs.append(logic.recorder.records)
    assert runs[0] == runs[1] and len(runs[0]) > 200
    if rate == 0.0:   # steps wait after every tick
        assert all(early) and logic.statistics()["idle_look_aheads"] == len(by["idle"])
        assert {steps for _, steps in by["tick"]} == {1}   # a tick computes one step at most
        # the rewinds over the step taken after a publication; the wrench's over the five taken before it
        assert [steps for _, steps in by["input"] if steps != 1] == [5] and len(by["input"]) >= 9
        # as many as step() would compute (doubling from the last input), none past the next publication
        assert all(start + steps <= 10 * (start // 10 + 1) for start, steps in by["idle"]) and len(by["idle"]) > 39
    else:   # and not while the lengths move
        assert 0 < sum(early) < len(early) / 2


def test_real_time_factor_scales_the_schedule():
    clock = FakeClock(t=0.0)
    logic, _, _ = make_logic(prism(), clock=clock, real_time_factor=2.5)
    counts = run_ticks(logic, clock, [1e-3 * k + 1e-7 for k in range(1, 9)])
    assert counts == [math.floor(2.5 * k) for k in range(1, 9)]
    # 2 or 3 steps a tick is the nominal share, 2.5, rounded down or up: no burst
    assert logic.max_steps_per_tick == 3 and logic.burst_ticks == 0


def test_as_fast_as_possible_steps_for_one_tick_period():
    clock = FakeClock(t=0.0, per_read=0.25e-3)  # every clock read costs 0.25 ms
    logic, _, _ = make_logic(prism(), clock=clock, real_time_factor=0.0)
    assert logic.tick() == 4 and logic.tick() == 4
    # each tick took its four steps' clock reads, 1 ms; with no schedule there is no nominal share to exceed
    stats = logic.statistics()
    assert (stats["ticks"], stats["tick_max_ms"], stats["max_steps_per_tick"], stats["burst_ticks"]) == (2, 1.0, 4, 0)


def test_no_tick_runs_longer_than_its_wall_clock_bound():
    """Issue 13: an absurd real-time factor or a slow tick rate made tick() raise or run for seconds. Every
    step here costs 10 ms of the clock: a 1 Hz tick at the largest real-time factor is owed a million
    steps, and runs 0.1 s (TICK_WALL_LIMIT) of them, then reports the overrun."""
    clock = FakeClock(t=0.0, per_read=0.01)
    logic, _, _ = make_logic(prism(), clock=clock, real_time_factor=1e6, step_rate=1.0)
    clock.t = 1.0
    assert logic.tick() == 10 and logic.overruns == 1
    logic.update(real_time_factor=0.0)  # as fast as possible: one tick period, at most 0.1 s
    assert logic.tick() == 10


def test_pause_single_step_resume():
    clock = FakeClock(t=0.0)
    logic, sent, _ = make_logic(prism(), clock=clock)
    run_ticks(logic, clock, [1e-3 + 1e-7, 2e-3 + 1e-7])
    assert logic.pause() == (True, "paused at t = 0.002000 s")
    assert logic.pause() == (False, "already paused")
    assert run_ticks(logic, clock, [0.5, 0.6]) == [2, 2]
    n = len(sent)
    assert logic.single_step() == (True, "stepped to t = 0.003000 s")
    assert [k for k, _ in sent[n:]] == ["clock", "node_poses", "cable_states", "cable_impulses", "markers"]
    assert logic.resume() == (True, "resumed at t = 0.003000 s")
    assert logic.resume() == (False, "not paused")
    assert logic.single_step() == (False, "not paused: call pause first")
    # the paused time is not caught up: one step per millisecond from the resume on
    assert run_ticks(logic, clock, [0.6 + 1e-3 * k + 1e-7 for k in (1, 2, 3)]) == [4, 5, 6]


def test_reset_returns_to_the_scene_and_restarts_the_log():
    scene = prism()
    logic, sent, _ = make_logic(scene)
    logic.recorder = recorder = FakeRecorder()
    logic.receive("cable_rest_lengths", rest_lengths_msg(["c0"], [0.3]))
    logic.receive("external_wrench", wrench_msg("n1", [0.0, 0.0, 5.0]))
    for _ in range(17):
        logic.step()
    assert logic.reset() == (True, "reset to the scene's initial state; now logging to restart1.mcap")
    assert recorder.restarts == 1 and logic.sim.time == 0.0
    np.testing.assert_array_equal(logic.sim.positions, scene.positions)
    np.testing.assert_array_equal(logic.sim.rest_lengths, scene.cable_rest_lengths)
    assert not np.any(logic.sim.external_forces)
    for _ in range(10):
        logic.step()
    logic.publish()
    plain = ts.Simulator(scene, method="elastic", dt=1e-3).run(steps=10)
    np.testing.assert_array_equal(sent[-2][1].effort, sum(plain.impulses[k] for k in range(10)))
    assert stamp_of(sent[-2][1]) == 10_000_000


def test_runtime_parameters():
    """An accepted change goes out on /parameter_events, stamped with the simulation time, with the
    values as the node took them (an integer becomes the double it is); a refused one sends nothing."""
    logic, sent, _ = make_logic(prism())
    for _ in range(7):
        logic.step()
    assert logic.update(real_time_factor=2, marker_rate=5.0).real_time_factor == 2.0
    with pytest.raises(ValueError, match=r"^parameter 'dt' is read-only while running \(restart the node\)$"):
        logic.update(dt=0.1)
    with pytest.raises(ValueError, match=r"^parameter 'solver' is read-only while running \(restart the node\)$"):
        logic.update(solver="osqp")
    with pytest.raises(ValueError, match="^parameter 'publish_rate': must be >= 1e-06, got -1.0$"):
        logic.update(publish_rate=-1.0)
    assert logic.update() == logic.settings  # nothing changed: no event
    assert logic.settings.publish_rate == 100.0 and logic.settings.real_time_factor == 2.0
    (event,) = [m for k, m in sent if k == "parameter_events"]
    assert (event.stamp.sec, event.stamp.nanosec, event.node) == (0, 7_000_000, "/tensegrity_sim")
    assert [(p.name, p.value.type, p.value.double_value) for p in event.changed_parameters] == [
        ("real_time_factor", 3, 2.0), ("marker_rate", 3, 5.0)]
    assert M.parameter_changes(event) == {"real_time_factor": 2.0, "marker_rate": 5.0}
    assert isinstance(event.changed_parameters[0].value.double_value, float)


def test_diagnostics_warn_while_overrunning():
    clock = FakeClock(t=0.0)
    logic, sent, _ = make_logic(prism(), clock=clock)
    run_ticks(logic, clock, [1e-3 + 1e-7, 10e-3 + 1e-7])  # 2 steps at most: 7 behind, an overrun
    logic.publish_diagnostics()
    logic.update(real_time_factor=1.0)  # restarts the schedule: on time again
    run_ticks(logic, clock, [11e-3 + 1e-7])
    logic.publish_diagnostics()
    reports = [m.status[0] for k, m in sent if k == "diagnostics"]
    assert [r.level for r in reports] == [M.byte(1), M.byte(0)]
    values = {kv.key: kv.value for kv in reports[0].values}
    assert values["overruns"] == "1" and values["steps"] == "3" and values["max_lag_ms"] == "7.0"
    assert reports[0].message.startswith("1 overrun(s) since the last report")


def test_markers_go_out_at_marker_rate():
    """publish_rate 100 Hz, marker_rate 25 Hz: a MarkerArray with every 4th publication, the first one
    included, and the count restarts on reset."""
    logic, sent, _ = make_logic(ts.load_scene("prism3"), publish_rate=100.0, marker_rate=25.0)
    assert logic.settings.markers_every == 4
    for _ in range(120):
        logic.step()
        if logic.publication_due:
            logic.publish()
    keys = [k for k, _ in sent]
    assert keys.count("node_poses") == 12 and keys.count("markers") == 3
    stamps = [stamp_of(m.markers[0]) for k, m in sent if k == "markers"]
    assert stamps == [10_000_000, 50_000_000, 90_000_000]


def test_lockstep_waits_for_an_answer_to_each_publication():
    """lockstep: a publication (every 10 steps) holds the ticks until an applied input answers it; a refused one
    does not; the wait is not owed (the schedule restarts at the answer: one step a tick after it, no burst);
    the publication's clock, poses and cable states go out again every LOCKSTEP_REPEAT s meanwhile, to the
    transport only; and the run is the one that takes the same inputs right after each publication."""
    from tensegrity_sim.ros.node_logic import LOCKSTEP_REPEAT

    clock = FakeClock(t=0.0)
    recorder = FakeRecorder()
    logic, sent, _ = make_logic(prism(), clock=clock, lockstep=True)
    logic.recorder = recorder
    names = logic.sim.scene.cable_names
    counts = run_ticks(logic, clock, [1e-3 * k + 1e-7 for k in range(1, 16)])
    assert counts == list(range(1, 11)) + [10] * 5 and logic.awaiting
    assert logic.next_tick(clock.t) is None
    records = len(recorder.records)
    poses = [m for k, m in sent if k == "node_poses"]
    clock.t += LOCKSTEP_REPEAT
    logic.tick()
    again = [m for k, m in sent if k == "node_poses"]
    assert len(again) == 2 and stamp_of(again[1]) == stamp_of(poses[0]) == 10_000_000
    assert len(recorder.records) == records   # the log has it once
    assert logic.receive("cable_rest_lengths", rest_lengths_msg(["nope"], [0.3])) is not None
    assert run_ticks(logic, clock, [clock.t + 1e-3]) == [10] and logic.awaiting
    answer = rest_lengths_msg([names[0]], [0.3])
    assert logic.receive("cable_rest_lengths", answer) is None and not logic.awaiting
    t = clock.t
    counts = run_ticks(logic, clock, [t + 1e-3 * k + 1e-7 for k in range(1, 13)])
    assert counts == list(range(11, 21)) + [20, 20] and logic.burst_ticks == 0
    # the same inputs right after the tenth step, without lockstep
    twin, _, _ = make_logic(prism())
    for _ in range(10):
        twin.step()
    twin.receive("cable_rest_lengths", answer)
    for _ in range(10):
        twin.step()
    assert np.array_equal(twin.sim.positions, logic.sim.positions)
