"""Environment steps per second: ``tensegrity_sim/Roll-v0``'s vector environment against Gymnasium's MuJoCo
environment of the same robot (issue 50).

Contenders, each stepping random actions in [-1, 1] (one control period of 20 ms = 20 steps of 1 ms each):

* ``vector``: :class:`~tensegrity_sim.envs.RollVectorEnv` of ``--copies`` copies (one compiled call a period);
* ``single``: one :class:`~tensegrity_sim.envs.RollEnv`, stepped one by one;
* ``mujoco``: a Gymnasium ``MujocoEnv`` of the scene's MJCF (``bench/mujoco_peer.py``: a free body per rigid
  strut, a tendon per cable, the ground a plane, the struts capsules on it; the ``implicitfast`` integrator),
  stepped one by one. An action's targets are reeled toward at 1 m/s as ours are: each of the period's 20 steps
  (``frame_skip``) moves the tendons' spring lengths (``tendon_lengthspring``) and steps. Not Euler, MuJoCo's
  cheapest: under these random actions its step goes unstable every 0.2-1.2 s (77 times in 2,000 periods, each
  time MuJoCo's ``mjWARN_BADQACC`` and a reset to the start pose: the friction of the capsules' contacts turns a
  strut about its axis, whose inertia is only a round-off-sized 1e-6 of its transverse one, or 10 times in
  2,000 periods with a solid rod's 4.4e-4), so it would step a robot that keeps falling from its start pose
  rather than one that rolls; ``implicitfast``, MuJoCo's recommended integrator, ran those 2,000 periods without
  a reset (``resets`` in the CSV counts them over the bench's run: 0 expected);
* ``mujoco_sync``: Gymnasium's ``SyncVectorEnv`` of ``--copies`` of them.

Rates are environment steps (control periods) per second of wall time, best of ``--repeats`` turns of
``--seconds`` each after a warm-up, the contenders taking turns in one process; ``ratio``: the vector environment's rate over each contender's. CSV: ``bench/results/envs.csv``.

    python3 bench/bench_envs.py --copies 256 --seconds 0.25 --repeats 5
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym  # noqa: E402
import mujoco  # noqa: E402
from gymnasium.envs.mujoco.mujoco_env import MujocoEnv  # noqa: E402

import tensegrity_sim as ts  # noqa: E402
from bench.mujoco_peer import MujocoPeer  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.envs import RollEnv, RollVectorEnv  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


class MujocoRoll(MujocoEnv):
    """The roll task's robot in MuJoCo through Gymnasium's ``MujocoEnv``: an action in [-1, 1] per cable is a
    spring-length target between 0.5 and 1.0 of the scene's rest length, reeled toward at 1 m/s step by step as
    ours is (setting it at once makes MuJoCo's Euler step go unstable within 0.1 s); observation qpos and qvel;
    reward the bodies' mean x progress."""

    metadata = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"], "render_fps": 50}

    def __init__(self, xml_path: str, rest: np.ndarray, **kwargs):
        model = mujoco.MjModel.from_xml_path(xml_path)
        size = model.nq + model.nv
        super().__init__(xml_path, 20, gym.spaces.Box(-np.inf, np.inf, (size,), np.float64), **kwargs)
        self.rest = rest
        self.resets = 0   # MuJoCo's own resets of an unstable step (its clock going back), over the env's life
        self.action_space = gym.spaces.Box(-1.0, 1.0, (len(rest),), np.float64)
        self.reach = 1.0 * self.model.opt.timestep   # m of rest length a step (the motors' 1 m/s)

    def _set_action_space(self):   # MujocoEnv's from the actuators: this model has none; set in __init__
        return None

    def step(self, action):
        before = self.data.xpos[1:, 0].mean()
        target = self.rest * (0.75 + 0.25 * np.asarray(action))
        spring = self.model.tendon_lengthspring
        start = self.data.time
        # the period's spring lengths at once (the motors' positions at each step's end), then MujocoEnv's
        # do_simulation (mj_step, and mj_rnePostConstraint after the last) with one length set before each step:
        # a per-step clip and do_simulation took a quarter of the peer's time in Python
        now = spring[:, 1].copy()
        reach = self.reach * np.arange(1, self.frame_skip + 1)[:, None]
        reel = now + np.clip(target - now, -reach, reach)
        for lengths in reel:
            spring[:, 1] = lengths
            mujoco.mj_step(self.model, self.data)
        mujoco.mj_rnePostConstraint(self.model, self.data)
        self.resets += self.data.time < start
        obs = np.concatenate([self.data.qpos, self.data.qvel])
        return obs, float(self.data.xpos[1:, 0].mean() - before), False, False, {}

    def reset_model(self):
        self.model.tendon_lengthspring[:, 1] = self.rest
        self.set_state(self.init_qpos, self.init_qvel)
        return np.concatenate([self.data.qpos, self.data.qvel])


def _rates(contenders: dict, repeats: int, seconds: float) -> dict:
    """Environment steps per second of each contender ``name: (step, copies)``: ``step()`` (``copies``
    environment steps each) called until ``seconds`` of wall time have passed, the best of ``repeats`` such turns
    taken in rotation (a shared machine's load then falls on every contender alike, and only ever adds time).
    Every contender's turn lasts about as long, each in its steady state: with a set number of periods a turn, one
    MuJoCo environment's 20 periods took 13 ms against the vector environment's 170 ms, and its short turns
    started from caches that the vector environment's turn had emptied (1,460-1,550 env-steps/s in five runs,
    against 1,600-1,670 with turns of 0.25 s)."""
    best = {name: 0.0 for name in contenders}
    for step, _ in contenders.values():
        step()   # warm-up (compiling)
    for _ in range(repeats):
        for name, (step, copies) in contenders.items():
            calls, start = 0, time.perf_counter()
            while True:
                step()
                calls += 1
                elapsed = time.perf_counter() - start
                if elapsed >= seconds:
                    break
            best[name] = max(best[name], calls * copies / elapsed)
    return best


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--copies", type=int, default=256)
    parser.add_argument("--seconds", type=float, default=0.25, help="wall seconds of each timed turn")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    scene = ts.load_scene("icosahedron_ground")
    rng = np.random.default_rng(0)
    na = len(scene.cables)
    vec = RollVectorEnv(args.copies)
    vec.reset(seed=0)
    single = RollEnv()
    single.reset(seed=0)

    peer = MujocoPeer(scene, model="elastic", dt=1e-3, integrator="implicitfast")
    with tempfile.TemporaryDirectory() as tmp:
        xml = Path(tmp) / "icosahedron_ground.xml"
        xml.write_text(peer.xml)
        rest = scene.cable_rest_lengths
        env = MujocoRoll(str(xml), rest)
        env.reset(seed=0)
        sync = gym.vector.SyncVectorEnv([lambda: MujocoRoll(str(xml), rest) for _ in range(args.copies)])
        sync.reset(seed=0)
        contenders = {
            "vector": (lambda: vec.step(rng.uniform(-1, 1, (args.copies, na))), args.copies),
            "single": (lambda: single.step(rng.uniform(-1, 1, na)), 1),
            "mujoco": (lambda: env.step(rng.uniform(-1, 1, na)), 1),
            "mujoco_sync": (lambda: sync.step(rng.uniform(-1, 1, (args.copies, na))), args.copies)}
        rates = _rates(contenders, args.repeats, args.seconds)
        resets = {"mujoco": env.resets, "mujoco_sync": sum(e.resets for e in sync.envs)}
    ours = rates["vector"]
    out = [{"contender": name, "copies": contenders[name][1], "env_steps_per_s": float(rate),
            "ratio": float(ours / rate), "resets": resets.get(name, 0)} for name, rate in rates.items()]
    for row in out:
        print(f"{row['contender']:<12} {row['copies']:>5} copies {row['env_steps_per_s']:>12.1f} env-steps/s   "
              f"vector / this: {row['ratio']:.2f}   unstable resets: {row['resets']}")
    write_csv(RESULTS / "envs.csv", out)


if __name__ == "__main__":
    main()
