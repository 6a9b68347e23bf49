"""Tensions of locked structures (issue 20): the inextensible method's published tensions beside the
elastic twin's, before and after the self-stress rule, and what the rule costs per step.

Run from the repository root: ``python3 bench/prestress_tensions.py [--cost-only]`` (a few minutes). Writes
``bench/results/prestress.csv`` (tension statistics) and ``bench/results/prestress_cost.csv`` (µs per
step with the rule and without it, taking turns in one process); ``bench/report.py`` renders both.

Scenes: the thrown icosahedron of the work-precision study at 0.3 m/s (``bench.cases.icosahedron_thrown``),
and the 3-strut prism with rigid struts at 0.5 m/s; 0.3 s each. "QP multipliers" is the inextensible
method with the rule switched off (what it published before issue 20); "residual" is the largest node
impulse the published impulses leave out (:attr:`~tensegrity_sim.methods.inextensible.self_stress.SelfStress.residual`).
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

import tensegrity_sim as ts  # noqa: E402
from bench.cases import icosahedron_thrown, rigid_consistent  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from bench.timing import time_runs  # noqa: E402
from tensegrity_sim.methods.inextensible.method import LIMIT_TOL  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
DTS = (1e-3, 5e-4, 2.5e-4)
DURATION = 0.3
TENSION_FIELDS = ["scene", "configuration", "dt", "median_N", "p99_N", "max_N", "max_after_first_N", "switches",
                  "residual_Ns"]
COST_FIELDS = ["scene", "dt", "steps", "us_per_step_rule", "us_per_step_qp_only", "ratio"]


def prism3_thrown(scale: float = 0.5, seed: int = 0) -> ts.Scene:
    """The built-in prism with rigid struts, random node velocities (normal, ``scale`` m/s)."""
    d = ts.load_scene("prism3").to_dict()
    for s in d["struts"]:
        s["stiffness"] = "rigid"
        del s["rest_length"]
    rng = np.random.default_rng(seed)
    for node in d["nodes"]:
        node["velocity"] = [float(c) for c in rng.normal(scale=scale, size=3)]
    d["name"] = "prism3_rigid_thrown"
    return rigid_consistent(d)


def scenes() -> dict[str, ts.Scene]:
    return {"icosahedron_thrown (0.3 m/s)": icosahedron_thrown(scale=0.3),
            "prism3_rigid_thrown (0.5 m/s)": prism3_thrown(),
            "prism3 (elastic struts, 0.5 m/s)": random_prism_elastic()}


def random_prism_elastic() -> ts.Scene:
    """The built-in prism (elastic struts: no self-stress among the QP rows) with the same velocities."""
    d = ts.load_scene("prism3").to_dict()
    for node, v in zip(d["nodes"], prism3_thrown().velocities):
        node["velocity"] = [float(c) for c in v]
    return ts.Scene.from_dict(d)


def simulator(scene: ts.Scene, method: str, dt: float, rule: bool = True) -> ts.Simulator:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ts.Simulator(scene, method=method, dt=dt)
    if not rule:   # what the method published before issue 20: the multipliers, flags at LIMIT_TOL
        sim._method.self_stress.possible = False
        sim._method._taut_tol = LIMIT_TOL
    return sim


def tension_row(name: str, config: str, sim: ts.Simulator) -> dict:
    traj = sim.run(duration=DURATION)
    t = traj.tensions
    rule = getattr(sim._method, "self_stress", None)
    return {"scene": name, "configuration": config, "dt": sim.dt, "median_N": float(np.median(t)),
            "p99_N": float(np.percentile(t, 99)), "max_N": float(t.max()), "max_after_first_N": float(t[1:].max()),
            "switches": int(np.count_nonzero(np.diff(traj.slack, axis=0))),
            "residual_Ns": float(rule.residual) if rule is not None and rule.possible else 0.0}


def tension_rows(progress=print) -> list[dict]:
    rows = []
    for name, scene in scenes().items():
        if name.startswith("prism3 (elastic"):
            continue
        for dt in DTS:
            rows.append(tension_row(name, "inextensible", simulator(scene, "inextensible", dt)))
            rows.append(tension_row(name, "inextensible, QP multipliers", simulator(scene, "inextensible", dt, False)))
            rows.append(tension_row(name, "elastic twin", simulator(scene, "elastic", dt)))
            progress(rows[-3])
    return rows


def cost_rows(progress=print, dt: float = 5e-4, steps: int = 200, repeats: int = 15) -> list[dict]:
    """µs per step with the rule and without it (the QP's multipliers published), best of ``repeats``
    runs taking turns in this process."""
    rows = []
    for name, scene in scenes().items():
        sims = {True: simulator(scene, "inextensible", dt), False: simulator(scene, "inextensible", dt, False)}
        best = {True: np.inf, False: np.inf}
        for _ in range(repeats):
            for rule, sim in sims.items():
                timing = time_runs(lambda sim=sim: sim.run(steps=steps), setup=sim.reset, repeats=1)
                best[rule] = min(best[rule], timing.best)
        rows.append({"scene": name, "dt": dt, "steps": steps, "us_per_step_rule": 1e6 * best[True] / steps,
                     "us_per_step_qp_only": 1e6 * best[False] / steps, "ratio": best[True] / best[False]})
        progress(rows[-1])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cost-only", action="store_true", help="only measure the rule's cost again")
    args = parser.parse_args()
    if not args.cost_only:
        write_csv(RESULTS / "prestress.csv", tension_rows(), TENSION_FIELDS)
    write_csv(RESULTS / "prestress_cost.csv", cost_rows(), COST_FIELDS)


if __name__ == "__main__":
    main()
