"""The ``tensegrity_sim`` ROS 2 node: rclpy wiring around :class:`~.node_logic.SimNodeLogic`.

The only module that imports rclpy. Everything the node does is in the node logic; this file declares
the parameters, creates the publishers, subscriptions, services and timers, and converts between ROS
callbacks and the logic's methods. Entry point: ``ros2 run tensegrity_sim sim_node`` (``main``).

Timers run on the steady clock, so the node never waits for the ``/clock`` it publishes itself (even
with ``use_sim_time``). SIGINT and SIGTERM stop the spin loop between callbacks; the log is then finished
and the summary printed.

Discovery: with Jazzy's defaults (``ROS_AUTOMATIC_DISCOVERY_RANGE`` unset, i.e. SUBNET) Fast DDS finds other
processes by multicast only, which a loopback without multicast (a laptop offline, a container, CI) does not
carry, so two processes on such a host never meet. Unless discovery is configured (any of
:data:`DISCOVERY_SETTINGS` set), the node adds this host as a static peer (``ROS_STATIC_PEERS=127.0.0.1``):
it then announces itself to the other processes on this host by unicast as well, and any ROS 2 process
here with default settings finds it; discovery on the network is unchanged (``msg_docs/dds.md``).
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import fields

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from std_srvs.srv import Trigger

from ..scene import load_scene
from ..simulator import Simulator
from . import messages as M
from .live import DIAGNOSTICS_PERIOD, StepperScheduling
from .log import LogRecorder, SignalLatch, log_file_path
from .node_logic import RUNTIME_PARAMETERS, SERVICES, TOPICS, NodeSettings, Qos, SimNodeLogic

__all__ = ["SimNode", "main"]

NODE_NAME = "tensegrity_sim"
# rclpy publishes every accepted parameter change itself (stamped by the node's clock, the value as set);
# the node logic's event, stamped with simulation time, goes to the log only
PUBLISHED_BY_RCLPY = {"parameter_events"}
DISCOVERY_SETTINGS = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY", "ROS_DISCOVERY_SERVER")


def _qos(q: Qos) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=q.depth,
                      reliability=ReliabilityPolicy.RELIABLE if q.reliability == "reliable"
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE if q.durability == "volatile"
                      else DurabilityPolicy.TRANSIENT_LOCAL)


class SimNode(Node):
    """Parameters, topics and services of ``msg_docs/``; behaviour in :class:`SimNodeLogic`."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        for f in fields(NodeSettings):
            if f.name != "node_name":
                # numbers typed dynamically so that "dt:=1" (an integer) is accepted; NodeSettings checks
                self.declare_parameter(f.name, f.default, ParameterDescriptor(
                    description=f.metadata["doc"], read_only=not f.metadata["runtime"],
                    dynamic_typing=isinstance(f.default, float)))
        values = {name: self.get_parameter(name).value for name in NodeSettings().parameters}
        settings = NodeSettings(**values, node_name=self.get_fully_qualified_name())
        sim = Simulator(load_scene(settings.scene), method=settings.method, dt=settings.dt,
                        solver=settings.qp_solver)
        self.logic = SimNodeLogic(sim, settings, transport=self._publish, clock=time.monotonic,
                                  logger=self.get_logger())
        self.recorder = None
        path = log_file_path(settings.log_path, sim.scene.name)
        if path is not None:
            self.recorder = LogRecorder(path, self.logic.channels(), self.logic.run_info())
            self.logic.recorder = self.recorder
        self._outputs = {
            key: self.create_publisher(M.message_class(spec.typename), spec.name, _qos(spec.qos))
            for key, spec in TOPICS.items() if spec.direction == "out" and key not in PUBLISHED_BY_RCLPY}
        for key, spec in TOPICS.items():
            if spec.direction == "in":
                self.create_subscription(M.message_class(spec.typename), spec.name,
                                         lambda msg, key=key: self.logic.receive(key, msg), _qos(spec.qos))
        for name, method in SERVICES.items():
            action = getattr(self.logic, method)
            self.create_service(Trigger, f"~/{name}",
                                lambda request, response, action=action: self._answer(action, response))
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(1.0 / settings.step_rate, self.logic.tick, clock=steady)
        self.create_timer(DIAGNOSTICS_PERIOD, self.logic.publish_diagnostics, clock=steady)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f"scene {sim.scene.name}: {sim.method_reason}; dt {sim.dt:g} s, publishing every "
            f"{settings.publish_every} steps, real-time factor {settings.real_time_factor:g}; "
            f"log: {path if path is not None else 'off'}")

    def _publish(self, key: str, message) -> None:
        if key not in PUBLISHED_BY_RCLPY:
            self._outputs[key].publish(message)

    @staticmethod
    def _answer(action, response):
        response.success, response.message = action()
        return response

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        changes = {p.name: p.value for p in parameters if p.name in RUNTIME_PARAMETERS}
        try:
            self.logic.update(**changes)
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def close(self) -> None:
        """Finish the log and print the summary (on every way out of ``main``)."""
        if self.recorder is not None:
            self.recorder.finish()
        summary = self.logic.summary()
        if self.recorder is not None:
            summary += [f"{'log':<27} {p}" for p in self.recorder.paths]
        print("\n".join(summary), flush=True)


def peer_on_this_host(environ=os.environ) -> bool:
    """Add ``ROS_STATIC_PEERS=127.0.0.1`` to ``environ`` unless one of :data:`DISCOVERY_SETTINGS` is set
    (see the module's docstring); True if added."""
    if any(environ.get(name) for name in DISCOVERY_SETTINGS):
        return False
    environ["ROS_STATIC_PEERS"] = "127.0.0.1"
    return True


def main(args=None) -> None:
    """``ros2 run tensegrity_sim sim_node``. rclpy's own signal handlers are off: SIGINT and SIGTERM only
    latch, and the spin loop stops between callbacks, so the log is never cut inside a write. (Plain
    ``init``/``try_shutdown`` rather than ``with rclpy.init()``, which not every Jazzy rclpy has.)"""
    peer_on_this_host()  # before rclpy.init, which reads it
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:  # rcl's RCLError: ROS arguments it cannot parse (e.g. "-p log_path:=")
        print(f"sim_node: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    node = None
    try:
        with SignalLatch() as latch:
            node = SimNode()
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            scheduling = StepperScheduling(node.logic.settings.thread_priority, node.get_logger())
            try:
                while rclpy.ok():
                    scheduling.follow(node.logic.settings.real_time_factor > 0.0)
                    executor.spin_once(timeout_sec=0.1)
                    latch.raise_if_signalled()
            finally:
                scheduling.restore()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass  # SIGTERM raises SystemExit(143) through here, after the log is finished below
    except (ValueError, OSError) as exc:  # a bad parameter or scene, an unwritable log: say which, exit 2
        print(f"sim_node: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
