"""The rclpy node, where ROS 2 is installed (skipped only where rclpy cannot be imported): it publishes
the contract's topics, refuses bad input, answers its services and leaves a log that replays."""
import time

import pytest
import yaml

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from tensegrity_sim.ros.rclpy_node import SimNode  # noqa: E402
from tensegrity_sim.ros.replay import replay  # noqa: E402
from ros_helpers import prism_dict  # noqa: E402


@pytest.fixture
def ros(tmp_path):
    rclpy.init()
    scene = tmp_path / "prism.yaml"
    scene.write_text(yaml.safe_dump(prism_dict()))
    node = SimNode(parameter_overrides=[Parameter("scene", value=str(scene)),
                                        Parameter("method", value="elastic"),
                                        Parameter("log_path", value=str(tmp_path / "node.mcap"))])
    peer = rclpy.create_node("peer")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    executor.add_node(peer)
    yield node, peer, executor, tmp_path
    node.close()
    node.destroy_node()
    peer.destroy_node()
    rclpy.try_shutdown()


def spin_until(executor, done, timeout=10.0):
    end = time.monotonic() + timeout
    while not done() and time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    return done()


def test_node_publishes_refuses_and_serves(ros):
    node, peer, executor, tmp_path = ros
    poses, states = [], []
    peer.create_subscription(PoseArray, "/tensegrity_sim/node_poses", poses.append, 10)
    peer.create_subscription(JointState, "/tensegrity_sim/cable_states", states.append, 10)
    assert spin_until(executor, lambda: len(poses) >= 5 and len(states) >= 5)
    assert len(poses[-1].poses) == 6 and poses[-1].header.frame_id == "world"
    assert list(states[-1].name) == [f"c{k}" for k in range(9)]

    publisher = peer.create_publisher(JointState, "/tensegrity_sim/cable_rest_lengths", 10)
    assert spin_until(executor, lambda: publisher.get_subscription_count() > 0)
    publisher.publish(JointState(name=["nope"], position=[0.5]))
    assert spin_until(executor, lambda: node.logic.refused["cable_rest_lengths"] == 1)

    client = peer.create_client(Trigger, "/tensegrity_sim/pause")
    assert client.wait_for_service(timeout_sec=5.0)
    future = client.call_async(Trigger.Request())
    assert spin_until(executor, future.done)
    assert future.result().success and node.logic.paused
    steps = node.logic.sim.step_count
    spin_until(executor, lambda: False, timeout=0.2)
    assert node.logic.sim.step_count == steps

    node.close()
    assert replay(tmp_path / "node.mcap").ok


def test_this_host_is_a_static_peer_unless_discovery_is_configured():
    from tensegrity_sim.ros.rclpy_node import DISCOVERY_SETTINGS, peer_on_this_host

    environ = {"ROS_DOMAIN_ID": "3"}
    assert peer_on_this_host(environ) and environ == {"ROS_DOMAIN_ID": "3", "ROS_STATIC_PEERS": "127.0.0.1"}
    for name in DISCOVERY_SETTINGS:  # whatever the user set is left as it is
        environ = {name: "x"}
        assert not peer_on_this_host(environ) and environ == {name: "x"}


def test_unparsable_ros_arguments_are_an_error_not_a_traceback():
    from dds_child import spawn

    with spawn("-m", "tensegrity_sim.ros.rclpy_node", "--ros-args", "-p", "log_path:=") as node:
        _, err = node.communicate(timeout=60)
    assert node.returncode == 2
    assert "\nsim_node: error: " in err and "log_path" in err and "Traceback" not in err  # after rcl's own line
