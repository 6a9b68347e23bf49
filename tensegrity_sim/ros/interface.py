"""The ``tensegrity_sim`` node's interface (contract §4, ``msg_docs/``): its topics (names, types,
direction, QoS), services and parameters, with the parameters' validation (:class:`NodeSettings`).
:mod:`.node_logic` behaves behind it (and re-exports it); the log and its readers import it from here.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, field, fields

from ..checks import MIN_DT, describe, real
from ..methods.qp.solvers import SOLVERS

__all__ = ["Qos", "TopicSpec", "TOPICS", "SERVICES", "resolve_topic", "stamp_ns", "MIN_RATE", "MAX_REAL_TIME_FACTOR",
           "MAX_THREAD_PRIORITY", "NodeSettings", "RUNTIME_PARAMETERS", "FAILURE_STATUS"]


# --------------------------------------------------------------------------- topics
@dataclass(frozen=True)
class Qos:
    """The QoS a topic is offered (publisher) or requested (subscription) with."""

    reliability: str = "reliable"     # "reliable" | "best_effort"
    depth: int = 10                   # history: keep_last(depth)
    durability: str = "volatile"      # "volatile" | "transient_local"


@dataclass(frozen=True)
class TopicSpec:
    """name: relative to the node (``~/x``) or absolute (``/clock``); typename: "pkg/msg/Name";
    direction: "in" (subscribed) or "out" (published)."""

    name: str
    typename: str
    direction: str
    qos: Qos


# Impulses and contact events are sums and events: a subscriber that needs every one has room for one
# second of publications at 100 Hz before the publisher's history overwrites anything.
TOPICS: dict[str, TopicSpec] = {
    "cable_rest_lengths": TopicSpec("~/cable_rest_lengths", "sensor_msgs/msg/JointState", "in", Qos()),
    "external_wrench": TopicSpec("~/external_wrench", "geometry_msgs/msg/WrenchStamped", "in", Qos()),
    "clock": TopicSpec("/clock", "rosgraph_msgs/msg/Clock", "out", Qos(depth=1)),
    "node_poses": TopicSpec("~/node_poses", "geometry_msgs/msg/PoseArray", "out", Qos()),
    "cable_states": TopicSpec("~/cable_states", "sensor_msgs/msg/JointState", "out", Qos()),
    "cable_impulses": TopicSpec("~/cable_impulses", "sensor_msgs/msg/JointState", "out", Qos(depth=100)),
    "contacts": TopicSpec("~/contacts", "diagnostic_msgs/msg/DiagnosticArray", "out", Qos(depth=100)),
    "markers": TopicSpec("~/markers", "visualization_msgs/msg/MarkerArray", "out", Qos()),
    "diagnostics": TopicSpec("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", "out", Qos()),
    # rclcpp's and rclpy's parameter-events QoS (rmw_qos_profile_parameter_events): keep_last 1000
    "parameter_events": TopicSpec("/parameter_events", "rcl_interfaces/msg/ParameterEvent", "out", Qos(depth=1000)),
}


# std_srvs/Trigger services: name (under the node, ~/name) -> the SimNodeLogic method answering it
SERVICES: dict[str, str] = {"reset": "reset", "pause": "pause", "resume": "resume", "step": "single_step"}


def resolve_topic(name: str, node_name: str) -> str:
    """``~/x`` under the node's fully qualified name (``/ns/node``); absolute names unchanged."""
    return node_name.rstrip("/") + name[1:] if name.startswith("~/") else name


def stamp_ns(seconds: float) -> int:
    """Simulation time (s) as integer nanoseconds, the unit of every stamp and log time."""
    return int(round(seconds * 1e9))


# --------------------------------------------------------------------------- parameters
# Bounds that keep the schedule's arithmetic (steps per tick, steps per publication) in range: a rate
# below MIN_RATE (one per 11.6 days) means "never", a real-time factor above MAX_REAL_TIME_FACTOR means
# "as fast as possible", which 0 says.
MIN_RATE = 1e-6                 # Hz
MAX_REAL_TIME_FACTOR = 1e6
MAX_THREAD_PRIORITY = 99        # Linux's highest SCHED_FIFO priority


def _doc(text: str, runtime: bool = False) -> dict:
    return {"doc": text, "runtime": runtime}


@dataclass(frozen=True)
class NodeSettings:
    """The node's parameters, validated on construction (a bad one raises ``ValueError`` naming it).

    ``fields(NodeSettings)`` is the parameter list: the rclpy node declares them with these defaults and
    descriptions, ``config/sim_node.yaml`` and ``msg_docs/parameters.md`` list them.
    """

    scene: str = field(default="prism3", metadata=_doc("built-in scene name or path to a scene YAML file"))
    method: str = field(default="auto", metadata=_doc("stepping method: elastic | inextensible | massive | auto"))
    solver: str = field(default="auto", metadata=_doc(
        f"QP backend of the inextensible method: {' | '.join(SOLVERS)}, or auto (or empty) for the method's "
        f"default"))
    dt: float = field(default=1e-3, metadata=_doc("simulated time per step, s"))
    step_rate: float = field(default=1000.0, metadata=_doc(
        "rate of the stepping timer, Hz of wall-clock (steady) time; each tick runs the steps due"))
    publish_rate: float = field(default=100.0, metadata=_doc(
        "outputs per second of simulated time, Hz; at most 1/dt (rounded to a whole number of steps)",
        runtime=True))
    marker_rate: float = field(default=10.0, metadata=_doc(
        "markers per second of simulated time, Hz: every round(publish_rate / marker_rate)-th publication "
        "(a display needs no more, and a MarkerArray costs more to serialise than all other outputs)",
        runtime=True))
    real_time_factor: float = field(default=1.0, metadata=_doc(
        f"simulated seconds per wall-clock second, at most {MAX_REAL_TIME_FACTOR:g}; 0 = as fast as possible",
        runtime=True))
    frame_id: str = field(default="world", metadata=_doc("frame of node_poses and markers"))
    log_path: str = field(default="bags", metadata=_doc(
        "MCAP log: a .mcap file, a directory (a timestamped file in it), or empty for no log"))
    max_rest_length_rate: float = field(default=0.0, metadata=_doc(
        "fastest a rest length may change, m/s (a motor reels at a finite speed); 0 = no limit"))
    thread_priority: int = field(default=0, metadata=_doc(
        f"SCHED_FIFO priority (1-{MAX_THREAD_PRIORITY}) of the thread that steps, while real_time_factor > 0: "
        "the OS runs it before every ordinary thread, so no other process delays a tick; 0 = the default "
        "scheduler. Needs root, CAP_SYS_NICE or an rtprio limit (ulimit -r); refused, the node warns and "
        "steps on the default scheduler"))
    lockstep: bool = field(default=False, metadata=_doc(
        "wait for the controller: after each node_poses publication no step runs until a cable_rest_lengths "
        "or external_wrench message is applied, so a run is the same however late a controller answers (the "
        "schedule restarts at each answer)"))
    node_name: str = field(default="/tensegrity_sim", metadata=_doc(
        "fully qualified node name, the prefix of ~/ topics (set by the node, not a parameter)"))

    def __post_init__(self):
        for name in ("scene", "method", "frame_id", "node_name"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value:
                raise ValueError(f"parameter {name!r}: must be a non-empty string, got {value!r}")
        if not isinstance(self.log_path, str):
            raise ValueError(f"parameter 'log_path': must be a string, got {self.log_path!r}")
        if self.solver not in ("auto", "", *SOLVERS):
            raise ValueError(f"parameter 'solver': must be one of {', '.join(SOLVERS)}, auto or empty, got "
                             f"{self.solver!r}")
        if (isinstance(self.thread_priority, bool) or not isinstance(self.thread_priority, numbers.Integral)
                or not 0 <= self.thread_priority <= MAX_THREAD_PRIORITY):
            raise ValueError(f"parameter 'thread_priority': must be an integer from 0 to {MAX_THREAD_PRIORITY}, got "
                             f"{describe(self.thread_priority)}")
        object.__setattr__(self, "thread_priority", int(self.thread_priority))
        if not isinstance(self.lockstep, bool):
            raise ValueError(f"parameter 'lockstep': must be true or false, got {describe(self.lockstep)}")
        if not self.node_name.startswith("/"):
            raise ValueError(f"parameter 'node_name': must be fully qualified (start with /), got "
                             f"{self.node_name!r}")
        for name, minimum, strict, maximum in (
                ("dt", 0.0, True, math.inf), ("step_rate", MIN_RATE, False, math.inf),
                ("publish_rate", MIN_RATE, False, math.inf), ("marker_rate", MIN_RATE, False, math.inf),
                ("real_time_factor", 0.0, False, MAX_REAL_TIME_FACTOR), ("max_rest_length_rate", 0.0, False, math.inf)):
            value = getattr(self, name)
            try:
                number = real(value, name)
            except ValueError:
                raise ValueError(f"parameter {name!r}: must be a finite number, got {describe(value)}") from None
            if number < minimum or (strict and number == minimum):
                raise ValueError(f"parameter {name!r}: must be {'>' if strict else '>='} {minimum:g}, got {value!r}")
            if number > maximum:
                raise ValueError(f"parameter {name!r}: must be <= {maximum:g}, got {value!r}")
            object.__setattr__(self, name, number)
        if self.dt < MIN_DT:
            raise ValueError(f"parameter 'dt': must be >= {MIN_DT:g} s (stamps are integer nanoseconds), got "
                             f"{self.dt!r}")
        if self.publish_rate * self.dt > 1.0 + 1e-12:
            raise ValueError(f"parameter 'publish_rate': must be at most 1/dt = {1.0 / self.dt:g} Hz (one "
                             f"publication per step), got {self.publish_rate!r}")
        # asked after every step (SimNodeLogic.publication_due): worked out once
        object.__setattr__(self, "_publish_every", max(1, int(round(1.0 / (self.publish_rate * self.dt)))))

    @property
    def publish_every(self) -> int:
        """Steps between two publications: ``round(1 / (publish_rate dt))``, at least 1."""
        return self._publish_every

    @property
    def markers_every(self) -> int:
        """Publications between two marker arrays: ``round(publish_rate / marker_rate)``, at least 1."""
        return max(1, int(round(self.publish_rate / self.marker_rate)))

    @property
    def qp_solver(self) -> str | None:
        """``Simulator(..., solver=)``: the backend named, or None for the method's default."""
        return None if self.solver in ("auto", "") else self.solver

    @property
    def parameters(self) -> dict:
        """The ROS parameters (every field but ``node_name``) and their values."""
        return {k: v for k, v in asdict(self).items() if k != "node_name"}


RUNTIME_PARAMETERS = tuple(f.name for f in fields(NodeSettings) if f.metadata.get("runtime"))

# the /diagnostics status of a failed step is named "<node name>: step failed" (the periodic one "...: stepping")
FAILURE_STATUS = "step failed"
