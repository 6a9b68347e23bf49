"""Shared scene builders for the tests (small analytic scenes built as dicts)."""
import numpy as np
import pytest

import tensegrity_sim as ts
from bench.analytic import bungee_dict, deadband_dict  # noqa: F401  (re-exported to the tests)


def random_velocities(scene: ts.Scene, seed: int, scale: float = 1.0) -> ts.Scene:
    """The same scene with random initial velocities on every free node."""
    rng = np.random.default_rng(seed)
    d = scene.to_dict()
    for node in d["nodes"]:
        if not node["fixed"]:
            node["velocity"] = list(rng.normal(scale=scale, size=3))
    return ts.Scene.from_dict(d)


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
