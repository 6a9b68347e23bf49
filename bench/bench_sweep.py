"""Wall time of a sweep of 1 s icosahedron runs, embedded and through a local Ray cluster.

    python3 bench/bench_sweep.py --runs 10000      # writes bench/results/sweep.csv and sweep.md, prints the table

The spec: the built-in icosahedron, elastic, dt = 1 ms, 1 s per run, a grid of c0's rest length (runs/100
values in [0.9, 1.05]) times 100 random initial velocities of n0 (normal, 2 m/s), contact detection off
(``--contacts`` keeps the scene's). Embedded: this process (one worker). Ray: ``ray start --head`` on a
free port with as many CPUs as cores, the sweep submitted with ``--address``, ``ray stop`` after. The
wall time includes building every run's scene and writing the Parquet file; the CPU time is that of the
sweep's own process (a loaded machine stretches wall time, not CPU time; Ray's work is in its workers).
"""
from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.sweep import load_spec, run_sweep  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def spec(runs: int, contacts: bool) -> dict:
    rng = np.random.default_rng(0)
    out = {"scene": "icosahedron", "method": "elastic", "dt": 0.001, "duration": 1.0,
           "vary": {"rest_lengths.c0": [float(x) for x in np.linspace(0.9, 1.05, max(1, runs // 100))],
                    "velocity.n0": [[float(c) for c in rng.normal(scale=2.0, size=3)] for _ in range(100)]}}
    if not contacts:
        out["contacts"] = "none"
    return out


def _timed(run) -> tuple[float, float, object]:
    wall, cpu = time.perf_counter(), time.process_time()
    result = run()
    return time.perf_counter() - wall, time.process_time() - cpu, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10_000)
    parser.add_argument("--contacts", action="store_true", help="keep the scene's contact detection")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_sweep_"))
    path = work / "spec.yaml"
    path.write_text(yaml.safe_dump(spec(args.runs, args.contacts), sort_keys=False))
    sweep = load_spec(path)
    rows = []
    wall, cpu, summary = _timed(lambda: run_sweep(sweep, work / "embedded.parquet"))
    rows.append(("embedded (this process)", summary, wall, cpu))
    ray = shutil.which("ray", path=os.path.dirname(sys.executable)) or "ray"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    temp = Path("/tmp") / f"ray_bench_{os.getpid()}"
    subprocess.run([ray, "start", "--head", f"--port={port}", f"--num-cpus={os.cpu_count()}",
                    "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp}"],
                   check=True, capture_output=True)
    try:
        wall, cpu, summary = _timed(lambda: run_sweep(sweep, work / "ray.parquet", address=f"127.0.0.1:{port}"))
        rows.append((f"local Ray cluster ({os.cpu_count()} CPUs)", summary, wall, cpu))
    finally:
        subprocess.run([ray, "stop", "--force"], capture_output=True)
        shutil.rmtree(temp, ignore_errors=True)
    import pyarrow.parquet as pq

    a, b = pq.read_table(work / "embedded.parquet"), pq.read_table(work / "ray.parquet")
    same = a.equals(b)
    shutil.rmtree(work, ignore_errors=True)
    lines = ["## Sweeps (issue 12)\n",
             f"`python3 bench/bench_sweep.py --runs {args.runs}{' --contacts' if args.contacts else ''}`: "
             f"{args.runs} runs of 1 s (1000 steps) of the elastic icosahedron, contact detection "
             f"{'on' if args.contacts else 'off'}; load average at the end {os.getloadavg()[0]:.1f} on "
             f"{os.cpu_count()} cores. Embedded and Ray tables identical: {same}.\n",
             "| where | runs | groups | wall time (s) | CPU time of the sweep process (s) | scene-steps/s (wall) |",
             "| --- | --- | --- | --- | --- | --- |"]
    lines += [f"| {where} | {s.runs} | {s.groups} | {wall:.1f} | {cpu:.1f} | {s.scene_steps / wall:,.0f} |"
              for where, s, wall, cpu in rows]
    text = "\n".join(lines) + "\n"
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sweep.md").write_text(text)
    write_csv(RESULTS / "sweep.csv", [{"where": where, "runs": s.runs, "groups": s.groups, "wall_s": wall, "cpu_s": cpu,
                                       "scene_steps_per_s": s.scene_steps / wall, "identical": same}
                                      for where, s, wall, cpu in rows])
    print(text)


if __name__ == "__main__":
    main()
