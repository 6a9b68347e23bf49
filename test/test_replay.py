"""Replay: a log alone re-runs its simulation bit for bit, and any alteration is caught and located."""
import json

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.writer import Writer

import tensegrity_sim as ts
from tensegrity_sim.cli import main, simulate
from tensegrity_sim.commands import parse_commands
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.log import RUN_INFO, LogRecorder, LogWriter
from tensegrity_sim.ros.node_logic import NodeSettings, SimNodeLogic
from tensegrity_sim.ros.replay import LogError, log_info, replay
from ros_helpers import FakeClock, prism, prism_dict, rest_lengths_msg, rewrite, wrench_msg

COMMANDS = [
    {"time": 0.0, "rest_lengths": {"c0": 0.55, "c4": 0.6}},
    {"time": 0.05, "rest_lengths": {"c0": 0.45}, "forces": {"n3": [0.0, 0.0, 20.0]}},
    {"time": 0.12, "forces": {"n3": [0.0, 0.0, 0.0], "n1": [2.0, 0.0, 0.0]}},
]


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    """A 0.3 s run of the prism with rest-length and force commands, logged by ``tensegrity-sim run``."""
    folder = tmp_path_factory.mktemp("replay")
    scene_file, commands, log = folder / "prism.yaml", folder / "commands.yaml", folder / "run.mcap"
    scene_file.write_text(yaml.safe_dump(prism_dict(gravity=9.81)))
    commands.write_text(yaml.safe_dump(COMMANDS))
    assert main(["run", str(scene_file), "--duration", "0.3", "--method", "elastic", "--commands", str(commands),
                 "--log", str(log), "--quiet"]) == 0
    return log


def plain_contacts():
    """The contact events of the logged run, from a plain Simulator with the same commands, per step."""
    scene = ts.Scene.from_dict(prism_dict(gravity=9.81))
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    events = []
    simulate(sim, 300, parse_commands(COMMANDS, scene), on_step=lambda r: events.append(r.contacts))
    return events


def test_replay_reproduces_a_run_with_commands(logged, capsys):
    report = replay(logged)
    assert report.ok and report.steps == 300 and report.notes == []
    # a contacts message at each publication (every 10 steps) whose steps had contact events
    steps = plain_contacts()
    with_contacts = sum(any(steps[k:k + 10]) for k in range(0, 300, 10))
    assert with_contacts > 0  # the prism collapses through itself
    assert report.compared == {**{t: 30 for t in ("/clock", "/tensegrity_sim/node_poses", "/tensegrity_sim/cable_states",
                                                  "/tensegrity_sim/cable_impulses")},
                               "/tensegrity_sim/markers": 3,  # marker_rate 10 Hz: publications 0, 10, 20
                               "/tensegrity_sim/contacts": with_contacts}
    assert report.inputs["/tensegrity_sim/external_wrench"] == 3
    assert report.inputs["/tensegrity_sim/cable_rest_lengths"] > 50  # a ramp: a message every step
    assert main(["replay", str(logged)]) == 0
    assert "result           every logged state reproduced bit for bit" in capsys.readouterr().out


def test_copy_without_changes_replays(logged, tmp_path):
    """A copy decoded and re-encoded by rosbags is the log byte for byte, every message (so what the
    node's templates wrote is what rosbags writes), and replays."""
    rewrite(logged, tmp_path / "copy.mcap")
    contents = []
    for path in (logged, tmp_path / "copy.mcap"):
        with open(path, "rb") as f:
            messages = make_reader(f).iter_messages(log_time_order=False)
            contents.append([(c.topic, m.log_time, m.data) for _, c, m in messages])
    assert len(contents[0]) > 150 and contents[0] == contents[1]
    assert replay(tmp_path / "copy.mcap").ok


def test_altered_state_is_caught_at_its_step(logged, tmp_path, capsys):
    def alter(topic, index, msg):
        if topic == "/tensegrity_sim/node_poses" and index == 6:  # the 7th publication: step 70
            msg.poses[2].position.z = float(np.nextafter(msg.poses[2].position.z, np.inf))  # one ulp
        return msg

    rewrite(logged, tmp_path / "altered.mcap", alter)
    report = replay(tmp_path / "altered.mcap")
    m = report.mismatch
    assert (m.step, m.time_ns, m.topic, m.field) == (70, 70_000_000, "/tensegrity_sim/node_poses", "poses[2].position.z")
    assert float(m.logged) == np.nextafter(float(m.replayed), np.inf)
    assert main(["replay", str(tmp_path / "altered.mcap")]) == 1
    assert "MISMATCH at step 70 (t = 0.070000000 s), /tensegrity_sim/node_poses: poses[2].position.z" in \
        capsys.readouterr().out


def test_altered_input_is_caught_at_the_next_publication(logged, tmp_path):
    def alter(topic, index, msg):
        if topic == "/tensegrity_sim/cable_rest_lengths" and index == 30:  # the ramp at t = 30 ms
            assert message_time(msg) == 30_000_000
            msg.position = M.float64s(np.asarray(msg.position) * 0.5)  # short enough to be taut: it pulls
        return msg

    rewrite(logged, tmp_path / "input.mcap", alter)
    m = replay(tmp_path / "input.mcap").mismatch
    assert (m.step, m.topic) == (40, "/tensegrity_sim/node_poses") and m.field.startswith("poses[")


def message_time(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_dropped_message_is_caught(logged, tmp_path):
    rewrite(logged, tmp_path / "dropped.mcap",
            lambda topic, index, msg: None if topic == "/tensegrity_sim/markers" and index == 1 else msg)
    m = replay(tmp_path / "dropped.mcap").mismatch
    assert (m.step, m.topic, m.field, m.logged, m.replayed) == (
        110, "/tensegrity_sim/markers", "message", "none", "a message")


def test_summed_impulses_are_checked(logged, tmp_path):
    def alter(topic, index, msg):
        if topic == "/tensegrity_sim/cable_impulses" and index == 20:
            msg.effort = M.float64s(np.asarray(msg.effort) * (1 + 1e-15))
        return msg

    rewrite(logged, tmp_path / "impulses.mcap", alter)
    m = replay(tmp_path / "impulses.mcap").mismatch
    assert (m.step, m.topic) == (210, "/tensegrity_sim/cable_impulses") and m.field.startswith("effort[")


def test_settings_that_cannot_be_reproduced_are_refused(logged, tmp_path):
    rewrite(logged, tmp_path / "settings.mcap", run_info={"method_settings": json.dumps({"dt": 0.001,
                                                                                          "method": "exotic"})})
    with pytest.raises(LogError, match=r"method settings .*exotic.* cannot be reproduced"):
        replay(tmp_path / "settings.mcap")


def test_not_a_log(tmp_path):
    (tmp_path / "x.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(LogError, match=r"x\.mcap: not an MCAP file \(it does not start with the MCAP magic\)$"):
        replay(tmp_path / "x.mcap")
    with pytest.raises(LogError, match="cannot read"):
        replay(tmp_path / "missing.mcap")
    with open(tmp_path / "other.mcap", "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2")
        writer.finish()
    with pytest.raises(LogError, match="no 'tensegrity_sim' metadata: not a tensegrity_sim log"):
        replay(tmp_path / "other.mcap")
    with LogWriter(tmp_path / "partial.mcap", [], {"method": "elastic"}):
        pass
    with pytest.raises(LogError, match="'tensegrity_sim' metadata lacks dt, method_reason, method_settings, "
                                       "node_settings, package_version, scene_name, scene_yaml, topics"):
        log_info(tmp_path / "partial.mcap")
    assert main(["replay", str(tmp_path / "missing.mcap")]) == 2


def test_node_run_with_pauses_single_steps_refusals_and_rate_limit_replays(tmp_path):
    """What the real-time node does (ticks on a clock, pause, single steps while paused, resume, refused
    and rate-limited inputs, a runtime publish-rate change) is reproduced from its log."""
    clock = FakeClock(t=0.0)
    sim = ts.Simulator(prism(gravity=9.81), method="elastic", dt=1e-3)
    logic = SimNodeLogic(sim, NodeSettings(scene="prism", max_rest_length_rate=0.5, marker_rate=100.0), clock=clock,
                         logger=type("Quiet", (), {"warning": lambda self, text: None})())
    path = tmp_path / "node.mcap"
    with LogRecorder(path, logic.channels(), logic.run_info()) as recorder:
        logic.recorder = recorder
        rng = np.random.default_rng(3)
        for k in range(1, 400):
            clock.t = 1e-3 * k + rng.uniform(0, 0.9e-3)
            logic.tick()
            if k == 40:
                logic.receive("cable_rest_lengths", rest_lengths_msg(["c2", "c5"], [0.5, 0.7]))
            if k == 60:
                logic.receive("cable_rest_lengths", rest_lengths_msg(["c2", "zz"], [0.1, 0.7]))  # refused
                logic.receive("external_wrench", wrench_msg("n5", [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]))  # refused
                logic.receive("external_wrench", wrench_msg("n5", [0.0, 1.0, 3.0]))
            if k == 100:
                logic.pause()
            if k in (110, 115, 116):
                logic.single_step()
            if k == 150:
                logic.resume()
                logic.update(publish_rate=40.0)
            if k % 97 == 0:
                logic.publish_diagnostics()
        logic.publish()  # end on a publication: the replay steps up to the last logged message
    report = replay(path)
    assert report.ok, report.mismatch
    assert report.steps == sim.step_count and report.notes[0].startswith("2 input message(s) refused again")
    assert report.compared["/tensegrity_sim/node_poses"] == logic.publications


def test_info_reports_counts_and_slack_statistics(logged, capsys):
    """The slack and snap statistics of ``info`` against a plain Simulator run with the same commands."""
    scene = ts.Scene.from_dict(prism_dict(gravity=9.81))
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    tensions = []
    simulate(sim, 300, parse_commands(COMMANDS, scene), on_step=lambda r: tensions.append(r.tensions))
    published = np.array(tensions)[9::10]
    slack = published == 0.0
    snaps = int(np.count_nonzero(slack[:-1] & ~slack[1:]))
    assert 0 < snaps and slack.any()
    lines = log_info(logged)
    assert f"snaps            {snaps} slack-to-taut changes" in lines
    share = ", ".join(f"{n} {100.0 * c / 30:.0f}%" for n, c in zip(scene.cable_names, slack.sum(axis=0)) if c)
    assert f"slack            {share} (of 30 cable_states messages)" in lines
    k = np.unravel_index(np.argmax(published), published.shape)
    assert f"max tension      {published[k]:.6g} N ({scene.cable_names[k[1]]} at t = {(k[0] + 1) * 0.01:.6f} s)" \
        in lines
    assert main(["info", str(logged)]) == 0
    out = capsys.readouterr().out
    assert "/tensegrity_sim/node_poses" in out and "geometry_msgs/msg/PoseArray" in out
    assert "sim time         0.000000 s to 0.300000 s (300 steps)" in out
    events = [e for step in plain_contacts() for e in step]
    begins = sum(e.kind == "begin" for e in events)
    assert f"contacts         {begins} begin, {len(events) - begins} end, {len({e.members for e in events})} " \
           f"member pairs, smallest distance {min(e.distance for e in events):.6g} m" in out


# --------------------------------------------------------------------------- runtime parameter changes
def node_run_with_parameter_changes(path, change=50.0):
    """A ticked node (publish 100 Hz, markers 10 Hz) whose publish_rate becomes ``change`` at 150 ms and
    real_time_factor 2 at 250 ms; returns the logic. Markers go out with every round(publish_rate / 10)-th
    publication, so the change moves them."""
    clock = FakeClock(t=0.0)
    sim = ts.Simulator(prism(gravity=9.81), method="elastic", dt=1e-3)
    logic = SimNodeLogic(sim, NodeSettings(scene="prism"), clock=clock)
    with LogRecorder(path, logic.channels(), logic.run_info()) as recorder:
        logic.recorder = recorder
        for k in range(1, 451):
            clock.t = 1e-3 * k + 1e-7
            logic.tick()
            if k == 150:
                logic.update(publish_rate=change)
            if k == 250:
                logic.update(real_time_factor=2)
    return logic


def marker_times(path):
    with open(path, "rb") as f:
        return [m.log_time for _, _, m in make_reader(f).iter_messages(topics=["/tensegrity_sim/markers"])]


def test_runtime_parameter_changes_are_logged_and_replayed(tmp_path):
    """Each accepted change is one rcl_interfaces/ParameterEvent on /parameter_events at the simulation
    time it took effect (the node's name, the value as the node took it), and the replay applies it
    there: before, a log with a changed publish_rate replayed with the markers of the old rate."""
    logic = node_run_with_parameter_changes(tmp_path / "params.mcap")
    with open(tmp_path / "params.mcap", "rb") as f:
        events = [(m.log_time, M.deserialize(m.data, "rcl_interfaces/msg/ParameterEvent"))
                  for _, _, m in make_reader(f).iter_messages(topics=["/parameter_events"])]
    assert [(t, e.stamp.sec, e.stamp.nanosec, e.node, [(p.name, p.value.type, p.value.double_value)
                                                       for p in e.changed_parameters])
            for t, e in events] == [(150_000_000, 0, 150_000_000, "/tensegrity_sim", [("publish_rate", 3, 50.0)]),
                                    (250_000_000, 0, 250_000_000, "/tensegrity_sim", [("real_time_factor", 3, 2.0)])]
    assert all(not (e.new_parameters or e.deleted_parameters) for _, e in events)
    # at 100 Hz markers with every 10th publication (10 ms apart): 10, 110 ms; the countdown of 10 started
    # at 110 ms is 5 publications in at 150 ms and runs out 5 more, 20 ms apart, later: 270 ms; then every
    # 5th publication, 100 ms apart, to the end (the real-time factor leaves simulated time alone)
    assert logic.sim.step_count == 150 + 100 + 2 * 200
    assert marker_times(tmp_path / "params.mcap") == [t * 1_000_000 for t in (10, 110, 270, 370, 470, 570)]
    report = replay(tmp_path / "params.mcap")
    assert report.ok, report.mismatch
    assert report.compared["/parameter_events"] == 2 and report.steps == logic.sim.step_count


def test_an_altered_parameter_event_is_caught(tmp_path):
    """publish_rate 50 -> 25 in the log: the replay, publishing where the log did (every 20 ms), puts
    markers with every round(25 / 10) = 2nd publication from the one at 270 ms on, so the first marker
    the run did not publish is at step 310 (the run's next is at 370 ms). A value the node would refuse
    is named as refused, at the event."""
    node_run_with_parameter_changes(tmp_path / "params.mcap")
    for value, expected in ((25.0, (310, "/tensegrity_sim/markers", "message", "none", "a message")),
                            (-1.0, (150, "/parameter_events", "changed_parameters", "a change the node took",
                                    "refused: parameter 'publish_rate': must be >= 1e-06, got -1.0"))):
        def alter(topic, index, msg, value=value):
            if topic == "/parameter_events" and index == 0:
                msg.changed_parameters[0].value.double_value = value
            return msg

        rewrite(tmp_path / "params.mcap", tmp_path / "altered.mcap", alter)
        m = replay(tmp_path / "altered.mcap").mismatch
        assert (m.step, m.topic, m.field, m.logged, m.replayed) == expected


def test_a_reset_log_embeds_the_parameters_of_then(tmp_path):
    """After a runtime change and a reset, the new file starts from the changed settings and replays."""
    clock = FakeClock(t=0.0)
    sim = ts.Simulator(prism(), method="elastic", dt=1e-3)
    logic = SimNodeLogic(sim, NodeSettings(scene="prism"), clock=clock)
    with LogRecorder(tmp_path / "run.mcap", logic.channels(), logic.run_info()) as recorder:
        logic.recorder = recorder
        for k in range(1, 301):
            clock.t = 1e-3 * k + 1e-7
            logic.tick()
            if k == 50:
                logic.update(publish_rate=50.0)
            if k == 100:
                logic.reset()
    second = recorder.paths[1]
    with open(second, "rb") as f:
        info = next(r.metadata for r in make_reader(f).iter_metadata() if r.name == RUN_INFO)
    assert json.loads(info["node_settings"])["publish_rate"] == 50.0
    assert marker_times(second) == [t * 1_000_000 for t in (20, 120)]  # every 5th publication, 20 ms apart
    assert replay(recorder.paths[0]).ok and replay(second).ok
