"""The node live to Foxglove, without ROS (``tensegrity-sim serve --foxglove [PORT]``).

The same :class:`~tensegrity_sim.ros.node_logic.SimNodeLogic` as the rclpy and DDS nodes runs the
simulation; its outputs go out through the official ``foxglove-sdk`` WebSocket server (extra
``foxglove``), one channel per output topic with the node's topic name, message encoding ``cdr`` and a
``ros2msg`` schema: the very bytes and schemas the MCAP log holds, so Foxglove shows a live run and a
log alike and ``foxglove/tensegrity_sim.json`` lays out both. The server advertises the ``time``
capability and broadcasts the simulation time with every ``/clock``. Inputs are not taken here (use
the DDS or rclpy node to drive it); the run is stopped with Ctrl-C, which finishes the log.
"""
from __future__ import annotations

import logging
import time

import foxglove

from ..scene import load_scene
from ..simulator import Simulator
from . import messages as M
from .live import run_logged
from .log import SignalLatch, log_file_path
from .node_logic import TOPICS, NodeSettings, SimNodeLogic, resolve_topic

__all__ = ["DEFAULT_PORT", "FoxgloveTransport", "serve_foxglove"]

DEFAULT_PORT = 8765  # Foxglove's default for a WebSocket connection


class FoxgloveTransport:
    """The logic's raw output callback (``transport(key, data)``, CDR bytes) onto Foxglove channels.

    server: the :func:`foxglove.start_server` server, whose time follows ``/clock``; context: the
    ``foxglove.Context`` it was started with; node_name: the node's fully qualified name. Every message
    is logged at the simulation time of the latest ``/clock`` (a publication sends its clock first)."""

    def __init__(self, server, context, node_name: str):
        self._server = server
        self._time_ns = 0
        self.channels = {
            key: foxglove.Channel(resolve_topic(spec.name, node_name), message_encoding="cdr", context=context,
                                  schema=foxglove.Schema(name=spec.typename, encoding="ros2msg",
                                                         data=M.schema_text(spec.typename).encode()))
            for key, spec in TOPICS.items() if spec.direction == "out"}

    def __call__(self, key: str, data: bytes) -> None:
        if key == "clock":
            clock = M.deserialize(data, TOPICS["clock"].typename).clock
            self._time_ns = clock.sec * 1_000_000_000 + clock.nanosec
            self._server.broadcast_time(self._time_ns)
        self.channels[key].log(data, log_time=self._time_ns)

    def poll(self, logic: SimNodeLogic, log: logging.Logger) -> None:
        """No inputs come through Foxglove: nothing to take (what :func:`~.live.spin` asks of a transport)."""

    def wait(self, timeout: float) -> bool:
        """No inputs come through Foxglove: sleep ``timeout`` s (what :func:`~.live.spin` asks of a transport)."""
        time.sleep(timeout)
        return False


def serve_foxglove(settings: NodeSettings, *, port: int = DEFAULT_PORT, host: str = "127.0.0.1",
                   log: logging.Logger | None = None) -> None:
    """Run the node, streaming to Foxglove on ``ws://host:port`` (port 0: any free one, logged), until
    SIGINT or SIGTERM; then print the summary. However it ends, the log (if any) is finished and the
    server stopped."""
    log = log or logging.getLogger("tensegrity_sim")
    sim = Simulator(load_scene(settings.scene), method=settings.method, dt=settings.dt, solver=settings.qp_solver)
    path = log_file_path(settings.log_path, sim.scene.name)
    context = foxglove.Context()
    server = foxglove.start_server(name="tensegrity_sim", host=host, port=port, context=context,
                                   capabilities=[foxglove.Capability.Time])
    try:
        with SignalLatch() as latch:
            transport = FoxgloveTransport(server, context, settings.node_name)
            logic = SimNodeLogic(sim, settings, transport=transport, raw_transport=True, logger=log)
            run_logged(logic, transport, path, latch=latch, log=log,
                       serving=f"serving {sim.scene.name} ({sim.method}, dt = {sim.dt:g} s) to Foxglove on "
                               f"ws://{host}:{server.port}")
    except KeyboardInterrupt:
        pass  # Ctrl-C is how a server is stopped
    finally:
        server.stop()
