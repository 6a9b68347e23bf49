"""What the rods' mass blocks cost the JAX backend's ground (issue 46): the built-in ``three_bar`` (a motor at each
rod's middle, end caps) reeling three cables to 60 % on the ground, B copies stepped by the JAX run, its rods with
their consistent blocks (the block Gauss-Seidel's ``block_sweeps``: 149 sweeps) against the same robot with the
rods' mass and payloads lumped at their ends by the lever rule (60 sweeps), and the numba batch's compiled ground
loop with the blocks beside them.

    python3 bench/bench_jax_rods.py                       # 256 copies, 200 steps, float64, best of 3
    python3 bench/bench_jax_rods.py --copies 1024 --dtype float32

Contenders take turns in one process, each timed after a warm-up (compile), best of ``--repeats``; the JAX runs
keep their state on the device. Writes ``bench/results/jax_rods.csv`` (scene-steps/s = copies x steps / wall
time) and prints it; every row names the device and the load (``os.getloadavg``).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import tensegrity_sim as ts  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.batch import BatchSimulator  # noqa: E402
from tensegrity_sim.commands import parse_commands  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
DT = 1e-3


def _robot(lumped: bool) -> ts.Scene:
    """three_bar as built (its rods' mass spread along them, a payload at each middle), or with each rod's mass and
    payloads lumped at its ends by the lever rule (the same weight on each node, no block)."""
    d = ts.load_scene("three_bar").to_dict()
    if lumped:
        nodes = {node["name"]: node for node in d["nodes"]}
        for strut in d["struts"]:
            strut["mass_distribution"] = "ends"
            for payload in strut.pop("payloads", ()):
                nodes[strut["nodes"][0]]["mass"] += (1.0 - payload["at"]) * payload["mass"]
                nodes[strut["nodes"][1]]["mass"] += payload["at"] * payload["mass"]
    return ts.Scene.from_dict(d)


def _schedule(scene: ts.Scene):
    """c0, c1 and c5 reeled to 60 % over 0.4 s and held."""
    rest = dict(zip(scene.cable_names, scene.cable_rest_lengths))
    points = [{"time": t, "rest_lengths": {c: float(f * rest[c]) for c in ("c0", "c1", "c5")}}
              for t, f in ((0.0, 1.0), (0.4, 0.6))]
    return parse_commands(points, scene, "reel")


def _runner(scene: ts.Scene, copies: int, steps: int, backend: str, dtype: str | None):
    """A callable that runs ``steps`` steps of ``copies`` copies from the scene's state (a fresh batch each call,
    built outside the timing), and the batch's ground sweeps (None for numba)."""
    kwargs = {} if backend == "numba" else {"backend": "jax", "dtype": dtype}
    schedule = _schedule(scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = BatchSimulator(scene, copies, method="elastic", dt=DT, **kwargs)
    sweeps = None if backend == "numba" else sim._engine.model.ground.sweeps
    x0, v0 = sim._x.copy(), sim._v.copy()

    def run():
        sim._x[...], sim._v[...] = x0, v0
        sim._engine.invalidate()
        sim._step_count = 0
        sim.run(steps=steps, every=steps, commands=schedule)

    return run, sweeps


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--copies", type=int, default=256, help="copies (default 256)")
    parser.add_argument("--steps", type=int, default=200, help="steps per timed call (default 200)")
    parser.add_argument("--repeats", type=int, default=3, help="timed turns per contender (default 3)")
    parser.add_argument("--dtype", default="float64", choices=("float64", "float32"), help="the JAX runs' precision")
    parser.add_argument("--out", default=str(RESULTS / "jax_rods.csv"), help="the CSV written")
    args = parser.parse_args(argv)
    import jax

    contenders = {
        "jax, rods' blocks": _runner(_robot(False), args.copies, args.steps, "jax", args.dtype),
        "jax, rods lumped": _runner(_robot(True), args.copies, args.steps, "jax", args.dtype),
        "numba batch, rods' blocks": _runner(_robot(False), args.copies, args.steps, "numba", None),
    }
    for run, _ in contenders.values():   # warm-up: compile
        run()
    best = {name: float("inf") for name in contenders}
    for _ in range(args.repeats):
        for name, (run, _) in contenders.items():
            start = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - start)
    device = str(jax.devices()[0])
    rows = [{"contender": name, "copies": args.copies, "steps": args.steps, "dtype": args.dtype,
             "sweeps": "" if sweeps is None else sweeps, "wall_s": best[name],
             "scene_steps_per_s": args.copies * args.steps / best[name], "device": device,
             "load": os.getloadavg()[0]} for name, (_, sweeps) in contenders.items()]
    RESULTS.mkdir(exist_ok=True)
    write_csv(Path(args.out), rows)
    for row in rows:
        print(f"{row['contender']:28s} sweeps {str(row['sweeps']):>4s}  {row['scene_steps_per_s']:12,.0f} "
              f"scene-steps/s  ({row['wall_s']:.3f} s, load {row['load']:.1f}, {device})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
