"""``tensegrity-sim serve --foxglove``: a real WebSocket client (websocket-client) speaks Foxglove's
protocol to the foxglove-sdk server, and what it receives must be the very bytes the run's log holds."""
import json
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import websocket
from mcap.reader import make_reader

from tensegrity_sim import load_scene
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.node_logic import TOPICS, resolve_topic
from tensegrity_sim.ros.record import read_log

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode of a message: u8 opcode, u32 subscription id, u64 log time (ns), payload


def _start(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "tensegrity_sim.cli", "serve", "prism3", "--foxglove", "0",
                             "--log-path", str(tmp_path / "live.mcap")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if "ws://" in line:
            return proc, int(line.rsplit(":", 1)[1].split(";")[0])
        assert line or proc.poll() is None, f"serve ended: {proc.communicate()}"
    raise AssertionError("the server never said where it listens")


def test_a_websocket_client_receives_the_channels_and_the_logged_messages(tmp_path):
    proc, port = _start(tmp_path)
    try:
        ws = websocket.create_connection(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], timeout=30)
        info = json.loads(ws.recv())
        assert info["op"] == "serverInfo" and "time" in info["capabilities"]
        wanted = {resolve_topic(s.name, "/tensegrity_sim"): s for s in TOPICS.values() if s.direction == "out"}
        channels = {}
        while len(channels) < len(wanted):
            message = ws.recv()
            if isinstance(message, str) and json.loads(message)["op"] == "advertise":
                channels.update({c["topic"]: c for c in json.loads(message)["channels"]})
        assert set(channels) == set(wanted)
        for topic, channel in channels.items():
            assert (channel["encoding"], channel["schemaEncoding"]) == ("cdr", "ros2msg")
            assert channel["schemaName"] == wanted[topic].typename
            assert channel["schema"] == M.schema_text(wanted[topic].typename)
        subscribed = {1: "/tensegrity_sim/cable_states", 2: "/tensegrity_sim/node_poses"}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": sid, "channelId": channels[topic]["id"]} for sid, topic in subscribed.items()]}))
        received = []
        while len(received) < 20:
            message = ws.recv()
            if isinstance(message, bytes) and message[0] == MESSAGE_DATA:
                sid, log_time = struct.unpack_from("<IQ", message, 1)
                received.append((subscribed[sid], log_time, message[13:]))
        ws.close()
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    with open(tmp_path / "live.mcap", "rb") as f:
        logged = {(channel.topic, m.log_time): bytes(m.data)
                  for _, channel, m in make_reader(f).iter_messages(topics=list(subscribed.values()))}
    # every message streamed is the logged one, byte for byte, at the same simulation time
    for topic, log_time, data in received:
        assert logged[(topic, log_time)] == data
    states = [M.deserialize(d, "sensor_msgs/msg/JointState") for t, _, d in received if t.endswith("cable_states")]
    assert states and all(list(s.name) == list(load_scene("prism3").cable_names) for s in states)
    # publications every 10 ms of simulated time (publish_rate 100 Hz, dt 1 ms)
    assert all(t % 10_000_000 == 0 for _, t, _ in received)
    # a node's log is read back like run's: the streamed states are in it
    record = read_log(tmp_path / "live.mcap")
    for topic, log_time, data in received:
        if topic.endswith("cable_states"):
            k = int(np.searchsorted(record.times, log_time * 1e-9 - 1e-12))
            tension = np.asarray(M.deserialize(data, "sensor_msgs/msg/JointState").effort)
            assert np.array_equal(record.tensions[k], tension)


def test_the_layout_shows_the_node_s_topics():
    """foxglove/tensegrity_sim.json: every panel reads a topic the node publishes (or the layout's own
    script's output), and the script reads cable_states; every panel is placed."""
    with open(Path(__file__).parent.parent / "foxglove" / "tensegrity_sim.json") as f:
        layout = json.load(f)
    published = {resolve_topic(s.name, "/tensegrity_sim") for s in TOPICS.values() if s.direction == "out"}
    script = next(iter(layout["userNodes"].values()))["sourceCode"]
    assert 'inputs = ["/tensegrity_sim/cable_states"]' in script
    made = "/studio_script/cable_slack"
    assert f'output = "{made}"' in script
    panels = layout["configById"]
    topics = set(panels["3D!structure"]["topics"])
    paths = [p["value"] for panel in panels.values() for p in panel.get("paths", [])]
    assert topics <= published and "/tensegrity_sim/markers" in topics
    assert {p.split(".")[0] for p in paths} == {"/tensegrity_sim/cable_states", "/tensegrity_sim/cable_impulses", made}

    def placed(node):
        return {node} if isinstance(node, str) else placed(node["first"]) | placed(node["second"])

    assert placed(layout["layout"]) == set(panels)
