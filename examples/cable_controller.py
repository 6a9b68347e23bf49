#!/usr/bin/env python3
"""A small controller for ``tensegrity-sim serve``, over DDS, with no ROS install.

It drives the node the way a ROS 2 controller would, on the node's topics: it reads ``cable_states``
(and ``cable_impulses``) and publishes ``cable_rest_lengths``, a periodic contraction: for half of every
period the chosen cables are let out (rest length ``(1 + slack) L``, so they go slack), for the other
half reeled in (``(1 - pull) L``, so they snap taut), where ``L`` is each cable's length when the
controller starts. Every slack and every snap is printed as it is seen, with the snap's impulse.

    tensegrity-sim serve prism3 --transport dds &
    python3 examples/cable_controller.py --cables c0,c1,c2 --period 1.0 --duration 10

``--push NODE FX FY FZ`` also pushes a node with a force (N, world axes) for the first 0.2 s
(``external_wrench``, then a zero wrench to clear it).
Needs the "dds" extra: ``pip install -e ".[dds]"``.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.dds import Participant

PUSH_TIME = 0.2  # s


def _stamp(msg) -> tuple[int, int]:
    return msg.header.stamp.sec, msg.header.stamp.nanosec


def rest_length_command(names: list[str], lengths: np.ndarray):
    """sensor_msgs/JointState: ``name`` = cables, ``position`` = rest lengths, m."""
    return M.joint_state(M.header(time.time_ns(), ""), names, position=lengths)


def wrench_command(node: str, force):
    """geometry_msgs/WrenchStamped on ``node`` (the frame id), ``force`` N in world axes."""
    return M.wrench_stamped(M.header(time.time_ns(), node), force)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--domain-id", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    parser.add_argument("--interface", default="lo", help="network interface (default: lo)")
    parser.add_argument("--node", default="/tensegrity_sim", help="the simulator node's name")
    parser.add_argument("--cables", help="comma-separated cables to drive (default: every cable)")
    parser.add_argument("--period", type=float, default=1.0, help="s of wall-clock time per cycle")
    parser.add_argument("--slack", type=float, default=0.15, help="let out by this fraction of L")
    parser.add_argument("--pull", type=float, default=0.05, help="reel in by this fraction of L")
    parser.add_argument("--duration", type=float, default=math.inf, help="s, then stop (default: Ctrl-C)")
    parser.add_argument("--push", nargs=4, metavar=("NODE", "FX", "FY", "FZ"))
    args = parser.parse_args(argv)

    with Participant(domain_id=args.domain_id, interface=args.interface, node_name="cable_controller") as dds:
        states = dds.reader(f"{args.node}/cable_states", "sensor_msgs/msg/JointState")
        impulses = dds.reader(f"{args.node}/cable_impulses", "sensor_msgs/msg/JointState")
        rest = dds.writer(f"{args.node}/cable_rest_lengths", "sensor_msgs/msg/JointState")
        wrench = dds.writer(f"{args.node}/external_wrench", "geometry_msgs/msg/WrenchStamped")

        print(f"waiting for {args.node}/cable_states on domain {args.domain_id} ...", flush=True)
        first = None
        while first is None:
            dds.wait(1.0)
            got, _ = states.take_messages()
            first = got[-1] if got else None
        names = list(first.name)
        driven = args.cables.split(",") if args.cables else names
        unknown = sorted(set(driven) - set(names))
        if unknown:
            parser.error(f"--cables: unknown cable(s) {', '.join(unknown)} (cables: {', '.join(names)})")
        index = [names.index(c) for c in driven]
        reference = np.asarray(first.position, float)[index]
        print(f"driving {', '.join(driven)}; L = {np.round(reference, 4).tolist()} m", flush=True)
        if args.push:
            node, force = args.push[0], [float(v) for v in args.push[1:]]
            while wrench.matched == 0:
                time.sleep(0.01)
            wrench.write(wrench_command(node, force))
            print(f"pushing {node} with {force} N for {PUSH_TIME} s", flush=True)

        slack = np.zeros(len(driven), bool)
        pending: dict[tuple[int, int], dict] = {}  # stamp -> tensions (N), impulses (N s) of the driven cables
        phase = None
        start = time.monotonic()
        while time.monotonic() - start < args.duration:
            elapsed = time.monotonic() - start
            if args.push and elapsed >= PUSH_TIME:
                wrench.write(wrench_command(node, [0.0, 0.0, 0.0]))  # zero clears the force
                args.push = None
            released = (elapsed / args.period) % 1.0 < 0.5
            if released != phase:
                phase = released
                factor = 1.0 + args.slack if released else 1.0 - args.pull
                rest.write(rest_length_command(driven, factor * reference))
            dds.wait(0.01)
            # Impulses and states are published together, with the same stamp: pair them by it.
            for msg in impulses.take_messages()[0]:
                pending.setdefault(_stamp(msg), {})["impulse"] = np.asarray(msg.effort, float)[index]
            for msg in states.take_messages()[0]:
                pending.setdefault(_stamp(msg), {})["tension"] = np.asarray(msg.effort, float)[index]
            for stamp in sorted(s for s, got in pending.items() if len(got) == 2):
                got = pending.pop(stamp)
                now_slack = got["tension"] == 0.0
                t = stamp[0] + 1e-9 * stamp[1]
                for k in np.flatnonzero(now_slack & ~slack):
                    print(f"t = {t:7.3f} s  {driven[k]} goes slack", flush=True)
                for k in np.flatnonzero(~now_slack & slack):
                    print(f"t = {t:7.3f} s  {driven[k]} snaps taut: {got['tension'][k]:.4g} N, impulse "
                          f"{got['impulse'][k]:.4g} N s since the previous state", flush=True)
                slack = now_slack
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(0)
