#!/usr/bin/env python3
"""Plays a gait (a command schedule from ``tensegrity-sim optimize-gait``) on the node, over DDS, with no ROS install.

At the control rate (``--rate`` Hz, default 50: the environments' 20 ms) it reads the node's clock from
``node_poses`` and publishes ``cable_rest_lengths``: each of the gait's cables at the gait's rest length for that
time since the first pose it saw (the schedule's ramps, repeated as the file gives them; held after its end).

    tensegrity-sim serve icosahedron_ground --transport dds &
    python3 examples/policy_controller.py --gait examples/gait.yaml --seconds 6

``examples/gait.yaml`` is ``tensegrity-sim optimize-gait icosahedron_ground --out examples/gait.yaml`` (CMA-ES,
5.15 m along +x in 6 s offline). Needs the "dds" extra: ``pip install -e ".[dds]"``. ``--offline`` drives the
node's logic in this process instead (``test/test_policy_controller.py``).
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

    def update(self, t: float) -> dict[str, float]:
        rest = self.schedule.rest_lengths_at(t, self.base)[self.schedule.rest_cables]
        return dict(zip(self.names, map(float, rest)))


def _centre(scene, x: np.ndarray) -> np.ndarray:
    return scene.masses @ x / scene.masses.sum()


def drive_offline(gait: str, seconds: float, rate: float = 50.0, scene: str = "icosahedron_ground") -> np.ndarray:
    """Play ``gait`` for ``seconds`` s through the node's logic in this process (no DDS): the commands go in as
    ``cable_rest_lengths`` messages at ``rate`` Hz, as over DDS. Returns the centre of mass's displacement (3,) m."""
    from tensegrity_sim import Simulator, load_scene
    from tensegrity_sim.commands import load_commands
    from tensegrity_sim.ros import messages as M
    from tensegrity_sim.ros.node_logic import NodeSettings, SimNodeLogic

    loaded = load_scene(scene)
    player = GaitPlayer(load_commands(gait, loaded), loaded)
    sim = Simulator(loaded, method="elastic", dt=1e-3)
    logic = SimNodeLogic(sim, NodeSettings(scene=scene, method="elastic", dt=sim.dt, log_path=""),
                         transport=lambda key, msg: None, clock=lambda: 0.0)
    start = _centre(loaded, sim.positions)
    period = round(1.0 / (rate * sim.dt))   # steps between commands
    for k in range(round(seconds / sim.dt)):
        if k % period == 0:
            command = player.update(k * sim.dt)
            reason = logic.receive("cable_rest_lengths", M.joint_state(M.header(0, ""), list(command),
                                                                        position=list(command.values())))
            if reason is not None:
                raise RuntimeError(f"the node refused the command: {reason}")
        if logic.step() is None:
            raise RuntimeError("the node paused after a failed step")
    return _centre(loaded, sim.positions) - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gait", required=True, help="a command schedule (tensegrity-sim optimize-gait --out)")
    parser.add_argument("--seconds", type=float, default=6.0, help="s of the node's time to play it")
    parser.add_argument("--rate", type=float, default=50.0, help="commands per second (default 50)")
    parser.add_argument("--domain-id", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    parser.add_argument("--interface", default="lo", help="network interface (default: lo)")
    parser.add_argument("--node", default="/tensegrity_sim", help="the simulator node's name")
    parser.add_argument("--scene", default="icosahedron_ground", help="the scene the node runs")
    parser.add_argument("--offline", action="store_true", help="drive the node's logic in this process (no DDS)")
    args = parser.parse_args(argv)
    if args.offline:
        moved = drive_offline(args.gait, args.seconds, args.rate, args.scene)
        print(f"centre of mass moved {np.round(moved, 4).tolist()} m in {args.seconds:g} s")
        return 0
    from roll_controller import latest_pose   # beside this file
    from tensegrity_sim import load_scene
    from tensegrity_sim.commands import load_commands
    from tensegrity_sim.ros import messages as M
    from tensegrity_sim.ros.dds import Participant

    scene = load_scene(args.scene)
    player = GaitPlayer(load_commands(args.gait, scene), scene)
    with Participant(domain_id=args.domain_id, interface=args.interface, node_name="policy_controller") as dds:
        poses = dds.reader(f"{args.node}/node_poses", "geometry_msgs/msg/PoseArray")
        rest = dds.writer(f"{args.node}/cable_rest_lengths", "sensor_msgs/msg/JointState")
        t0 = start = x = None
        next_command = 0.0
        while True:
            dds.wait(0.2 / args.rate)
            latest = latest_pose(poses)
            if latest is None:
                continue
            t, x = latest
            if t0 is None:
                t0, start = t, _centre(scene, x)
            if t - t0 >= args.seconds:
                break
            if t - t0 >= next_command:
                command = player.update(t - t0)
                rest.write(M.joint_state(M.header(time.time_ns(), ""), list(command), position=list(command.values())))
                next_command += 1.0 / args.rate
        print(f"centre of mass moved {np.round(_centre(scene, x) - start, 4).tolist()} m in {args.seconds:g} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
