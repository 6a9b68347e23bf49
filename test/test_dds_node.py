"""``tensegrity-sim serve --transport dds`` end to end: the simulator and a controller in separate
processes on their own domain over loopback; everything the controller receives is decoded by rosbags
(in the controller and here) and checked against closed forms, the node's own log and its replay."""
import contextlib
import importlib.util
import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

import tensegrity_sim as ts
from dds_child import NODE, NODE_OUTPUTS, random_domain, rest_lengths, spawn
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.messages import TYPESTORE
from tensegrity_sim.ros.node_logic import RUNTIME_PARAMETERS
from tensegrity_sim.ros.log import RUN_INFO
from tensegrity_sim.ros.replay import replay

CHILD = "test/dds_child.py"
PRISM = ts.load_scene("prism3")
MASS = sum(n.mass for n in PRISM.nodes)  # kg, free-floating, no gravity
DT = 1e-3


@contextlib.contextmanager
def serving(domain: int, *args: str):
    """``tensegrity-sim serve`` in its own process; stopped with SIGINT on the way out."""
    with spawn("-m", "tensegrity_sim.cli", "serve", *args, "--transport", "dds", "--domain-id", str(domain),
               timeout=30) as server:
        try:
            yield server
        finally:
            if server.poll() is None:
                server.send_signal(signal.SIGINT)


def control(domain: int, actions: list, timeout: float = 60) -> tuple[dict, dict]:
    """Run the controller child; return (decoded messages by output key, mark times)."""
    with spawn(CHILD, "control", str(domain), json.dumps(actions)) as controller:
        out, err = controller.communicate(timeout=timeout)
    assert controller.returncode == 0, err
    received, marks = {k: [] for k in NODE_OUTPUTS}, {}
    for line in out.splitlines():
        record = json.loads(line)
        if "mark" in record:
            marks[record["mark"]] = record["at"]
        else:
            data = bytes.fromhex(record["cdr"])
            received[record["key"]].append((TYPESTORE.deserialize_cdr(data, NODE_OUTPUTS[record["key"]][1]), data,
                                            record["received"]))
    return received, marks


def finish(server) -> tuple[str, str]:
    server.send_signal(signal.SIGINT)
    out, err = server.communicate(timeout=30)
    assert server.returncode == 0, err
    return out, err


def stamp(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def logged(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """Every message of an MCAP log by topic: (log time ns, CDR bytes)."""
    out = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append((message.log_time, message.data))
    return out


def summary(text: str) -> dict[str, str]:
    return dict(line.split(None, 1) for line in text.splitlines() if line and not line.startswith("["))


def test_a_controller_process_drives_the_simulator_process(tmp_path):
    domain, log = random_domain(), tmp_path / "run.mcap"
    c0_rest = PRISM.cables[0].rest_length
    force = np.array([0.0, 0.0, 2.0])  # N on n3
    actions = [{"sleep": 0.3}, {"wrench": ["n3", force.tolist()]}, {"sleep": 0.3},
               {"rest": [["c0"], [0.9 * c0_rest]]}, {"sleep": 0.5}]
    with serving(domain, "prism3", "--log-path", str(log)) as server:
        received, _ = control(domain, actions)
        out, err = finish(server)
    stats = summary(out)
    assert stats["refused_rest_lengths"] == "0" and stats["refused_wrenches"] == "0"
    assert stats["undecodable_samples"] == "0"

    # The log: the node took both inputs, as sent, and a replay re-simulates every logged state from
    # them bit for bit. So the states below are the simulator's with the inputs applied.
    log_messages = logged(log)
    (t_wrench, wrench_cdr), = log_messages[f"{NODE}/external_wrench"]
    (t_rest, rest_cdr), = log_messages[f"{NODE}/cable_rest_lengths"]
    wrench = TYPESTORE.deserialize_cdr(wrench_cdr, "geometry_msgs/msg/WrenchStamped")
    assert wrench.header.frame_id == "n3" and [wrench.wrench.force.x, wrench.wrench.force.y,
                                              wrench.wrench.force.z] == force.tolist()
    rest = TYPESTORE.deserialize_cdr(rest_cdr, "sensor_msgs/msg/JointState")
    assert list(rest.name) == ["c0"] and rest.position.tolist() == [0.9 * c0_rest]
    assert replay(log).ok

    # What crossed DDS is what the node published and logged, byte for byte, at the same times.
    for key in ("clock", "node_poses", "cable_states", "cable_impulses"):
        by_time = dict(log_messages[NODE_OUTPUTS[key][0]])
        for m, data, _ in received[key]:
            when = m.clock if key == "clock" else m.header.stamp
            assert by_time[when.sec * 10**9 + when.nanosec] == data, key

    # The documented content. Every topic: 100 Hz of sim time, none lost (the readers matched at
    # slightly different moments, so the topics are compared where they overlap).
    series = {}
    for key in ("node_poses", "cable_states", "cable_impulses"):
        series[key] = {round(stamp(m), 9): m for m, _, _ in received[key]}
        assert np.allclose(np.diff(sorted(series[key])), 0.01, rtol=0, atol=1e-9), key
    stamps = np.array(sorted(set.intersection(*(set(v) for v in series.values()))))
    assert len(stamps) >= len(received["node_poses"]) - 2
    poses, states, impulses = ([series[key][s] for s in stamps] for key in series)
    # Poses: scene order, frame world, identity orientation.
    for m in poses:
        assert m.header.frame_id == "world" and len(m.poses) == len(PRISM.nodes)
        assert all((p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w) == (0, 0, 0, 1)
                   for p in m.poses)
    x = np.array([[[p.position.x, p.position.y, p.position.z] for p in m.poses] for m in poses])
    # The external force on the free-floating prism: the centre of mass (equal masses) accelerates at
    # F / M from the step the force took effect, exactly under velocity Verlet (a constant force).
    com = x.mean(axis=1)
    t0 = t_wrench * 1e-9
    expected = PRISM.positions.mean(axis=0) + 0.5 * np.outer(np.clip(stamps - t0, 0, None) ** 2, force / MASS)
    assert np.allclose(com, expected, rtol=0, atol=1e-9)
    assert com[-1, 2] - com[0, 2] > 0.01  # it did move

    # Cable states: lengths are the distances between the published poses; tensions answer the command.
    ends = np.array([[PRISM.node_names.index(a) for a in c.nodes] for c in PRISM.cables])
    for m, xk in zip(states, x):
        assert list(m.name) == list(PRISM.cable_names)
        assert np.allclose(m.position, np.linalg.norm(xk[ends[:, 1]] - xk[ends[:, 0]], axis=1), rtol=0, atol=1e-12)
    # Tensions follow k max(0, l - L) with the commanded rest length L from the step after it arrived
    # (a published tension is the last step's mean, so it lags the published length by half a step).
    k0 = PRISM.cables[0].stiffness
    tension_c0 = np.array([m.effort[0] for m in states])
    length_c0 = np.array([m.position[0] for m in states])
    before = stamps <= t_rest * 1e-9
    assert np.allclose(tension_c0[before], k0 * (length_c0[before] - c0_rest), rtol=1e-3, atol=0)
    first_after = int(np.argmax(~before))
    assert tension_c0[first_after] == pytest.approx(k0 * (length_c0[first_after] - 0.9 * c0_rest), rel=0.05)
    assert tension_c0[first_after] > tension_c0[before].max() + 50

    # Impulses: each message the sum over its 10 steps: while the prism still rests in its initial
    # equilibrium, 10 dt times the (constant) tension.
    at_rest = [k for k, s in enumerate(stamps) if s <= t0]
    assert at_rest, "the controller should see the prism at rest before it pushes"
    for k in at_rest:
        assert np.allclose(impulses[k].effort, 10 * DT * np.asarray(states[k].effort), rtol=1e-9, atol=0)
    assert all(np.all(m.effort >= 0) for m in impulses)
    clock = {round(m.clock.sec + 1e-9 * m.clock.nanosec, 9) for m, _, _ in received["clock"]}
    assert set(stamps) <= clock  # every publication has its /clock


def test_bad_messages_from_the_network_are_refused_and_the_node_keeps_going(tmp_path):
    domain, log = random_domain(), tmp_path / "run.mcap"
    c0 = PRISM.cables[0].rest_length
    garbled = bytearray(M.serialize(rest_lengths(["c0"], [0.5]), "sensor_msgs/msg/JointState"))
    at = garbled.index(b"c0")
    garbled[at:at + 2] = b"\xff\xfe"  # valid CDR, invalid UTF-8: DDS passes it, a decoder must refuse it
    actions = [
        {"rest": [["nope"], [0.5]]},                 # unknown cable
        {"rest": [["c0"], [float("nan")]]},          # not finite
        {"rest": [["c0"], [-0.5]]},                  # not > 0
        {"rest": [["c0", "c1"], [0.5]]},             # lengths disagree
        {"rest": [["c0", "c0"], [0.5, 0.6]]},        # named twice
        {"wrench": ["n9", [1.0, 0.0, 0.0]]},         # unknown node
        {"wrench": ["n3", [float("inf"), 0.0, 0.0]]},
        {"wrench": ["n3", [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]},  # torque on a point
        {"cdr": ["cable_rest_lengths", bytes(garbled).hex()]},
        {"wrong_type": "cable_rest_lengths"},        # another type on the topic: DDS does not match it
        {"command": "explode"}, {"command": "set dt 0.5"}, {"command": "set publish_rate -3"},
        {"command": "set gravity 1"}, {"command": "set publish_rate fast"},
        {"sleep": 0.3}, {"mark": "good"},
        {"rest": [["c0"], [0.9 * c0]]},              # and good ones still work
        {"sleep": 0.3}, {"command": "set publish_rate 50"}, {"mark": "slower"}, {"sleep": 0.3},
    ]
    with serving(domain, "prism3", "--log-path", str(log)) as server:
        received, marks = control(domain, actions)
        assert server.poll() is None  # alive
        out, err = finish(server)
    stats = summary(out)
    assert (stats["refused_rest_lengths"], stats["refused_wrenches"], stats["undecodable_samples"]) == ("5", "3", "1")
    for reason in ["unknown cable 'nope'", "position[0] ('c0'): a rest length must be finite and > 0 m, got nan",
                   "got -0.5", "position has 1 values for 2 names", "cable 'c0' is named more than once",
                   "header.frame_id 'n9' is not a node", "wrench.force must be finite",
                   "wrench.torque must be zero",
                   "/tensegrity_sim/cable_rest_lengths: refused: undecodable sensor_msgs/msg/JointState"]:
        assert reason in err, reason
    results = [m.data for m, _, _ in received["command_result"]]
    assert results[0].startswith("explode: failed: unknown command")
    assert results[1] == "set dt 0.5: failed: parameter 'dt' is read-only while running (restart the node)"
    assert results[2].startswith("set publish_rate -3: failed: parameter 'publish_rate': must be >= 1e-06")
    assert results[3] == "set gravity 1: failed: unknown parameter 'gravity' (runtime parameters: " \
                         + ", ".join(RUNTIME_PARAMETERS) + ")"
    assert results[4] == "set publish_rate fast: failed: parameter 'publish_rate': not a number: 'fast'"
    assert results[5] == "set publish_rate 50: ok: publish_rate = 50.0"
    slower = [stamp(m) for m, _, t in received["cable_states"] if t > marks["slower"] + 0.05]
    assert len(slower) > 3 and np.allclose(np.diff(slower), 0.02, rtol=0, atol=1e-9)
    # Nothing bad changed anything (the prism stayed in its equilibrium); the good command after them did.
    before = [m.effort[0] for m, _, t in received["cable_states"] if t < marks["good"]]
    after = [m.effort[0] for m, _, t in received["cable_states"] if marks["good"] < t < marks["slower"]]
    assert np.allclose(before, before[0], rtol=1e-9, atol=0)
    assert max(after) > before[0] + 50
    # The accepted change went out on /parameter_events, the bytes the log holds; the log, refusals and
    # parameter change included, replays bit for bit.
    ((event, data, _),) = received["parameter_events"]
    assert event.node == NODE and [(p.name, p.value.type, p.value.double_value)
                                   for p in event.changed_parameters] == [("publish_rate", 3, 50.0)]
    assert logged(log)["/parameter_events"] == [(event.stamp.sec * 10**9 + event.stamp.nanosec, data)]
    assert replay(log).ok


def test_services_are_commands_on_a_topic(tmp_path):
    domain, log = random_domain(), tmp_path / "run.mcap"
    actions = [{"sleep": 0.2}, {"command": "pause"}, {"sleep": 0.3}, {"mark": "paused"},
               {"command": "step"}, {"command": "step"}, {"sleep": 0.3},
               {"command": "resume"}, {"sleep": 0.3}, {"command": "reset"}, {"sleep": 0.2}]
    with serving(domain, "prism3", "--log-path", str(log)) as server:
        received, marks = control(domain, actions)
        out, _ = finish(server)
    results = [m.data for m, _, _ in received["command_result"]]
    assert [r.split(":")[0:2] for r in results] == [["pause", " ok"], ["step", " ok"], ["step", " ok"],
                                                     ["resume", " ok"], ["reset", " ok"]]
    clock = [(m.clock.sec + 1e-9 * m.clock.nanosec, t) for m, _, t in received["clock"]]
    paused_at = float(results[0].split("paused at t = ")[1].split()[0])
    # no publication while paused (a stamp rebuilt from sec + 1e-9 nanosec may exceed the printed time
    # it equals by round-off: the same 1 ns tolerance as below)
    late = [s for s, t in clock if t < marks["paused"] and s > paused_at + 1e-9]
    assert not late, (paused_at, late)
    # Each single step publishes at once, one dt later; then every 10 ms again; then time restarts at 0.
    after = [s for s, t in clock if t > marks["paused"]]
    assert np.allclose(after[:2], [paused_at + DT, paused_at + 2 * DT], rtol=0, atol=1e-9)
    resumed = np.array(after[2:])
    restart = int(np.flatnonzero(np.diff(resumed) < 0)[0]) + 1
    assert np.allclose(np.diff(resumed[1:restart]), 0.01, rtol=0, atol=1e-9)
    assert resumed[restart] < 0.05
    # The reset started a second log file; both are finished and replay.
    files = [line.split(None, 1)[1] for line in out.splitlines() if line.startswith("log ")]
    assert len(files) == 2 and all(replay(f).ok for f in files)


def test_start_up_and_shut_down_are_clean(tmp_path):
    domain, log = random_domain(), tmp_path / "run.mcap"
    # SIGTERM stops a server as it stops the rclpy node: status 128 + 15, summary printed, log finished.
    with serving(domain, "prism3", "--log-path", str(log)) as server:
        control(domain, [{"sleep": 0.2}])
        server.send_signal(signal.SIGTERM)
        out, err = server.communicate(timeout=30)
    assert server.returncode == 143, err
    assert f"log                         {log}" in out
    assert replay(log).ok
    with open(log, "rb") as f:
        reader = make_reader(f)
        counts = reader.get_summary().statistics.channel_message_counts
    assert sum(counts.values()) > 0
    # A bad interface or domain is refused at start with the reason, before anything runs.
    refusals = [(("--transport", "dds", "--interface", "nonexistent0"), "no network interface named 'nonexistent0'"),
                (("--transport", "dds", "--domain-id", "999"), "domain_id must be a whole number in [0, 232], got 999"),
                (("--transport", "dds", "--publish-rate", "0"), "parameter 'publish_rate': must be >= 1e-06, got 0.0"),
                (("--transport", "dds", "--solver", "cplex"), "parameter 'solver': must be one of daqp, osqp, nnls, "
                                                              "sparse, auto or empty, got 'cplex'")]
    if importlib.util.find_spec("rclpy") is None:
        refusals.append((("--transport", "rclpy"), "--transport rclpy: rclpy does not import here"))
    for args, reason in refusals:
        with spawn("-m", "tensegrity_sim.cli", "serve", "--log-path", "", *args) as bad:
            out, err = bad.communicate(timeout=30)
        assert bad.returncode == 2 and reason in err
    # Nothing of this test is left running.
    mine = [pid for pid in os.listdir("/proc") if pid.isdigit() and _cmdline(pid).count(str(domain))
            and "--domain-id" in _cmdline(pid)]
    assert mine == []


@pytest.mark.filterwarnings("ignore::tensegrity_sim.LengthOffsetWarning")  # the icosahedron is prestressed
def test_serve_builds_the_simulator_from_its_parameters_and_the_scene(tmp_path):
    """--method and --solver reach the simulator, and so do the scene's contact kinds: the log embeds
    what ran (the method's settings, the node's, the scene as run), and replays."""
    d = ts.load_scene("icosahedron").to_dict()
    d["contact"] = {"kinds": ["strut_strut", "strut_cable"]}
    scene, log, domain = tmp_path / "ico.yaml", tmp_path / "run.mcap", random_domain()
    scene.write_text(ts.Scene.from_dict(d).to_yaml())
    with serving(domain, str(scene), "--method", "inextensible", "--solver", "nnls", "--log-path", str(log)) as server:
        control(domain, [{"sleep": 0.3}])
        finish(server)
    with open(log, "rb") as f:
        info = next(r.metadata for r in make_reader(f).iter_metadata() if r.name == RUN_INFO)
    assert info["method"] == "inextensible" and json.loads(info["method_settings"])["solver"] == "nnls"
    assert json.loads(info["node_settings"])["solver"] == "nnls"
    assert ts.Scene.from_dict(yaml.safe_load(info["scene_yaml"])).contact_kinds == ("strut_strut", "strut_cable")
    result = replay(log)
    assert result.ok and result.steps > 50


def _cmdline(pid: str) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def test_the_example_controller_makes_cables_go_slack_and_snap():
    domain = random_domain()
    with serving(domain, "prism3", "--log-path", "") as server:
        with spawn("examples/cable_controller.py", "--domain-id", str(domain), "--cables", "c0,c1,c2",
                   "--period", "0.6", "--duration", "1.5", "--push", "n3", "0", "0", "5") as example:
            out, err = example.communicate(timeout=60)
        finish(server)
    assert example.returncode == 0, err
    assert "pushing n3 with [0.0, 0.0, 5.0] N" in out
    slack = {line.split()[4] for line in out.splitlines() if line.endswith("goes slack")}
    snaps = [line.split() for line in out.splitlines() if "snaps taut" in line]
    assert slack == {"c0", "c1", "c2"}  # let out by 15 %, every driven cable goes slack
    assert {s[4] for s in snaps} <= slack and snaps  # ... and snaps taut again when reeled in
    for s in snaps:  # "t = T s  cX snaps taut: F N, impulse J N s since the previous state"
        assert float(s[7]) > 0 and float(s[10]) > 0


CROSSING = {  # strut sA flies at 0.5 m/s through the fixed strut sB: contact from 0.12 s to 0.28 s
    "name": "crossing",
    "nodes": [{"name": "a0", "position": [-0.1, 0.0, -0.5], "mass": 0.5, "velocity": [0.5, 0.0, 0.0]},
              {"name": "a1", "position": [-0.1, 0.0, 0.5], "mass": 0.5, "velocity": [0.5, 0.0, 0.0]},
              {"name": "b0", "position": [0.0, -0.5, 0.0], "fixed": True},
              {"name": "b1", "position": [0.0, 0.5, 0.0], "fixed": True}],
    "struts": [{"name": "sA", "nodes": ["a0", "a1"], "stiffness": 1.0e4, "radius": 0.02},
               {"name": "sB", "nodes": ["b0", "b1"], "stiffness": 1.0e4, "radius": 0.02}],
}


def test_contact_events_reach_the_controller(tmp_path):
    """Contacts as msg_docs/contacts.md documents them, parsed here from the rosbags-decoded messages,
    against the closed form: sA's axis crosses sB's at x = -0.1 + 0.5 t, so the capsules (radii 0.02)
    touch from x = -0.04 to x = +0.04, t = 0.12 s to 0.28 s, at the origin, normal +-x."""
    scene = tmp_path / "crossing.yaml"
    scene.write_text(ts.Scene.from_dict(CROSSING).to_yaml())
    domain = random_domain()
    # By the mark the first run's contacts are over (they end at t = 0.28 s; the server's start, loading the
    # compiled detector's kernels, can take half a second of it); the reset replays them from t = 0.
    actions = [{"sleep": 1.5}, {"mark": "reset"}, {"command": "reset"}, {"sleep": 0.6}]
    with serving(domain, str(scene), "--log-path", "") as server:
        received, marks = control(domain, actions)
        finish(server)
    events = []
    for m, _, t in received["contacts"]:
        if t < marks["reset"]:
            continue
        for status in m.status:
            values = {kv.key: kv.value for kv in status.values}
            assert status.name == f"contact {values['member_a']} {values['member_b']}"
            assert status.message == values["kind"]
            events.append((stamp(m), values))
    assert [(v["kind"], v["member_a"], v["member_b"]) for _, v in events] == [("begin", "sA", "sB"),
                                                                               ("end", "sA", "sB")]
    for (published, v), t, side in zip(events, (0.12, 0.28), (-1.0, 1.0)):
        assert float(v["time"]) == pytest.approx(t, abs=1e-9)
        assert published - 0.01 < float(v["time"]) <= published + 1e-12  # reported in its publication
        assert np.allclose(json.loads(v["point_a"]), [0.04 * side, 0.0, 0.0], atol=1e-9)
        assert np.allclose(json.loads(v["point_b"]), [0.0, 0.0, 0.0], atol=1e-9)
        assert np.allclose(json.loads(v["normal"]), [-side, 0.0, 0.0], atol=1e-9)
        assert abs(float(v["distance"])) < 1e-9
