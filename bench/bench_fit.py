"""``tensegrity-sim fit`` against known truths (issue 49): a nominal scene with every fitted parameter 1.3x and
0.7x the truth, logs noise-free and with 1 mm of Gaussian noise on every pose (``scripts/add_pose_noise.py``).

Cases: ``prism`` (prism3 thrown, cables slackening and snapping, damped, 2 s free; stiffness and damping) and
``roll`` (icosahedron_ground rolling under ``examples/roll.yaml``, damped, 10 s commanded; stiffness, damping and
the ground's friction; with ``chord``, the start states' Jacobian reused). Each fit's wall time, CPU time, the devices JAX ran on (one
CPU device per core: ``spread_over_cores``) and the load average of the machine are recorded.

Run: ``python3 bench/bench_fit.py [--cases prism,roll] [--factors 1.3,0.7] [--noise 0,0.001] [--duration S]``
(``--duration``: every case's log that long instead); writes ``bench/results/fit.csv`` (``--out``: another file;
the roll's rows are in ``fit_roll.csv``) and prints each row.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import tensegrity_sim as ts  # noqa: E402
from add_pose_noise import rewrite_poses  # noqa: E402
from bench.cases import rigid_consistent  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.cli import main  # noqa: E402
from tensegrity_sim.methods.jax.fit import spread_over_cores  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def prism_truth() -> ts.Scene:
    d = ts.load_scene("prism3").to_dict()
    rng = np.random.default_rng(3)
    for node in d["nodes"]:
        node["velocity"] = [float(c) for c in rng.normal(scale=1.5, size=3)]
    for c in d["cables"]:
        c["damping"] = 0.5
    return rigid_consistent(d)


def roll_truth() -> ts.Scene:
    d = ts.load_scene("icosahedron_ground").to_dict()
    for c in d["cables"]:
        c["damping"] = 2.0
    return ts.Scene.from_dict(d)


CASES = {  # truth, duration (s), commands, parameters
    "prism": (prism_truth, 2.0, None, "stiffness,damping"),
    "roll": (roll_truth, 10.0, ROOT / "examples" / "roll.yaml", "stiffness,damping,friction"),
}


def nominal(truth: ts.Scene, factor: float) -> ts.Scene:
    d = truth.to_dict()
    for c in d["cables"]:
        c["stiffness"] *= factor
        c["damping"] *= factor
    if d.get("ground"):
        d["ground"]["friction"] *= factor
    return ts.Scene.from_dict(d)


def truth_values(truth: ts.Scene) -> dict[str, float]:
    return {"stiffness": truth.cables[0].stiffness, "damping": truth.cables[0].damping,
            "friction": truth.ground.friction if truth.ground else 0.0}


def main_() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="prism,roll")
    parser.add_argument("--factors", default="1.3,0.7")
    parser.add_argument("--noise", default="0,0.001")
    parser.add_argument("--duration", type=float, help="s: every case's log this long (default: the case's)")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "fit.csv")
    args = parser.parse_args()
    spread_over_cores()   # before JAX runs: the fit's tangents on every core
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for case in args.cases.split(","):
            make, duration, commands, params = CASES[case]
            duration = args.duration or duration
            truth = make()
            (tmp / "truth.yaml").write_text(truth.to_yaml())
            log = tmp / f"{case}.mcap"
            argv = ["run", str(tmp / "truth.yaml"), "--method", "elastic", "--duration", str(duration), "--quiet",
                    "--log", str(log)]
            assert main(argv + (["--commands", str(commands)] if commands else [])) == 0
            expected = truth_values(truth)
            for sigma in (float(s) for s in args.noise.split(",")):
                source = log
                if sigma > 0:
                    rng = np.random.default_rng(0)
                    source = tmp / f"{case}_noisy.mcap"
                    rewrite_poses(log, source, lambda x: x + rng.normal(scale=sigma, size=x.shape))
                for factor in (float(f) for f in args.factors.split(",")):
                    start_wall, start_cpu = time.perf_counter(), time.process_time()
                    result = ts.fit(source, params, scene=nominal(truth, factor), chord=case == "roll")
                    wall, cpu = time.perf_counter() - start_wall, time.process_time() - start_cpu
                    row = {"case": case, "duration_s": duration, "noise_m": sigma, "start_factor": factor,
                           "params": params, "windows": result.windows, "window_steps": result.window * result.every,
                           "evaluations": result.evaluations, "jacobians": result.jacobians, "wall_s": wall,
                           "cpu_s": cpu, "devices": jax.device_count(), "load_1min": os.getloadavg()[0],
                           "noise_estimate_m": result.noise, "rms_start_m": result.rms_start,
                           "rms_fitted_m": result.rms_fitted}
                    for u, value, sigma_u in zip(result.unknowns, result.fitted, result.sigma):
                        row[f"{u.kind}_rel_error"] = value / expected[u.kind] - 1.0
                        row[f"{u.kind}_sigma_rel"] = sigma_u / expected[u.kind]
                    rows.append(row)
                    print(", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()),
                          flush=True)
                    # after every fit, so that a run stopped part way keeps the rows it has
                    write_csv(args.out, rows, list(dict.fromkeys(k for row in rows for k in row)))
    return 0


if __name__ == "__main__":
    sys.exit(main_())
