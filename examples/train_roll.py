#!/usr/bin/env python3
"""Trains a policy that rolls ``icosahedron_ground`` toward +x: PPO from rejax (the ``train`` extra) on the JAX
environment :class:`tensegrity_sim.envs.jax_roll.RollJax`, end to end in JAX on whatever device JAX finds.

    python3 examples/train_roll.py --minutes 20 --out examples/policies/roll_icosahedron.npz

It trains in chunks of ``--chunk`` environment steps until ``--minutes`` of wall time (or ``--steps``) are spent;
after each chunk it rolls the policy's mean action for ``--eval-seconds`` s of 4 robots and records the distance
their centre of mass moved along the goal. It writes the best policy seen (``--out``: an .npz of the actor's
weights and the observation normalisation, which ``examples/policy_controller.py --policy`` plays on the node),
the learning curve (``--plot``, PNG) and its numbers (``--curve``, CSV). The algorithm is rejax's PPO; this file
only adapts the environment to gymnax's base class (rejax's input) and picks the settings.
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
import time

import numpy as np

EVAL_ROBOTS = 4


def gymnax_env(**params):
    """``RollJax(**params)`` as a ``gymnax.environments.environment.Environment`` (gymnax's ``step`` adds the
    autoreset that rejax's PPO expects) and its parameters."""
    import gymnax
    from gymnax.environments import spaces

    from tensegrity_sim.envs.jax_roll import RollJax

    roll = RollJax(**params)

    class GymnaxRoll(gymnax.environments.environment.Environment):
        def reset_env(self, key, params):
            return roll.reset(key, params)

        def step_env(self, key, state, action, params):
            return roll.step(key, state, action, params)

        @property
        def default_params(self):
            return roll.default_params

        def action_space(self, params=None):
            return spaces.Box(-1.0, 1.0, (roll.num_actions,))

        def observation_space(self, params=None):
            return spaces.Box(-np.inf, np.inf, (roll.num_observations,), dtype=np.float64)

    return GymnaxRoll(), roll


def actor_layers(actor_params) -> list[tuple[np.ndarray, np.ndarray]]:
    """(kernel, bias) of the actor's dense layers in order: the MLP's hidden layers, then the action mean."""
    p = actor_params["params"]
    hidden = p["features"]
    layers = [hidden[f"Dense_{i}"] for i in range(len(hidden))]
    return [(np.asarray(d["kernel"]), np.asarray(d["bias"])) for d in layers + [p["action_mean"]]]


def check_pairs(actor, actor_params, mean, var, count: int = 16, seed: int = 0):
    """``count`` observations drawn about the normalisation's mean (its standard deviation) and the actor's mean
    actions for them, clipped to [-1, 1], computed by flax: a policy file's own check
    (``test/test_policy_controller.py`` requires :class:`policy_controller.MlpPolicy` to give them)."""
    import jax
    import jax.numpy as jnp

    obs = mean + np.sqrt(var) * np.random.default_rng(seed).standard_normal((count, len(mean)))
    x = (jnp.asarray(obs) - mean) / jnp.sqrt(var + 1e-8)
    action = actor.apply(actor_params, x, method="_action_dist").mean()
    return obs, np.clip(np.asarray(jax.device_get(action), dtype=float), -1.0, 1.0)


def save_policy(path: str, algo, ts, roll, meta: dict) -> None:
    """The actor's weights (``w0``, ``b0``, ...; swish between layers), the observation normalisation (``obs_mean``,
    ``obs_var``: the policy acts on ``(obs - mean) / sqrt(var + 1e-8)``), the task's settings the controller needs
    (``cables``, ``rest_range``, ``reel_speed``, ``control_dt``, ``goal``), :func:`check_pairs` (``check_obs``,
    ``check_actions``) and ``meta`` (strings and numbers)."""
    arrays = {}
    for i, (w, b) in enumerate(actor_layers(ts.actor_ts.params)):
        arrays[f"w{i}"], arrays[f"b{i}"] = w, b
    mean, var = np.asarray(ts.obs_rms_state.mean, dtype=float), np.asarray(ts.obs_rms_state.var, dtype=float)
    arrays["obs_mean"], arrays["obs_var"] = mean, var
    arrays["check_obs"], arrays["check_actions"] = check_pairs(algo.actor, ts.actor_ts.params, mean, var)
    task = roll.task
    r0 = task.rest0[task.actuated[0]]
    arrays.update(cables=np.array(task.cables), rest_range=np.array([task.low[0] / r0, task.high[0] / r0]),
                  reel_speed=task.reel_speed, control_dt=task.control_dt)
    arrays.update({k: np.asarray(v) for k, v in meta.items()})
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    np.savez_compressed(path, **arrays)


def make_evaluate(algo, roll, params, seconds: float):
    """A jitted function (train state, key) -> distances (EVAL_ROBOTS,) m the centre of mass
    moves along the goal in ``seconds`` s with the policy's mean action."""
    import jax
    import jax.numpy as jnp

    periods = int(round(seconds / roll.task.control_dt))

    def distances(ts, key):
        keys = jax.random.split(key, EVAL_ROBOTS)
        obs, states = jax.vmap(roll.reset, in_axes=(0, None))(keys, params)
        start = jax.vmap(lambda s: roll._com(s.carry.x[..., 0]))(states)

        def body(carry, _):
            obs, states = carry
            x = algo.normalize_obs(ts.obs_rms_state, obs)
            mean = algo.actor.apply(ts.actor_ts.params, x, method="_action_dist").mean()
            obs, states, _, _, _ = jax.vmap(roll.step, in_axes=(0, 0, 0, None))(keys, states, mean, params)
            return (obs, states), None

        (_, states), _ = jax.lax.scan(body, (obs, states), None, length=periods)
        end = jax.vmap(lambda s: roll._com(s.carry.x[..., 0]))(states)
        return (end - start)[:, :2] @ params.goal

    return jax.jit(distances)


def plot_curve(path: str, rows: list[dict], title: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.array([r["steps"] for r in rows]) / 1e6
    mean = np.array([r["mean_m"] for r in rows])
    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=100)
    ax.plot(steps, mean, "o-", color="C0", label="policy's mean action, mean of 4 robots")
    ax.fill_between(steps, [r["min_m"] for r in rows], [r["max_m"] for r in rows], color="C0", alpha=0.2,
                    label="their least and most")
    if rows and rows[0].get("baseline_m") is not None:
        ax.axhline(rows[0]["baseline_m"], color="C3", ls="--", label="examples/roll_controller.py")
    ax.set_xlabel("environment steps (millions of 20 ms control periods)")
    ax.set_ylabel("distance along the goal (m)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="roll_policy.npz", help="the policy file (.npz)")
    parser.add_argument("--plot", default="", help="the learning curve (PNG); default: --out with .png")
    parser.add_argument("--curve", default="", help="the learning curve's numbers (CSV); default: --out with .csv")
    parser.add_argument("--minutes", type=float, default=20.0, help="wall time to train (default 20)")
    parser.add_argument("--steps", type=int, default=0, help="stop after this many environment steps (0: none)")
    parser.add_argument("--chunk", type=int, default=65536, help="environment steps between evaluations")
    parser.add_argument("--envs", type=int, default=64, help="robots stepped in parallel")
    parser.add_argument("--rollout", type=int, default=64, help="control periods per robot per PPO iteration")
    parser.add_argument("--episode-seconds", type=float, default=10.0, help="training episodes' length (s)")
    parser.add_argument("--eval-seconds", type=float, default=10.0, help="evaluation rollouts' length (s)")
    parser.add_argument("--control-dt", type=float, default=0.02, help="s per action (default 0.02)")
    parser.add_argument("--effort-cost", type=float, default=0.01, help="reward lost per m of cable reeled")
    parser.add_argument("--hidden", type=int, nargs="+", default=[64, 64], help="the MLPs' hidden layer sizes")
    parser.add_argument("--lr", type=float, default=3e-4, help="Adam's learning rate")
    parser.add_argument("--baseline", type=float, default=None,
                        help="a distance (m) to draw as roll_controller.py's (bench/compare_roll.py measures it)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    stem = os.path.splitext(args.out)[0]
    plot, curve = args.plot or stem + ".png", args.curve or stem + ".csv"

    import jax
    from rejax import PPO

    task = {"control_dt": args.control_dt, "effort_cost": args.effort_cost}
    env, roll = gymnax_env(episode_seconds=args.episode_seconds, **task)
    eval_roll = gymnax_env(episode_seconds=args.eval_seconds, **task)[1]
    params = env.default_params
    minibatches = 8
    algo = PPO.create(env=env, env_params=params, num_envs=args.envs, num_steps=args.rollout,
                      num_epochs=4, num_minibatches=minibatches, learning_rate=args.lr, max_grad_norm=0.5,
                      gamma=0.99, gae_lambda=0.95, clip_eps=0.2, ent_coef=0.0, vf_coef=0.5,
                      total_timesteps=args.chunk, eval_freq=args.chunk, skip_initial_evaluation=True,
                      normalize_observations=True, normalize_rewards=True,
                      agent_kwargs={"hidden_layer_sizes": tuple(args.hidden), "activation": "swish"})
    algo = algo.replace(eval_callback=lambda algo, ts, rng: jax.numpy.zeros(()))
    train = jax.jit(lambda ts: algo.train(train_state=ts)[0])
    evaluate = make_evaluate(algo, eval_roll, params, args.eval_seconds)
    ts = algo.init_state(jax.random.PRNGKey(args.seed))
    # the environment is float64 (RollJax enables x64) and rejax's running statistics start float32
    rms = ts.obs_rms_state
    ts = ts.replace(obs_rms_state=rms.replace(mean=rms.mean.astype(float), var=rms.var.astype(float)))
    print(f"JAX on {jax.devices()[0].platform} ({jax.devices()[0].device_kind}); {args.envs} robots; "
          f"{args.chunk} steps a chunk; up to {args.minutes:g} min", flush=True)

    rows, best = [], -np.inf
    start, steps = time.time(), 0
    meta = {"scene": "icosahedron_ground", "goal": np.asarray(params.goal), "activation": "swish",
            "algorithm": "rejax PPO"}
    while True:
        d = np.asarray(evaluate(ts, jax.random.PRNGKey(10_000 + args.seed)))
        row = {"steps": steps, "wall_s": round(time.time() - start, 1), "mean_m": float(d.mean()),
               "min_m": float(d.min()), "max_m": float(d.max()), "baseline_m": args.baseline}
        rows.append(row)
        print(f"{row['wall_s']:7.1f} s  {steps:9d} steps  {args.eval_seconds:g} s rolled "
              f"{row['mean_m']:.3f} m (min {row['min_m']:.3f}, max {row['max_m']:.3f})", flush=True)
        if row["mean_m"] > best:
            best = row["mean_m"]
            save_policy(args.out, algo, ts, roll, {**meta, "steps": steps, "distance_m": best,
                                             "eval_seconds": args.eval_seconds})
        with open(curve, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(row))
            w.writeheader()
            w.writerows(rows)
        plot_curve(plot, rows, f"PPO (rejax) on RollJax: {args.eval_seconds:g} s rolls of icosahedron_ground")
        elapsed = time.time() - start
        per_chunk = elapsed / max(len(rows) - 1, 1)
        if (args.steps and steps >= args.steps) or elapsed + per_chunk > 60.0 * args.minutes:
            break
        ts = train(ts)
        steps += args.chunk
    print(f"best: {best:.3f} m in {args.eval_seconds:g} s; {steps} steps in {time.time() - start:.0f} s; "
          f"policy {args.out}, curve {plot}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
