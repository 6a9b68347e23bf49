"""Shared scene builders for the tests (small analytic scenes built as dicts), and the test process's ROS 2
environment.

ROS domain: every test process (each pytest run, each xdist worker) takes its own ROS domain id when this
file is imported, before any test creates a participant: :func:`ros_env.free_domain` starts at a random id
in 1..100 and takes the first one whose RTPS discovery ports on this host are free, so that a ROS process or
another test run on the machine is never heard. It goes into ``ROS_DOMAIN_ID``, which rclpy in this process
and every process a test starts inherit; the DDS tests that start their own participants pick a fresh free
id per test the same way (``dds_child.random_domain``). Discovery is set to this host only
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``; ``ROS_STATIC_PEERS`` and Fast DDS / Cyclone profile files
are dropped), so the tests depend neither on the machine's domain or discovery settings nor on multicast,
and send nothing beyond the loopback.

``TENSEGRITY_SIM_REQUIRE_RCLPY=1`` (CI's ROS leg sets it) makes a missing rclpy an error instead of
skipping the rclpy tests.
"""
import os

import numpy as np
import pytest

import tensegrity_sim as ts
from bench.analytic import bungee_dict, deadband_dict  # noqa: F401  (re-exported to the tests)
from ros_env import isolate

ROS_DOMAIN_ID = isolate()

if os.environ.get("TENSEGRITY_SIM_REQUIRE_RCLPY") == "1":
    try:
        import rclpy  # noqa: F401
    except ImportError as exc:
        pytest.exit(f"TENSEGRITY_SIM_REQUIRE_RCLPY=1 but rclpy does not import: {exc}", returncode=3)


def random_velocities(scene: ts.Scene, seed: int, scale: float = 1.0) -> ts.Scene:
    """The same scene with random initial velocities on every free node."""
    rng = np.random.default_rng(seed)
    d = scene.to_dict()
    for node in d["nodes"]:
        if not node["fixed"]:
            node["velocity"] = list(rng.normal(scale=scale, size=3))
    return ts.Scene.from_dict(d)


@pytest.fixture
def bungee():
    return ts.Scene.from_dict(bungee_dict())
