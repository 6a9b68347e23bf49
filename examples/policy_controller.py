#!/usr/bin/env python3
"""Plays a trained policy or a gait on the node, over DDS, with no ROS install.

At every ``node_poses`` message it reads the node's clock and the node positions and publishes
``cable_rest_lengths``:

* ``--policy FILE.npz`` (``examples/train_roll.py``'s file): every control period (the file's, 20 ms) the policy's
  mean action from the observation ``tensegrity_sim/Roll-v0`` defines (cable lengths, the motors' rest lengths,
  positions relative to the centre of mass, velocities: the positions' difference over the last message's
  interval, goal), and, at every message, the rest lengths the motors reach toward its targets at the file's reel
  speed, as the environment reels them;
* ``--gait FILE.yaml`` (a command schedule from ``tensegrity-sim optimize-gait``): at ``--rate`` Hz (default 50)
  the gait's rest lengths at the time since the first pose it saw (its ramps repeated as the file gives them).

    tensegrity-sim serve icosahedron_ground --transport dds --lockstep &
    python3 examples/policy_controller.py --policy examples/policies/roll_icosahedron.npz --seconds 10
    python3 examples/policy_controller.py --gait examples/gait.yaml --seconds 6

It answers every pose in turn (a gait's last command again between its samples), so a node in lockstep
(``--lockstep``, msg_docs/parameters.md) waits for each answer and the run is the ``--offline`` one exactly,
however late the answers come; without it a loaded machine's delays change a closed-loop policy's run.

``examples/gait.yaml`` is ``tensegrity-sim optimize-gait icosahedron_ground --out examples/gait.yaml`` (CMA-ES,
5.15 m along +x in 6 s offline). Needs the "dds" extra: ``pip install -e ".[dds]"``. ``--offline`` drives the
node's logic in this process instead (``test/test_policy_controller.py``, ``bench/compare_roll.py``).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np


class GaitPlayer:
    """The rest lengths (name -> m) a gait (``tensegrity_sim.commands.CommandSchedule`` of ``scene``) gives at a
    time (s since the start)."""

    def __init__(self, schedule, scene):
        self.schedule = schedule
        self.base = scene.cable_rest_lengths
        self.names = [scene.cable_names[i] for i in schedule.rest_cables]

    def update(self, t: float, positions: np.ndarray | None = None) -> dict[str, float]:
        rest = self.schedule.rest_lengths_at(t, self.base)[self.schedule.rest_cables]
        return dict(zip(self.names, map(float, rest)))


class MlpPolicy:
    """The mean action of a policy file (``examples/train_roll.py``): ``obs`` normalised by the file's running
    statistics, dense layers ``w0, b0, w1, b1, ...`` with swish (x sigmoid(x)) between them, clipped to [-1, 1]."""

    def __init__(self, path: str):
        with np.load(path) as f:
            data = {k: f[k] for k in f.files}
        count = sum(1 for k in data if k.startswith("w") and k[1:].isdigit())
        if count == 0 or "obs_mean" not in data:
            raise ValueError(f"{path}: not a policy file (no layers w0, b0, ... and obs_mean, obs_var)")
        self.layers = [(data[f"w{i}"].astype(float), data[f"b{i}"].astype(float)) for i in range(count)]
        self.mean, self.var = data["obs_mean"], data["obs_var"]
        self.meta = {k: v for k, v in data.items() if not (k[0] in "wb" and k[1:].isdigit()) and
                     not k.startswith("obs_")}

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        h = (np.asarray(obs, dtype=float) - self.mean) / np.sqrt(self.var + 1e-8)
        for w, b in self.layers[:-1]:
            h = h @ w + b
            h = h / (1.0 + np.exp(-h))
        w, b = self.layers[-1]
        return np.clip(h @ w + b, -1.0, 1.0)


class PolicyPlayer:
    """A policy file's commands: :meth:`update` (time s, node positions (N, 3) m) -> rest lengths (name -> m) of
    the actuated cables. A new action every ``control_dt`` s from ``tensegrity_sim/Roll-v0``'s observation
    (velocities: the positions' change since the previous call over its time), and at every call the motors'
    positions reeled toward its targets at ``reel_speed`` m/s since the period began, up to the next call's time
    (the interval since the previous call assumed)."""

    def __init__(self, policy: MlpPolicy, scene):
        m = policy.meta
        self.policy, self.scene = policy, scene
        self.names = [str(n) for n in m["cables"]]
        index = {n: i for i, n in enumerate(scene.cable_names)}
        self.actuated = np.array([index[n] for n in self.names])
        rest0 = scene.cable_rest_lengths[self.actuated]
        low, high = (float(v) for v in m["rest_range"])
        self.low, self.high = low * rest0, high * rest0
        self.control_dt, self.reel_speed = float(m["control_dt"]), float(m["reel_speed"])
        self.goal = np.asarray(m["goal"], dtype=float)
        self.ends = np.array([[scene.node_names.index(a) for a in c.nodes] for c in scene.cables])
        self.rest = rest0.copy()        # the motors' positions (m) at the end of the current period
        self.start = rest0.copy()       # ... at its start
        self.target = rest0.copy()
        self.began = self.previous = None   # the current period's start time; the previous call's (t, x)

    def observe(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        lengths = np.linalg.norm(x[self.ends[:, 1]] - x[self.ends[:, 0]], axis=1)
        return np.concatenate([lengths, self.rest, (x - _centre(self.scene, x)).ravel(), v.ravel(), self.goal])

    def update(self, t: float, positions: np.ndarray) -> dict[str, float]:
        x = np.asarray(positions, dtype=float)
        step = t - self.previous[0] if self.previous is not None else 0.0
        if self.began is None or t - self.began >= self.control_dt - 1e-9:
            v = (x - self.previous[1]) / step if step > 0 else np.zeros_like(x)
            self.start = self.rest
            self.target = self.low + 0.5 * (self.policy(self.observe(x, v)) + 1.0) * (self.high - self.low)
            reach = self.reel_speed * self.control_dt
            self.rest = self.start + np.clip(self.target - self.start, -reach, reach)
            self.began = t if self.began is None else self.began + self.control_dt
        self.previous = (t, x)
        reach = self.reel_speed * min(t - self.began + step, self.control_dt)
        now = self.start + np.clip(self.target - self.start, -reach, reach)
        return dict(zip(self.names, map(float, now)))


def _centre(scene, x: np.ndarray) -> np.ndarray:
    return scene.masses @ x / scene.masses.sum()


def load_player(scene, gait: str | None = None, policy: str | None = None):
    """A :class:`GaitPlayer` of ``gait`` or a :class:`PolicyPlayer` of ``policy`` on ``scene``."""
    if policy is not None:
        return PolicyPlayer(MlpPolicy(policy), scene)
    from tensegrity_sim.commands import load_commands
    return GaitPlayer(load_commands(gait, scene), scene)


class Answers:
    """What the controller sends at each ``node_poses`` message (stamp ``t`` s, node positions ``x``): the player's
    command at ``t - t0`` (``t0``: the first message's stamp) every ``1/rate`` s (``rate`` None: at every
    message), and the last command again in between, so that a node in lockstep (its parameter ``lockstep``)
    has every publication answered; nothing for a stamp it has seen (a lockstep node repeats the one it waits
    on) or once ``seconds`` s have passed (:attr:`done`). :attr:`moved`: the centre of mass's displacement (3,) m
    from the first message to the last."""

    def __init__(self, player, scene, seconds: float, rate: float | None):
        self.player, self.scene, self.seconds, self.rate = player, scene, seconds, rate
        self.t0 = self.start = self.last = self.x = None
        self.command: dict[str, float] = {}
        self.next_command = 0.0
        self.done = False

    def __call__(self, t: float, x: np.ndarray) -> dict[str, float] | None:
        if self.done or (self.last is not None and t <= self.last):
            return None
        if self.t0 is None:
            self.t0, self.start = t, _centre(self.scene, x)
        self.last, self.x = t, x
        if t - self.t0 >= self.seconds - 1e-9:
            self.done = True
            return None
        if self.rate is None or t - self.t0 >= self.next_command - 1e-9:
            self.next_command += 1.0 / self.rate if self.rate is not None else 0.0
            self.command = self.player.update(t - self.t0, x)
        return self.command

    @property
    def moved(self) -> np.ndarray:
        return _centre(self.scene, self.x) - self.start


def drive_offline(player, seconds: float, rate: float | None = 50.0, scene: str = "icosahedron_ground",
                  method: str = "elastic") -> np.ndarray:
    """Drive the node's logic in this process (no DDS) for ``seconds`` s of its time as :func:`main` drives the
    node: at every ``node_poses`` publication the :class:`Answers` of the ``player`` go in as
    ``cable_rest_lengths`` messages, before the next step (as a node in lockstep takes them). ``player``: a
    :class:`GaitPlayer`, :class:`PolicyPlayer`, or anything with that ``update(t, positions)``. Returns the centre
    of mass's displacement (3,) m from the first publication to the one ``seconds`` s after it."""
    from roll_controller import offline_node   # beside this file
    from tensegrity_sim.ros import messages as M

    loaded, sim, logic, poses = offline_node(scene, method)
    answers = Answers(player, loaded, seconds, rate)
    while not answers.done:
        if logic.step() is None:
            raise RuntimeError("the node paused after a failed step")
        if not logic.publication_due:
            continue
        logic.publish()
        msg = poses[-1]
        command = answers(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, _positions(msg))
        if command:
            reason = logic.receive("cable_rest_lengths", M.joint_state(M.header(0, ""), list(command),
                                                                        position=list(command.values())))
            if reason is not None:
                raise RuntimeError(f"the node refused the command: {reason}")
    return answers.moved


def _positions(msg) -> np.ndarray:
    """The node positions (N, 3) m of a ``node_poses`` message."""
    return np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--policy", help="a policy file (.npz, examples/train_roll.py --out)")
    which.add_argument("--gait", help="a command schedule (tensegrity-sim optimize-gait --out)")
    parser.add_argument("--seconds", type=float, default=6.0, help="s of the node's time to play it")
    parser.add_argument("--rate", type=float, default=50.0, help="a gait's commands per second (default 50)")
    parser.add_argument("--domain-id", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    parser.add_argument("--interface", default="lo", help="network interface (default: lo)")
    parser.add_argument("--node", default="/tensegrity_sim", help="the simulator node's name")
    parser.add_argument("--scene", default="icosahedron_ground", help="the scene the node runs")
    parser.add_argument("--offline", action="store_true", help="drive the node's logic in this process (no DDS)")
    args = parser.parse_args(argv)
    from tensegrity_sim import load_scene

    scene = load_scene(args.scene)
    try:
        player = load_player(scene, args.gait, args.policy)
    except (OSError, ValueError, KeyError) as e:
        print(f"policy_controller: {e}", file=sys.stderr)
        return 2
    rate = None if args.policy else args.rate   # a policy sees every pose (its reel), a gait is sampled
    if args.offline:
        moved = drive_offline(player, args.seconds, rate, args.scene)
        print(f"centre of mass moved {np.round(moved, 4).tolist()} m in {args.seconds:g} s")
        return 0
    from tensegrity_sim.ros import messages as M
    from tensegrity_sim.ros.dds import Participant

    with Participant(domain_id=args.domain_id, interface=args.interface, node_name="policy_controller") as dds:
        poses = dds.reader(f"{args.node}/node_poses", "geometry_msgs/msg/PoseArray")
        rest = dds.writer(f"{args.node}/cable_rest_lengths", "sensor_msgs/msg/JointState")
        answers = Answers(player, scene, args.seconds, rate)
        while not answers.done:
            dds.wait(0.002)
            got, _ = poses.take_messages()
            for msg in got:   # every pose in turn: a node in lockstep waits for the answer to each
                command = answers(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, _positions(msg))
                if command:
                    rest.write(M.joint_state(M.header(time.time_ns(), ""), list(command),
                                             position=list(command.values())))
        print(f"centre of mass moved {np.round(answers.moved, 4).tolist()} m in {args.seconds:g} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
