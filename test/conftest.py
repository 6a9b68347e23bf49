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


@pytest.fixture
def bungee():
    return ts.Scene.from_dict(bungee_dict())
