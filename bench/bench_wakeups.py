"""How late this machine wakes a thread that sleeps to a 1 ms grid, on the default scheduler and on
``SCHED_FIFO`` (the node's ``thread_priority``, through the node's own :class:`StepperScheduling`): what a live
node's ticks start from before any of its work. A wake-up over a period late is one the node owes two steps
for (``bench/bench_node.py``'s catch-up ticks).

Run: ``python3 bench/bench_wakeups.py [--wakeups 20000] [--priority 50] [--csv FILE]`` (default CSV:
``bench/results/wakeups.csv``). The policies take turns, the machine otherwise idle; FIFO needs root,
CAP_SYS_NICE or an rtprio limit (else its row says the OS refused it). Prints figures; never asserts a time.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

from bench.tables import RESULTS, write_csv  # noqa: E402
from tensegrity_sim.ros.live import StepperScheduling  # noqa: E402

PERIOD = 1e-3   # s


def lateness(wakeups: int) -> np.ndarray:
    """Each wake-up's lateness (s) after its time on a grid of :data:`PERIOD`, sleeping to it."""
    late = np.empty(wakeups)
    start = time.monotonic()
    for k in range(wakeups):
        due = start + (k + 1) * PERIOD
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        late[k] = time.monotonic() - due
    return late


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wakeups", type=int, default=20000)
    parser.add_argument("--priority", type=int, default=50, help="the SCHED_FIFO priority of the second policy")
    parser.add_argument("--rounds", type=int, default=2, help="turns of the two policies")
    parser.add_argument("--csv", type=Path, default=RESULTS / "wakeups.csv")
    args = parser.parse_args()
    refused = []

    class Log:   # StepperScheduling's warning, kept for the row
        def warning(self, text):
            refused.append(text)

    rows = []
    for _ in range(args.rounds):
        for priority in (0, args.priority):
            scheduling = StepperScheduling(priority, Log() if priority else logging.getLogger(__name__))
            scheduling.follow(True)
            try:
                late = lateness(args.wakeups)
            finally:
                scheduling.restore()
            policy = "default" if priority == 0 else ("refused" if refused else f"SCHED_FIFO {priority}")
            row = {"scheduler": policy, "wakeups": args.wakeups, "period_ms": PERIOD * 1e3,
                   "late_over_a_period": int((late > PERIOD).sum()), "late_p50_ms": float(np.median(late) * 1e3),
                   "late_p999_ms": float(np.percentile(late, 99.9) * 1e3), "late_max_ms": float(late.max() * 1e3)}
            rows.append(row)
            print(f"{policy:>14}: {row['late_over_a_period']} of {args.wakeups} wake-ups over a period late; "
                  f"lateness p50 {row['late_p50_ms']:.3f} ms, p99.9 {row['late_p999_ms']:.3f} ms, "
                  f"max {row['late_max_ms']:.2f} ms", flush=True)
    write_csv(args.csv, rows)
    print(f"wrote {args.csv}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
