"""The throw benchmark (issue 47): many random throws of the built-in robots onto a plane over a wide space
(``test/throw_cases.py``'s ``wide_throw``: both methods, the three free robots, drop heights 1 um to 0.5 m with
a third set down at rest, friction 0-2, restitution 0-1, spins, two cable commands mid-run, member contact
response on a third), each held to what a well-posed run satisfies (``throw_cases.problems``: no error, a
finite state, nothing sunk beyond 0.1 mm, no energy created where that is a law).

Throw ``i`` of ``--seed S`` is drawn from ``numpy.random.default_rng([47, S, i])``: any one replays alone
(``--first i --count 1``). Prints every failing case (a dict for ``throw_cases.run_throw``) and writes the
counts per method and robot to ``bench/results/throws.csv`` (``--out``), the last row the total.

``--rods``: elastic throws of the same space with the robots' rigid struts carrying their mass as rods (the
consistent mass blocks and a payload each, ``throw_cases.rod_throw``), to ``bench/results/throws_rods.csv``.

Run: ``python3 bench/bench_throws.py [--count N] [--seed S] [--first I] [--steps K] [--out PATH] [--rods]``
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "test")]

import throw_cases  # noqa: E402

from bench.tables import RESULTS, write_csv  # noqa: E402


def case_of(seed: int, index: int, steps: int, rods: bool = False) -> dict:
    draw = throw_cases.rod_throw if rods else throw_cases.wide_throw
    return draw(np.random.default_rng([47 if not rods else 46, seed, index]), steps=steps)


def write(path: Path, groups: dict, args) -> dict:
    """The counts per method and robot, then their total (returned), to the CSV ``path``."""
    rows = [groups[k] for k in sorted(groups)]
    total = {"method": "all", "robot": "all", "steps": args.steps, "seed": args.seed}
    for key in ("throws", "stopped", "unsound", "set_down", "contact_response"):
        total[key] = sum(r[key] for r in rows)
    write_csv(path, rows + [total], FIELDS)
    return total


FIELDS = ["method", "robot", "throws", "stopped", "unsound", "set_down", "contact_response", "steps", "seed"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--first", type=int, default=0, help="index of the first throw")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--out", type=Path, default=None, help="default bench/results/throws.csv "
                        "(throws_rods.csv with --rods)")
    parser.add_argument("--rods", action="store_true", help="elastic throws with the robots' rods carrying their "
                        "mass (consistent blocks, payloads; throw_cases.rod_throw, drawn from [46, S, i])")
    args = parser.parse_args(argv)
    if args.out is None:
        args.out = RESULTS / ("throws_rods.csv" if args.rods else "throws.csv")
    groups: dict[tuple, dict] = {}
    start = time.perf_counter()
    for i in range(args.first, args.first + args.count):
        case = case_of(args.seed, i, args.steps, args.rods)
        out = throw_cases.run_throw(case)
        found = throw_cases.problems(case, out)
        row = groups.setdefault((case["method"], case["robot"]), {
            "method": case["method"], "robot": case["robot"], "throws": 0, "stopped": 0, "unsound": 0,
            "set_down": 0, "contact_response": 0, "steps": args.steps, "seed": args.seed})
        row["throws"] += 1
        row["stopped"] += out["error"] is not None
        row["unsound"] += bool(found) and out["error"] is None
        row["set_down"] += case["height"] < 1e-3
        row["contact_response"] += case.get("response") is not None
        if found:
            print(f"throw {i}: {'; '.join(found)}\n  case: {case}", flush=True)
        if (i - args.first + 1) % 25 == 0:   # the counts so far, written as they stand
            print(f"{i - args.first + 1} throws, {time.perf_counter() - start:.0f} s", flush=True)
            write(args.out, groups, args)
    total = write(args.out, groups, args)
    print(f"{total['throws']} throws {args.first}..{args.first + args.count - 1} of {args.steps} steps (seed "
          f"{args.seed}): {total['stopped']} stopped, {total['unsound']} unsound otherwise, "
          f"{time.perf_counter() - start:.0f} s; {args.out}")
    return 1 if total["stopped"] or total["unsound"] else 0


if __name__ == "__main__":
    sys.exit(main())
