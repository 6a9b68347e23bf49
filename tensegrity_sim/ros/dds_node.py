"""The node over DDS, for machines without ROS 2 (``tensegrity-sim serve --transport dds``).

The same :class:`~tensegrity_sim.ros.node_logic.SimNodeLogic` as the rclpy node does all the work; this
module only carries its messages, on the same topics with the same types and QoS, through the
ROS-compatible DDS participant of :mod:`tensegrity_sim.ros.dds`, so a ROS 2 Jazzy machine on the same domain
and network sees and drives it like the rclpy node. What differs, because DDS alone cannot do it:

* **services**: a ROS 2 service pairs a request with its reply by a correlation id that each ROS
  middleware carries its own way (rmw_cyclonedds in a header inside the payload, rmw_fastrtps, Jazzy's
  default, in RTPS inline QoS that the Cyclone DDS Python binding cannot write), so a service offered
  here would answer some ROS machines and not others. The services are offered as a topic instead:
  ``~/command`` (std_msgs/msg/String) takes ``reset``, ``pause``, ``resume``, ``step`` and
  ``set NAME VALUE`` (a runtime parameter), and ``~/command_result`` (std_msgs/msg/String) answers each
  with ``"<command>: ok: <message>"`` or ``"<command>: failed: <message>"``.
* **parameters** are given at start (the command line); the runtime ones change with ``set``.
* **log output** goes to the Python logger (stderr), not to ``/rosout``.
* a sample that does not even decode is refused here with a logged reason (rmw drops those silently).
"""
from __future__ import annotations

import logging

from .dds import DEFAULT_INTERFACE, Participant, QosProfile, ros_peer_settings
from ..scene import load_scene
from ..simulator import Simulator
from . import messages as M
from .live import run_logged
from .log import SignalLatch, log_file_path
from .node_logic import RUNTIME_PARAMETERS, SERVICES, TOPICS, NodeSettings, Qos, SimNodeLogic, resolve_topic

__all__ = ["COMMAND_TOPIC", "RESULT_TOPIC", "DdsTransport", "run_command", "serve"]

COMMAND_TOPIC = "~/command"
RESULT_TOPIC = "~/command_result"
_STRING = "std_msgs/msg/String"


def qos_profile(qos: Qos) -> QosProfile:
    """The node logic's QoS as the DDS participant's."""
    return QosProfile(reliable=qos.reliability == "reliable", depth=qos.depth,
                      transient_local=qos.durability == "transient_local")


class DdsTransport:
    """Writers for the node's outputs, readers for its inputs and for ``~/command``.

    ``transport(key, data)`` is the logic's raw output callback (CDR bytes); :meth:`poll` feeds the logic
    what arrived, and :meth:`wait` waits for it.
    """

    def __init__(self, participant: Participant, node_name: str):
        self._participant = participant
        self.writers, self.readers = {}, {}
        for key, spec in TOPICS.items():
            make = participant.writer if spec.direction == "out" else participant.reader
            endpoints = self.writers if spec.direction == "out" else self.readers
            endpoints[key] = make(resolve_topic(spec.name, node_name), spec.typename, qos_profile(spec.qos))
        self.commands = participant.reader(resolve_topic(COMMAND_TOPIC, node_name), _STRING)
        self.results = participant.writer(resolve_topic(RESULT_TOPIC, node_name), _STRING)
        self.undecodable = 0

    def __call__(self, key: str, data: bytes) -> None:
        """The logic's raw transport: an output's CDR bytes, the very bytes the log records."""
        self.writers[key].write_cdr(data)

    def poll(self, logic: SimNodeLogic, log: logging.Logger) -> None:
        """Hand every input that arrived to the logic, and run every command, in arrival order per topic."""
        for key, reader in self.readers.items():
            for message in self._take(reader, log):
                logic.receive(key, message, decoded=True)
        for message in self._take(self.commands, log):
            self.results.write(M.new(_STRING, data=run_command(logic, message.data)))

    def wait(self, timeout: float) -> bool:
        """Block until an input or a command arrives or ``timeout`` s pass; True if one is there."""
        return self._participant.wait(timeout)

    def _take(self, reader, log: logging.Logger) -> list:
        """The messages a reader holds; each sample that does not decode is refused (logged, counted)."""
        messages, refused = reader.take_messages()
        self.undecodable += len(refused)
        for reason in refused:
            log.warning(f"{reader.topic}: refused: {reason}")  # as the node logic words a refusal
        return messages


def run_command(logic: SimNodeLogic, text: str) -> str:
    """Run one ``~/command`` and return its ``~/command_result`` text (see the module docstring)."""
    words = text.split()
    if len(words) == 1 and words[0] in SERVICES:
        ok, message = getattr(logic, SERVICES[words[0]])()
    elif len(words) == 3 and words[0] == "set":
        ok, message = _set_parameter(logic, words[1], words[2])
    else:
        ok, message = False, (f"unknown command (commands: {', '.join(SERVICES)}, "
                              f"set NAME VALUE with NAME in {', '.join(RUNTIME_PARAMETERS)})")
    return f"{text.strip()}: {'ok' if ok else 'failed'}: {message}"


def _set_parameter(logic: SimNodeLogic, name: str, text: str) -> tuple[bool, str]:
    """``set NAME VALUE``: what the rclpy node's set-parameters callback does, for a number."""
    if name not in logic.settings.parameters:
        return False, f"unknown parameter {name!r} (runtime parameters: {', '.join(RUNTIME_PARAMETERS)})"
    try:
        value = float(text)
    except ValueError:
        return False, f"parameter {name!r}: not a number: {text!r}"
    try:
        logic.update(**{name: value})
    except ValueError as exc:
        return False, str(exc)
    return True, f"{name} = {getattr(logic.settings, name)!r}"


def serve(settings: NodeSettings, *, domain_id: int = 0, interface: str = DEFAULT_INTERFACE,
          log: logging.Logger | None = None) -> None:
    """Run the node over DDS until SIGINT or SIGTERM, then print the summary, as the rclpy node does:
    SIGINT returns, SIGTERM leaves as ``SystemExit(143)``. However it ends, the log (if any) is finished
    and every DDS entity is deleted."""
    log = log or logging.getLogger("tensegrity_sim")
    sim = Simulator(load_scene(settings.scene), method=settings.method, dt=settings.dt, solver=settings.qp_solver)
    namespace, _, name = settings.node_name.rpartition("/")
    path = log_file_path(settings.log_path, sim.scene.name)
    try:
        with SignalLatch() as latch, Participant(domain_id=domain_id, interface=interface, node_name=name,
                                                 namespace=namespace or "/") as dds:
            transport = DdsTransport(dds, settings.node_name)
            logic = SimNodeLogic(sim, settings, transport=transport, raw_transport=True, logger=log)
            peer = ros_peer_settings(interface, domain_id)
            notes = () if peer is None else (
                f"ROS 2 processes on this host see it with {peer} (or ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST): "
                f"Jazzy's default discovery needs multicast, which loopback does not carry (msg_docs/dds.md)",)
            run_logged(logic, transport, path, latch=latch, log=log,
                       serving=f"serving {sim.scene.name} ({sim.method}, dt = {sim.dt:g} s) over DDS on domain "
                               f"{domain_id}, interface {interface}", notes=notes,
                       extra=lambda: [f"{'undecodable_samples':<27} {transport.undecodable}"])
    except KeyboardInterrupt:
        pass  # Ctrl-C is how a server is stopped
