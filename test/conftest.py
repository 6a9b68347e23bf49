"""Shared scene builders for the tests (small analytic scenes built as dicts)."""
import numpy as np
import pytest

import tensegrity_sim as ts


def bungee_dict(k=100.0, m=1.0, rest=1.0, drop=0.5, g=9.81, damping=0.0):
    """A mass hanging on one tension-only cable from a fixed anchor at the origin, released at rest
    ``drop`` m below the anchor (so it falls freely before the cable snaps taut)."""
    return {
        "name": "bungee",
        "gravity": [0.0, 0.0, -g],
        "nodes": [
            {"name": "anchor", "position": [0.0, 0.0, 0.0], "fixed": True},
            {"name": "mass", "position": [0.0, 0.0, -drop], "mass": m},
        ],
        "cables": [{"name": "c", "nodes": ["anchor", "mass"], "stiffness": k, "rest_length": rest,
                    "damping": damping}],
    }


def deadband_dict(k=50.0, m=2.0, half_gap=1.0, slack=0.1, v0=0.5):
    """A mass between two fixed anchors on the x axis, each cable slack by ``slack`` at the centre."""
    return {
        "name": "deadband",
        "nodes": [
            {"name": "left", "position": [-half_gap, 0.0, 0.0], "fixed": True},
            {"name": "mass", "position": [0.0, 0.0, 0.0], "mass": m, "velocity": [v0, 0.0, 0.0]},
            {"name": "right", "position": [half_gap, 0.0, 0.0], "fixed": True},
        ],
        "cables": [
            {"name": "cl", "nodes": ["left", "mass"], "stiffness": k, "rest_length": half_gap + slack},
            {"name": "cr", "nodes": ["mass", "right"], "stiffness": k, "rest_length": half_gap + slack},
        ],
    }


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
