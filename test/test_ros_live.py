"""Real ROS 2 against the live node, each in its own process (the ROS leg of CI; skipped only where rclpy
cannot be imported): this test process is an ordinary rclpy process (Fast DDS) that drives

* ``sim_node`` (the rclpy node) in a process of its own: its topics arrive at the publish rate (in
  simulated time), a rest-length
  command changes a cable's tension as the elastic law says, ``pause``/``step``/``resume``/``reset`` answer
  and act, a runtime parameter is set and a bad one refused with its reason, SIGINT ends it cleanly and its
  log (written under rclpy) replays bit for bit and opens in rosbags;
* ``tensegrity-sim serve --transport dds`` (Cyclone DDS, no rclpy in that process): its topics arrive at the
  publish rate and a real rclpy publisher's rest-length command and ``~/command`` are obeyed.

Every wait is bounded; every process is stopped on the way out (``dds_child.spawn``). The domain and the
discovery range are the test process's own (conftest.py).
"""
import contextlib
import signal
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402
from rosbags.rosbag2 import Reader as RosbagsReader  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

import tensegrity_sim as ts  # noqa: E402
from dds_child import NODE, NODE_INPUTS, NODE_OUTPUTS, spawn  # noqa: E402
from tensegrity_sim.ros import messages as M  # noqa: E402
from tensegrity_sim.ros.messages import TYPESTORE  # noqa: E402
from tensegrity_sim.ros.replay import replay  # noqa: E402

PRISM = ts.load_scene("prism3")  # at rest in its own equilibrium: tensions constant until commanded
RATE = 100.0  # Hz, the node's default publish rate (dt 1 ms, every 10 steps)
STREAMS = ("clock", "node_poses", "cable_states", "cable_impulses")


class Driver:
    """An rclpy node in this process that records every output of the node as (message, monotonic s)."""

    def __init__(self):
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("live_driver", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.got = {key: [] for key in (*STREAMS, "command_result")}
        for key in self.got:
            topic, typename = NODE_OUTPUTS[key]
            self.node.create_subscription(M.message_class(typename), topic,
                                          lambda m, key=key: self.got[key].append((m, time.monotonic())),
                                          QoSProfile(depth=100))  # reliable: nothing lost while spinning

    def spin_until(self, done, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while not done() and time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.02)
        return done()

    def publisher(self, key: str):
        topic, typename = NODE_INPUTS[key]
        pub = self.node.create_publisher(M.message_class(typename), topic, 10)
        assert self.spin_until(lambda: pub.get_subscription_count() > 0, 20), f"no one subscribes to {topic}"
        return pub

    def call(self, client, request, timeout: float = 10.0):
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout), f"{client.srv_name}: no answer in {timeout} s"
        return future.result()

    def close(self):
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def driver():
    d = Driver()
    yield d
    d.close()


@contextlib.contextmanager
def running(*args: str):
    """``python *args`` in its own process, stopped with SIGINT on the way out (killed if it hangs)."""
    with spawn(*args, timeout=30) as proc:
        try:
            yield proc
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)


def finish(proc) -> tuple[str, str]:
    """SIGINT, then the process must finish by itself (log closed, summary printed) with status 0."""
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    return out, err


def stamp_ns(msg) -> int:
    stamp = msg.clock if hasattr(msg, "clock") else msg.header.stamp
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def check_streams_at_rate(driver, rate: float = RATE, count: int = 30) -> None:
    """The next ``count`` messages of every stream arrive (bounded wait) at the publish rate in simulated
    time: consecutive stamps one period apart, or a whole number of periods where a sample was superseded
    in a history (at most a few, on a loaded machine). Speed in wall-clock time depends on the machine
    and is not asserted (bench/bench_dds.py measures it)."""
    first = {k: len(driver.got[k]) for k in STREAMS}
    assert driver.spin_until(lambda: all(len(driver.got[k]) >= first[k] + count for k in STREAMS), 60), \
        {NODE_OUTPUTS[k][0]: len(driver.got[k]) - first[k] for k in STREAMS}
    period = round(1e9 / rate)
    for key in STREAMS:
        gaps = np.diff([stamp_ns(m) for m, _ in driver.got[key][first[key]:]])
        periods = np.round(gaps / period)
        assert np.all(periods >= 1) and np.all(np.abs(gaps - periods * period) < 1e3), (key, gaps.tolist())
        assert np.median(periods) == 1, (key, gaps.tolist())


def until_answered(driver, send, answered, timeout: float = 20.0) -> bool:
    """``send()`` every 0.5 s until ``answered()`` (bounded). A new publisher's first samples can be lost:
    its side may match the node's subscription before the node's side has matched it, and a volatile
    subscription takes nothing sent before that. So the first command is repeated; it must be idempotent."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        send()
        if driver.spin_until(answered, min(0.5, end - time.monotonic())):
            return True
    return False


def check_rest_length_command(driver, publisher) -> None:
    """Shortening c0 by 10 % raises its tension from k (l - L0) to k (l - 0.9 L0) (the elastic law)."""
    k, rest = PRISM.cables[0].stiffness, PRISM.cables[0].rest_length
    before = [m for m, _ in driver.got["cable_states"][-20:]]
    for m in before:
        assert m.effort[0] == pytest.approx(k * (m.position[0] - rest), rel=1e-3)
    highest = max(m.effort[0] for m in before)
    n = len(driver.got["cable_states"])
    command = M.joint_state(M.header(0, ""), ["c0"], [0.9 * rest])
    raised = lambda: [m for m, _ in driver.got["cable_states"][n:] if m.effort[0] > highest + 0.05 * k * rest]
    assert until_answered(driver, lambda: publisher.publish(command), raised), "the command did nothing"
    m = raised()[0]
    assert m.effort[0] == pytest.approx(k * (m.position[0] - 0.9 * rest), rel=0.05)


def check_log(path) -> None:
    """A log the live node wrote: it replays bit for bit and rosbags reads and decodes every message."""
    assert replay(path).ok
    with RosbagsReader(path) as reader:
        count = 0
        for connection, _, data in reader.messages():
            TYPESTORE.deserialize_cdr(data, connection.msgtype)
            count += 1
        assert count == reader.message_count > 0


def test_sim_node_process_driven_by_rclpy(driver, tmp_path):
    log = tmp_path / "node.mcap"
    with running("-m", "tensegrity_sim.ros.rclpy_node", "--ros-args", "-p", "scene:=prism3",
                 "-p", f"log_path:={log}") as node:
        assert driver.spin_until(lambda: "tensegrity_sim" in driver.node.get_node_names(), 30), \
            "sim_node never appeared in the graph"
        check_streams_at_rate(driver)
        check_rest_length_command(driver, driver.publisher("cable_rest_lengths"))

        clients = {name: driver.node.create_client(Trigger, f"{NODE}/{name}")
                   for name in ("pause", "step", "resume", "reset")}
        assert all(c.wait_for_service(timeout_sec=10) for c in clients.values())
        answer = driver.call(clients["pause"], Trigger.Request())
        assert answer.success and answer.message.startswith("paused at t = ")
        paused_at = round(float(answer.message.split()[-2]) * 1e9)
        driver.spin_until(lambda: False, 0.1)  # publications in flight
        n = len(driver.got["clock"])
        driver.spin_until(lambda: False, 0.3)
        assert len(driver.got["clock"]) == n and stamp_ns(driver.got["clock"][-1][0]) <= paused_at  # nothing steps
        answer = driver.call(clients["step"], Trigger.Request())
        assert answer.success and answer.message == f"stepped to t = {(paused_at + 1_000_000) * 1e-9:.6f} s"
        assert driver.spin_until(lambda: stamp_ns(driver.got["node_poses"][-1][0]) == paused_at + 1_000_000, 5)
        assert driver.call(clients["resume"], Trigger.Request()).success
        assert driver.spin_until(lambda: stamp_ns(driver.got["clock"][-1][0]) > paused_at + 0.1e9, 10)
        answer = driver.call(clients["reset"], Trigger.Request())
        assert answer.success and answer.message.startswith("reset to the scene's initial state")
        n = len(driver.got["node_poses"])
        assert driver.spin_until(lambda: any(stamp_ns(m) < paused_at for m, _ in driver.got["node_poses"][n:]), 10)
        k = n + next(i for i, (m, _) in enumerate(driver.got["node_poses"][n:]) if stamp_ns(m) < paused_at)
        poses = driver.got["node_poses"][k][0].poses
        np.testing.assert_allclose([[p.position.x, p.position.y, p.position.z] for p in poses], PRISM.positions,
                                   atol=1e-2)  # back at the start, a few ms in

        parameters = driver.node.create_client(SetParameters, f"{NODE}/set_parameters")
        assert parameters.wait_for_service(timeout_sec=10)
        bad = driver.call(parameters, SetParameters.Request(
            parameters=[Parameter("publish_rate", value=-5.0).to_parameter_msg()])).results[0]
        assert not bad.successful and "publish_rate" in bad.reason
        good = driver.call(parameters, SetParameters.Request(
            parameters=[Parameter("publish_rate", value=50.0).to_parameter_msg()])).results[0]
        assert good.successful, good.reason
        driver.spin_until(lambda: False, 0.2)  # publications in flight at the old rate
        check_streams_at_rate(driver, rate=50.0, count=10)
        out, _ = finish(node)
    logs = [line.split(None, 1)[1] for line in out.splitlines() if line.startswith("log ")]
    assert logs == [str(log), str(tmp_path / "node_reset1.mcap")]
    for path in logs:
        check_log(path)


def test_dds_transport_seen_from_rclpy_both_ways(driver, tmp_path):
    log = tmp_path / "dds.mcap"
    with running("-m", "tensegrity_sim.cli", "serve", "prism3", "--transport", "dds", "--log-path", str(log),
                 "--domain-id", str(driver.context.get_domain_id())) as server:
        check_streams_at_rate(driver)
        check_rest_length_command(driver, driver.publisher("cable_rest_lengths"))
        command = driver.publisher("command")
        n = len(driver.got["command_result"])  # a no-op change until the node hears this publisher
        no_op = M.new("std_msgs/msg/String", data="set publish_rate 100")
        assert until_answered(driver, lambda: command.publish(no_op), lambda: len(driver.got["command_result"]) > n)
        assert driver.got["command_result"][n][0].data.startswith("set publish_rate 100: ok")
        for text, answer in (("pause", "pause: ok: paused at t = "),
                             ("set publish_rate -5", "set publish_rate -5: failed: "),
                             ("resume", "resume: ok: resumed at t = ")):
            n = len(driver.got["command_result"])
            command.publish(M.new("std_msgs/msg/String", data=text))
            results = lambda: [m.data for m, _ in driver.got["command_result"][n:] if m.data.startswith(f"{text}: ")]
            assert driver.spin_until(results, 10), f"no answer to {text!r}"
            assert results()[0].startswith(answer), results()
        out, err = finish(server)
    assert "refused_rest_lengths        0" in out
    assert f"see it with ROS_DOMAIN_ID={driver.context.get_domain_id()} ROS_STATIC_PEERS=127.0.0.1" in err  # banner
    check_log(log)
