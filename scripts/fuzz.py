"""The long fuzz run (issue 13): the suite's fuzz targets (test/test_fuzz.py) with more cases and fresh
randomness, then the counts per target: tried, accepted, refused cleanly, crashed.

Run: ``python scripts/fuzz.py [--scale N]`` (default 20: twenty times the suite's cases, about 100 000).
A crash fails its target (hypothesis shrinks it and prints the smallest input); the other targets still
run. Exit status 1 if anything crashed.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

TEST_DIR = Path(__file__).resolve().parents[1] / "test"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=20.0, help="cases per target, times the suite's (default 20)")
    parser.add_argument("--ci", action="store_true", help="the suite's own cases (its fixed seed) instead of fresh "
                                                          "ones: with --scale 1, the counts of a CI run")
    args = parser.parse_args()
    os.environ["FUZZ_SCALE"] = str(args.scale)
    os.environ["FUZZ_RANDOM"] = "0" if args.ci else "1"
    sys.path.insert(0, str(TEST_DIR))
    import pytest

    import fuzz_cases

    start = time.perf_counter()
    status = pytest.main(["-q", "-p", "no:cacheprovider", "-W", "ignore", str(TEST_DIR / "test_fuzz.py")])
    wall = time.perf_counter() - start
    targets = sorted({target for target, _ in fuzz_cases.TALLY})
    print(f"\n{'target':<32}{'tried':>9}{'accepted':>10}{'refused':>10}{'crashed':>9}")
    totals = [0, 0, 0, 0]
    for target in targets:
        counts = [fuzz_cases.TALLY[target, kind] for kind in ("accepted", "refused", "crashed")]
        row = [sum(counts), *counts]
        totals = [a + b for a, b in zip(totals, row)]
        print(f"{target:<32}" + "".join(f"{n:>{w}}" for n, w in zip(row, (9, 10, 10, 9))))
    print(f"{'total':<32}" + "".join(f"{n:>{w}}" for n, w in zip(totals, (9, 10, 10, 9))))
    print(f"scale {args.scale:g}, {wall:.0f} s")
    return 1 if totals[3] or status else 0


if __name__ == "__main__":
    sys.exit(main())
