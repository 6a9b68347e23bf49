"""Where a control period of ``tensegrity_sim/Roll-v0``'s vector environment spends its CPU time (issue 50): the
compiled ground run (``ground_steps``: every copy's 20 steps) against everything else a ``step()`` does in Python
(actions checked, the reel, ``BatchSimulator.run``'s bookkeeping and guard, observation, reward, infos).

CPU seconds (``time.process_time``: the process's threads together), not wall time: on a shared machine a
neighbour's load lengthens wall time but hardly the work done, so two trees measured an hour apart still
compare. ``--threads`` (default 1) sets numba's threads. Each figure is the best of ``--repeats`` turns of
``--periods`` periods with random actions in [-1, 1]. CSV: ``bench/results/env_period.csv``.

    python3 bench/bench_env_period.py --copies 256
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba  # noqa: E402

from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.envs import RollVectorEnv  # noqa: E402
from tensegrity_sim.methods.elastic import _ground_kernels  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--copies", type=int, default=256)
    parser.add_argument("--periods", type=int, default=20, help="control periods per timed turn")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1, help="numba's threads")
    args = parser.parse_args(argv)
    numba.set_num_threads(args.threads)
    compiled = _ground_kernels.ground_steps
    spent = [0.0]

    def timed(*arguments):   # the compiled run, its CPU time added up (ElasticBatch looks it up at each call)
        start = time.process_time()
        compiled(*arguments)
        spent[0] += time.process_time() - start

    _ground_kernels.ground_steps = timed
    vec = RollVectorEnv(args.copies)
    vec.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (args.periods, args.copies, vec.single_action_space.shape[0]))
    for a in actions[:3]:   # warm-up (compiling)
        vec.step(a)
    best_total = best_kernel = np.inf
    for _ in range(args.repeats):
        spent[0] = 0.0
        start = time.process_time()
        for a in actions:
            vec.step(a)
        total = (time.process_time() - start) / args.periods
        best_total, best_kernel = min(best_total, total), min(best_kernel, spent[0] / args.periods)
    _ground_kernels.ground_steps = compiled
    rows = [{"part": name, "copies": args.copies, "threads": args.threads, "cpu_ms_per_period": 1e3 * value,
             "share": value / best_total}
            for name, value in (("compiled run", best_kernel), ("python", best_total - best_kernel),
                                ("period", best_total))]
    for row in rows:
        print(f"{row['part']:<13} {row['cpu_ms_per_period']:8.2f} ms CPU a period   {row['share']:6.1%}")
    write_csv(RESULTS / "env_period.csv", rows)


if __name__ == "__main__":
    main()
