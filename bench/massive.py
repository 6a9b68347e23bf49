"""The full model (method "massive", physics.md §4b) beside its two limits: three studies, printed and written to
``bench/results/massive_*.csv``.

* ``drop``: the hard case where the three methods differ. prism3 with its bottom triangle fixed, every cable
  3 cm slack, dropped under gravity until its top triangle's three cables snap taut together (by symmetry).
  The energy kept at that first snap, per method, against the closed form: the three cables' symmetric mode
  has the effective mass ``m/3`` per cable (top nodes of mass ``m``; the elastic struts take no part in an
  impact), so a plastic snap (inextensible) loses ``1/2 m de^2`` and the plates' (massive) that times
  ``m_c/(m/3 + m_c)``, with ``de`` the cables' rate at the snap; the elastic method loses nothing.
* ``order``: the 1-D snap (``analytic.plate_snap_dict``: 1 kg at 1 m/s on an anchored cable, plate 0.5 kg,
  10 rad/s) against its closed form after the rebound, over steps: located snaps (the default) and not
  located; error against wall time per simulated second.
* ``speed``: the icosahedron thrown (spin and random node velocities; struts elastic at 1e5 N/m, since the
  massive method takes no rigid struts yet) with cable plates of 0.05 kg, 1 ms: the massive method's ``run()``
  (compiled) and numpy reference against the elastic method's, all with located switches (CPU time, best of 7
  taken in turns; the references best of 2), and MuJoCo's Euler on the same structure with spring tendons
  (massless cables), where ``mujoco`` is installed.

* ``ground``: the icosahedron with elastic struts resting on the ground, lifted 0.2 m and thrown down spinning
  (:func:`thrown`, as in ``test/test_massive_ground.py``), 250 steps of 1 ms through its landing: the massive method (cable
  plates of 0.05 kg; with contacts it steps by its numpy reference) against the elastic method's compiled
  ``run()`` and its numpy reference (CPU time, best of 3 taken in turns).

``python3 bench/massive.py [--quick] [--study drop|order|speed|ground]``.
"""
from __future__ import annotations

import math
import time
import warnings

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim.system import System

G = 9.81


def drop_scene(plate: float, slack: float = 0.03) -> ts.Scene:
    d = ts.load_scene("prism3").to_dict()
    for n in d["nodes"][:3]:
        n["fixed"] = True
    for c in d["cables"]:
        c["rest_length"] += slack
        c["mass"] = plate
    d["gravity"] = [0.0, 0.0, -G]
    return ts.Scene.from_dict(d)


def first_snap(sim: ts.Simulator, plate: float) -> dict:
    """Step ``sim`` (a :func:`drop_scene`) up to the step of the first snap: the kinetic energy before it, the
    energy lost in it (measured: the total's change, the plates' energy included), and the closed form's loss
    for the simulator's method from the cables' rate before it."""
    slack0 = sim.slack()
    top = np.array([3, 4, 5])   # c3, c4, c5: the top triangle
    m = float(sim.system.masses[3])
    for k in range(100_000):
        before = sim.energy()
        x, v = sim.positions, sim.velocities
        r = sim.step()
        if (~r.slack & slack0).any():
            break
    snapped = np.flatnonzero(~r.slack & slack0)
    ends = sim.system.cable_ends[top]
    d = x[ends[:, 1]] - x[ends[:, 0]]
    unit = d / np.linalg.norm(d, axis=1)[:, None]
    rate = float(np.mean(np.einsum("ij,ij->i", v[ends[:, 1]] - v[ends[:, 0]], unit)))
    plastic = 0.5 * m * rate ** 2
    predicted = {"elastic": 0.0, "inextensible": plastic, "massive": plastic * plate / (m / 3 + plate)}[sim.method]
    lost = before["total"] - sim.energy()["total"]
    return {"method": sim.method, "plate_kg": plate, "dt": sim.dt, "snap_step": k + 1,
            "cables": " ".join(sim.scene.cable_names[i] for i in snapped),
            "kinetic_before_J": before["kinetic"], "lost_J": lost, "closed_form_lost_J": predicted,
            "kept": 1.0 - lost / before["kinetic"], "closed_form_kept": 1.0 - predicted / before["kinetic"],
            "plates_lost_J": sim.energy_lost}


def drop_rows(plate: float = 0.2, dt: float = 1e-4) -> list[dict]:
    """:func:`first_snap` of each method."""
    rows = []
    for method in ("elastic", "inextensible", "massive"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ts.LengthOffsetWarning)
            rows.append(first_snap(ts.Simulator(drop_scene(plate), method=method, dt=dt), plate))
    return rows


def order_rows(quick: bool) -> list[dict]:
    """The 1-D snap (``analytic.plate_snap_dict``) against its closed form after the rebound, over steps."""
    from bench.analytic import plate_snap_dict, plate_snap_exact
    plate, omega, duration = 0.5, 10.0, 0.45
    scene = ts.Scene.from_dict(plate_snap_dict(plate, omega))
    rows = []
    for locate in (True, False):
        for dt in (4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4) if not quick else (2e-3, 1e-3, 5e-4):
            dt *= 1.0 + 1 / 7   # the snap inside a step
            sim = ts.Simulator(scene, method="massive", dt=dt, locate_switches=locate)
            steps = round(duration / dt)
            start = time.perf_counter()
            sim.run(steps=steps)
            wall = time.perf_counter() - start
            exact = plate_snap_exact(sim.time, plate, omega)[0]
            rows.append({"locate_switches": locate, "dt": dt, "pos_err_m": abs(sim.positions[1, 0] - exact[1, 0]),
                         "wall_per_sim_s": wall / sim.time})
    for a, b in zip(rows, rows[1:]):
        if a["locate_switches"] == b["locate_switches"]:
            b["ratio"] = a["pos_err_m"] / b["pos_err_m"]
    return rows


def thrown_icosahedron(plate: float) -> ts.Scene:
    raw = ts.load_scene("icosahedron").to_dict()
    x = np.array([n["position"] for n in raw["nodes"]])
    rng = np.random.default_rng(7)
    v = np.cross([0.3, -0.5, 2.0], x - x.mean(axis=0)) + 1.5 * rng.normal(size=x.shape)
    v -= v.mean(axis=0)
    index = {n["name"]: i for i, n in enumerate(raw["nodes"])}
    for node, vi in zip(raw["nodes"], v):
        node["velocity"] = [float(a) for a in vi]
    for s in raw["struts"]:
        a, b = (index[e] for e in s["nodes"])
        s["stiffness"], s["rest_length"] = 1e5, float(np.linalg.norm(x[b] - x[a]))
    for c in raw["cables"]:
        c["mass"] = plate
    return ts.Scene.from_dict(raw)


STRUT_K = 1e5   # N/m: the struts of the ground study (test_massive_ground.py's scenes too)


def resting(plate: float) -> ts.Scene:
    """The built-in ``icosahedron_ground`` (at rest on three nodes, its prestress form-found) with elastic struts
    pre-compressed by their share of that prestress (the free end's balance along the strut), so that the
    form-found state is still at rest, and every cable carrying ``plate`` kg."""
    raw = ts.load_scene("icosahedron_ground").to_dict()
    system = System(ts.Scene.from_dict(raw))
    x = system.scene.positions
    _, length, n = system.geometry(x)
    t = np.zeros(system.n_members)
    cables = slice(system.n_struts, None)
    t[cables] = system.stiffness[cables] * (length[cables] - system.scene.cable_rest_lengths)
    force = system.assemble(t[:, None] * n) + system.gravity_force
    names = [node["name"] for node in raw["nodes"]]
    for i, strut in enumerate(raw["struts"]):
        a, b = (names.index(e) for e in strut["nodes"])
        top = a if x[a, 2] > x[b, 2] else b          # off the ground: its balance is the strut's and cables'
        other = b if top == a else a
        tension = float(force[top] @ (x[top] - x[other])) / length[i]
        strut["stiffness"], strut["rest_length"] = STRUT_K, float(length[i] - tension / STRUT_K)
    for cable in raw["cables"]:
        cable["mass"] = plate
    return ts.Scene.from_dict(raw)


def thrown(plate: float) -> ts.Scene:
    """:func:`resting` lifted 0.2 m and thrown down at 1 m/s, sideways at (1, 0.5) m/s, spinning at 3 rad/s."""
    raw = resting(plate).to_dict()
    x = np.array([node["position"] for node in raw["nodes"]])
    v = np.cross([0.0, 0.0, 3.0], x - x.mean(axis=0)) + np.array([1.0, 0.5, -1.0])
    for node, vi in zip(raw["nodes"], v):
        node["position"][2] += 0.2
        node["velocity"] = [float(a) for a in vi]
    return ts.Scene.from_dict(raw)


def speed_rows(quick: bool, repeats: int = 7) -> list[dict]:
    """CPU time per step of each run, best of ``repeats`` taken in turns (one of each per round), so that a
    change in the machine's load falls on all of them alike; with ``mujoco`` installed, MuJoCo's Euler on the
    same structure beside them (spring tendons: its cables have no mass)."""
    steps = 300 if quick else 1000
    runs = []   # (label, reset, run n steps, rounds)
    for label, method, plate, compiled in (("massive run() (compiled)", "massive", 0.05, True),
                                           ("massive (numpy reference)", "massive", 0.05, False),
                                           ("elastic run() (compiled)", "elastic", 0.0, True),
                                           ("elastic (numpy reference)", "elastic", 0.0, False)):
        sim = ts.Simulator(thrown_icosahedron(plate), method=method, dt=1e-3, locate_switches=True)
        if compiled is False:
            sim._method.compiled = False
        sim.run(steps=20)   # warm: kernels loaded, caches filled
        runs.append((label, sim.reset, lambda n, sim=sim: sim.run(steps=n, every=n), repeats if compiled else 2))
    try:
        from bench.mujoco_peer import MujocoPeer
        peer = MujocoPeer(thrown_icosahedron(0.0), model="elastic", dt=1e-3, integrator="Euler")
        runs.append(("MuJoCo mj_step(nstep) (spring tendons)", peer.reset, peer.advance, repeats))
    except ImportError:   # mujoco is a benchmark extra
        pass
    best = {label: math.inf for label, *_ in runs}
    for k in range(repeats):
        for label, reset, run, rounds in runs:
            if k < rounds:   # the references are slow: two rounds
                reset()
                start = time.process_time()
                run(steps)
                best[label] = min(best[label], time.process_time() - start)
    rows = [{"run": label, "steps": steps, "us_per_step": 1e6 * best[label] / steps} for label, *_ in runs]
    base = next(r["us_per_step"] for r in rows if r["run"].startswith("elastic run()"))
    for r in rows:
        r["over_elastic_run"] = r["us_per_step"] / base
    return rows


def ground_rows(repeats: int = 3) -> list[dict]:
    """CPU time per step of the thrown icosahedron's landing, best of ``repeats`` taken in turns."""
    steps, runs = 250, []
    for label, method, plate, compiled in (("massive (numpy reference: contacts)", "massive", 0.05, True),
                                           ("elastic run() (compiled)", "elastic", 0.0, True),
                                           ("elastic (numpy reference)", "elastic", 0.0, False)):
        sim = ts.Simulator(thrown(plate), method=method, dt=1e-3)
        sim._method.compiled = sim._method.compiled and compiled
        runs.append((label, sim))
    best = {label: math.inf for label, _ in runs}
    for _ in range(repeats):
        for label, sim in runs:
            sim.reset()
            start = time.process_time()
            sim.run(steps=steps, every=steps)
            best[label] = min(best[label], time.process_time() - start)
    rows = [{"run": label, "steps": steps, "us_per_step": 1e6 * best[label] / steps} for label, _ in runs]
    base = next(r["us_per_step"] for r in rows if r["run"].startswith("elastic run()"))
    for r in rows:
        r["over_elastic_run"] = r["us_per_step"] / base
    return rows


def main(argv=None) -> int:
    import argparse
    from pathlib import Path

    from bench.tables import write_csv
    parser = argparse.ArgumentParser(description="The massive method: the drop hard case, order, speed.")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--study", choices=("drop", "order", "speed", "ground"), help="one study only")
    args = parser.parse_args(argv)
    out = Path(__file__).resolve().parent / "results"
    studies = {"drop": drop_rows, "order": lambda: order_rows(args.quick), "speed": lambda: speed_rows(args.quick),
               "ground": ground_rows}
    for name in [args.study] if args.study else studies:
        rows = studies[name]()
        print(f"-- {name}")
        for row in rows:
            print("  " + ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
        fields = list(dict.fromkeys(k for row in rows for k in row))
        write_csv(out / f"massive_{name}.csv", rows, fields)
    return 0


if __name__ == "__main__":
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first
    raise SystemExit(main())
