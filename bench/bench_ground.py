"""Steps per second with ground contact: the icosahedron resting on its face and rolling (``examples/
roll.yaml``), both methods, beside MuJoCo with its ground contact (bench/mujoco_peer.py: a plane, capsule
struts, elliptic cones, impratio 100), in one process taking turns (the machine is shared: read the
ratios, not the rates). Never asserts a time.

Run: ``python bench/bench_ground.py [--duration S] [--repeats N]``.
"""
from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim.commands import load_commands
from tensegrity_sim.methods.inextensible import LengthOffsetWarning

ROLL = Path(__file__).resolve().parents[1] / "examples" / "roll.yaml"


def _ours(scene, method, steps, schedule):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LengthOffsetWarning)
        sim = ts.Simulator(scene, method=method, dt=1e-3)
    start = time.perf_counter()
    for k in range(steps):
        if schedule is not None:
            sim.set_rest_lengths(schedule.rest_lengths_at(k * sim.dt, sim.rest_lengths))
        sim.step()
    return steps / (time.perf_counter() - start), sim.positions


def _mujoco(scene, steps, schedule):
    """MuJoCo's rate and final positions; its explicit step may go unstable under the roll's snaps
    (it then warns and its positions are meaningless)."""
    from bench.mujoco_peer import MujocoPeer
    peer = MujocoPeer(scene, dt=1e-3, integrator="Euler")
    model, data = peer.model, peer.data
    tendons = peer._tendons
    start = time.perf_counter()
    if schedule is None:
        peer.advance(steps)
    else:
        base = scene.cable_rest_lengths
        for k in range(steps):
            rest = schedule.rest_lengths_at(k * 1e-3, base)
            model.tendon_lengthspring[tendons, 1] = rest
            peer._mj.mj_step(model, data)
    return steps / (time.perf_counter() - start), peer.positions()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=2.0, help="simulated s per run")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args(argv)
    scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(ROLL, scene)
    steps = int(round(args.duration / 1e-3))
    cases = [("resting", None), ("rolling", schedule)]
    print(f"icosahedron_ground, dt = 1 ms, {steps} steps per run, best of {args.repeats}")
    print(f"{'case':10s} {'inextensible':>14s} {'elastic':>10s} {'mujoco':>10s}   ratios to MuJoCo; how far the centre "
          "of mass moved (horizontally) by the end")
    mass = scene.masses
    start = mass @ scene.positions / mass.sum()
    for name, sched in cases:
        best = {}
        finals = {}
        for _ in range(args.repeats):
            for who in ("inextensible", "elastic", "mujoco"):
                if who == "inextensible" and sched is not None:
                    continue   # the locked icosahedron cannot reel a cable in with inextensible cables
                rate, x = _mujoco(scene, steps, sched) if who == "mujoco" else _ours(scene, who, steps, sched)
                best[who] = max(best.get(who, 0.0), rate)
                finals[who] = float(np.linalg.norm((mass @ x / mass.sum() - start)[:2]))
        row = [f"{best[w]:10.0f}" if w in best else f"{'-':>10s}" for w in ("inextensible", "elastic", "mujoco")]
        ratios = ", ".join(f"{w} {best[w] / best['mujoco']:.3f}" for w in ("inextensible", "elastic") if w in best)
        where = ", ".join(f"{w} {finals[w]:.3f} m" for w in finals)
        print(f"{name:10s} {row[0]:>14s} {row[1]:>10s} {row[2]:>10s}   {ratios}; {where}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
