"""What the non-finite guard of ``Simulator.step`` costs (issue 13), per step.

Run: ``python bench/bench_guard.py [--steps N] [--repeats R]``. For each built-in scene and method it
times ``Simulator.step()`` (guard included) and the guard alone (:func:`~tensegrity_sim.simulator.finite_step`
on that step's result), best of ``--repeats`` runs of ``--steps`` calls taking turns, CPU time, and prints
the guard's share of a step. Never asserts a time.
"""
from __future__ import annotations

import argparse
import time
import warnings

import tensegrity_sim as ts
from tensegrity_sim.simulator import finite_step

DT = 1e-3


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    warnings.simplefilter("ignore", ts.LengthOffsetWarning)
    print(f"{'scene':<14}{'method':<14}{'step':>10}{'guard':>10}{'share':>8}")
    for name in ts.builtin_scenes():
        for method in ("elastic", "inextensible"):
            sim = ts.Simulator(ts.load_scene(name), method=method, dt=DT)
            out = sim._method.step(sim._state)  # a result of the right shapes for the guard alone
            best = {"step": float("inf"), "guard": float("inf")}
            for _ in range(args.repeats):
                start = time.process_time()
                for _ in range(args.steps):
                    sim.step()
                best["step"] = min(best["step"], time.process_time() - start)
                start = time.process_time()
                for _ in range(args.steps):
                    finite_step(out)
                best["guard"] = min(best["guard"], time.process_time() - start)
            step, guard = best["step"] / args.steps, best["guard"] / args.steps
            print(f"{name:<14}{method:<14}{step * 1e6:>8.1f}us{guard * 1e6:>8.2f}us{100 * guard / step:>7.1f}%",
                  flush=True)


if __name__ == "__main__":
    main()
