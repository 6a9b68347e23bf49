"""tensegrity_sim.envs: Gymnasium's checker passes; the vector environment is N single environments (same seeds and
actions, 1e-12); the reel and the reward against a plain Simulator stepped by hand; a refused copy ends its episode
truncated with the reason; bad input gets a clear error and changes nothing."""
import warnings

import numpy as np
import pytest

import gymnasium as gym
from gymnasium.utils.env_checker import check_env

import tensegrity_sim as ts
from tensegrity_sim.envs import ROLL_ID, RollEnv, RollVectorEnv

SHORT = dict(episode_seconds=0.1, noise=0.05)   # 5 control periods: a test sees resets


def test_check_env_and_render():
    env = gym.make(ROLL_ID, render_mode="rgb_array", episode_seconds=0.2)
    assert isinstance(env.unwrapped, RollEnv)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the observations' infinite bounds: Gymnasium's warning, not a failure
        check_env(env.unwrapped)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (320, 320, 3) and frame.dtype == np.uint8 and frame.std() > 0


def test_vector_equals_single_environments():
    n = 3
    vec = gym.make_vec(ROLL_ID, num_envs=n, vectorization_mode="vector_entry_point", **SHORT)
    assert isinstance(vec, RollVectorEnv)
    singles = [RollEnv(**SHORT) for _ in range(n)]
    obs, _ = vec.reset(seed=7)
    for i, env in enumerate(singles):
        o, _ = env.reset(seed=7 + i)
        assert np.array_equal(o, obs[i])
    rng = np.random.default_rng(3)
    ended = np.zeros(n, dtype=bool)
    resets = 0
    for _ in range(12):
        actions = rng.uniform(-1, 1, (n, vec.single_action_space.shape[0]))
        obs, rewards, terminated, truncated, _ = vec.step(actions)
        assert not terminated.any()
        for i, env in enumerate(singles):
            if ended[i]:   # NEXT_STEP autoreset: this step is the copy's reset
                o, r, tr = env.reset()[0], 0.0, False
                resets += 1
            else:
                o, r, _, tr, _ = env.step(actions[i])
            np.testing.assert_allclose(obs[i], o, rtol=0, atol=1e-12)
            assert abs(rewards[i] - r) <= 1e-12 and truncated[i] == tr
        ended = truncated
    assert resets == 2 * n   # 12 steps of 5-period episodes: two autoresets per copy
    listed, _ = vec.reset(seed=[7, 8, 9])   # one seed per copy: the same as seed=7
    assert np.array_equal(listed, RollVectorEnv(n, **SHORT).reset(seed=7)[0])


def test_reel_and_reward_against_a_plain_simulator():
    """Action -1 on c4: its rest length goes down reel_speed dt a step (the motor), the other cables hold; the
    Simulator stepped with those rest lengths by hand gives the same states (1e-10, as test_batch.py's batch
    against Simulator), and the rewards add up to the centre of mass's progress minus the effort."""
    env = RollEnv(cables=["c4", "c5"], noise=0.0, reel_speed=0.5, effort_cost=0.3, goal=(0.0, 2.0))
    obs, info = env.reset(seed=0)
    sim = ts.Simulator(env.task.scene, method="elastic", dt=1e-3, contacts=())
    rest = env.task.scene.cable_rest_lengths.copy()
    total, start = 0.0, info["com"]
    for _ in range(3):
        obs, reward, _, _, info = env.step(np.array([-1.0, 1.0]))
        total += reward
        for _ in range(20):
            rest[4] -= 0.5 * 1e-3
            sim.set_rest_lengths(rest)
            sim.step()
        np.testing.assert_allclose(env.task.sim.positions[0], sim.positions, rtol=0, atol=1e-10)
    nc = len(env.task.scene.cables)
    assert abs(obs[nc] - (env.task.scene.cable_rest_lengths[4] - 0.5 * 0.06)) < 1e-14   # c4's motor
    assert obs[nc + 1] == env.task.scene.cable_rest_lengths[5]                            # c5 held at +1
    np.testing.assert_allclose(obs[-2:], [0.0, 1.0])
    assert abs(total - ((info["com"] - start)[1] - 0.3 * 0.5 * 0.06)) < 1e-12


@pytest.mark.parametrize("cables", [None, ["c9", "c2", "c4"]])
def test_compiled_period_equals_its_numpy_reference(cables):
    """The reel, the rewards and the observations by the compiled kernels (envs/_kernels.py) against the task's
    numpy arithmetic (``compiled=False``): the same environment stepped with the same seeds and actions through
    autoresets, every output equal to 1e-12 (the centres of mass summed in another order)."""
    params = dict(SHORT, effort_cost=0.7) if cables is None else dict(SHORT, cables=cables, effort_cost=0.7)
    envs = [RollVectorEnv(4, **params) for _ in range(2)]
    envs[1].task.compiled = False
    for a, b in zip(envs[0].reset(seed=5), envs[1].reset(seed=5)):
        if isinstance(a, np.ndarray):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    rng = np.random.default_rng(2)
    moved = 0.0
    for _ in range(12):   # two autoresets of every copy
        action = rng.uniform(-1, 1, envs[0].action_space.shape)
        (obs, rewards, _, truncated, infos), (obs_ref, rewards_ref, _, truncated_ref, infos_ref) = \
            (env.step(action) for env in envs)
        np.testing.assert_allclose(obs, obs_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(rewards, rewards_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(infos["com"], infos_ref["com"], rtol=0, atol=1e-12)
        assert truncated.tolist() == truncated_ref.tolist()
        moved = max(moved, float(np.abs(rewards).max()))
    assert moved > 1e-4   # the robots moved (rewards that are not all zero)


def test_refused_copy_is_truncated_with_its_reason():
    vec = RollVectorEnv(3, **SHORT)
    vec.reset(seed=1)
    vec.reset(options={"reset_mask": np.array([False, True, False]), "noise": 1e12})   # no step resolves that
    obs, rewards, terminated, truncated, infos = vec.step(np.zeros((3, 24)))
    assert truncated.tolist() == [False, True, False] and not terminated.any()
    assert infos["_refused"].tolist() == [False, True, False] and "refused" not in str(infos["refused"][0])
    assert "moves at" in infos["refused"][1] and rewards[1] == 0.0 and np.isfinite(obs).all()
    obs, _, _, truncated, infos = vec.step(np.zeros((3, 24)))   # its autoreset
    assert not truncated.any() and "refused" not in infos and infos["time"][1] == 0.0


@pytest.mark.parametrize("action, message", [
    (np.zeros(23), r"action must have shape \(24,\)"),
    (np.full(24, np.nan), "not finite"),
    (np.full(24, 1.5), r"action\[0\] = 1.5 is outside \[-1, 1\]"),
    ("left", "action must be numbers"),
])
def test_bad_actions(action, message):
    env = RollEnv()
    obs, _ = env.reset(seed=0)
    before = env.task.sim.positions
    with pytest.raises(ValueError, match=message):
        env.step(action)
    assert np.array_equal(env.task.sim.positions, before)


@pytest.mark.parametrize("params, error, message", [
    (dict(cables=[]), ValueError, "no actuated cable"),
    (dict(cables=["c4", "rope"]), ValueError, "unknown cable 'rope'"),
    (dict(scene="icosahedron"), ValueError, "has no ground"),
    (dict(speed=2.0), TypeError, "unknown parameter 'speed'"),
    (dict(control_dt=0.0205), ValueError, "whole number of steps"),
    (dict(goal=(0.0, 0.0)), ValueError, "goal must be 2 finite numbers"),
    (dict(rest_range=(1.0, 0.5)), ValueError, "0 < low < high"),
])
def test_bad_parameters(params, error, message):
    with pytest.raises(error, match=message):
        gym.make(ROLL_ID, **params)
    with pytest.raises(error, match=message):
        RollVectorEnv(2, **params)


def test_bad_reset_option():
    env = RollEnv()
    with pytest.raises(ValueError, match="unknown option 'tilt'"):
        env.reset(options={"tilt": 1.0})


def test_jax_functional_env_equals_the_numba_one_over_an_episode():
    """RollJax (gymnax's interface) from RollEnv's start, the same actions: 25 control periods to 1e-9; its reset
    and step vmap over keys and states (a batch of robots)."""
    jax = pytest.importorskip("jax")   # the jax extra (CI's first leg installs it)
    from tensegrity_sim.envs.jax_roll import RollJax

    params_ = dict(episode_seconds=0.5, noise=0.05)
    env, fenv = RollEnv(**params_), RollJax(**params_)
    params = fenv.default_params
    obs, _ = env.reset(seed=3)
    x, v = env.task.sim.positions[0], env.task.sim.velocities[0]
    fobs, state = jax.jit(fenv.reset_to)(x, v, params)
    np.testing.assert_allclose(fobs, obs, rtol=0, atol=1e-12)
    step = jax.jit(fenv.step)
    key = jax.random.PRNGKey(0)
    rng = np.random.default_rng(0)
    done = truncated = False
    while not truncated:
        a = rng.uniform(-1, 1, 24)
        obs, reward, _, truncated, _ = env.step(a)
        fobs, state, freward, done, info = step(key, state, a, params)
        np.testing.assert_allclose(fobs, obs, rtol=0, atol=1e-9)
        assert abs(float(freward) - reward) <= 1e-9 and bool(done) == truncated and bool(info["finite"])
    assert int(state.elapsed) == 25
    keys = jax.random.split(key, 2)
    # jitted: one compile of each batched function, not one per primitive of its eager dispatch (measured at load 7:
    # 34 s eager, 11 s jitted)
    obs2, states = jax.jit(jax.vmap(fenv.reset, in_axes=(0, None)))(keys, params)
    assert obs2.shape == (2, fenv.num_observations) and not np.array_equal(obs2[0], obs2[1])
    batch_step = jax.jit(jax.vmap(fenv.step, in_axes=(0, 0, 0, None)))
    obs2, states, rewards, dones, _ = batch_step(keys, states, np.zeros((2, 24)), params)
    assert obs2.shape == (2, fenv.num_observations) and np.all(np.isfinite(obs2)) and rewards.shape == (2,)


@pytest.mark.parametrize("args, message", [
    (([3], None, None, None), r"copies: expected copy indices in \[0, 2\)"),
    (([1], np.zeros((2, 12, 3)), np.zeros((1, 12, 3)), None), "positions: expected shape"),
    (([1], "scene", np.zeros((1, 12, 3)), "scene"), "rigid strut 's0' has length"),
    (([1], "scene", np.zeros((1, 12, 3)), -np.ones((1, 24))), r"rest_lengths\[0\]\['c0'\]: must be > 0"),
])
def test_restart_refuses_bad_input_and_changes_nothing(args, message):
    scene = ts.load_scene("icosahedron_ground")
    sim = ts.BatchSimulator(scene, 2, method="elastic", contacts=())
    sim.run(steps=3)
    before = (sim.positions, sim.velocities, sim.rest_lengths)
    copies, x, v, rest = args
    x = scene.positions[None] * (1.1 if "length" in message else 1.0) if isinstance(x, str) else x
    rest = scene.cable_rest_lengths[None] if isinstance(rest, str) else rest
    with pytest.raises(ValueError, match=message):
        sim.restart(copies, x, v, rest)
    for a, b in zip(before, (sim.positions, sim.velocities, sim.rest_lengths)):
        assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="member contacts"):
        ts.BatchSimulator(scene, 2, method="elastic").restart([0], scene.positions[None], np.zeros((1, 12, 3)),
                                                               scene.cable_rest_lengths[None])


def test_core_imports_no_learning_library():
    """gymnasium and cma (the learn extra) load only with tensegrity_sim.envs or optimize-gait's search."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys, tensegrity_sim, tensegrity_sim.cli, tensegrity_sim.batch, tensegrity_sim.optimize.gait; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('gymnasium', 'cma')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == "[]"
