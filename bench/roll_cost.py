"""Where the inextensible roll's time goes (issue 47): ``icosahedron_ground`` under ``examples/roll.yaml``, the
inextensible method, each step taken alone (``Simulator.step``, the compiled loop off so that each step is timed by
itself; the same steps as ``run``'s, bench_ground.py's "inextensible step" row) and sorted by the path that took it:

* ``step kernel``: the whole step in ``_inextensible_kernels.step`` (its friction modes, motors and landing
  iterations compiled);
* ``Python path, events``: the step left to ``InextensibleMethod._step_python`` for events inside it (a snap or a
  landing cut there, several sub-steps), every friction solve answered by the compiled modes;
* ``Python path, reference modes``: ... with a friction solve the compiled modes refused (a QP that DAQP alone
  does not answer: ``FrictionalSolver._modes`` and its backend's fallbacks took it) or the jammed modes' retry;
* ``Python path, Newton``: ... with a friction solve whose modes cycled at both levels, answered by the
  semismooth Newton method (``FrictionalSolver._newton``); the step after such a step goes there at once
  (``InextensibleMethod._step_impl``).

Besides each path's steps, seconds and share, the run's kinetic energy (its largest, and at the end of each
phase of the schedule) says what the steps are doing: the locked icosahedron's motors pull at their
``reel_force`` and yank it, and it then rocks on its edges. Never asserts a time.

Run: ``python3 bench/roll_cost.py [--steps N]``; writes bench/results/roll_cost.csv.
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import tensegrity_sim as ts  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.commands import load_commands  # noqa: E402
from tensegrity_sim.methods.inextensible.method import LengthOffsetWarning  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).resolve().parent / "results"
KINDS = ("step kernel", "Python path, events", "Python path, reference modes", "Python path, Newton")


def measure(steps: int) -> list[dict]:
    scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(ROOT / "examples" / "roll.yaml", scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LengthOffsetWarning)
        sim = ts.Simulator(scene, method="inextensible", dt=1e-3, contacts=())   # as bench_ground.py: no detection
    method, solver = sim._method, sim._method.solver
    method.has_loop = lambda: False   # each step alone: through the step kernel, or the Python path where it declines
    calls = Counter()

    def counted(owner, name):
        inner = getattr(owner, name)

        def call(*args, **kwargs):
            calls[name] += 1
            return inner(*args, **kwargs)
        setattr(owner, name, call)

    for name in ("_newton", "_jammed", "_qp"):   # (the compiled modes, _modes_compiled, stay as they are)
        counted(solver, name)
    python = method._step_python

    def step_python(state):
        calls["python"] += 1
        return python(state)
    method._step_python = step_python

    base = sim.rest_lengths
    mass = scene.masses
    seconds, count = Counter(), Counter()
    energy = np.zeros(steps)
    sim.set_rest_lengths(schedule.rest_lengths_at(sim.time, base))
    sim.step()   # the first: the kernels loaded
    for k in range(1, steps):
        sim.set_rest_lengths(schedule.rest_lengths_at(sim.time, base))
        calls.clear()
        start = time.perf_counter()
        r = sim.step()
        took = time.perf_counter() - start
        if not calls["python"]:
            kind = KINDS[0]
        elif calls["_newton"]:
            kind = KINDS[3]
        elif calls["_qp"] or calls["_jammed"]:
            kind = KINDS[2]
        else:
            kind = KINDS[1]
        seconds[kind] += took
        count[kind] += 1
        energy[k] = 0.5 * float(np.einsum("i,ij,ij->", mass, r.velocities, r.velocities))
    total = sum(seconds.values())
    # the schedule's changes (reel in, hold, let out) that the run reaches
    ends = [f"of the {phase} {energy[k]:.2f} J" for phase, t in (("reel", 0.3), ("hold", 1.0), ("let-out", 1.3))
            if (k := round(t / sim.dt)) < steps]
    note = (f"{steps - 1} steps in {total:.3f} s ({(steps - 1) / total:,.0f} steps/s); kinetic energy at most "
            f"{energy.max():.2f} J{', at the end ' + ', '.join(ends) if ends else ''}; motor steps at their force "
            f"{method.stalls}")
    return [{"path": kind, "steps": count[kind], "seconds": seconds[kind],
             "ms_per_step": 1e3 * seconds[kind] / count[kind] if count[kind] else float("nan"),
             "share": seconds[kind] / total, "note": note if kind == KINDS[0] else ""} for kind in KINDS]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=2000, help="steps of the roll (default 2000: 2 s)")
    args = parser.parse_args(argv)
    rows = measure(args.steps)
    for row in rows:
        print(f"{row['path']:30s} {row['steps']:6d} steps {row['seconds']:8.3f} s {row['ms_per_step']:8.2f} ms/step "
              f"{100 * row['share']:5.1f} %")
    print(rows[0]["note"])
    write_csv(RESULTS / "roll_cost.csv", rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
