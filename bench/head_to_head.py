"""The stepping core beside MuJoCo, contenders taking turns in one process (issue 10's targets).

Run: ``python bench/head_to_head.py [--repeats R] [--methods elastic,inextensible] [--stages 10,20,30,50,100]
[--budget S] [--out DIR]``. ``--methods`` times the icosahedron rows of those methods only (the others'
rows in ``head_to_head.csv`` are kept as they were); ``--stages ""`` skips the towers (and keeps their CSV).

* **Icosahedron thrown** (``bench.cases``: struts rigid, dt = 1 ms): ``Simulator.step()`` in a Python
  loop against MuJoCo's ``mj_step(model, data)`` in a Python loop, and ``Simulator.run()`` against
  ``mj_step(model, data, nstep)``; the elastic method against MuJoCo's Euler with spring tendons, the
  inextensible one against MuJoCo's Euler with *limited* tendons (its model of an inextensible cable).
  The inextensible rows add the step with the self-stress rule in its numpy reference (what compiling
  it gained).
* **Towers** of ``--stages`` stages (no gravity), inextensible, at rest and moving (random node
  velocities of 0.05 m/s): the steady cost per step after a warm-up, and separately the cost of the first
  step after a command (``set_rest_lengths`` with the current lengths, as a controller holding its
  command at 100 Hz sends), each the best of ``--repeats``; the growth exponent of the steady cost; the
  shares of the steady cost spent in the QP and in the self-stress rule's publishing.

Every figure is CPU time of this process (``time.process_time``), the contenders of a row timed in
turn, repeat after repeat, so that a disturbance on a shared machine hits them alike; the best of the
repeats is reported, and the ratios are of the best. Never asserts a time.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

import tensegrity_sim as ts  # noqa: E402
from bench.bench_steps import agitated  # noqa: E402
from bench.cases import work_precision_cases  # noqa: E402
from bench.scale import tower_scene  # noqa: E402
from bench.tables import read_csv, write_csv  # noqa: E402
from bench.timing import time_alternating  # noqa: E402

def _python_loop(step):
    def run(n):
        for _ in range(n):
            step()
    return run


def icosahedron_rows(repeats: int, methods=("elastic", "inextensible")) -> list[dict]:
    import mujoco

    from bench.mujoco_peer import MujocoPeer
    scene = next(c for c in work_precision_cases() if c.name == "icosahedron_thrown").scene
    rows = []
    for method in methods:
        sim = ts.Simulator(scene, method=method, dt=1e-3, contacts=())
        peer = MujocoPeer(scene, model=method, dt=1e-3, integrator="Euler")
        model, data = peer.model, peer.data
        contenders = {
            "tensegrity_sim step()": (_python_loop(sim.step), sim.reset),
            "MuJoCo mj_step() loop": (_python_loop(lambda: mujoco.mj_step(model, data)), peer.reset),
            "tensegrity_sim run()": (lambda n: sim.run(steps=n, every=n), sim.reset),
            "MuJoCo mj_step(nstep)": (peer.advance, peer.reset),
        }
        pairs = [(0, 1), (2, 3)]
        if method == "inextensible":   # what compiling the self-stress rule gained (issue 10)
            plain = ts.Simulator(scene, method=method, dt=1e-3, contacts=())
            plain._method.self_stress.compiled = False
            contenders["tensegrity_sim step(), self-stress rule numpy"] = (_python_loop(plain.step), plain.reset)
            pairs.append((4, 1))
        timings = time_alternating(contenders, repeats=repeats, target=0.2, clock=time.process_time)
        best = {name: t.best for name, t in timings.items()}
        names = list(contenders)
        for ours, theirs in ((names[i], names[j]) for i, j in pairs):
            rows.append({"case": "icosahedron_thrown", "method": method, "ours": ours, "peer": theirs,
                         "peer_model": "spring tendons" if method == "elastic" else "limited tendons",
                         "ours_us": 1e6 * best[ours], "peer_us": 1e6 * best[theirs],
                         "ratio": best[theirs] / best[ours]})
    return rows


def _clock_calls(obj, name: str, spent: dict) -> None:
    """Add the CPU seconds spent inside ``obj.name(...)`` to ``spent[name]`` from now on."""
    inner = getattr(obj, name)

    def timed(*args, **kwargs):
        start = time.process_time()
        try:
            return inner(*args, **kwargs)
        finally:
            spent[name] += time.process_time() - start
    setattr(obj, name, timed)


def tower_rows(stages, repeats: int, budget: float, velocities=(0.0, 0.05), rules=("default",)) -> list[dict]:
    """Steady and after-a-command cost per step of the inextensible method on towers, at rest and moving,
    and the shares of the steady cost spent in the QP backend (``qp_share``) and in publishing the
    impulses of rows that carry a self-stress (``publish_share``, ``methods/self_stress.py``).
    ``rules``: the self-stress rule's paths to time, taking turns block by block on twin simulators:
    ``default`` (the path the size picks), ``dense`` or ``sparse`` (forced); ``sparse_share`` is the
    share of the rule's calls its sparse path answered."""
    rows = []
    for n in stages:
        for velocity in velocities:
            scene = agitated(tower_scene(n), velocity)
            sims, cold = {}, {}
            for rule in rules:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", ts.LengthOffsetWarning)
                    sim = ts.Simulator(scene, method="inextensible", dt=1e-3, contacts=())
                if rule != "default":
                    sim._method.self_stress.sparse = rule == "sparse"
                start = time.process_time()
                sim.step()                       # the very first step: no hint at all
                cold[rule] = time.process_time() - start
                for _ in range(10):              # warm-up
                    sim.step()
                sims[rule] = sim
            inside = {rule: {"solve": 0.0, "impulses": 0.0} for rule in rules}
            for rule, sim in sims.items():
                _clock_calls(sim._method.solver, "solve", inside[rule])
                _clock_calls(sim._method.self_stress, "impulses", inside[rule])
            steady, after = dict.fromkeys(rules, math.inf), dict.fromkeys(rules, math.inf)
            steady_total = dict.fromkeys(rules, 0.0)
            steady_inside = {rule: {"solve": 0.0, "impulses": 0.0} for rule in rules}
            steps = 0
            spent = time.process_time()
            for _ in range(repeats):
                for rule, sim in sims.items():
                    before = dict(inside[rule])
                    start = time.process_time()
                    for _ in range(5):
                        sim.step()
                    block = time.process_time() - start
                    steady[rule] = min(steady[rule], block / 5)
                    steady_total[rule] += block
                    for name in steady_inside[rule]:
                        steady_inside[rule][name] += inside[rule][name] - before[name]
                    sim.set_rest_lengths(sim.rest_lengths)   # a command (the same lengths: held)
                    start = time.process_time()
                    sim.step()
                    after[rule] = min(after[rule], time.process_time() - start)
                steps += 6
                if time.process_time() - spent > budget:
                    break
            for rule, sim in sims.items():
                counts = getattr(sim._method.solver, "counts", None)
                rule_counts = sim._method.self_stress.counts
                rows.append({"stages": n, "members": len(scene.struts) + len(scene.cables),
                             "velocity": velocity, "solver": sim.method_settings["solver"], "rule": rule,
                             "first_ms": 1e3 * cold[rule], "steady_ms": 1e3 * steady[rule],
                             "after_command_ms": 1e3 * after[rule], "after_over_steady": after[rule] / steady[rule],
                             "qp_share": steady_inside[rule]["solve"] / steady_total[rule],
                             "publish_share": steady_inside[rule]["impulses"] / steady_total[rule],
                             "guessed_share": (counts["guessed"] / max(sum(counts.values()), 1)) if counts else math.nan,
                             "sparse_share": rule_counts["sparse"] / max(sum(rule_counts.values()), 1)})
                print(f"  tower{n} v={velocity} rule={rule}: steady {1e3 * steady[rule]:.2f} ms, after a command "
                      f"{1e3 * after[rule]:.2f} ms, first {1e3 * cold[rule]:.1f} ms ({steps} steps timed); steady: "
                      f"QP {rows[-1]['qp_share']:.0%}, self-stress publishing {rows[-1]['publish_share']:.0%} "
                      f"(sparse path {rows[-1]['sparse_share']:.0%} of its calls)", flush=True)
    return rows


def exponent(rows, velocity, rule="default") -> float:
    pts = [(r["members"], r["steady_ms"]) for r in rows if r["velocity"] == velocity and r.get("rule", rule) == rule]
    if len(pts) < 2:
        return math.nan
    m, c = map(np.array, zip(*pts))
    return float(np.polyfit(np.log(m), np.log(c), 1)[0])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--methods", default="elastic,inextensible", help="icosahedron rows to time")
    parser.add_argument("--stages", default="10,20,30,50,100", help='tower sizes ("": no towers)')
    parser.add_argument("--budget", type=float, default=60.0, help="CPU seconds per tower configuration at most")
    parser.add_argument("--velocities", default="0,0.05", help="tower node velocity scales (m/s) to time")
    parser.add_argument("--rules", default="default",
                        help="self-stress rule paths timed in turns on towers: default, dense, sparse")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results")
    args = parser.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    rows = icosahedron_rows(args.repeats, methods)
    for r in rows:
        print(f"{r['method']:<13}{r['ours']:<24}{r['ours_us']:>9.2f} us   {r['peer']:<24}({r['peer_model']})"
              f"{r['peer_us']:>9.2f} us   ratio (peer/ours) {r['ratio']:.2f}", flush=True)
    table = args.out / "head_to_head.csv"
    kept = [r for r in read_csv(table) if r["method"] not in methods] if table.exists() else []
    if kept or rows:
        write_csv(table, sorted(kept + rows, key=lambda r: r["method"]), list(rows[0]) if rows else None)
    stages = [int(s) for s in args.stages.split(",") if s]
    if not stages:   # --stages "": the icosahedron only
        return 0
    velocities = [float(v) for v in args.velocities.split(",") if v]
    rules = [r for r in args.rules.split(",") if r]
    towers = tower_rows(stages, args.repeats, args.budget, velocities, rules)
    write_csv(args.out / "towers_inextensible.csv", towers)
    for velocity in velocities:
        for rule in rules:
            print(f"towers v={velocity} rule={rule}: growth exponent of the steady cost "
                  f"{exponent(towers, velocity, rule):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
