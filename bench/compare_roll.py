"""How far ``icosahedron_ground`` rolls in 10 s under each controller, measured the same way (issue 50).

Each controller drives the node's logic in this process (``examples/policy_controller.py``'s ``drive_offline``:
``serve``'s node, elastic method, 1 ms steps, ``node_poses`` published at 100 Hz, each controller answering
them with ``cable_rest_lengths`` as it does over DDS), from the scene's pose at rest, toward +x:

* ``roll_controller``: ``examples/roll_controller.py``'s punctuated rolling (heading +x), called at every pose;
* ``policy``: ``--policy`` (default ``examples/policies/roll_icosahedron.npz``, ``examples/train_roll.py``'s);
* ``gait``: ``--gait`` (default ``examples/gait.yaml``, optimize-gait's CMA-ES), sampled at 50 Hz.

``along_m``: the centre of mass's displacement along +x; ``across_m``: along +y; ``ratio``: ``along_m`` over the
roll controller's. CSV: ``bench/results/compare_roll.csv``.

    python3 bench/compare_roll.py --seconds 10
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "examples"))

import policy_controller as pc  # noqa: E402
import roll_controller as rc  # noqa: E402

from bench.tables import write_csv  # noqa: E402
from tensegrity_sim import load_scene  # noqa: E402

RESULTS = ROOT / "bench" / "results"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--policy", default=str(ROOT / "examples" / "policies" / "roll_icosahedron.npz"))
    parser.add_argument("--gait", default=str(ROOT / "examples" / "gait.yaml"))
    parser.add_argument("--out", default=str(RESULTS / "compare_roll.csv"))
    args = parser.parse_args(argv)
    scene = load_scene("icosahedron_ground")
    controllers = [
        ("roll_controller", rc.RollController(rc.planner_for(scene),
                                              dict(zip(scene.cable_names, scene.cable_rest_lengths)), (1.0, 0.0)),
         None),
        ("policy", pc.load_player(scene, policy=args.policy), None),
        ("gait", pc.load_player(scene, gait=args.gait), 50.0),
    ]
    rows = []
    for name, player, rate in controllers:
        moved = pc.drive_offline(player, args.seconds, rate)
        rows.append({"controller": name, "seconds": args.seconds, "along_m": float(moved[0]),
                     "across_m": float(moved[1])})
    for row in rows:
        row["ratio"] = row["along_m"] / rows[0]["along_m"]
        print(f"{row['controller']:16s} {row['along_m']:7.3f} m along +x, {row['across_m']:7.3f} m across in "
              f"{args.seconds:g} s: {row['ratio']:.2f}x the roll controller")
    write_csv(Path(args.out), rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
