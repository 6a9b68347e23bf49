"""The message backend (rclpy's classes where rclpy imports, rosbags' otherwise) changes no byte of a log.

The same scene and command schedule are logged by ``tensegrity-sim run --log`` in two processes: one as
this test process is (rclpy's classes in CI's ROS leg), one where rclpy cannot be imported (rosbags'
classes). Every message record of the two logs, inputs included, must be the same bytes at the same log
time; in the ROS leg this compares the two backends, in the other it checks the run is deterministic.
"""
import importlib.util
import json
from dataclasses import replace

import numpy as np
import yaml
from mcap.reader import make_reader

from dds_child import spawn
from ros_helpers import random_message
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.messages import TYPESTORE

# rclpy made unimportable before anything imports it, then the command line run as usual
WITHOUT_RCLPY = "import sys; sys.modules['rclpy'] = None; from tensegrity_sim.cli import main; sys.exit(main())"
WITH_WHAT_IMPORTS = "import sys; from tensegrity_sim.cli import main; sys.exit(main())"
BACKEND = "from tensegrity_sim.ros import messages as M; print(M.BACKEND)"

SCHEDULE = [  # rest-length ramps and force steps: every output moves, and both input topics are logged
    {"time": 0.0, "rest_lengths": {"c0": 0.95}},
    {"time": 0.05, "rest_lengths": {"c0": 0.8, "c4": 0.9}, "forces": {"n3": [0.0, 0.5, 20.0]}},
    {"time": 0.12, "rest_lengths": {"c0": 0.95}, "forces": {"n3": [0.0, 0.0, 0.0]}},
]


def records(path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [(channel.topic, message.log_time, message.data)
                for _, channel, message in make_reader(f).iter_messages(log_time_order=False)]


def test_logs_are_the_same_bytes_with_and_without_rclpy(tmp_path):
    (tmp_path / "commands.yaml").write_text(yaml.safe_dump(SCHEDULE))
    logs = {}
    for name, code in (("without", WITHOUT_RCLPY), ("as_is", WITH_WHAT_IMPORTS)):
        logs[name] = tmp_path / f"{name}.mcap"
        with spawn("-c", code, "run", "icosahedron", "--method", "elastic", "--duration", "0.2",
                   "--commands", str(tmp_path / "commands.yaml"), "--log", str(logs[name])) as run:
            _, err = run.communicate(timeout=120)
        assert run.returncode == 0, err
    with spawn("-c", BACKEND) as probe:
        out, _ = probe.communicate(timeout=60)
    rclpy_here = importlib.util.find_spec("rclpy") is not None
    assert out.strip() == ("rclpy" if rclpy_here else "rosbags")  # what the second run used

    without, as_is = records(logs["without"]), records(logs["as_is"])
    topics = {topic for topic, _, _ in without}
    assert {"/clock", "/tensegrity_sim/node_poses", "/tensegrity_sim/cable_states", "/tensegrity_sim/cable_impulses",
            "/tensegrity_sim/markers", "/tensegrity_sim/cable_rest_lengths",
            "/tensegrity_sim/external_wrench"} <= topics, topics
    assert len(without) == len(as_is) > 200
    for k, (a, b) in enumerate(zip(without, as_is)):
        assert a == b, f"record {k}: {json.dumps([a[0], a[1], len(a[2]), b[0], b[1], len(b[2])])}"


# message packages whose Python classes the node's backend provides (rclpy's, with the "ros" extra)
PACKAGES = ("builtin_interfaces", "std_msgs", "geometry_msgs", "sensor_msgs", "visualization_msgs", "diagnostic_msgs",
            "rosgraph_msgs", "rcl_interfaces")


def test_every_message_type_of_the_node_packages_comes_back_to_the_same_bytes():
    """Random content in every field of every message type of these packages (rosbags' bytes), decoded by
    the backend (rclpy's own deserializer with rclpy) and serialized again by :func:`messages.serialize`
    (rclpy objects copied into rosbags objects field by field): the same bytes. So no field kind (byte,
    char, bool, fixed arrays, sequences of messages, bounded strings, ...) is lost in the copy."""
    rng = np.random.default_rng(18)
    typenames = [t for t in sorted(TYPESTORE.fielddefs) if t.split("/")[0] in PACKAGES and "/msg/" in t]
    assert len(typenames) > 80
    for typename in typenames:
        for _ in range(3):
            message = random_message(typename, rng)
            if hasattr(message, "structure_needs_at_least_one_member"):  # no fields: its placeholder is 0 in rclpy
                message = replace(message, structure_needs_at_least_one_member=0)
            data = bytes(TYPESTORE.serialize_cdr(message, typename))
            assert M.serialize(M.deserialize(data, typename), typename) == data, typename
