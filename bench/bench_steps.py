"""Steps per second of each method (and QP backend) on the built-in scenes and on large towers (dt = 1 ms).

Run: ``python bench/bench_steps.py [--steps N] [--methods elastic,...] [--solvers auto,daqp,...]
[--stages 10,50]``. Prints a table with one column per method, the inextensible method once per QP backend
("auto": the backend it picks by size; after the rate, the share of QPs that the sparse backend answered
from its guess, without DAQP); never asserts a time. The rows are the built-in scenes and towers of
``--stages`` stages (without gravity).
Each figure is the best of ``--repeats`` timed runs after a warm-up run; a run stops early after
``--budget`` seconds (slow backends on large towers), and the figure is the steps it did per second.
``--velocity V`` gives every free node a random initial velocity of V m/s, so that the structure rattles
(cables go slack and snap) instead of resting in its equilibrium.

``--accuracy`` compares the QP backends instead: it records the QPs of runs, solves each again with
every backend (given the run's active-set hints, as in a run) and with quadprog (an independent solver;
the ``test`` extra), and prints the largest velocity error relative to quadprog's and the mean time per
QP. The runs: each built-in scene rattling (``--velocity``, default 0.3 m/s) with half of the nodes made
1e4 times heavier, and the towers of ``--stages`` at rest and rattling so (large towers: every tenth QP
of the run, at most 30). The error is relative to the larger of the free and the solved velocities (at
rest the solved ones are near zero). "osqp-default" is OSQP at its own default tolerances (eps 1e-3,
polishing off).
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim import formfinding
from tensegrity_sim.methods.qp import solvers as qp
from tensegrity_sim.methods.inextensible.method import LengthOffsetWarning


def scenes(stages=(10, 50)):
    for name in ("prism3", "icosahedron", "tower"):
        yield name, ts.load_scene(name)
    yield from towers(stages)


def towers(stages):
    for n in stages:
        # without gravity: a uniform tower of more than 15 stages buckles under its own weight
        yield f"tower{n}", ts.Scene.from_dict(formfinding.tower(n, gravity=(0.0, 0.0, 0.0)))


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
    """The best rate (steps/s) and, for the sparse QP backend, the share of its QPs answered by a guess."""
    sim = simulator(scene, method, dt, solver)
    timed_run(sim, min(steps, 200), budget / 4)  # warm-up
    best = 0.0
    for _ in range(repeats):
        sim.reset()
        best = max(best, timed_run(sim, steps, budget))
    counts = getattr(getattr(sim._method, "solver", None), "counts", None)
    return best, (counts["guessed"] / max(sum(counts.values()), 1) if counts else None)


class OsqpDefault(qp.OsqpSolver):
    """OSQP at its default tolerances, for the comparison only."""

    name = "osqp-default"
    settings = {}


def recorded_qps(scene, dt, steps, limit, stride=1):
    """Every ``stride``-th QP (v0, rows, warm hint), at most ``limit``, that the default backend solves
    in ``steps`` steps, and the free nodes' masses."""
    sim = simulator(scene, "inextensible", dt)
    solver = sim._method.solver
    problems = []
    solve = solver.solve
    seen = 0

    def recording(v0, rows, warm=None):
        nonlocal seen
        if len(problems) < limit and seen % stride == 0:
            problems.append((v0.copy(), qp.Rows(rows.nodes, rows.directions.copy(), rows.targets.copy(),
                                                rows.n_eq), None if warm is None else warm.copy()))
        seen += 1
        return solve(v0, rows, warm)
    solver.solve = recording
    for _ in range(steps):
        sim.step()
        if len(problems) >= limit:
            break
    return problems, sim.system.masses[sim.system.free]


def accuracy(args):
    import quadprog
    names = [n for n in args.solvers.split(",") if n != "auto"] + ["osqp-default"]
    velocity = args.velocity or 0.3
    print("QPs of runs; error = max |v - v_quadprog| / max(|v_quadprog|, |v_free|) over the QPs quadprog solves; "
          "time = mean per QP, warm-started from the run's hints")
    print(f"{'scene':<14}{'v m/s':>6}{'ratio':>6}{'QPs':>5}{'rows':>6}  " + "".join(f"{n:>24}" for n in names),
          flush=True)
    cases = [(name, scene, velocity, 1e4) for name, scene in scenes(stages=())]
    cases += [(name, scene, v, ratio) for name, scene in towers(args.stages)
              for v, ratio in ((0.0, 1.0), (velocity, 1.0), (velocity, 1e4))]
    for name, scene, v, ratio in cases:
        large = len(scene.nodes) > 100
        problems, mass = recorded_qps(agitated(scene, v, mass_ratio=ratio), args.dt, 300,
                                      30 if large else 60, 10 if large else 1)
        m = np.repeat(mass, 3)
        kept, refs = [], []
        for v0, rows, warm in problems:
            a = rows.dense(len(mass))
            try:   # quadprog refuses some degenerate problems (dependent active rows): those are skipped
                refs.append(quadprog.solve_qp(np.diag(m), m * v0.ravel(), -a.T, -rows.targets, rows.n_eq)[0])
                kept.append((v0, rows, warm))
            except ValueError:
                pass
        problems = kept
        row = f"{name:<14}{v:>6g}{ratio:>6g}{len(problems):>5}{max(len(r) for _, r, _ in problems):>6}  "
        for solver_name in names:
            solver = (OsqpDefault if solver_name == "osqp-default" else qp.SOLVERS[solver_name])(mass)
            error, spent = 0.0, 0.0
            try:
                for (v0, rows, warm), ref in zip(problems, refs):
                    start = time.perf_counter()
                    v, _ = solver._solve(v0.ravel(), rows, warm)   # raw output: no feasibility check
                    spent += time.perf_counter() - start
                    scale = max(float(np.max(np.abs(ref))), float(np.max(np.abs(v0))))
                    error = max(error, float(np.max(np.abs(v - ref))) / scale)
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
    parser.add_argument("--solvers", default=",".join(["auto"] + sorted(qp.SOLVERS)),
                        help="QP backends of the inextensible method, one column each (auto: by size)")
    parser.add_argument("--stages", default="10,50", help="towers of these many stages, comma-separated")
    parser.add_argument("--accuracy", action="store_true", help="compare the QP backends against quadprog")
    args = parser.parse_args()
    args.stages = [int(n) for n in args.stages.split(",") if n]
    if args.accuracy:
        accuracy(args)
        return
    columns = [(m, s) for m in args.methods.split(",")
               for s in (args.solvers.split(",") if "solver" in ts.METHODS[m].options else [None])]
    labels = [m if s is None else f"{m[:5]}/{s}" for m, s in columns]
    print(f"{'scene':<14}{'nodes':>6}{'members':>8}  " + "".join(f"{label:>18}" for label in labels), flush=True)
    for name, scene in scenes(args.stages):
        scene = agitated(scene, args.velocity)
        row = f"{name:<14}{len(scene.nodes):>6}{len(scene.struts) + len(scene.cables):>8}  "
        for m, s in columns:
            try:
                rate, guessed = steps_per_second(scene, m, args.dt, args.steps, args.repeats, args.budget,
                                                 None if s == "auto" else s)
                row += f"{rate:>13,.0f} st/s" if guessed is None else f"{rate:>8,.0f} st/s {guessed:>4.0%}"
            except (ValueError, qp.QPError) as exc:
                row += f"{'refused' if isinstance(exc, ValueError) else 'failed':>18}"
                print(f"  {name}/{m}{'/' + s if s else ''}: {exc}")
        print(row, flush=True)


if __name__ == "__main__":
    main()
