"""How late this machine wakes a thread that sleeps to a 1 ms grid, on the default scheduler and on
``SCHED_FIFO`` (the node's ``thread_priority``, through the node's own :class:`StepperScheduling`): what a live
node's ticks start from before any of its work. A wake-up over a period late is one the node owes two steps
for (``bench/bench_node.py``'s catch-up ticks).

Beside it, under the same policy, the pauses of a thread that never sleeps: it reads the clock in a loop, in
turns of 50 ms with 50 ms of sleep between them (half the time, as a stepping thread on FIFO may run), and
each time the clock moved over a period between two reads is a pause: the thread held off its core, by the
OS or the hypervisor. Those that the thread's own CPU time (``time.thread_time``) moved through too are
charged to it as work it did: a virtual machine whose host stops it counts that time as the running
thread's, and then a node's tick or idle work of under a period takes over one, on the CPU clock as on the
wall clock (``bench_node.py``'s ticks "the node's own work caused" count those too).

Run: ``python3 bench/bench_wakeups.py [--wakeups 20000] [--busy-seconds 20] [--priority 50] [--csv FILE]``
(default CSV: ``bench/results/wakeups.csv``). The policies take turns, the machine otherwise idle; FIFO needs
root, CAP_SYS_NICE or an rtprio limit (else its row says the OS refused it). Prints figures; never asserts a
time.
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
BUSY_TURN = 0.05   # s a busy thread reads the clock at a time, then sleeps as long


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


def pauses(seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """The pauses (s) of a thread reading the clock in a loop for ``seconds`` s in all, in turns of
    :data:`BUSY_TURN` s with as long a sleep between them: each gap of the monotonic clock over
    :data:`PERIOD` between two reads, and how far the thread's CPU time moved over it."""
    gaps, charged = [], []
    left = seconds
    while left > 0.0:
        turn = min(BUSY_TURN, left)
        wall, cpu = time.monotonic(), time.thread_time()
        end = wall + turn
        while wall < end:
            now, used = time.monotonic(), time.thread_time()
            if now - wall > PERIOD:
                gaps.append(now - wall)
                charged.append(used - cpu)
            wall, cpu = now, used
        left -= turn
        time.sleep(BUSY_TURN)
    return np.array(gaps), np.array(charged)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wakeups", type=int, default=20000)
    parser.add_argument("--priority", type=int, default=50, help="the SCHED_FIFO priority of the second policy")
    parser.add_argument("--busy-seconds", type=float, default=20.0,
                        help="s a thread that never sleeps reads the clock, per policy and round (0: none)")
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
                gaps, charged = pauses(args.busy_seconds)
            finally:
                scheduling.restore()
            policy = "default" if priority == 0 else ("refused" if refused else f"SCHED_FIFO {priority}")
            as_cpu = charged > 0.9 * gaps   # the CPU clock moved through (nearly all of) the pause
            row = {"scheduler": policy, "wakeups": args.wakeups, "period_ms": PERIOD * 1e3,
                   "late_over_a_period": int((late > PERIOD).sum()), "late_p50_ms": float(np.median(late) * 1e3),
                   "late_p999_ms": float(np.percentile(late, 99.9) * 1e3), "late_max_ms": float(late.max() * 1e3),
                   "busy_s": args.busy_seconds, "busy_pauses": len(gaps), "busy_pauses_charged_as_cpu":
                   int(as_cpu.sum()), "busy_pause_max_ms": float(gaps.max() * 1e3) if len(gaps) else 0.0}
            rows.append(row)
            print(f"{policy:>14}: {row['late_over_a_period']} of {args.wakeups} wake-ups over a period late; "
                  f"lateness p50 {row['late_p50_ms']:.3f} ms, p99.9 {row['late_p999_ms']:.3f} ms, "
                  f"max {row['late_max_ms']:.2f} ms; busy {args.busy_seconds:g} s: {len(gaps)} pauses over a "
                  f"period (the longest {row['busy_pause_max_ms']:.2f} ms), {row['busy_pauses_charged_as_cpu']} "
                  f"of them charged to the thread as CPU time", flush=True)
    write_csv(args.csv, rows)
    print(f"wrote {args.csv}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
