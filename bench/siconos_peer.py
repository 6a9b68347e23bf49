"""Siconos as a peer for the inextensible cases (issue 20): the snap pair, a slack pendulum (the sling),
and the thrown prism with rigid struts, stepped by tensegrity_sim and by Siconos 4.4 (Moreau--Jean,
theta = 0.5; ``bench/siconos_driver.py`` run by Debian's ``/usr/bin/python3`` in a subprocess,
``apt-get install python3-siconos``).

Run from the repository root: ``python3 bench/siconos_peer.py`` (a few minutes); writes
``bench/results/siconos.csv``, which ``bench/report.py`` renders. Per case, simulator and step:

* ``pos_err_m``: largest node-position error at the final time against the closed form (snap pair,
  sling) or, for the thrown prism, against tensegrity_sim's run at the finest step (``REFERENCE_DT``);
* ``imp_err_Ns``: largest error of a cable's impulse summed over the run, against the closed form; for
  the prism the sums' parts orthogonal to its self-stress (the part that is determined), against the
  same reference;
* ``cable_overshoot_m``: largest ``length - limit`` of a cable at any step's end (positive: stretched);
* ``strut_error_m``: largest ``| length - L |`` of a rigid strut at any step's end.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

import tensegrity_sim as ts  # noqa: E402
from bench import analytic  # noqa: E402
from bench.prestress_tensions import prism3_thrown  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.methods.qp.solvers import Rows  # noqa: E402
from tensegrity_sim.methods.inextensible.self_stress import self_stress_space  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
DRIVER = Path(__file__).resolve().parent / "siconos_driver.py"
DEBIAN_PYTHON = "/usr/bin/python3"
THETA = 0.5
DTS = (1e-3, 1e-4)
REFERENCE_DT = 1.25e-5
FIELDS = ["case", "simulator", "dt", "steps", "wall_s", "pos_err_m", "imp_err_Ns", "cable_overshoot_m",
          "strut_error_m"]
_SNAP_PAIR_GAP = 0.7853   # off the step grids, as in bench/cases.py


def siconos_available() -> bool:
    """Whether Debian's python3 can import Siconos."""
    try:
        return subprocess.run([DEBIAN_PYTHON, "-c", "import siconos.kernel"], capture_output=True).returncode == 0
    except OSError:
        return False


def _simulator(scene: ts.Scene, dt: float) -> ts.Simulator:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ts.Simulator(scene, method="inextensible", dt=dt)


def siconos_spec(scene: ts.Scene, dt: float, steps: int) -> dict:
    """The driver's input for ``scene``: free nodes as one system, the cables' limits as tensegrity_sim's
    inextensible method takes them (rest length plus the prestress stretch), the rigid struts' lengths."""
    sim = _simulator(scene, dt)
    sys_, method = sim.system, sim._method
    free = np.flatnonzero(sys_.free)
    index = np.full(sys_.n_nodes, -1)
    index[free] = np.arange(len(free))
    fixed = np.flatnonzero(~sys_.free)
    index[fixed] = -1 - np.arange(len(fixed))
    limits = method.limits(sim.rest_lengths)
    rigid = sys_.strut_ends[sys_.rigid]
    return {"masses": sys_.masses[free].tolist(), "q": sim.positions[free].ravel().tolist(),
            "v": sim.velocities[free].ravel().tolist(),
            "force": sys_.gravity_force[free].ravel().tolist(), "dt": dt, "steps": steps, "theta": THETA,
            "cables": [[int(index[a]), int(index[b]), float(lim)] for (a, b), lim in zip(sys_.cable_ends, limits)],
            "struts": [[int(index[a]), int(index[b]), float(length)]
                       for (a, b), length in zip(rigid, sys_.strut_rest[sys_.rigid])],
            "fixed": {str(j): sim.positions[node].tolist() for j, node in enumerate(fixed)}}


def run_siconos(scene: ts.Scene, dt: float, duration: float) -> dict:
    """Siconos's final positions (N, 3), summed impulses, drift and wall time (s, the subprocess)."""
    steps = int(round(duration / dt))
    spec = siconos_spec(scene, dt, steps)
    start = time.perf_counter()
    out = subprocess.run([DEBIAN_PYTHON, str(DRIVER)], input=json.dumps(spec), capture_output=True, text=True,
                         check=True)
    wall = time.perf_counter() - start
    result = json.loads(out.stdout)
    positions = scene.positions.copy()
    positions[~scene.fixed] = np.asarray(result["q"]).reshape(-1, 3)
    return {"positions": positions, "impulses": np.asarray(result["impulses"]), "wall_s": wall, "steps": steps,
            "cable_overshoot_m": result["cable_overshoot_m"], "strut_error_m": result["strut_error_m"]}


def run_tensegrity(scene: ts.Scene, dt: float, duration: float) -> dict:
    """tensegrity_sim's final positions, summed impulses, drift (the same measures) and wall time (s)."""
    sim = _simulator(scene, dt)
    sys_ = sim.system
    limits = sim._method.limits(sim.rest_lengths)
    rigid = sys_.strut_ends[sys_.rigid]
    steps = int(round(duration / dt))
    start = time.perf_counter()
    traj = sim.run(steps=steps)
    wall = time.perf_counter() - start
    x = traj.positions
    cables = np.linalg.norm(x[:, sys_.cable_ends[:, 1]] - x[:, sys_.cable_ends[:, 0]], axis=2)
    struts = np.linalg.norm(x[:, rigid[:, 1]] - x[:, rigid[:, 0]], axis=2)
    return {"positions": x[-1], "impulses": traj.impulses.sum(axis=0), "wall_s": wall, "steps": steps,
            "cable_overshoot_m": float(np.max(cables - limits)),
            "strut_error_m": float(np.max(np.abs(struts - sys_.strut_rest[sys_.rigid]), initial=0.0))}


def determined_part(scene: ts.Scene):
    """A function taking summed cable impulses (n_cables,) to their part orthogonal to the cable
    components of the structure's self-stresses at load (N*s): the part every solver must agree on."""
    sim = _simulator(scene, 1e-3)
    method = sim._method
    rows = Rows(method._row_nodes, sim.system.geometry(sim.positions, method._ends)[2], np.zeros(len(method._ends)),
                method._n_eq)
    basis, _, _ = self_stress_space(rows.dense(int(sim.system.free.sum())).T)
    cables = basis[method._n_eq:]
    q, _ = np.linalg.qr(cables) if cables.shape[1] else (cables, None)
    return lambda y: y - q @ (q.T @ y)


def cases() -> list[tuple[str, ts.Scene, float, object]]:
    """(name, scene, duration s, exact) with ``exact(duration) -> (positions, impulses)`` or None."""
    return [
        ("snap_pair", ts.Scene.from_dict(analytic.snap_pair_dict(d0=_SNAP_PAIR_GAP)), 0.5,
         lambda t: analytic.snap_pair_exact(t, "inextensible", d0=_SNAP_PAIR_GAP)),
        ("sling (slack pendulum)", ts.Scene.from_dict(analytic.sling_dict(x0=0.5003)), 1.0,
         lambda t: analytic.sling_exact(t, x0=0.5003)),
        ("prism3_rigid_thrown", prism3_thrown(), 0.3, None),
    ]


def rows(progress=print) -> list[dict]:
    out = []
    for name, scene, duration, exact in cases():
        if exact is not None:
            x_ref, imp_ref = exact(duration)
            part = lambda y: y   # noqa: E731  (a closed form: the impulses are unique)
        else:
            ref = run_tensegrity(scene, REFERENCE_DT, duration)
            part = determined_part(scene)
            x_ref, imp_ref = ref["positions"], part(ref["impulses"])
        for dt in DTS:
            for simulator, run in (("tensegrity_sim", run_tensegrity), ("Siconos 4.4 Moreau-Jean", run_siconos)):
                r = run(scene, dt, duration)
                row = {"case": name, "simulator": simulator, "dt": dt, "steps": r["steps"], "wall_s": r["wall_s"],
                       "pos_err_m": float(np.max(np.linalg.norm(r["positions"] - x_ref, axis=1))),
                       "imp_err_Ns": float(np.max(np.abs(part(r["impulses"]) - imp_ref))),
                       "cable_overshoot_m": r["cable_overshoot_m"],
                       "strut_error_m": r["strut_error_m"] if scene.struts else math.nan}
                out.append(row)
                progress(row)
    return out


def main() -> None:
    if not siconos_available():
        raise SystemExit(f"Siconos is not importable by {DEBIAN_PYTHON}: apt-get install python3-siconos")
    write_csv(RESULTS / "siconos.csv", rows(), FIELDS)


if __name__ == "__main__":
    main()
