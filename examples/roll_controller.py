#!/usr/bin/env python3
"""Rolls ``icosahedron_ground`` through the node's topics (punctuated rolling), over DDS, with no ROS install.

Each command cycle it reads the robot's pose (``node_poses``), finds the cable triangle it stands on (the
one whose three nodes are lowest), picks the edge of that triangle that faces the heading, and reels in
the three cables that tip the robot over that edge, holds, and lets them out again
(``cable_rest_lengths``); the robot lands on the next cable triangle, and the next cycle starts there.

Which cables tip it is known for one triangle and edge (``examples/roll.yaml``: standing on n0, n4, n8,
the cables n1-n6, n1-n7, n1-n8 tip it over n4-n8). Every other triangle and edge is the same up to a
symmetry of the structure: :class:`RollPlanner` finds the permutation of the nodes that maps struts to
struts and cables to cables (an automorphism of the scene's graph) and takes the known triangle and edge
to the current ones, and reels in the images of those cables.

    tensegrity-sim serve icosahedron_ground --transport dds &
    python3 examples/roll_controller.py --heading 1 0 --cycles 3

Needs the "dds" extra: ``pip install -e ".[dds]"``. Without DDS, :class:`RollController` is driven by
``test/test_roll_controller.py`` through the node's logic.
"""
from __future__ import annotations

import argparse
import itertools
import math
import os
import sys
import time

import numpy as np

# the known roll (examples/roll.yaml): standing on the cable triangle (n0, n4, n8), reeling in these cables
# of n1 tips the robot over the edge n4-n8; it lands on the triangle (n1, n6, n8)
KNOWN_BASE = ("n0", "n4", "n8")     # the third node first, then the edge
KNOWN_PULL = (("n1", "n6"), ("n1", "n7"), ("n1", "n8"))
KNOWN_LANDING = ("n1", "n6", "n8")
PULL = 0.6        # the reeled cables go to this fraction of their rest lengths
REEL = 0.3        # s to reel them in (and out again)
HOLD = 0.7        # s held in
SETTLE = 1.0      # s after letting them out before the next cycle may start ...
FLAT = 0.01       # ... once the base triangle's nodes are within this (m) of the same height: the robot
                  # sits on its face (its cables are undamped: it rocks, and a pull while it rocks back fails)


class RollPlanner:
    """The cables to reel in to tip the robot over the edge of its base triangle that faces a heading.

    ``nodes``: node names; ``struts``, ``cables``: (name, node a, node b) of each member (the scene's).
    """

    def __init__(self, nodes, struts, cables):
        self.nodes = list(nodes)
        index = {n: i for i, n in enumerate(self.nodes)}
        self.cable_names = [c[0] for c in cables]
        self._cable = {frozenset((index[a], index[b])): name for name, a, b in cables}
        self._strut = {frozenset((index[a], index[b])) for _, a, b in struts}
        n = len(self.nodes)
        self._kind = np.zeros((n, n), dtype=int)   # 0 none, 1 strut, 2 cable
        for pair in self._strut:
            i, j = tuple(pair)
            self._kind[i, j] = self._kind[j, i] = 1
        for pair in self._cable:
            i, j = tuple(pair)
            self._kind[i, j] = self._kind[j, i] = 2
        self.triangles = [t for t in itertools.combinations(range(n), 3)
                          if all(frozenset(p) in self._cable for p in itertools.combinations(t, 2))]
        self._known = [index[m] for m in KNOWN_BASE]
        self._pull = [(index[a], index[b]) for a, b in KNOWN_PULL]
        self._landing = [index[m] for m in KNOWN_LANDING]

    def _automorphism(self, fixed: dict[int, int]) -> list[int] | None:
        """A permutation ``p`` of the nodes with ``kind[p[i], p[j]] == kind[i, j]`` that extends ``fixed``
        (node -> image), by backtracking; None if there is none."""
        n = len(self.nodes)
        image = dict(fixed)
        order = list(fixed) + [i for i in range(n) if i not in fixed]

        def extend(k: int) -> bool:
            if k == n:
                return True
            i = order[k]
            used = set(image.values())
            for c in ([image[i]] if i in image else [c for c in range(n) if c not in used]):
                if all(self._kind[i, j] == self._kind[c, image[j]] for j in order[:k]):
                    image[i] = c
                    if extend(k + 1):
                        return True
                    if i not in fixed:
                        del image[i]
            return False

        return [image[i] for i in range(n)] if extend(0) else None

    def symmetry(self, third: int, e1: int, e2: int) -> list[int]:
        """The automorphism taking the known base triangle to (``third``, edge ``e1``-``e2``): the known
        third node to ``third`` and the known edge to that edge, in the one direction for which it exists
        (``test_roll_controller.py``: every edge of every cable triangle has exactly one; half of them are
        mirror images, which the mirror-symmetric rest shape makes rolls too)."""
        p = self._automorphism(dict(zip(self._known, (third, e1, e2))))
        return p if p is not None else self._automorphism(dict(zip(self._known, (third, e2, e1))))

    def base(self, positions: np.ndarray) -> tuple[int, int, int]:
        """The cable triangle the robot stands on: the one whose nodes are lowest on average."""
        return min(self.triangles, key=lambda t: float(positions[list(t), 2].sum()))

    def plan(self, positions: np.ndarray, heading) -> tuple[list[str], tuple[str, ...], tuple[str, str]]:
        """For node positions (N, 3) m and a horizontal ``heading`` (2,): the cables to reel in, the
        triangle the robot should land on, and the edge it tips over (node names)."""
        tri = self.base(positions)
        centre = positions[list(tri)].mean(axis=0)
        heading = np.asarray(heading, dtype=float)
        best = None
        for third in tri:
            e1, e2 = [m for m in tri if m != third]
            outward = 0.5 * (positions[e1] + positions[e2])[:2] - centre[:2]
            score = float(outward @ heading) / max(float(np.linalg.norm(outward)), 1e-12)
            if best is None or score > best[0]:
                best = (score, third, e1, e2)
        _, third, e1, e2 = best
        p = self.symmetry(third, e1, e2)
        cables = [self._cable[frozenset((p[a], p[b]))] for a, b in self._pull]
        return (cables, tuple(self.nodes[p[m]] for m in self._landing), (self.nodes[e1], self.nodes[e2]))


class RollController:
    """The command cycles: a cycle starts when the robot sits flat on a cable triangle (its three nodes
    within ``FLAT`` of one height) and, the previous cycle's cables let out ``SETTLE`` s before, its centre
    of mass is not moving against the heading; :meth:`update` then plans from the positions and commands
    the rest lengths of the chosen cables along the ramp (in over ``REEL`` s to ``PULL``, held ``HOLD`` s,
    out over ``REEL`` s), ``rest`` (name -> m) being the cables' rest lengths when it starts."""

    def __init__(self, planner: RollPlanner, rest: dict[str, float], heading=(1.0, 0.0)):
        self.planner = planner
        self.rest = dict(rest)
        self.heading = np.asarray(heading, dtype=float)
        self.cycle = -1
        self.start = -math.inf   # s, when the current cycle started
        self.cables: list[str] = []
        self.landing: tuple[str, ...] = ()
        self.edge: tuple[str, str] = ("", "")
        self._previous = None   # the last centre of mass seen (3,) m

    @staticmethod
    def ramp(t: float) -> float:
        """The fraction (0..1) of the pull at ``t`` s into a cycle."""
        if t < REEL + HOLD:
            return min(t / REEL, 1.0)
        return max(1.0 - (t - REEL - HOLD) / REEL, 0.0)

    def ready(self, t: float, positions: np.ndarray) -> bool:
        """Whether a new cycle may start at ``t`` s with the robot at ``positions`` (N, 3) m."""
        com = positions.mean(axis=0)
        previous, self._previous = self._previous, com
        if t < self.start + 2.0 * REEL + HOLD + SETTLE or previous is None:
            return False
        base = positions[list(self.planner.base(positions)), 2]
        return float(base.max() - base.min()) <= FLAT and float((com - previous)[:2] @ self.heading) >= 0.0

    def update(self, t: float, positions: np.ndarray) -> dict[str, float]:
        """The rest lengths (name -> m) to command at time ``t`` s, given the node positions (N, 3) m."""
        if self.ready(t, positions):
            self.cycle += 1
            self.start = t
            self.cables, self.landing, self.edge = self.planner.plan(positions, self.heading)
        f = self.ramp(t - self.start) if self.cycle >= 0 else 0.0
        return {c: self.rest[c] * (1.0 - (1.0 - PULL) * f) for c in self.cables}


def latest_pose(poses):
    """The newest ``node_poses`` message a DDS reader holds, as (its stamp s, node positions (N, 3) m), or None."""
    got, _ = poses.take_messages()
    if not got:
        return None
    msg = got[-1]
    return (msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
            np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses]))


def planner_for(scene) -> RollPlanner:
    """The :class:`RollPlanner` of a :class:`tensegrity_sim.Scene`."""
    return RollPlanner(scene.node_names, [(s.name, *s.nodes) for s in scene.struts],
                       [(c.name, *c.nodes) for c in scene.cables])


def offline_node(scene: str, method: str):
    """The node's logic on ``scene`` in this process, 1 ms steps, no transport: (the loaded scene, its simulator,
    the logic, the list its ``node_poses`` messages are appended to as it publishes)."""
    import warnings

    from tensegrity_sim import Simulator, load_scene
    from tensegrity_sim.ros.node_logic import NodeSettings, SimNodeLogic

    loaded = load_scene(scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the inextensible method's prestress warning, if asked for
        sim = Simulator(loaded, method=method, dt=1e-3)
    poses = []
    logic = SimNodeLogic(sim, NodeSettings(scene=scene, method=method, dt=sim.dt, log_path=""),
                         transport=lambda key, msg: poses.append(msg) if key == "node_poses" else None,
                         clock=lambda: 0.0)
    return loaded, sim, logic, poses


def drive_offline(cycles: int, heading=(1.0, 0.0), method: str = "auto", scene: str = "icosahedron_ground"):
    """Roll through the node's logic in this process (no ROS, no DDS): the controller reads each published
    ``node_poses`` message and sends ``cable_rest_lengths`` messages, as over DDS. Returns the controller
    and, per cycle, (edge tipped over, cables reeled, planned landing triangle, triangle stood on at the
    cycle's end, centre of mass (3,) m and time s at its end, when the next starts); the first entry is the
    start."""
    from tensegrity_sim.ros import messages as M

    loaded, sim, logic, poses = offline_node(scene, method)
    planner = planner_for(loaded)
    controller = RollController(planner, dict(zip(loaded.cable_names, loaded.cable_rest_lengths)), heading)
    history = [(None, [], (), tuple(planner.nodes[i] for i in planner.base(sim.positions)),
                sim.positions.mean(axis=0), 0.0)]
    limit = 6.0 * cycles + 10.0   # s of simulated time: a cycle takes about 3
    while True:
        if logic.step() is None:
            raise RuntimeError("the node paused after a failed step")
        if logic.publication_due:
            logic.publish()
            msg = poses[-1]
            x = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses])
            t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            before = (controller.cycle, controller.edge, controller.cables, controller.landing)
            command = controller.update(t, x)
            if controller.cycle != before[0] and before[0] >= 0:   # a cycle ended where the next starts
                history.append((*before[1:], tuple(planner.nodes[i] for i in planner.base(x)), x.mean(axis=0),
                                t))
                if len(history) > cycles:
                    return controller, history
            if t > limit:
                raise RuntimeError(f"no cycle started in the {limit:.0f} s allowed for {cycles} cycles")
            if not command:
                continue
            reason = logic.receive("cable_rest_lengths", M.joint_state(M.header(0, ""), list(command),
                                                                        position=list(command.values())))
            if reason is not None:
                raise RuntimeError(f"the node refused the command: {reason}")



def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--domain-id", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    parser.add_argument("--interface", default="lo", help="network interface (default: lo)")
    parser.add_argument("--node", default="/tensegrity_sim", help="the simulator node's name")
    parser.add_argument("--scene", default="icosahedron_ground", help="the scene the node runs")
    parser.add_argument("--heading", nargs=2, type=float, default=(1.0, 0.0), metavar=("X", "Y"))
    parser.add_argument("--cycles", type=int, default=3, help="command cycles, then stop")
    parser.add_argument("--offline", action="store_true",
                        help="drive the node's logic in this process (no DDS) and report the distance per cycle")
    args = parser.parse_args(argv)
    if args.offline:
        _, history = drive_offline(args.cycles, args.heading, scene=args.scene)
        for k in range(1, len(history)):
            edge, cables, landing, stood, com, t = history[k]
            step = (com - history[k - 1][4])[:2]
            print(f"cycle {k - 1}: over {'-'.join(edge)} reeling {','.join(cables)}: planned {','.join(landing)}, "
                  f"stands on {','.join(stood)} at {t:.2f} s; centre of mass moved {np.round(step, 3).tolist()} m "
                  f"({float(np.linalg.norm(step)):.3f} m, {float(step @ np.asarray(args.heading) / np.linalg.norm(args.heading)):.3f} m along the heading)")
        total = (history[-1][4] - history[0][4])[:2]
        print(f"rolled {float(np.linalg.norm(total)):.3f} m in {args.cycles} cycles "
              f"({float(np.linalg.norm(total)) / args.cycles:.3f} m per cycle) in {history[-1][5]:.2f} s")
        return 0
    from tensegrity_sim import load_scene
    from tensegrity_sim.ros import messages as M
    from tensegrity_sim.ros.dds import Participant

    scene = load_scene(args.scene)
    controller = RollController(planner_for(scene), dict(zip(scene.cable_names, scene.cable_rest_lengths)),
                                args.heading)
    with Participant(domain_id=args.domain_id, interface=args.interface, node_name="roll_controller") as dds:
        poses = dds.reader(f"{args.node}/node_poses", "geometry_msgs/msg/PoseArray")
        rest = dds.writer(f"{args.node}/cable_rest_lengths", "sensor_msgs/msg/JointState")
        start, t0 = None, None
        while True:
            dds.wait(0.01)
            latest = latest_pose(poses)
            if latest is None:
                continue
            t, x = latest
            if t0 is None:
                t0, start = t, x.mean(axis=0)
            cycle = controller.cycle
            command = controller.update(t - t0, x)
            if controller.cycle == args.cycles:
                break
            if controller.cycle != cycle:
                print(f"cycle {controller.cycle}: over {controller.edge}, reeling {controller.cables}, "
                      f"centre of mass {np.round(x.mean(axis=0) - start, 3).tolist()} m", flush=True)
            if command:
                rest.write(M.joint_state(M.header(time.time_ns(), ""), list(command),
                                         position=list(command.values())))
        print(f"rolled {float(np.linalg.norm((x.mean(axis=0) - start)[:2])):.3f} m in {args.cycles} cycles")
    return 0


if __name__ == "__main__":
    sys.exit(main())
