"""Scenes, fakes, message builders and a log rewriter shared by the tests of tensegrity_sim.ros."""
from __future__ import annotations

import math
import time

import numpy as np
import yaml
from mcap.reader import make_reader
from rosbags.interfaces import Nodetype

import tensegrity_sim as ts
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.messages import TYPESTORE
from tensegrity_sim.ros.log import RUN_INFO, LogWriter
from tensegrity_sim.ros.node_logic import NodeSettings, Qos, SimNodeLogic


def prism_dict(fixed_base: bool = False, gravity: float = 0.0, stretch: float = 0.95) -> dict:
    """A 3-strut twisted prism, not in equilibrium: cable rest lengths are ``stretch`` times the initial
    lengths, so it starts moving at once and some cables go slack and snap. ``fixed_base`` fixes n0."""
    r, h = 0.4, 0.6
    nodes = []
    for i in range(3):
        a = 2 * math.pi * i / 3
        nodes.append({"name": f"n{i}", "position": [r * math.cos(a), r * math.sin(a), 0.0], "mass": 0.5})
    for i in range(3):
        a = 2 * math.pi * i / 3 + math.radians(150)
        nodes.append({"name": f"n{i + 3}", "position": [r * math.cos(a), r * math.sin(a), h], "mass": 0.5})
    if fixed_base:
        nodes[0] = {"name": "n0", "position": nodes[0]["position"], "fixed": True}
    pos = {n["name"]: np.array(n["position"]) for n in nodes}

    def length(a, b):
        return float(np.linalg.norm(pos[a] - pos[b]))

    struts = [{"name": f"s{i}", "nodes": [f"n{i}", f"n{(i + 1) % 3 + 3}"], "stiffness": 2.0e4, "radius": 0.01}
              for i in range(3)]
    pairs = [("n0", "n1"), ("n1", "n2"), ("n2", "n0"), ("n3", "n4"), ("n4", "n5"), ("n5", "n3"),
             ("n0", "n3"), ("n1", "n4"), ("n2", "n5")]
    cables = [{"name": f"c{k}", "nodes": list(p), "stiffness": 2.0e3, "rest_length": stretch * length(*p),
               "radius": 0.002} for k, p in enumerate(pairs)]
    return {"name": "prism", "gravity": [0.0, 0.0, -gravity], "nodes": nodes, "struts": struts, "cables": cables}


def prism(**kwargs) -> ts.Scene:
    return ts.Scene.from_dict(prism_dict(**kwargs))


class FakeClock:
    """A monotonic clock under the test's control: ``t`` s, advancing ``per_read`` s at every read."""

    def __init__(self, t: float = 100.0, per_read: float = 0.0):
        self.t = t
        self.per_read = per_read

    def __call__(self) -> float:
        t = self.t
        self.t += self.per_read
        return t


class ListLogger:
    """Collects what the node logic logs."""

    def __init__(self):
        self.warnings: list[str] = []
        self.errors: list[str] = []

    def warning(self, text: str) -> None:
        self.warnings.append(text)

    def error(self, text: str) -> None:
        self.errors.append(text)


class FakeRecorder:
    """Records what the node logic records, in memory."""

    def __init__(self):
        self.records: list[tuple[str, object, int]] = []
        self.restarts = 0

    def record(self, records, log_time_ns):
        self.records += [(topic, data, log_time_ns) for topic, data in records]

    def restart(self, run_info):
        self.restarts += 1
        self.run_info = run_info
        return f"restart{self.restarts}.mcap"


def make_logic(scene: ts.Scene, clock=None, method: str = "elastic", cpu_clock=time.thread_time, **settings):
    """(node logic, list of (key, message) it sent, its logger) for ``scene`` at dt = 1 ms.
    Markers go out with every publication unless ``marker_rate`` is given."""
    sent: list = []
    settings.setdefault("marker_rate", settings.get("publish_rate", NodeSettings.publish_rate))
    logger = ListLogger()
    sim = ts.Simulator(scene, method=method, dt=settings.pop("dt", 1e-3))
    logic = SimNodeLogic(sim, NodeSettings(scene=scene.name, dt=sim.dt, **settings),
                         transport=lambda key, msg: sent.append((key, msg)), clock=clock or FakeClock(),
                         cpu_clock=cpu_clock, logger=logger)
    return logic, sent, logger


def rest_lengths_msg(names, values, velocity=(), effort=()):
    return M.joint_state(M.header(0, ""), names, values, velocity, effort)


def wrench_msg(node, force, torque=(0.0, 0.0, 0.0)):
    return M.wrench_stamped(M.header(0, node), force, torque)


def positions_of(pose_array) -> np.ndarray:
    return np.array([[p.position.x, p.position.y, p.position.z] for p in pose_array.poses])


def stamp_of(message) -> int:
    stamp = message.header.stamp
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def rewrite(src, dst, alter=None, run_info=None):
    """Copy a log message by message (decoded and re-encoded: identical bytes), through ``alter(topic, index,
    message)`` (return None to drop it), with ``run_info`` changes."""
    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        info = next(m.metadata for m in reader.iter_metadata() if m.name == RUN_INFO)
        channels = []
        for c in summary.channels.values():
            q = yaml.safe_load(c.metadata["offered_qos_profiles"])[0]
            channels.append((c.topic, summary.schemas[c.schema_id].name, Qos(q["reliability"], q["depth"],
                                                                             q["durability"])))
        counts = {}
        with LogWriter(dst, channels, {**info, **(run_info or {})}) as writer:
            for _, c, message in reader.iter_messages(log_time_order=False):
                typename = summary.schemas[c.schema_id].name
                msg = M.deserialize(message.data, typename)
                index = counts[c.topic] = counts.get(c.topic, -1) + 1
                if alter is not None:
                    msg = alter(c.topic, index, msg)
                if msg is not None:
                    writer.write(c.topic, M.serialize(msg, typename), message.log_time)


_NUMPY = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
          "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32, "int64": np.int64,
          "uint64": np.uint64, "float32": np.float32, "float64": np.float64}


def random_message(msgtype, rng):
    """A message of ``msgtype`` with random content in every field, built from the typestore."""
    def scalar(name, bound):
        if name == "string":
            return "".join(rng.choice(list("aZ_9é✓ "), int(rng.integers(0, bound or 9))))
        if name == "bool":
            return bool(rng.integers(2))
        if name.startswith("float"):
            return float(_NUMPY[name](rng.normal() * 1e3))
        if name == "byte":  # rosbags packs a scalar byte as a signed char
            return int(rng.integers(0, 128))
        info = np.iinfo(_NUMPY[name])
        return int(rng.integers(info.min, min(info.max, 2**63 - 1), endpoint=True))

    def array(name, n):
        if name == "string":
            return [scalar("string", 0) for _ in range(n)]
        if name.startswith("float"):
            return (rng.normal(size=n) * 1e3).astype(_NUMPY[name])
        if name == "bool":
            return rng.integers(0, 2, n).astype(bool)
        info = np.iinfo(_NUMPY[name])
        return rng.integers(info.min, min(info.max, 2**63 - 1), n, endpoint=True).astype(_NUMPY[name])

    def field(desc):
        node, detail = desc
        if node == Nodetype.BASE:
            return scalar(*detail)
        if node == Nodetype.NAME:
            return random_message(detail, rng)
        (element, element_detail), count = detail
        n = count if node == Nodetype.ARRAY else int(rng.integers(0, (count or 4) + 1))
        if element == Nodetype.BASE:
            return array(element_detail[0], n)
        return [random_message(element_detail, rng) for _ in range(n)]

    return TYPESTORE.types[msgtype](**{name: field(desc) for name, desc in TYPESTORE.fielddefs[msgtype][1]})
