"""Add Gaussian noise to every node position of a log's ``node_poses`` (motion capture's millimetres), writing a
new log that is the same in everything else: ``python scripts/add_pose_noise.py RUN.mcap NOISY.mcap --sigma
0.001 [--seed 0]`` (sigma in m, on each coordinate). ``tensegrity-sim fit NOISY.mcap`` then estimates the noise
level and fits through it."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Callable

import numpy as np

from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.interface import TOPICS
from tensegrity_sim.ros.log import RUN_INFO, LogWriter
from tensegrity_sim.ros.log_reader import LogReader, log_channels

TYPENAME = TOPICS["node_poses"].typename


def rewrite_poses(source: Path, target: Path, change: Callable[[np.ndarray], np.ndarray | None]) -> int:
    """Copy the log ``source`` to ``target`` with every node_poses message's positions (N, 3) replaced by
    ``change(positions)`` (None: the message left out). Returns the node_poses messages seen."""
    seen = 0
    with LogReader(source) as reader:
        run_info = reader.metadata[RUN_INFO]
        channels = log_channels(reader)
        poses_topic = next(c[0] for c in channels if c[1] == TYPENAME)
        with LogWriter(target, channels, run_info) as writer:
            for message in reader.messages():
                data = message.data
                if message.topic == poses_topic:
                    seen += 1
                    msg = M.deserialize(data, TYPENAME)
                    x = np.array([(p.position.x, p.position.y, p.position.z) for p in msg.poses])
                    x = change(x)
                    if x is None:
                        continue
                    for p, (a, b, c) in zip(msg.poses, x.tolist()):
                        p.position.x, p.position.y, p.position.z = a, b, c
                    data = M.serialize(msg, TYPENAME)
                writer.write(message.topic, data, message.log_time)
    return seen


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--sigma", type=float, default=1e-3, help="standard deviation, m (default 0.001)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    n = rewrite_poses(args.log, args.out, lambda x: x + rng.normal(scale=args.sigma, size=x.shape))
    print(f"{args.out}: {n} node_poses messages, Gaussian noise of {args.sigma:g} m on every coordinate")
    return 0


if __name__ == "__main__":
    sys.exit(main())
