"""The stepping core beside MuJoCo, contenders taking turns in one process (issue 10's targets).

Run: ``python bench/head_to_head.py [--repeats R] [--methods elastic,inextensible] [--stages 10,20,30,50,100]
[--velocities 0,0.05] [--configs default,main] [--warmup N] [--budget S] [--out DIR]``. ``--methods`` times
the icosahedron rows of those methods only (the others' rows in ``head_to_head.csv`` are kept as they
were; ``--methods ""``: none); ``--stages ""`` skips the towers (and keeps their CSV).

* **Icosahedron thrown** (``bench.cases``: struts rigid, dt = 1 ms): ``Simulator.step()`` in a Python
  loop against MuJoCo's ``mj_step(model, data)`` in a Python loop, and ``Simulator.run()`` against
  ``mj_step(model, data, nstep)``; the elastic method against MuJoCo's Euler with spring tendons, the
  inextensible one against MuJoCo's Euler with *limited* tendons (its model of an inextensible cable).
  The inextensible rows add the step with the self-stress rule in its numpy reference (what compiling
  it gained) and the step with its kernels called one by one through the solver's and the rule's API
  (``one_kernel = False``: what running a step in one kernel call gained). Both methods add ``run()``
  with the scene's default strut-strut contact detection against MuJoCo's ``mj_step(nstep)`` with the
  struts' capsules colliding (``MujocoPeer(strut_contacts=True)``: like for like, detection on in both)
  and against this simulator's own ``run()`` without detection (what detection costs). Every timed run starts
  ``SETTLE`` steps after a reset, each contender stepped there untimed: steady stepping after warm-up.
* **Towers** of ``--stages`` stages (no gravity), inextensible, at rest and moving (random node
  velocities of 0.05 m/s): the steady cost per step after a warm-up, and separately the cost of the first
  step after a command (``set_rest_lengths`` with the current lengths, as a controller holding its
  command at 100 Hz sends), each the best of ``--repeats``; the growth exponent of the steady cost; the
  shares of the steady cost spent in the QP and in the self-stress rule's publishing; beside them, in
  the same turns, MuJoCo's Euler with limited tendons on the same tower (its model of an inextensible
  cable: soft constraints, one solve a step, no snap located). ``--configs``
  names the configurations timed in turns on twin simulators (``tower_rows``): ``default`` (the paths
  the size picks), ``main`` (the dense self-stress rule and the sparse backend without its dual
  active-set method: the paths before issue 10's large-structure work), or a ``+``-joined choice of a
  QP backend, the dual method and the rule's path.

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
from bench.scale import finish_plot, loglog_slope, tower_scene  # noqa: E402
from bench.tables import read_csv, write_csv  # noqa: E402
from bench.timing import SETTLE, time_alternating  # noqa: E402

# MuJoCo steps a tower 4-8x (at rest) to 300-500x (moving) faster than this method: its turn in a round
# is this many steps
_PEER_BLOCK = 50


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
        # like for like with contact detection on: this simulator's default strut-strut detection (events
        # only) against MuJoCo's strut capsules colliding with each other; and the same run() without it
        detected = ts.Simulator(scene, method=method, dt=1e-3)
        capsules = MujocoPeer(scene, model=method, dt=1e-3, integrator="Euler", strut_contacts=True)
        contenders["tensegrity_sim run(), strut-strut detection"] = (lambda n: detected.run(steps=n, every=n),
                                                                     detected.reset)
        contenders["MuJoCo mj_step(nstep), strut capsule contacts"] = (capsules.advance, capsules.reset)
        pairs += [(len(contenders) - 2, len(contenders) - 1), (len(contenders) - 2, 2)]
        if method == "inextensible":   # what compiling the self-stress rule and the one-call step gained (issue 10)
            plain = ts.Simulator(scene, method=method, dt=1e-3, contacts=())
            plain._method.self_stress.compiled = False
            contenders["tensegrity_sim step(), self-stress rule numpy"] = (_python_loop(plain.step), plain.reset)
            api = ts.Simulator(scene, method=method, dt=1e-3, contacts=())
            api._method.one_kernel = False
            contenders["tensegrity_sim step(), kernels called through the API"] = (_python_loop(api.step), api.reset)
            pairs += [(len(contenders) - 2, 1), (len(contenders) - 1, 1)]
        timings = time_alternating(contenders, repeats=repeats, target=0.2, clock=time.process_time,
                                   settle=SETTLE)
        best = {name: t.best for name, t in timings.items()}
        names = list(contenders)
        for ours, theirs in ((names[i], names[j]) for i, j in pairs):
            rows.append({"case": "icosahedron_thrown", "method": method, "ours": ours, "peer": theirs,
                         "peer_model": ("this simulator" if theirs.startswith("tensegrity_sim")
                                        else "spring tendons" if method == "elastic" else "limited tendons")
                         + (", strut capsule contacts" if "capsule" in theirs else ""),
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


def _configured(scene, config: str) -> ts.Simulator:
    """An inextensible simulator of ``scene`` (dt = 1 ms) in configuration ``config``: ``default`` (the
    paths its size picks) or ``+``-joined choices ``qp=<backend>`` (a QP backend by name), ``dual=off``
    (the sparse backend without its dual active-set method: DAQP after a failed guess), ``rule=dense``
    or ``rule=sparse`` (the self-stress rule's path); ``main`` is ``dual=off+rule=dense``, the paths
    before issue 10's large-structure work."""
    choices = dict(part.split("=") for part in config.replace("main", "dual=off+rule=dense").split("+")
                   if part != "default")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        sim = ts.Simulator(scene, method="inextensible", dt=1e-3, contacts=(), solver=choices.get("qp"))
    if "rule" in choices:   # dense: the SVD for rows that are not the load time's too (no moving path)
        rule = sim._method.self_stress
        rule.sparse = choices["rule"] == "sparse"
        rule.moving = rule.moving and rule.sparse
    if choices.get("dual") == "off" and hasattr(sim._method.solver, "dual"):
        sim._method.solver.dual = False
    return sim


def tower_rows(stages, repeats: int, budget: float, velocities=(0.0, 0.05), configs=("default",),
               warmup: int = 10) -> list[dict]:
    """Steady and after-a-command cost per step of the inextensible method on towers, at rest and moving,
    and the shares of the steady cost spent in the QP backend (``qp_share``) and in publishing the
    impulses of rows that carry a self-stress (``publish_share``, ``methods/inextensible/self_stress.py``), for each
    of ``configs`` (:func:`_configured`), their twin simulators taking turns block by block;
    ``guessed_share``: the QPs the sparse backend's guess answered, ``dual_share`` those its dual
    active-set method answered; ``sparse_share``: the rule's calls its sparse path answered; ``mujoco_ms``:
    MuJoCo's steady step with limited tendons (the best of blocks of ``_PEER_BLOCK`` steps, one block after
    each round of the configurations), ``mujoco_over_ours`` its ratio to the configuration's steady step."""
    from bench.mujoco_peer import MujocoPeer
    rows = []
    for n in stages:
        for velocity in velocities:
            scene = agitated(tower_scene(n), velocity)
            sims, cold = {}, {}
            for config in configs:
                sim = _configured(scene, config)
                start = time.process_time()
                sim.step()                       # the very first step: no hint at all
                cold[config] = time.process_time() - start
                for _ in range(warmup):
                    sim.step()
                sims[config] = sim
            peer = MujocoPeer(scene, model="inextensible", dt=1e-3, integrator="Euler")
            peer.advance(warmup + 1)
            peer_steady = math.inf
            inside = {config: {"solve": 0.0, "impulses": 0.0} for config in configs}
            for config, sim in sims.items():
                _clock_calls(sim._method.solver, "solve", inside[config])
                _clock_calls(sim._method.self_stress, "impulses", inside[config])
            steady, after = dict.fromkeys(configs, math.inf), dict.fromkeys(configs, math.inf)
            steady_total = dict.fromkeys(configs, 0.0)
            steady_inside = {config: {"solve": 0.0, "impulses": 0.0} for config in configs}
            steps = 0
            spent = time.process_time()
            for _ in range(repeats):
                for config, sim in sims.items():
                    before = dict(inside[config])
                    start = time.process_time()
                    for _ in range(5):
                        sim.step()
                    block = time.process_time() - start
                    steady[config] = min(steady[config], block / 5)
                    steady_total[config] += block
                    for name in steady_inside[config]:
                        steady_inside[config][name] += inside[config][name] - before[name]
                    sim.set_rest_lengths(sim.rest_lengths)   # a command (the same lengths: held)
                    start = time.process_time()
                    sim.step()
                    after[config] = min(after[config], time.process_time() - start)
                start = time.process_time()   # MuJoCo in its turn: _PEER_BLOCK steps of the same tower
                peer.advance(_PEER_BLOCK)
                peer_steady = min(peer_steady, (time.process_time() - start) / _PEER_BLOCK)
                steps += 6
                if time.process_time() - spent > budget:
                    break
            for config, sim in sims.items():
                counts = getattr(sim._method.solver, "counts", {})
                rule_counts = sim._method.self_stress.counts
                qps = max(sum(counts.values()), 1)
                rows.append({"stages": n, "members": len(scene.struts) + len(scene.cables),
                             "velocity": velocity, "config": config, "solver": sim.method_settings["solver"],
                             "first_ms": 1e3 * cold[config], "steady_ms": 1e3 * steady[config],
                             "after_command_ms": 1e3 * after[config], "after_over_steady": after[config] / steady[config],
                             "mujoco_ms": 1e3 * peer_steady, "mujoco_over_ours": peer_steady / steady[config],
                             "qp_share": steady_inside[config]["solve"] / steady_total[config],
                             "publish_share": steady_inside[config]["impulses"] / steady_total[config],
                             "guessed_share": counts["guessed"] / qps if counts else math.nan,
                             "dual_share": counts.get("dual", 0) / qps if counts else math.nan,
                             "sparse_share": rule_counts["sparse"] / max(sum(rule_counts.values()), 1)})
                print(f"  tower{n} v={velocity} {config}: steady {1e3 * steady[config]:.2f} ms, after a command "
                      f"{1e3 * after[config]:.2f} ms, first {1e3 * cold[config]:.1f} ms ({steps} steps timed), "
                      f"MuJoCo's limited tendons {1e3 * peer_steady:.2f} ms; "
                      f"steady: QP {rows[-1]['qp_share']:.0%}, self-stress publishing {rows[-1]['publish_share']:.0%}; "
                      f"QPs {counts}, rule {rule_counts}", flush=True)
    return rows


def exponent(rows, velocity, config="default") -> float:
    """The growth exponent of the steady step of ``config`` at ``velocity``."""
    return loglog_slope([(r["members"], r["steady_ms"]) for r in rows
                         if r["velocity"] == velocity and r["config"] == config])


def plot_towers(rows, path) -> None:
    """Steady cost per step (ms) against members, log-log, one line per configuration and velocity, with
    its growth exponent; the step after a command as open markers."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.0, 4.2))
    for config in dict.fromkeys(r["config"] for r in rows):
        for velocity in sorted({r["velocity"] for r in rows}):
            pts = sorted((r["members"], r["steady_ms"], r["after_command_ms"]) for r in rows
                         if r["config"] == config and r["velocity"] == velocity)
            if not pts:
                continue
            m, steady, after = map(np.array, zip(*pts))
            label = f"{config}, {'moving' if velocity else 'at rest'} (p = {exponent(rows, velocity, config):.2f})"
            line, = ax.loglog(m, steady, "-o" if velocity else "--s", ms=3.5, label=label)
            ax.loglog(m, after, "o" if velocity else "s", ms=6, mfc="none", color=line.get_color())
    for velocity in sorted({r["velocity"] for r in rows}):
        pts = sorted({(r["members"], r["mujoco_ms"]) for r in rows if r["velocity"] == velocity})
        m, peer = map(np.array, zip(*pts))
        ax.loglog(m, peer, ":^" if velocity else ":v", ms=3.5, color="0.4",
                  label=f"MuJoCo limited tendons, {'moving' if velocity else 'at rest'} "
                        f"(p = {loglog_slope(pts):.2f})")
    ax.set_xlabel("members (towers, inextensible, no gravity, dt = 1 ms)")
    ax.set_ylabel("CPU time per step (ms)")
    ax.set_title("steady step (filled) and the step after a command (open); p: growth exponent", fontsize=8)
    finish_plot(fig, ax, path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--methods", default="elastic,inextensible", help="icosahedron rows to time")
    parser.add_argument("--stages", default="10,20,30,50,100", help='tower sizes ("": no towers)')
    parser.add_argument("--budget", type=float, default=60.0, help="CPU seconds per tower configuration at most")
    parser.add_argument("--velocities", default="0,0.05", help="tower node velocity scales (m/s) to time")
    parser.add_argument("--configs", default="default,main",
                        help="tower configurations timed in turns (see _configured): default, main, or "
                             "+-joined qp=<backend>, dual=off, rule=dense|sparse")
    parser.add_argument("--warmup", type=int, default=10, help="tower steps before the timing")
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
    configs = [c for c in args.configs.split(",") if c]
    towers = tower_rows(stages, args.repeats, args.budget, velocities, configs, args.warmup)
    write_csv(args.out / "towers_inextensible.csv", towers)
    plot_towers(towers, args.out / "towers_inextensible.png")
    for velocity in velocities:
        for config in configs:
            print(f"towers v={velocity} {config}: growth exponent of the steady cost "
                  f"{exponent(towers, velocity, config):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
