"""Steps per second of each method on the built-in scenes and on large towers (dt = 1 ms).

Run: ``python bench/bench_steps.py [--steps N] [--methods elastic,...]``. Prints a table; never
asserts a time. Each figure is the best of ``--repeats`` timed runs after a warm-up run.
"""
from __future__ import annotations

import argparse
import time

import tensegrity_sim as ts
from tensegrity_sim import formfinding


def scenes():
    for name in ("prism3", "icosahedron"):
        yield name, ts.load_scene(name)
    for stages in (10, 50):
        # without gravity: a uniform tower of more than 15 stages buckles under its own weight
        yield f"tower{stages}", ts.Scene.from_dict(formfinding.tower(stages, gravity=(0.0, 0.0, 0.0)))


def steps_per_second(scene, method, dt, steps, repeats):
    sim = ts.Simulator(scene, method=method, dt=dt)
    sim.run(steps=min(steps, 500))  # warm-up
    best = float("inf")
    for _ in range(repeats):
        sim.reset()
        start = time.perf_counter()
        for _ in range(steps):
            sim.step()
        best = min(best, time.perf_counter() - start)
    return steps / best


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--methods", default=",".join(sorted(ts.METHODS)))
    args = parser.parse_args()
    methods = args.methods.split(",")
    print(f"{'scene':<14}{'nodes':>6}{'members':>8}  " + "".join(f"{m:>16}" for m in methods))
    for name, scene in scenes():
        row = f"{name:<14}{len(scene.nodes):>6}{len(scene.struts) + len(scene.cables):>8}  "
        for m in methods:
            try:
                row += f"{steps_per_second(scene, m, args.dt, args.steps, args.repeats):>12,.0f} st/s"
            except ValueError as exc:
                row += f"{'refused':>16}"
                print(f"  {name}/{m}: {exc}")
        print(row, flush=True)


if __name__ == "__main__":
    main()
