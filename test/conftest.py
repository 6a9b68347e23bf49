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

``TENSEGRITY_SIM_REQUIRE_RCLPY=1`` (CI's ROS leg sets it) makes a missing rclpy or colcon an error instead
of skipping the rclpy tests and the colcon workspace's (test/test_colcon.py).
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
    try:
        import colcon_core  # noqa: F401
        import colcon_ros  # noqa: F401
    except ImportError as exc:
        pytest.exit(f"TENSEGRITY_SIM_REQUIRE_RCLPY=1 but colcon does not import (the colcon extra): {exc}",
                    returncode=3)


def random_velocities(scene: ts.Scene, seed: int, scale: float = 1.0) -> ts.Scene:
    """The same scene with random initial velocities on every free node."""
    rng = np.random.default_rng(seed)
    d = scene.to_dict()
    for node in d["nodes"]:
        if not node["fixed"]:
            node["velocity"] = list(rng.normal(scale=scale, size=3))
    return ts.Scene.from_dict(d)


def record_advances(sim: ts.Simulator) -> list[tuple[int, int]]:
    """The calls of ``sim``'s method's compiled loop from now on, as they happen: (the step count they start
    from, the steps they compute)."""
    calls = []
    advance = sim._method.advance

    def counted(state, steps, *args, **kwargs):
        calls.append((state.step_count, steps))
        return advance(state, steps, *args, **kwargs)

    sim._method.advance = counted
    return calls


def class_k_dict():
    """Two rigid struts sharing node b (class-k) and a cable closing the triangle, all moving."""
    return {"nodes": [{"name": "a", "position": [0, 0, 0], "mass": 1.0, "velocity": [0, 1, 0]},
                      {"name": "b", "position": [1, 0, 0], "mass": 2.0, "velocity": [0, 0, 1]},
                      {"name": "c", "position": [1, 1, 0], "mass": 1.5, "velocity": [1, 0, 0]}],
            "struts": [{"name": "s0", "nodes": ["a", "b"], "stiffness": "rigid"},
                       {"name": "s1", "nodes": ["b", "c"], "stiffness": "rigid"}],
            "cables": [{"name": "c0", "nodes": ["a", "c"], "stiffness": 100.0, "rest_length": 1.2}]}


@pytest.fixture
def bungee():
    return ts.Scene.from_dict(bungee_dict())
