"""Steps per second of each method (and QP backend) on the built-in scenes and on large towers (dt = 1 ms).

Run: ``python bench/bench_steps.py [--steps N] [--methods elastic,...] [--solvers daqp,...]``. Prints a
table with one column per method, the inextensible method once per QP backend; never asserts a time.
Each figure is the best of ``--repeats`` timed runs after a warm-up run; a run stops early after
``--budget`` seconds (slow backends on large towers), and the figure is the steps it did per second.
``--velocity V`` gives every free node a random initial velocity of V m/s, so that the structure rattles
(cables go slack and snap) instead of resting in its equilibrium.

``--accuracy`` compares the QP backends instead: it records the QPs of a rattling run (``--velocity``,
default 0.3 m/s) of each small scene with half of the nodes made 1e4 times heavier, solves each again
with every backend and with quadprog (an independent solver; the ``test`` extra), and prints the largest
velocity error relative to quadprog's and the mean time per QP. "osqp-default" is OSQP at its own
default tolerances (eps 1e-3, polishing off).
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim import formfinding
from tensegrity_sim.methods import qp
from tensegrity_sim.methods.inextensible import LengthOffsetWarning


def scenes(large=True):
    for name in ("prism3", "icosahedron", "tower"):
        yield name, ts.load_scene(name)
    for stages in (10, 50) if large else (10,):
        # without gravity: a uniform tower of more than 15 stages buckles under its own weight
        yield f"tower{stages}", ts.Scene.from_dict(formfinding.tower(stages, gravity=(0.0, 0.0, 0.0)))


def agitated(scene, velocity, mass_ratio=1.0, seed=0):
    """``scene`` with random node velocities of scale ``velocity`` m/s and, if ``mass_ratio`` is not 1,
    every other free node ``mass_ratio`` times heavier."""
    if velocity == 0 and mass_ratio == 1:
        return scene
    rng = np.random.default_rng(seed)
    d = scene.to_dict()
    for i, node in enumerate(d["nodes"]):
        if not node["fixed"]:
            node["velocity"] = list(rng.normal(scale=velocity, size=3))
            if i % 2:
                node["mass"] *= mass_ratio
    return ts.Scene.from_dict(d)


def simulator(scene, method, dt, solver=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LengthOffsetWarning)
        return ts.Simulator(scene, method=method, dt=dt, solver=solver)


def timed_run(sim, steps, budget):
    """Steps per second of up to ``steps`` steps, stopping after ``budget`` seconds."""
    start = time.perf_counter()
    done = 0
    while done < steps:
        sim.step()
        done += 1
        if time.perf_counter() - start > budget:
            break
    return done / (time.perf_counter() - start)


def steps_per_second(scene, method, dt, steps, repeats, budget, solver=None):
    sim = simulator(scene, method, dt, solver)
    timed_run(sim, min(steps, 200), budget / 4)  # warm-up
    best = 0.0
    for _ in range(repeats):
        sim.reset()
        best = max(best, timed_run(sim, steps, budget))
    return best


class OsqpDefault(qp.OsqpSolver):
    """OSQP at its default tolerances, for the comparison only."""

    name = "osqp-default"
    settings = {}


def recorded_qps(scene, dt, steps, limit):
    """The first ``limit`` QPs (v0, rows, masses) the default backend solves in ``steps`` steps."""
    sim = simulator(scene, "inextensible", dt)
    solver = sim._method.solver
    problems = []
    solve = solver.solve

    def recording(v0, rows, warm=None):
        if len(problems) < limit:
            problems.append((v0.copy(), qp.Rows(rows.nodes, rows.directions.copy(), rows.targets.copy(),
                                                rows.n_eq)))
        return solve(v0, rows, warm)
    solver.solve = recording
    sim.run(steps=steps)
    return problems, sim.system.masses[sim.system.free]


def accuracy(args):
    import quadprog
    names = args.solvers.split(",") + ["osqp-default"]
    print(f"QPs of a rattling run ({args.velocity or 0.3} m/s), node masses differing by 1e4; error = max |v - "
          f"v_quadprog| / max |v_quadprog| over the QPs quadprog solves; time = mean per QP (cold start)")
    print(f"{'scene':<14}{'QPs':>5}{'rows':>6}  " + "".join(f"{n:>24}" for n in names), flush=True)
    for name, scene in scenes(large=False):
        problems, mass = recorded_qps(agitated(scene, args.velocity or 0.3, mass_ratio=1e4), args.dt, 300, 60)
        m = np.repeat(mass, 3)
        kept, refs = [], []
        for v0, rows in problems:
            a = rows.dense(len(mass))
            try:   # quadprog refuses some degenerate problems (dependent active rows): those are skipped
                refs.append(quadprog.solve_qp(np.diag(m), m * v0.ravel(), -a.T, -rows.targets, rows.n_eq)[0])
                kept.append((v0, rows))
            except ValueError:
                pass
        problems = kept
        row = f"{name:<14}{len(problems):>5}{max(len(r) for _, r in problems):>6}  "
        for solver_name in names:
            solver = (OsqpDefault if solver_name == "osqp-default" else qp.SOLVERS[solver_name])(mass)
            error, spent = 0.0, 0.0
            try:
                for (v0, rows), ref in zip(problems, refs):
                    start = time.perf_counter()
                    v, _ = solver._solve(v0.ravel(), rows, None)   # raw output: no feasibility check
                    spent += time.perf_counter() - start
                    error = max(error, float(np.max(np.abs(v - ref)) / np.max(np.abs(ref))))
                row += f"{error:>11.1e} {1e6 * spent / len(problems):>8,.0f} us/QP"
            except qp.QPError as exc:
                row += f"{'failed: ' + exc.status:>24}"
        print(row, flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--budget", type=float, default=10.0, help="seconds per timed run at most")
    parser.add_argument("--velocity", type=float, default=0.0, help="random initial node speeds, m/s")
    parser.add_argument("--methods", default=",".join(sorted(ts.METHODS)))
    parser.add_argument("--solvers", default=",".join(sorted(qp.SOLVERS)),
                        help="QP backends of the inextensible method, one column each")
    parser.add_argument("--accuracy", action="store_true", help="compare the QP backends against quadprog")
    args = parser.parse_args()
    if args.accuracy:
        accuracy(args)
        return
    columns = [(m, s) for m in args.methods.split(",")
               for s in (args.solvers.split(",") if "solver" in ts.METHODS[m].options else [None])]
    labels = [m if s is None else f"{m[:5]}/{s}" for m, s in columns]
    print(f"{'scene':<14}{'nodes':>6}{'members':>8}  " + "".join(f"{label:>18}" for label in labels), flush=True)
    for name, scene in scenes():
        scene = agitated(scene, args.velocity)
        row = f"{name:<14}{len(scene.nodes):>6}{len(scene.struts) + len(scene.cables):>8}  "
        for m, s in columns:
            try:
                rate = steps_per_second(scene, m, args.dt, args.steps, args.repeats, args.budget, s)
                row += f"{rate:>13,.0f} st/s"
            except (ValueError, qp.QPError) as exc:
                row += f"{'refused' if isinstance(exc, ValueError) else 'failed':>18}"
                print(f"  {name}/{m}{'/' + s if s else ''}: {exc}")
        print(row, flush=True)


if __name__ == "__main__":
    main()
