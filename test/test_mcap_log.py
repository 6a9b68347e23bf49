"""The MCAP log read back by two independent readers: ``mcap`` with ``mcap-ros2-support`` (which decodes
with the schema text in the file) and ``rosbags`` (rosbag2's reader logic, QoS parsing included)."""
import json
import os
import re
import signal
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader as RosbagsReader

import tensegrity_sim as ts
from tensegrity_sim.cli import main, simulate
from tensegrity_sim.commands import parse_commands
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.log import LogRecorder, LogWriter, SignalLatch, log_file_path
from tensegrity_sim.ros.log_reader import LogReader
from tensegrity_sim.ros.node_logic import TOPICS, NodeSettings, SimNodeLogic
from tensegrity_sim.ros.offline import CommandDriver
from tensegrity_sim.ros.replay import replay
from ros_helpers import positions_of, prism, prism_dict, rest_lengths_msg, stamp_of

COMMANDS = [
    {"time": 0.0, "rest_lengths": {"c0": 0.55, "c4": 0.6}},
    {"time": 0.05, "rest_lengths": {"c0": 0.45}, "forces": {"n3": [0.0, 0.0, 20.0]}},
    {"time": 0.12, "forces": {"n3": [0.0, 0.0, 0.0], "n1": [2.0, 0.0, 0.0]}},
]
STEPS = 300


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """An offline run through the node logic with rest-length ramps, force steps, one refused input and
    one diagnostics message, logged; with everything the node received and sent, and when."""
    scene = prism(gravity=9.81)
    path = tmp_path_factory.mktemp("log") / "run.mcap"
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    sent, received = [], []
    logic = SimNodeLogic(sim, NodeSettings(scene="prism", dt=1e-3, marker_rate=100.0),
                         transport=lambda key, msg: sent.append((key, msg, logic.stamp_ns())))
    take = logic.receive

    def receive(key, msg):
        received.append((key, msg, logic.stamp_ns()))
        return take(key, msg)

    logic.receive = receive
    with LogRecorder(path, logic.channels(), logic.run_info()) as recorder:
        logic.recorder = recorder
        simulate(sim, STEPS, parse_commands(COMMANDS, scene), driver=CommandDriver(logic))
        assert logic.receive("cable_rest_lengths", rest_lengths_msg(["nope"], [1.0])) is not None
        logic.publish_diagnostics()
    return {"scene": scene, "sim": sim, "path": path, "sent": sent, "received": received, "logic": logic}


def expected_counts(run):
    counts = {run["logic"].topic_names[k]: 0 for k in TOPICS}
    for key, _, _ in run["sent"] + run["received"]:
        counts[run["logic"].topic_names[key]] += 1
    return counts


def by_topic(run, key):
    return [(msg, t) for k, msg, t in run["sent"] + run["received"] if k == key]


def test_mcap_reader_sees_a_ros2_log(run):
    counts = expected_counts(run)
    assert counts["/tensegrity_sim/cable_rest_lengths"] > 50 and counts["/tensegrity_sim/external_wrench"] == 3
    assert counts["/tensegrity_sim/node_poses"] == STEPS // 10
    with open(run["path"], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        stats = summary.statistics
        assert stats.message_count == sum(counts.values())
        assert (stats.message_start_time, stats.message_end_time) == (0, STEPS * 1_000_000)
        got = {c.topic: stats.channel_message_counts.get(cid, 0) for cid, c in summary.channels.items()}
        assert got == counts  # every topic registered, even without messages (contacts)
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            key = next(k for k, name in run["logic"].topic_names.items() if name == channel.topic)
            assert (schema.name, schema.encoding, channel.message_encoding) == (TOPICS[key].typename, "ros2msg", "cdr")
            assert b"\n================================================================================\nMSG: " in \
                schema.data or schema.name == "rosgraph_msgs/msg/Clock" and b"builtin_interfaces/Time" in schema.data
            qos = yaml.safe_load(channel.metadata["offered_qos_profiles"])
            assert len(qos) == 1 and qos[0]["reliability"] == TOPICS[key].qos.reliability
            assert qos[0]["depth"] == TOPICS[key].qos.depth and qos[0]["history"] == "keep_last"
            assert channel.metadata["topic_type_hash"].startswith("RIHS01_")
        times = {}
        decoded = {}
        for schema, channel, message, msg in reader.iter_decoded_messages(log_time_order=False):
            assert message.publish_time == message.log_time
            times.setdefault(channel.topic, []).append(message.log_time)
            decoded.setdefault(channel.topic, []).append(msg)
    names = run["logic"].topic_names
    for key in TOPICS:
        assert times.get(names[key], []) == [t for _, t in by_topic(run, key)]
    for (sent, t), logged in zip(by_topic(run, "node_poses"), decoded[names["node_poses"]]):
        assert stamp_of(logged) == t
        np.testing.assert_array_equal(positions_of(logged), positions_of(sent))
    for (sent, t), logged in zip(by_topic(run, "cable_states"), decoded[names["cable_states"]]):
        assert list(logged.name) == list(sent.name)
        for f in ("position", "velocity", "effort"):
            np.testing.assert_array_equal(np.asarray(getattr(logged, f)), getattr(sent, f))
    for (sent, t), logged in zip(by_topic(run, "external_wrench"), decoded[names["external_wrench"]]):
        assert logged.header.frame_id == sent.header.frame_id and logged.wrench.force.z == sent.wrench.force.z
    assert [m.clock.nanosec for m in decoded["/clock"]] == [t for _, t in by_topic(run, "clock")]
    assert [len(m.markers) for m in decoded[names["markers"]]] == [len(m.markers) for m, _ in by_topic(run, "markers")]


def test_log_embeds_what_reruns_it(run):
    with open(run["path"], "rb") as f:
        records = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    info = records["tensegrity_sim"]
    assert ts.Scene.from_dict(yaml.safe_load(info["scene_yaml"])) == run["scene"]
    assert (info["method"], float(info["dt"]), info["package_version"]) == ("elastic", 1e-3, ts.__version__)
    assert json.loads(info["method_settings"]) == run["sim"].method_settings
    assert NodeSettings(**json.loads(info["node_settings"])) == run["logic"].settings
    bag = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    assert (bag["version"], bag["storage_identifier"], bag["ros_distro"]) == (9, "mcap", "jazzy")
    counts = expected_counts(run)
    assert bag["message_count"] == sum(counts.values())
    assert {t["topic_metadata"]["name"]: t["message_count"] for t in bag["topics_with_message_count"]} == counts
    assert bag["duration"]["nanoseconds"] == STEPS * 1_000_000


def test_rosbags_reader_sees_the_same_log(run):
    counts = expected_counts(run)
    names = run["logic"].topic_names
    with RosbagsReader(run["path"]) as reader:
        assert reader.message_count == sum(counts.values())
        assert (reader.start_time, reader.duration) == (0, STEPS * 1_000_000 + 1)
        connections = {c.topic: c for c in reader.connections}
        assert {t: c.msgcount for t, c in connections.items()} == counts
        for key, spec in TOPICS.items():
            c = connections[names[key]]
            qos = c.ext.offered_qos_profiles[0]
            assert c.msgtype == spec.typename and c.ext.serialization_format == "cdr"
            assert (qos.reliability.name.lower(), qos.depth, qos.durability.name.lower(), qos.history.name.lower()) \
                == (spec.qos.reliability, spec.qos.depth, spec.qos.durability, "keep_last")
        poses = [(t, M.TYPESTORE.deserialize_cdr(raw, c.msgtype))
                 for c, t, raw in reader.messages(connections=[connections[names["node_poses"]]])]
    assert [t for t, _ in poses] == [t for _, t in by_topic(run, "node_poses")]
    for (t, logged), (sent, _) in zip(poses, by_topic(run, "node_poses")):
        np.testing.assert_array_equal(positions_of(logged), positions_of(sent))


def test_writer_finishes_once_and_on_exceptions(tmp_path):
    path = tmp_path / "broken.mcap"
    spec = TOPICS["clock"]
    with pytest.raises(RuntimeError):
        with LogWriter(path, [("/clock", spec.typename, spec.qos)], {"a": "b"}) as writer:
            writer.write("/clock", M.serialize(M.new(spec.typename, clock=M.time(5)), spec.typename), 5)
            raise RuntimeError("boom")
    size = path.stat().st_size
    writer.finish()
    assert path.stat().st_size == size
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_summary().statistics.message_count == 1
        assert [m.clock.nanosec for *_, m in reader.iter_decoded_messages()] == [5]
    with RosbagsReader(path) as reader:
        assert reader.message_count == 1


def test_log_file_path(tmp_path):
    now = datetime(2025, 3, 4, 5, 6, 7)
    assert log_file_path("", "prism3", now) is None
    assert log_file_path("out/run.mcap", "prism3", now) == Path("out/run.mcap")
    first = log_file_path(str(tmp_path), "prism3", now)
    assert first == tmp_path / "prism3_20250304-050607.mcap"
    first.write_bytes(b"")
    assert log_file_path(str(tmp_path), "prism3", now) == tmp_path / "prism3_20250304-050607_1.mcap"


def test_reset_starts_a_new_complete_log(tmp_path):
    scene = prism()
    logic = SimNodeLogic(ts.Simulator(scene, method="elastic", dt=1e-3), NodeSettings(scene="prism", marker_rate=100.0))
    with LogRecorder(tmp_path / "node.mcap", logic.channels(), logic.run_info()) as recorder:
        logic.recorder = recorder
        for _ in range(25):
            logic.step()
            if logic.publication_due:
                logic.publish()
        assert logic.reset()[1].endswith(str(tmp_path / "node_reset1.mcap"))
        for _ in range(12):
            logic.step()
            if logic.publication_due:
                logic.publish()
    assert recorder.paths == [tmp_path / "node.mcap", tmp_path / "node_reset1.mcap"]
    for path, publications in zip(recorder.paths, (2, 1)):
        with RosbagsReader(path) as reader:
            assert reader.start_time == 10_000_000
            assert reader.message_count == 5 * publications
        assert replay(path).ok


@pytest.mark.parametrize("signum, status", [(signal.SIGINT, 130), (signal.SIGTERM, 128 + signal.SIGTERM)])
def test_interrupted_run_leaves_a_finished_log(tmp_path, signum, status):
    scene_file = tmp_path / "prism.yaml"
    scene_file.write_text(yaml.safe_dump(prism_dict()))
    path = tmp_path / "cut.mcap"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(ts.__file__).parents[1]),
                                                        os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-u", "-m", "tensegrity_sim.cli", "run", str(scene_file), "--quiet",
                             "--duration", "10000", "--log", str(path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 60
        while not path.exists() and time.monotonic() < deadline:  # the log exists: signals are latched
            time.sleep(0.05)
        time.sleep(0.3)
        proc.send_signal(signum)
        proc.wait(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == status
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        count = reader.get_summary().statistics.message_count
        assert count > 25 and sum(1 for _ in reader.iter_decoded_messages()) == count
    with RosbagsReader(path) as reader:
        assert reader.message_count == count
    assert replay(path).ok


def test_run_log_without_a_value_goes_to_bags(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "prism.yaml").write_text(yaml.safe_dump(prism_dict()))
    assert main(["run", "prism.yaml", "--duration", "0.05", "--quiet", "--log"]) == 0
    (log,) = (tmp_path / "bags").iterdir()
    assert re.fullmatch(r"prism_\d{8}-\d{6}\.mcap", log.name)
    assert f"log              bags/{log.name}" in capsys.readouterr().out
    assert replay(log).ok


def test_signal_latch_raises_at_the_safe_point_only():
    before = signal.getsignal(signal.SIGINT)   # SIG_IGN when the suite runs as a background job
    with pytest.raises(KeyboardInterrupt):
        with SignalLatch() as latch:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.01)  # the handler has run: nothing raised yet
            assert latch.signum == signal.SIGINT
            latch.raise_if_signalled()
    with pytest.raises(SystemExit) as exit_:
        with SignalLatch():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.01)
    assert exit_.value.code == 128 + signal.SIGTERM  # raised on leaving the block, not lost
    assert signal.getsignal(signal.SIGINT) is before  # handlers restored


def test_writing_a_publication_at_once_is_writing_its_messages_in_turn(tmp_path):
    """``LogWriter.write_all`` (what the node records a publication through) writes the very file that
    ``write`` called once per message does: the same bytes, sequence numbers and counts included, across
    several chunks."""
    spec = TOPICS["clock"]
    channels = [("/clock", spec.typename, spec.qos), ("/b", spec.typename, spec.qos)]
    batches = [[(topic, M.serialize(M.new(spec.typename, clock=M.time(k + j)), spec.typename))
                for j, topic in enumerate(("/clock", "/b", "/clock"))] for k in range(3000)]
    files = []
    for at_once in (False, True):
        path = tmp_path / str(at_once) / "log.mcap"  # the same name: the rosbag2 metadata holds it
        with LogWriter(path, channels, {"a": "b"}, chunk_size=4096, flush_period=None) as writer:
            for k, batch in enumerate(batches):
                if at_once:
                    writer.write_all(batch, 1000 * k)
                else:
                    for topic, data in batch:
                        writer.write(topic, data, 1000 * k)
        assert writer.counts == {"/clock": 6000, "/b": 3000}
        files.append(path.read_bytes())
    assert files[0] == files[1] and len(files[0]) > 10 * 4096
    with open(tmp_path / "True" / "log.mcap", "rb") as f:
        read = [(c.topic, m.data, m.log_time, m.publish_time, m.sequence)
                for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
    sequences = {"/clock": iter(range(6000)), "/b": iter(range(3000))}  # per channel, from 0
    assert read == [(topic, data, 1000 * k, 1000 * k, next(sequences[topic]))
                    for k, batch in enumerate(batches) for topic, data in batch]


def test_messages_wait_up_to_the_pending_size_and_the_flush_period(tmp_path):
    """Crash safety with waiting messages: they go to mcap's writer once ``pending_size`` bytes of them wait,
    and once the flush period has passed everything written is on disk, readable as an unfinished log
    (what a crash would leave)."""
    spec = TOPICS["clock"]
    now = [0.0]
    path = tmp_path / "log.mcap"
    writer = LogWriter(path, [("/clock", spec.typename, spec.qos)], {"a": "b"}, chunk_size=1 << 20,
                       pending_size=100, flush_period=1.0, clock=lambda: now[0])
    data = M.serialize(M.new(spec.typename, clock=M.time(0)), spec.typename)  # 12 bytes
    for k in range(8):  # 96 bytes: all wait
        writer.write("/clock", data, k)
    assert writer.counts["/clock"] == 0
    writer.write("/clock", data, 8)  # 108 bytes: all nine go on (into the chunk in progress, in memory)
    assert writer.counts["/clock"] == 9
    writer.write("/clock", data, 9)
    with LogReader(path) as reader:
        assert sum(1 for _ in reader.messages()) == 0 and reader.unfinished
    now[0] = 1.0  # the flush period has passed: the next write sends everything out and syncs it
    writer.write("/clock", data, 10)
    with LogReader(path) as reader:
        assert [m.log_time for m in reader.messages()] == list(range(11))
    writer.write("/clock", data, 11)
    writer.finish()
    with LogReader(path) as reader:
        assert [m.sequence for m in reader.messages()] == list(range(12)) and not reader.unfinished


def test_drain_writes_out_when_the_flush_period_ends_soon(tmp_path):
    """drain() (the node's idle time) hands on the waiting messages, and writes everything out once the flush
    period ends within FLUSH_AHEAD s, not before: the write that would find the flush due (in a tick) then
    does not, and the next period counts from the drain's write-out."""
    from tensegrity_sim.ros.log import FLUSH_AHEAD

    spec = TOPICS["clock"]
    now = [0.0]
    path = tmp_path / "log.mcap"
    writer = LogWriter(path, [("/clock", spec.typename, spec.qos)], {"a": "b"}, chunk_size=1 << 20,
                       pending_size=100, flush_period=1.0, clock=lambda: now[0])
    data = M.serialize(M.new(spec.typename, clock=M.time(0)), spec.typename)
    writer.write("/clock", data, 0)
    now[0] = 1.0 - FLUSH_AHEAD - 1e-3
    writer.drain()   # handed on, into the chunk in progress, in memory
    assert writer.counts["/clock"] == 1
    with LogReader(path) as reader:
        assert sum(1 for _ in reader.messages()) == 0
    writer.write("/clock", data, 1)
    now[0] = 1.0 - FLUSH_AHEAD
    writer.drain()
    with LogReader(path) as reader:
        assert [m.log_time for m in reader.messages()] == [0, 1]
    now[0] = 1.0   # the old period's end: no write-out
    writer.write("/clock", data, 2)
    with LogReader(path) as reader:
        assert [m.log_time for m in reader.messages()] == [0, 1]
    now[0] = 2.0 - FLUSH_AHEAD   # a period after the drain's write-out: the write finds it due
    writer.write("/clock", data, 3)
    with LogReader(path) as reader:
        assert [m.log_time for m in reader.messages()] == [0, 1, 2, 3]
    writer.finish()


def test_the_disk_sync_runs_beside_the_writer_and_a_failed_one_fails_the_log(tmp_path, monkeypatch):
    """The flush period's sync to the disk (``os.fsync``) runs on a thread of its own: the write that starts
    it returns while it is still running (the node's tick does not wait for the disk), the next flush does
    not start another beside it, and finishing waits for it before the file is closed. A sync that fails
    fails the log at the next flush, naming the error, as a failed write does. A log to /dev/null, which
    has no disk to sync to, is not synced."""
    import errno
    import threading
    from tensegrity_sim.ros import log as log_module
    from tensegrity_sim.ros.log import LogWriteError

    spec = TOPICS["clock"]
    data = M.serialize(M.new(spec.typename, clock=M.time(0)), spec.typename)
    started, release, calls = threading.Event(), threading.Event(), []
    error = []

    def fsync(fd):
        calls.append(threading.current_thread().name)
        started.set()
        assert release.wait(10.0)
        if error:
            raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(log_module.os, "fsync", fsync)
    now = [0.0]
    path = tmp_path / "log.mcap"
    writer = LogWriter(path, [("/clock", spec.typename, spec.qos)], {"a": "b"}, pending_size=0, flush_period=1.0,
                       clock=lambda: now[0])
    writer.write("/clock", data, 0)
    now[0] = 1.0
    writer.write("/clock", data, 1)   # a flush: its sync starts, and the write returns while it waits
    assert started.wait(10.0) and not release.is_set()
    assert calls == ["log-sync_0"] and threading.current_thread().name != calls[0]
    now[0] = 2.0
    writer.write("/clock", data, 2)   # the next flush: the sync still runs, no second one beside it
    assert len(calls) == 1
    release.set()
    writer.finish()
    with LogReader(path) as reader:
        assert [m.log_time for m in reader.messages()] == [0, 1, 2] and not reader.unfinished
    # a sync that fails
    started.clear()
    error.append(True)
    now[0] = 0.0
    writer = LogWriter(tmp_path / "failing.mcap", [("/clock", spec.typename, spec.qos)], {"a": "b"}, pending_size=0,
                       flush_period=1.0, clock=lambda: now[0])
    now[0] = 1.0
    writer.write("/clock", data, 0)
    assert started.wait(10.0)
    with pytest.raises(LogWriteError, match=r"failing\.mcap: writing the log failed at t = 0\.000000 s after \d+ "
                                            r"messages: Input/output error"):
        for _ in range(10_000):   # flushes, until one finds the failed sync over
            now[0] += 1.0
            writer.write("/clock", data, 0)
            time.sleep(1e-3)
    # /dev/null: never synced
    calls.clear()
    writer = LogWriter("/dev/null", [("/clock", spec.typename, spec.qos)], {"a": "b"}, pending_size=0,
                       flush_period=1.0, clock=lambda: now[0])
    now[0] = 3.0
    writer.write("/clock", data, 0)
    writer.finish()
    assert calls == []
