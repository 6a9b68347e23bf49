"""The elastic method's accuracy options beside MuJoCo: work-precision of the elastic cases (bungee, dead
band, snap pair, thrown icosahedron, kicked tower) and the matched-error table, for the
documentation's methods page (docs/methods.md) and ``auto``'s guidance (issue 15).

Every elastic configuration of tensegrity_sim (plain Verlet, located order 2, order 4) and MuJoCo's
Euler, implicitfast and RK4 run on the same step grid, taking turns in one process
(:func:`bench.work_precision.alternating_sweep`: the machine is shared and its load drifts). Writes
``work_precision_elastic.csv``, one ``wp_<case>_elastic.png`` per case and ``matched_error.csv`` /
``matched_error.md``: for each decade of final-position error, the wall time per simulated second of
the cheapest configuration of each simulator that reaches it (interpolated on its Pareto front); and
``step_cost.csv``: the CPU time of one step of each configuration (``run()``, the compiled loop), the
configurations taking turns, and its ratio to plain Verlet's.

Run from the repository root: ``python3 bench/elastic_options.py`` (``--quick``: the coarse grid;
``--costs``: the step costs only).
"""
from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

import time  # noqa: E402

import tensegrity_sim as ts  # noqa: E402
from bench import work_precision  # noqa: E402
from bench.cases import work_precision_cases  # noqa: E402
from bench.runners import mujoco_runners, tensegrity_runners  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from bench.timing import time_alternating  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "elastic_options"
LEVELS = [10.0 ** -k for k in range(2, 14)]   # final-position errors of the table, m
MATCHED_FIELDS = ["case", "error_m", "tensegrity_sim", "tensegrity_sim_s", "MuJoCo", "MuJoCo_s", "MuJoCo_over_ours"]


def matched_error_rows(rows: list[dict], accuracy: dict) -> list[dict]:
    """Per case and error level (:data:`LEVELS`, from the largest that some configuration misses and
    down to ten times the reference's accuracy), the cheapest configuration of each simulator that
    reaches it and its wall time per simulated second (NaN where none does), and their ratio."""
    out = []
    for case in dict.fromkeys(r["case"] for r in rows):
        sub = [r for r in rows if r["case"] == case]
        best = {}
        for level in LEVELS:
            if level < 10.0 * accuracy[case]:
                break
            for simulator in ("tensegrity_sim", "MuJoCo"):
                times = {r["variant"]: work_precision.time_to_reach([q for q in sub if q["simulator"] == simulator
                                                                     and q["variant"] == r["variant"]], level)
                         for r in sub if r["simulator"] == simulator}
                reached = {v: t for v, t in times.items() if math.isfinite(t)}
                best[simulator] = min(reached.items(), key=lambda item: item[1]) if reached else ("-", math.nan)
            if best["tensegrity_sim"][0] == "-" and best["MuJoCo"][0] == "-":
                break
            out.append({"case": case, "error_m": level,
                        "tensegrity_sim": best["tensegrity_sim"][0], "tensegrity_sim_s": best["tensegrity_sim"][1],
                        "MuJoCo": best["MuJoCo"][0], "MuJoCo_s": best["MuJoCo"][1],
                        "MuJoCo_over_ours": best["MuJoCo"][1] / best["tensegrity_sim"][1]})
    return out


def matched_error_markdown(rows: list[dict]) -> str:
    lines = ["| case | final-position error (m) | tensegrity_sim: cheapest | s per simulated s | "
             "MuJoCo: cheapest | s per simulated s | MuJoCo / tensegrity_sim |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        cells = [r["case"], f"{r['error_m']:.0e}"] + [
            f"{r[k]:.3g}" if math.isfinite(r[k]) else "not reached" if k.endswith("_s") else "-"
            for k in ("tensegrity_sim_s", "MuJoCo_s", "MuJoCo_over_ours")]
        lines.append(f"| {cells[0]} | {cells[1]} | {r['tensegrity_sim']} | {cells[2]} | {r['MuJoCo']} | {cells[3]} | "
                     f"{cells[4]} |")
    return "\n".join(lines) + "\n"


CONFIGURATIONS = {"elastic": {}, "elastic located": {"locate_switches": True}, "elastic order 4": {"order": 4},
                  "elastic order 4 unlocated": {"order": 4, "locate_switches": False}}


def step_cost_rows(cases, dt: float = 1e-3) -> list[dict]:
    """CPU time per step (us) of every elastic configuration on every case at ``dt``, in ``run()``,
    taking turns (best of 5), and its ratio to plain Verlet's."""
    rows = []
    for case in cases:
        sims = {name: ts.Simulator(case.scene, method="elastic", dt=dt, contacts=(), **options)
                for name, options in CONFIGURATIONS.items()}
        timings = time_alternating({name: (lambda n, sim=sim: sim.run(steps=n, every=n), sim.reset)
                                    for name, sim in sims.items()}, repeats=5, clock=time.process_time)
        plain = timings["elastic"].best
        rows += [{"case": case.name, "variant": name, "dt": dt, "us_per_step": 1e6 * t.best,
                  "ratio_to_plain": t.best / plain} for name, t in timings.items()]
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the coarse step grid (1e-2 .. 1e-4 s)")
    parser.add_argument("--out", type=Path, default=OUT, help=f"output directory (default: {OUT})")
    parser.add_argument("--cases", default="", help="comma-separated case names (default: every elastic case)")
    parser.add_argument("--repeats", type=int, default=3, help="timed rounds per run (best kept)")
    parser.add_argument("--budget", type=float, default=5.0, help="longest run timed, s")
    parser.add_argument("--costs", action="store_true", help="only the step costs (step_cost.csv)")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")   # MuJoCo's divergence warnings: the rows say "unstable"
    wanted = set(filter(None, args.cases.split(",")))
    # without a ground: a scene with one is stepped by plain Verlet only
    cases = [c for c in work_precision_cases() if "elastic" in c.models and c.scene.ground is None
             and (not wanted or c.name in wanted)]
    runners = ([r for r in tensegrity_runners() if r.model == "elastic"]
               + [r for r in mujoco_runners() if r.model == "elastic"])

    def dts(runner):   # as run_all's sweep: MuJoCo is cheap per step, its curves go further down
        if args.quick:
            return work_precision.DTS_QUICK
        return work_precision.DTS_FULL + (work_precision.DTS_MUJOCO_EXTRA if runner.simulator == "MuJoCo" else ())
    args.out.mkdir(parents=True, exist_ok=True)
    costs = step_cost_rows(cases)
    write_csv(args.out / "step_cost.csv", costs)
    for row in costs:
        print(f"{row['case']:20} {row['variant']:28} {row['us_per_step']:8.2f} us/step  x{row['ratio_to_plain']:.2f}")
    if args.costs:
        return 0
    rows, accuracy = [], {}
    for case in cases:
        ref = work_precision.reference_for(case, "elastic", quick=args.quick)
        accuracy[case.name] = ref.accuracy_m
        print(f"{case.name}: reference {ref.source}, accuracy {ref.accuracy_m:.1e} m", flush=True)
        sub = work_precision.alternating_sweep(case, runners, ref, dts, repeats=args.repeats, budget=args.budget)
        rows += sub
        work_precision.plot(case, "elastic", sub, ref, args.out / f"wp_{case.name}_elastic.png")
        write_csv(args.out / "work_precision_elastic.csv", rows, work_precision.FIELDS)
    matched = matched_error_rows(rows, accuracy)
    write_csv(args.out / "matched_error.csv", matched, MATCHED_FIELDS)
    (args.out / "matched_error.md").write_text(matched_error_markdown(matched))
    print(matched_error_markdown(matched))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
