"""Many random throws of the built-in robots onto a plane (issue 28; ``test/throw_cases.py``): each must run
its steps with no error, a finite state, no node sinking more than 0.1 mm into the ground and (inextensible,
rigid struts, plastic ground) no energy created. Prints each failing case (replayable: a dict for
``throw_cases.run_throw``) and the counts; exit status 1 if any failed.

Run: ``python scripts/throws.py [--count N] [--seed S] [--steps K]`` (default 200 throws of 400 steps).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

import throw_cases  # noqa: E402

SINK_TOL = 1e-4   # m


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=400)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    failed, start = 0, time.perf_counter()
    for i in range(args.count):
        case = throw_cases.random_throw(rng, steps=args.steps)
        out = throw_cases.run_throw(case)
        problems = throw_cases.problems(case, out)
        if problems:
            failed += 1
            print(f"throw {i}: {'; '.join(problems)}\n  case: {case}", flush=True)
    print(f"{args.count} throws of {args.steps} steps (seed {args.seed}): {args.count - failed} passed, "
          f"{failed} failed, {time.perf_counter() - start:.0f} s")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
