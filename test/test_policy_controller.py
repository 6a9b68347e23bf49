"""examples/policy_controller.py (issue 50): the shipped gait (examples/gait.yaml, optimize-gait's CMA-ES) and the
shipped policy (examples/policies/roll_icosahedron.npz, examples/train_roll.py's PPO) played through the node's
logic, and over DDS to the live node, as cable_rest_lengths messages roll the robot along the goal (+x)."""
import ast
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

import tensegrity_sim as ts
from tensegrity_sim.commands import load_commands

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))
import policy_controller as pc  # noqa: E402

GAIT = ROOT / "examples" / "gait.yaml"
POLICY = ROOT / "examples" / "policies" / "roll_icosahedron.npz"


def test_player_gives_the_schedules_rest_lengths():
    scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(GAIT, scene)
    player = pc.GaitPlayer(schedule, scene)
    for t in (0.0, 0.37, 1.5, 5.99, 30.0):
        expected = schedule.rest_lengths_at(t, scene.cable_rest_lengths)
        assert player.update(t) == {n: expected[i] for i, n in enumerate(scene.cable_names)}


@pytest.fixture(scope="module")
def offline():
    """The displacement (3,) m each shipped controller gives through the node's logic in this process, by name."""
    scene = ts.load_scene("icosahedron_ground")
    return {"gait": pc.drive_offline(pc.load_player(scene, gait=str(GAIT)), 6.0),
            "policy": pc.drive_offline(pc.load_player(scene, policy=str(POLICY)), 10.0, rate=None)}


def test_gait_through_the_node_rolls_along_the_goal(offline):
    """Offline the gait rolls 5.15 m along +x in 6 s (run --commands: the rest lengths ramped every step); the
    node's 50 Hz commands hold each value for 20 ms, and the robot still rolls over 3 m along +x."""
    moved = offline["gait"]
    assert moved[0] > 3.0, moved
    assert abs(moved[2]) < 0.3 and np.all(np.isfinite(moved))


LOCKSTEP = ("--lockstep", "--real-time-factor", "0")   # each publication waits for its answer; no schedule


def over_dds(tmp_path, *controller: str, node: tuple[str, ...] = ()) -> np.ndarray:
    """``serve --transport dds`` (with the options ``node``) and ``policy_controller.py *controller`` in separate
    processes: the centre of mass's displacement (3,) m the controller printed."""
    pytest.importorskip("cyclonedds")   # the dds extra (CI's first leg installs it)
    from dds_child import random_domain, spawn

    domain = str(random_domain())
    with spawn("-m", "tensegrity_sim.cli", "serve", "icosahedron_ground", "--method", "elastic", "--transport", "dds",
               "--domain-id", domain, "--log-path", str(tmp_path / "run.mcap"), *node, timeout=30) as server:
        try:
            with spawn("examples/policy_controller.py", *controller, "--domain-id", domain, timeout=60) as child:
                out, err = child.communicate(timeout=90)
            assert child.returncode == 0, err
        finally:
            server.send_signal(signal.SIGINT)
    return np.array(ast.literal_eval(out.split("moved ")[1].split(" m")[0]))


def test_gait_over_dds_moves_the_live_node_as_offline(tmp_path, offline):
    """The gait over DDS to the live node in lockstep (as fast as the answers come): the centre of mass the
    controller sees moves as through the node's logic in one process (to the 0.1 mm it prints), over 3 m along
    +x, however late the commands land."""
    moved = over_dds(tmp_path, "--gait", str(GAIT), "--seconds", "6", node=LOCKSTEP)
    assert np.max(np.abs(moved - offline["gait"])) <= 5.1e-5, (moved, offline["gait"])


def test_policy_file_gives_the_actions_flax_gave():
    """The numpy MLP of the controller against the actor (flax, rejax's network) that wrote the file: its mean
    actions for the 16 observations the file keeps (examples/train_roll.py's check_pairs)."""
    policy = pc.MlpPolicy(str(POLICY))
    with np.load(POLICY) as f:
        obs, actions = f["check_obs"], f["check_actions"]
    got = np.array([policy(o) for o in obs])
    assert np.max(np.abs(got - actions)) < 1e-9
    assert np.ptp(actions) > 0.1   # not a constant policy


def test_policy_player_observes_and_reels_as_the_environment():
    """The player's first observation (a robot at rest) is ``Roll-v0``'s at a reset without noise, and the motors'
    positions it reaches in a control period are the environment's after the same action (to 1e-12)."""
    from tensegrity_sim.envs import RollEnv

    scene = ts.load_scene("icosahedron_ground")
    player = pc.load_player(scene, policy=str(POLICY))
    env = RollEnv(control_dt=player.control_dt, episode_seconds=1.0)
    obs, _ = env.reset(seed=0, options={"noise": 0.0})
    x = env.task.sim.positions[0].copy()
    assert np.max(np.abs(player.observe(x, np.zeros_like(x)) - obs)) < 1e-12
    first = player.update(0.0, x)
    env.step(player.policy(obs))
    after = env.task.sim.rest_lengths[0, env.task.actuated]
    assert np.max(np.abs(player.rest - after)) < 1e-12
    moved = np.abs(after - scene.cable_rest_lengths)
    assert moved.max() > 0.5 * player.reel_speed * player.control_dt   # some motor reeled at full speed
    assert first == dict(zip(player.names, scene.cable_rest_lengths.tolist()))   # at t = 0 nothing has moved yet


def test_policy_through_the_node_rolls_along_the_goal(offline):
    """The trained policy through the node's logic (the DDS loop's 100 Hz poses, in one process): its centre of
    mass moves over 3 m along +x in 10 s (measured 6.48 m; the roll controller 2.61 m)."""
    assert offline["policy"][0] > 3.0, offline["policy"]


def test_policy_over_dds_moves_the_live_node_as_offline(tmp_path, offline):
    """The trained policy over DDS to the live node in lockstep: the centre moves as offline (to the 0.1 mm the
    controller prints), over 3 m along +x in 10 s. Without lockstep, on CI's loaded machine, the commands of a
    run in real time landed late enough that the robot rolled 1.9 m along -x instead (a policy trained with
    commands that act at once): what lockstep is for."""
    moved = over_dds(tmp_path, "--policy", str(POLICY), "--seconds", "10", node=LOCKSTEP)
    assert np.max(np.abs(moved - offline["policy"])) <= 5.1e-5, (moved, offline["policy"])


def test_controller_refuses_a_file_that_is_no_policy(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    np.savez(bad, weights=np.zeros(3))
    assert pc.main(["--policy", str(bad), "--offline", "--seconds", "0.1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a policy file" in err and str(bad) in err
