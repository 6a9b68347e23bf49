"""Write the built-in rolling schedules (tensegrity_sim/schedules/superball_roll.yaml, three_bar_roll.yaml).

``superball_roll``: examples/roll_controller.py's closed loop (find the cable triangle the robot stands on,
reel in the three cables that tip it over the edge facing +x, let them out, wait until it sits flat) run on
the built-in ``superball`` in this process; each cycle's ramp corners (start, pulled, held, released) are
written as a command schedule that replays the same rolls open loop. ``three_bar_roll``: the 3-bar's tip
over an edge of its base triangle, by reeling in two of its actuated cables (see the schedule's header).

    python3 scripts/roll_schedules.py        # rewrites both files, prints how far each robot rolled
"""
from __future__ import annotations

import importlib.util
import sys
import warnings
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import tensegrity_sim as ts  # noqa: E402
from tensegrity_sim.commands import load_commands  # noqa: E402

SCHEDULES = ROOT / "tensegrity_sim" / "schedules"


def _controller():
    spec = importlib.util.spec_from_file_location("roll_controller", ROOT / "examples" / "roll_controller.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def centre(scene: ts.Scene, positions: np.ndarray) -> np.ndarray:
    """The centre of mass (3,) m of node positions (N, 3) m (the lumped masses)."""
    return (scene.masses[:, None] * positions).sum(axis=0) / scene.masses.sum()


def superball_points(cycles: int = 3, duration: float = 12.0) -> list[dict]:
    rc = _controller()
    scene = ts.load_scene("superball")
    sim = ts.Simulator(scene, method="elastic", dt=1e-3)
    rest = dict(zip(scene.cable_names, sim.rest_lengths))
    control = rc.RollController(rc.planner_for(scene), rest)
    points, starts = [], []
    while sim.time < duration and len(starts) <= cycles:
        command = control.update(sim.time, sim.positions)
        if control.cycle >= len(starts):
            if control.cycle == cycles:
                break
            starts.append(round(sim.time, 3))
            cables = sorted(command)
            full = {c: float(rest[c]) for c in cables}
            pulled = {c: float(rest[c] * rc.PULL) for c in cables}
            t0 = starts[-1]
            points += [{"time": t0, "rest_lengths": full},
                       {"time": round(t0 + rc.REEL, 3), "rest_lengths": pulled},
                       {"time": round(t0 + rc.REEL + rc.HOLD, 3), "rest_lengths": pulled},
                       {"time": round(t0 + 2 * rc.REEL + rc.HOLD, 3), "rest_lengths": full}]
        sim.set_rest_lengths(command)
        sim.run(steps=10)
    return points


def three_bar_points() -> list[dict]:
    scene = ts.load_scene("three_bar")
    rest = dict(zip(scene.cable_names, scene.cable_rest_lengths))
    pull = {c: float(0.6 * rest[c]) for c in ("c0", "c2")}
    full = {c: float(rest[c]) for c in pull}
    return [{"time": 0.0, "rest_lengths": full}, {"time": 0.4, "rest_lengths": pull},
            {"time": 1.2, "rest_lengths": pull}, {"time": 1.6, "rest_lengths": full}]


class _Plain(yaml.SafeDumper):
    """Writes repeated values out (no YAML anchors: a schedule reads as it runs)."""

    def ignore_aliases(self, data) -> bool:
        return True


HEADERS = {
    "superball_roll.yaml": (
        "superball rolling towards +x: three punctuated rolls, each reeling in three cables to 60 % of their\n"
        "rest lengths over 0.3 s, holding 0.7 s and letting them out over 0.3 s, the next once the robot sits\n"
        "flat on its new cable triangle (examples/roll_controller.py's rule, run closed loop to find them)."),
    "three_bar_roll.yaml": (
        "three_bar tipping over an edge of its base triangle and rolling onto its side: the actuated bottom\n"
        "cables c0 (n0-n1) and c2 (n2-n0) are reeled in to 60 % over 0.4 s, held 0.8 s and let out over 0.4 s\n"
        "(of the actuated sets of one to three cables at 40, 60 or 80 %, with the rods' consistent mass, the one\n"
        "that moves the centre farthest in 3 s and leaves no cable slack: 0.32 m; the same cables at 40 % move\n"
        "it 1 % farther and leave two slack; its two mirror images tip it over the other two edges)."),
}


def main() -> int:
    warnings.simplefilter("ignore")
    for name, points, duration in (("superball_roll.yaml", superball_points(), 12.0),
                                   ("three_bar_roll.yaml", three_bar_points(), 4.0)):
        text = ("# GENERATED FILE - regenerate with: python3 scripts/roll_schedules.py\n"
                + "".join(f"# {line}\n" for line in HEADERS[name].splitlines())
                + yaml.dump(points, Dumper=_Plain, default_flow_style=None, sort_keys=False, width=120))
        (SCHEDULES / name).write_text(text)
        scene = ts.load_scene(name.split("_roll")[0])
        sim = ts.Simulator(scene, method="elastic", dt=1e-3)
        start = centre(scene, sim.positions)
        sim.run(duration=duration, commands=load_commands(SCHEDULES / name, scene))
        moved = centre(scene, sim.positions) - start
        print(f"{name}: the centre moved {np.linalg.norm(moved[:2]):.3f} m horizontally in {duration:g} s "
              f"(x {moved[0]:+.3f} m, y {moved[1]:+.3f} m)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
