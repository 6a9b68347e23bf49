"""examples/policy_controller.py (issue 50): the shipped gait (examples/gait.yaml, optimize-gait's CMA-ES) played
through the node's logic as cable_rest_lengths messages at 50 Hz rolls the robot along the goal (+x)."""
import sys
from pathlib import Path

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim.commands import load_commands

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))
import policy_controller as pc  # noqa: E402

GAIT = ROOT / "examples" / "gait.yaml"


def test_player_gives_the_schedules_rest_lengths():
    scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(GAIT, scene)
    player = pc.GaitPlayer(schedule, scene)
    for t in (0.0, 0.37, 1.5, 5.99, 30.0):
        expected = schedule.rest_lengths_at(t, scene.cable_rest_lengths)
        assert player.update(t) == {n: expected[i] for i, n in enumerate(scene.cable_names)}


def test_gait_through_the_node_rolls_along_the_goal():
    """Offline the gait rolls 5.15 m along +x in 6 s (run --commands: the rest lengths ramped every step); the
    node's 50 Hz commands hold each value for 20 ms, and the robot still rolls over 3 m along +x."""
    moved = pc.drive_offline(str(GAIT), 6.0)
    assert moved[0] > 3.0, moved
    assert abs(moved[2]) < 0.3 and np.all(np.isfinite(moved))
