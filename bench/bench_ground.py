"""Steps per second with ground contact: the icosahedron resting on its face and rolling (``examples/
roll.yaml``), both methods, beside MuJoCo with its ground contact (bench/mujoco_peer.py: a plane, capsule
struts, elliptic cones, impratio 100), in one process taking turns (the machine is shared: read the
ratios, not the rates; the load average is printed and written beside them). Never asserts a time.

Like for like: each of our methods beside MuJoCo with the same cable model (the inextensible method
beside MuJoCo's limited tendons, the elastic one beside its spring tendons), each MuJoCo model with its
Euler and implicitfast integrators; a MuJoCo run is *stable* when MuJoCo raised no bad-acceleration
warning and the centre of mass stayed within 0.5 m of the ground, and the ratio is taken to the faster
stable integrator (named in the output). The rolling inextensible icosahedron is locked: its motors reel
the cables in with unlimited force, which the rigid structure can only follow by leaving the ground, so
its rate is reported with how high the centre of mass went. The ``variant`` column names MuJoCo's
integrator, or ``numpy modes`` for the inextensible method with its friction modes solved by their numpy
reference instead of the compiled kernel (issue 28: what compiling them gained, in the same process).

Run: ``python bench/bench_ground.py [--duration S] [--repeats N]``; writes ``bench/results/ground.csv``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

import tensegrity_sim as ts  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.commands import load_commands  # noqa: E402
from tensegrity_sim.methods.inextensible import LengthOffsetWarning  # noqa: E402

ROLL = Path(__file__).resolve().parents[1] / "examples" / "roll.yaml"
RESULTS = Path(__file__).resolve().parent / "results" / "ground.csv"
INTEGRATORS = ("Euler", "implicitfast")


def _ours(scene, method, steps, schedule, reference_modes=False):
    """Our rate and final positions; ``reference_modes``: the friction modes by their numpy reference
    (``FrictionalSolver._modes``) instead of the compiled kernel, everything else the same."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LengthOffsetWarning)
        sim = ts.Simulator(scene, method=method, dt=1e-3)
    if reference_modes:
        sim._method.solver._modes_compiled = lambda v0, rows, warm: None
    start = time.perf_counter()
    for k in range(steps):
        if schedule is not None:
            sim.set_rest_lengths(schedule.rest_lengths_at(k * sim.dt, sim.rest_lengths))
        sim.step()
    return steps / (time.perf_counter() - start), sim.positions


def _mujoco(scene, model, integrator, steps, schedule):
    """MuJoCo's rate, final positions and whether it stayed stable (``model``: its cable model,
    "elastic" or "inextensible")."""
    from bench.mujoco_peer import MujocoPeer
    peer = MujocoPeer(scene, model=model, dt=1e-3, integrator=integrator)
    mj, mj_model, data, tendons = peer._mj, peer.model, peer.data, peer._tendons
    base = scene.cable_rest_lengths
    # the commanded rest length moves a spring tendon's length, or a limited tendon's limit (kept at its
    # offset above the rest length: the prestressed cables start longer than their rest lengths)
    law = mj_model.tendon_lengthspring[:, 1] if model == "elastic" else mj_model.tendon_range[:, 1]
    offset = law[tendons] - base
    start = time.perf_counter()
    if schedule is None:
        peer.advance(steps)
    else:
        for k in range(steps):
            law[tendons] = schedule.rest_lengths_at(k * 1e-3, base) + offset
            mj.mj_step(mj_model, data)
    rate = steps / (time.perf_counter() - start)
    return rate, peer.positions(), not peer.unstable


def _centre(scene, x):
    m = scene.masses
    return m @ x / m.sum()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=2.0, help="simulated s per run")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(ROLL, scene)
    steps = int(round(args.duration / 1e-3))
    start = _centre(scene, scene.positions)
    print(f"icosahedron_ground, dt = 1 ms, {steps} steps per run, best of {args.repeats}, contenders in turn; "
          f"load average at the start {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    rows = []
    for case, sched in (("resting", None), ("rolling", schedule)):
        contenders = [("ours", m, "") for m in ("inextensible", "elastic")]
        contenders += [("ours", "inextensible", "numpy modes")]
        contenders += [("mujoco", m, i) for m in ("inextensible", "elastic") for i in INTEGRATORS]
        best, finals, stable = {}, {}, {}
        for who in contenders:   # warm-up: numba's compilation and MuJoCo's first allocations, untimed
            if who[0] == "ours":
                _ours(scene, who[1], 50, sched, who[2] == "numpy modes")
            else:
                _mujoco(scene, who[1], who[2], 50, sched)
        for _ in range(args.repeats):
            for who in contenders:
                if who[0] == "ours":
                    rate, x = _ours(scene, who[1], steps, sched, who[2] == "numpy modes")
                    ok = bool(np.isfinite(x).all())
                else:
                    rate, x, ok = _mujoco(scene, who[1], who[2], steps, sched)
                best[who] = max(best.get(who, 0.0), rate)
                finals[who] = x
                stable[who] = stable.get(who, True) and ok and abs(_centre(scene, x)[2] - start[2]) < 0.5
        load = os.getloadavg()[0]
        for who in contenders:
            centre = _centre(scene, finals[who]) - start
            row = {"case": case, "simulator": who[0], "cables": who[1], "variant": who[2] or "-",
                   "steps_per_s": best[who], "stable": stable[who],
                   "centre_moved_m": float(np.linalg.norm(centre[:2])), "centre_rose_m": float(centre[2]),
                   "ratio_to_mujoco": float("nan"), "mujoco_integrator": "-", "load": load}
            if who[0] == "ours":
                peers = [p for p in contenders if p[0] == "mujoco" and p[1] == who[1] and stable[p]]
                if peers:
                    peer = max(peers, key=best.get)
                    row["ratio_to_mujoco"], row["mujoco_integrator"] = best[who] / best[peer], peer[2]
            rows.append(row)
            ratio = (f"  {row['ratio_to_mujoco']:.3f}x MuJoCo ({row['mujoco_integrator']})"
                     if who[0] == "ours" else "")
            print(f"{case:8s} {who[0]:7s} {who[1]:13s} {row['variant']:13s} {best[who]:10.0f} steps/s  "
                  f"{'stable' if stable[who] else 'UNSTABLE':8s} centre moved {row['centre_moved_m']:.3f} m, "
                  f"rose {row['centre_rose_m']:+.3f} m{ratio}  (load {load:.1f})")
    write_csv(RESULTS, rows)
    print(f"written {RESULTS}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
