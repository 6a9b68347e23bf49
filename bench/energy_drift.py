"""Long-run energy behaviour of the elastic method (velocity Verlet) against classical RK4.

A free-floating prism3 with random initial velocities large enough that cables go slack and snap taut
again and again. Prints, per integrator, the energy error (relative to the initial energy) averaged over
the first and the last tenth of the run: a drift shows as a growing error, a symplectic method's error
stays at the same level. RK4 here is a plain reference written on the same force routine.

Run: ``python bench/energy_drift.py [--steps N] [--dt S]``.
"""
from __future__ import annotations

import argparse

import numpy as np

import tensegrity_sim as ts


def scene(seed: int = 0, speed: float = 1.5) -> ts.Scene:
    d = ts.load_scene("prism3").to_dict()
    rng = np.random.default_rng(seed)
    for node in d["nodes"]:
        node["velocity"] = list(rng.normal(scale=speed, size=3))
    return ts.Scene.from_dict(d)


def verlet_energies(sc, dt, steps, every):
    sim = ts.Simulator(sc, method="elastic", dt=dt)
    out, switches, slack = [], 0, sim.slack()
    for k in range(steps):
        r = sim.step()
        switches += int(np.count_nonzero(r.slack != slack))
        slack = r.slack
        if k % every == 0:
            out.append(sim.energy()["total"])
    return np.array(out), switches


def rk4_energies(sc, dt, steps, every):
    sim = ts.Simulator(sc, method="elastic", dt=dt)
    method, state = sim._method, sim._state
    x, v = state.positions.copy(), state.velocities.copy()

    def acc(x, v):
        return method.accelerations(x, v, state).acc

    out = []
    for k in range(steps):
        k1x, k1v = v, acc(x, v)
        k2x, k2v = v + 0.5 * dt * k1v, acc(x + 0.5 * dt * k1x, v + 0.5 * dt * k1v)
        k3x, k3v = v + 0.5 * dt * k2v, acc(x + 0.5 * dt * k2x, v + 0.5 * dt * k2v)
        k4x, k4v = v + dt * k3v, acc(x + dt * k3x, v + dt * k3v)
        x = x + dt / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
        v = v + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        if k % every == 0:
            state.positions, state.velocities = x, v
            out.append(sim.energy()["total"])
    return np.array(out)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--dt", type=float, default=1e-3)
    args = parser.parse_args()
    sc = scene()
    every = max(args.steps // 1000, 1)
    e0 = ts.Simulator(sc, method="elastic", dt=args.dt).energy()["total"]
    ev, switches = verlet_energies(sc, args.dt, args.steps, every)
    er = rk4_energies(sc, args.dt, args.steps, every)
    tenth = len(ev) // 10
    print(f"prism3, random velocities, dt={args.dt:g} s, {args.steps} steps, E0={e0:.6g} J, "
          f"{switches} slack/taut switches (Verlet run)")
    for name, e in (("verlet", ev), ("rk4", er)):
        rel = (e - e0) / abs(e0)
        print(f"{name:>7}: mean relative energy error first tenth {np.mean(rel[:tenth]):+.3e}, "
              f"last tenth {np.mean(rel[-tenth:]):+.3e}, max |error| {np.max(np.abs(rel)):.3e}")


if __name__ == "__main__":
    main()
