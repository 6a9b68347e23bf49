"""What MCAP logging costs, per step, at 1 kHz stepping and 100 Hz publishing.

Run: ``python bench/bench_log.py [SCENE ...] [--steps N] [--repeats R]`` (default: the built-in scenes).
For each scene (dt = 1 ms, publish_rate = 100 Hz, so one publication every 10 steps) it times, per step,
best of ``--repeats`` runs after a warm-up:

* ``bare``: ``Simulator.step()`` alone;
* ``node``: the node logic stepping and building every output message at 100 Hz, sent nowhere;
* ``node+log``: the same, every input and output also serialised to CDR and written to an MCAP file.

``log`` = node+log - node is the logging cost; it is printed against the node's step time and against the
1 ms a step may take at 1 kHz. Never asserts a time.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import tensegrity_sim as ts
from tensegrity_sim.ros.log import LogRecorder
from tensegrity_sim.ros.node_logic import NodeSettings, SimNodeLogic

DT = 1e-3
PUBLISH_RATE = 100.0


def per_step(run, steps: int, repeats: int) -> float:
    """Best time per step, s, of ``run(steps)`` over ``repeats`` runs."""
    run(min(steps, 500))  # warm-up
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        run(steps)
        best = min(best, time.perf_counter() - start)
    return best / steps


def measure(scene: ts.Scene, steps: int, repeats: int, folder: Path) -> tuple[float, float, float]:
    settings = NodeSettings(scene=scene.name, dt=DT, publish_rate=PUBLISH_RATE)

    def bare(n):
        sim = ts.Simulator(scene, dt=DT)
        for _ in range(n):
            sim.step()

    def node(n, log=False):
        logic = SimNodeLogic(ts.Simulator(scene, dt=DT), settings)
        recorder = LogRecorder(folder / f"{scene.name}.mcap", logic.channels(), logic.run_info()) if log else None
        logic.recorder = recorder
        for _ in range(n):
            logic.step()
            if logic.publication_due:
                logic.publish()
        if recorder is not None:
            recorder.finish()

    return (per_step(bare, steps, repeats), per_step(node, steps, repeats),
            per_step(lambda n: node(n, log=True), steps, repeats))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", help="built-in names or YAML files (default: the built-ins)")
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    names = args.scenes or list(ts.builtin_scenes())
    print(f"dt = {DT * 1e3:g} ms, publish every {NodeSettings(dt=DT, publish_rate=PUBLISH_RATE).publish_every} "
          f"steps; times per step, best of {args.repeats} x {args.steps} steps")
    print(f"{'scene':<14}{'bare':>10}{'node':>10}{'node+log':>10}{'log':>10}  {'log/node':>9}  {'log/1ms':>8}")
    with tempfile.TemporaryDirectory() as folder:
        for name in names:
            scene = ts.load_scene(name)
            bare, node, logged = measure(scene, args.steps, args.repeats, Path(folder))
            log = logged - node
            print(f"{scene.name:<14}{bare * 1e6:>8.1f}us{node * 1e6:>8.1f}us{logged * 1e6:>8.1f}us"
                  f"{log * 1e6:>8.1f}us  {100 * log / node:>8.1f}%  {100 * log / DT:>7.2f}%", flush=True)


if __name__ == "__main__":
    main()
