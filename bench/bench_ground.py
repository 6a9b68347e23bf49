"""Steps per second with ground contact (issues 11 and 28): the icosahedron resting on its face and rolling
(``examples/roll.yaml``) beside MuJoCo with its ground contact (bench/mujoco_peer.py: a plane, capsule
struts, elliptic cones, impratio 100, no strut-strut contacts), in one process taking turns (the machine
is shared: read the ratios, not the rates); the real-time factor of ``tensegrity-sim run
icosahedron_ground --commands examples/roll.yaml --duration 10 --method elastic``; and the closed forms of
``test/test_ground.py`` measured on each method's compiled path and on its reference, exactness beside speed.
Never asserts a time.

Contenders, like for like (our strut-strut detection off: the peer has none; on, for information), each
of our methods beside MuJoCo with the same cable model (the elastic method beside its spring tendons, the
inextensible one beside its limited tendons), each MuJoCo model with Euler and implicitfast; a MuJoCo run
is *stable* when MuJoCo raised no bad-acceleration warning and the centre of mass stayed within 0.5 m of
its start in height, and a ratio is taken to the faster stable integrator (``mujoco_integrator``):

* resting, 2 s: ours through ``Simulator.run`` (the compiled loop) and through ``Simulator.step`` one step
  at a time (steps computed ahead); the inextensible method also with each step through its Python path
  (``Python path``: ``one_kernel = False``, the friction modes still compiled: what the step kernel
  gained) and with its friction modes solved by their numpy reference (``numpy modes``: what compiling
  them gained); MuJoCo ``mj_step(nstep)`` in C;
* rolling, 2 s under the roll's commands: ours through ``Simulator.run(commands=...)`` (the schedule
  evaluated inside the compiled ground loop), as ``tensegrity-sim run --commands`` (the same, in chunks of
  1,000 steps, with its summary) and by ``set_rest_lengths`` + ``step`` before each step (a length that did not
  change keeps the steps computed ahead, a new one is checked and its step taken alone); MuJoCo's commanded
  tendon length (a spring tendon's length, a limited tendon's limit at its offset above the rest length) +
  ``mj_step`` from Python, and (the peer of our runs)
  each stretch of unchanged commands in one ``mj_step(nstep)``. The inextensible method's ``run(commands=...)``
  evaluates the schedule in its compiled loop too (issue 47). The step-by-step loops of both take each
  step's lengths from an array evaluated before the timing starts: the schedule's Python (~25 us a step, the
  same for both) is not what they compare. The
  inextensible icosahedron with rigid struts locks a few mm into the reel: its motors stall at their
  ``reel_force`` (2 kN; before issue 47 they pulled without limit and launched it 3.6 m up) and it stays on the
  ground, its degenerate QPs mostly on the Python path; its rate is reported with how high its centre rose.

Member contacts (``--members``, issue 28): rigid strut B dropped across rigid strut A lying on the ground,
an elastic cable between them reeled in half-way (``crossed_struts``: B lands on A, rests across it and on the
ground, then slides over A), ``contact: response: true`` with the ground's friction: ours through
``Simulator.run`` (the touching pair's coupled block in the compiled loop), through ``Simulator.step`` and by
its numpy reference (each step the QP fixed point of ``friction.py``: what every step with the pair armed
cost before the coupled blocks were compiled), beside MuJoCo with the struts' capsules colliding with each
other and with the plane (``strut_contacts``, the same friction), each integrator, taking turns.

Run: ``python bench/bench_ground.py [--duration S] [--repeats N]``; writes bench/results/ground.csv and
ground_exactness.csv; ``--members`` writes ground_members.csv alone.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import tensegrity_sim as ts  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.commands import load_commands  # noqa: E402
from tensegrity_sim.methods.inextensible.method import LengthOffsetWarning  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ROLL = ROOT / "examples" / "roll.yaml"
RESULTS = Path(__file__).resolve().parent / "results"
G, MU = 9.81, 0.5


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _simulator(scene, method, contacts=(), compiled=True):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LengthOffsetWarning)
        sim = ts.Simulator(scene, method=method, dt=1e-3, contacts=contacts)
    if not compiled:
        sim._method.compiled = False
    return sim


def _ours(scene, method, steps, schedule, how, contacts=(), reference_modes=False, one_kernel=True):
    """Steps per second and the final positions: ``how`` "run" (one Simulator.run) or "step";
    ``reference_modes``: the inextensible method's friction modes by their numpy reference
    (``FrictionalSolver._modes``) instead of the compiled kernel, everything else the same (each step through
    the method's Python path); ``one_kernel = False``: each inextensible step through that Python path, its
    friction modes compiled (what the step kernel gained)."""
    sim = _simulator(scene, method, contacts)
    sim._method.one_kernel = one_kernel
    if reference_modes:
        sim._method.solver._modes_compiled = lambda v0, rows, warm: None
    sim.run(steps=2)   # the kernels loaded, the first contact solved
    if how == "step" and schedule is not None:   # each step's lengths, evaluated before the timing
        base = sim.rest_lengths
        commanded = [schedule.rest_lengths_at(sim.time + k * sim.dt, base) for k in range(steps)]
    start = time.perf_counter()
    if how == "run":
        sim.run(steps=steps, commands=schedule)
    else:
        if schedule is None:
            for k in range(steps):
                sim.step()
        else:
            for rest in commanded:
                sim.set_rest_lengths(rest)
                sim.step()
    return steps / (time.perf_counter() - start), sim.positions


def _mujoco(scene, steps, schedule, integrator, model="elastic"):
    """MuJoCo's rate, final positions and whether it flagged itself unstable (``model``: its cable model,
    "elastic" or "inextensible")."""
    from bench.mujoco_peer import MujocoPeer
    peer = MujocoPeer(scene, model=model, dt=1e-3, integrator=integrator)
    mj_model, data, tendons = peer.model, peer.data, peer._tendons
    base = scene.cable_rest_lengths
    # the commanded rest length moves a spring tendon's length, or a limited tendon's limit (kept at its
    # offset above the rest length: the prestressed cables start longer than their rest lengths)
    law = mj_model.tendon_lengthspring[:, 1] if model == "elastic" else mj_model.tendon_range[:, 1]
    offset = law[tendons] - base
    if schedule is not None:   # each step's lengths, evaluated before the timing
        commanded = [schedule.rest_lengths_at(k * 1e-3, base) + offset for k in range(steps)]
    start = time.perf_counter()
    if schedule is None:
        peer.advance(steps)
    else:
        for length in commanded:
            law[tendons] = length
            peer._mj.mj_step(mj_model, data)
    return steps / (time.perf_counter() - start), peer.positions(), peer.unstable


def _ours_commanded(scene, steps, schedule):
    """Steps per second and the final positions of the elastic roll as ``tensegrity-sim run --commands`` steps
    it (``cli.simulate``: ``Simulator.run(commands=...)`` in chunks, with the run's summary)."""
    from tensegrity_sim.cli import simulate

    sim = _simulator(scene, "elastic")
    sim.run(steps=2)   # the kernels loaded, the first contact solved
    start = time.perf_counter()
    simulate(sim, steps, schedule)
    return steps / (time.perf_counter() - start), sim.positions


def _mujoco_commanded(scene, steps, schedule, integrator):
    """MuJoCo's counterpart of :func:`_ours_commanded` (spring tendons): each stretch of steps whose commanded
    rest lengths do not change in one ``mj_step(nstep)``, the lengths evaluated per step as ours are."""
    from bench.mujoco_peer import MujocoPeer
    peer = MujocoPeer(scene, model="elastic", dt=1e-3, integrator=integrator)
    law, tendons, base = peer.model.tendon_lengthspring[:, 1], peer._tendons, scene.cable_rest_lengths
    offset = law[tendons] - base
    start = time.perf_counter()
    rests = [schedule.rest_lengths_at(k * 1e-3, base) for k in range(steps)]
    k = 0
    while k < steps:
        j = k + 1
        while j < steps and np.array_equal(rests[j], rests[k]):
            j += 1
        law[tendons] = rests[k] + offset
        peer.advance(j - k)
        k = j
    return steps / (time.perf_counter() - start), peer.positions(), peer.unstable


def speed(duration: float, repeats: int) -> list[dict]:
    scene = ts.load_scene("icosahedron_ground")
    schedule = load_commands(ROLL, scene)
    steps = int(round(duration / 1e-3))
    mass = scene.masses
    start = mass @ scene.positions / mass.sum()
    peers = [(f"mujoco {model} {integrator}", model, integrator)
             for model in ("elastic", "inextensible") for integrator in ("Euler", "implicitfast")]
    ours = {
        "resting": [("elastic run", "elastic", lambda: _ours(scene, "elastic", steps, None, "run")),
                    ("elastic step", "elastic", lambda: _ours(scene, "elastic", steps, None, "step")),
                    ("elastic run, detection on", "elastic",
                     lambda: _ours(scene, "elastic", steps, None, "run", None)),
                    ("inextensible run", "inextensible", lambda: _ours(scene, "inextensible", steps, None, "run")),
                    ("inextensible step", "inextensible", lambda: _ours(scene, "inextensible", steps, None, "step")),
                    ("inextensible step, Python path", "inextensible",
                     lambda: _ours(scene, "inextensible", min(steps, 500), None, "step", one_kernel=False)),
                    ("inextensible step, numpy modes", "inextensible",
                     lambda: _ours(scene, "inextensible", min(steps, 500), None, "step", reference_modes=True))],
        "rolling": [("elastic run", "elastic", lambda: _ours(scene, "elastic", steps, schedule, "run")),
                    ("elastic step", "elastic", lambda: _ours(scene, "elastic", steps, schedule, "step")),
                    ("elastic, as run --commands", "elastic", lambda: _ours_commanded(scene, steps, schedule)),
                    ("elastic step, detection on", "elastic",
                     lambda: _ours(scene, "elastic", steps, schedule, "step", None)),
                    ("inextensible run", "inextensible", lambda: _ours(scene, "inextensible", steps, schedule, "run")),
                    ("inextensible step", "inextensible",
                     lambda: _ours(scene, "inextensible", min(steps, 500), schedule, "step"))],
    }
    rows = []
    for case, contenders in ours.items():
        sched = schedule if case == "rolling" else None
        contenders = contenders + [(name, model, lambda m=model, i=integrator: _mujoco(scene, steps, sched, i, m))
                                   for name, model, integrator in peers]
        if case == "rolling":   # the peer of "elastic, as run --commands", ranked apart from the others
            contenders += [(f"mujoco elastic {integrator}, commands in stretches", "elastic",
                            lambda i=integrator: _mujoco_commanded(scene, steps, schedule, i))
                           for integrator in ("Euler", "implicitfast")]
        best, finals, unstable = {}, {}, {}
        for name, _, go in contenders:   # warm-up: compile, caches
            go()
        for _ in range(repeats):
            for name, _, go in contenders:
                out = go()
                best[name] = max(best.get(name, 0.0), out[0])
                finals[name] = out[1]
                unstable[name] = unstable.get(name, False) or (bool(out[2]) if len(out) > 2 else False)
        centre = {name: mass @ x / mass.sum() - start for name, x in finals.items()}
        stable = {name: not unstable[name] and bool(np.isfinite(finals[name]).all()) and abs(centre[name][2]) < 0.5
                  for name in best}
        for name, model, _ in contenders:
            row = {"case": case, "contender": name, "cables": model, "steps_per_s": round(best[name]),
                   "ratio_to_mujoco": float("nan"), "mujoco_integrator": "-",
                   "com_moved_m": float(np.linalg.norm(centre[name][:2])), "com_rose_m": float(centre[name][2]),
                   "stable": stable[name], "load": _load()}
            stretches = case == "rolling" and name in ("elastic, as run --commands", "elastic run")
            stable_peers = [] if name.startswith("mujoco") else [
                f"{p}, commands in stretches" if stretches else p for p, m, _ in peers
                if m == model and stable[f"{p}, commands in stretches" if stretches else p]]
            if stable_peers:
                peer = max(stable_peers, key=best.get)
                row["ratio_to_mujoco"], row["mujoco_integrator"] = best[name] / best[peer], peer.split()[2].rstrip(",")
            rows.append(row)
    return rows


def realtime() -> dict:
    """The real-time factor of the roll through the command line (a fresh process: kernels from the cache)."""
    cmd = [sys.executable, "-m", "tensegrity_sim.cli", "run", "icosahedron_ground", "--commands", str(ROLL),
           "--duration", "10", "--method", "elastic"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, check=True).stdout
    factor = float(re.search(r"real-time factor ([0-9.]+)", out).group(1))
    return {"case": "run icosahedron_ground --commands examples/roll.yaml --duration 10 --method elastic",
            "contender": "command line", "real_time_factor": factor, "load": _load()}


def exactness() -> list[dict]:
    """test_ground.py's closed forms, each method on its compiled path (the elastic blocks; the inextensible
    step kernel and its compiled loop) and its reference: the measured error beside the tolerance the test
    holds it to."""
    def strut(v0=0.0, theta=0.0):
        return ts.Scene.from_dict({
            "gravity": [G * np.sin(theta), 0.0, -G * np.cos(theta)], "ground": {"friction": MU},
            "nodes": [{"name": "a", "position": [0, 0, 0.01], "mass": 1.0, "velocity": [v0, 0, 0]},
                      {"name": "b", "position": [1, 0, 0.01], "mass": 1.0, "velocity": [v0, 0, 0]}],
            "struts": [{"name": "s", "nodes": ["a", "b"], "stiffness": "rigid", "radius": 0.01}]})

    rows = []
    for method, path, compiled in [(m, p, c) for m in ("elastic", "inextensible")
                                   for p, c in (("compiled", True), ("reference", False))]:
        tr = _simulator(strut(2.0), method, compiled=compiled).run(duration=0.6)
        d_stop = 2.0 ** 2 / (2 * MU * G)
        rows.append({"closed form": "sliding strut stops at v0^2/(2 mu g)", "method": method, "path": path,
                     "relative error": abs(tr.positions[-1, 0, 0] - d_stop) / d_stop, "tolerance": 0.01})
        tr = _simulator(strut(theta=np.arctan(0.9 * MU)), method, compiled=compiled).run(duration=1.0)
        rows.append({"closed form": "no creep below the friction angle (m in 1 s)", "method": method, "path": path,
                     "relative error": float(np.abs(tr.positions - tr.positions[0]).max()), "tolerance": 1e-6})
        theta = np.arctan(1.2 * MU)
        tr = _simulator(strut(theta=theta), method, compiled=compiled).run(duration=0.5)
        accel = (tr.velocities[-1, 0, 0] - tr.velocities[99, 0, 0]) / (tr.time[-1] - tr.time[99])
        expected = G * (np.sin(theta) - MU * np.cos(theta))
        rows.append({"closed form": "sliding down a slope at g (sin - mu cos)", "method": method, "path": path,
                     "relative error": abs(accel - expected) / expected, "tolerance": 0.01})
        ball = ts.Scene.from_dict({"gravity": [0, 0, -G], "ground": {"friction": 0.5, "restitution": 0.5},
                                   "nodes": [{"name": "p", "position": [0, 0, 1.0], "mass": 1.0}]})
        tr = _simulator(ball, method, compiled=compiled).run(duration=1.0)
        after = tr.time > np.sqrt(2.0 / G) + 2e-3
        rows.append({"closed form": "bounce to e^2 h (m, e = 0.5, h = 1 m)", "method": method, "path": path,
                     "relative error": abs(tr.positions[after, 0, 2].max() - 0.25), "tolerance": 1e-3})
        sim = _simulator(ts.load_scene("icosahedron_ground"), method, compiled=compiled)
        x0 = sim.positions
        tr = sim.run(duration=0.3)
        rows.append({"closed form": "icosahedron at rest: drift (m in 0.3 s)", "method": method, "path": path,
                     "relative error": float(np.abs(tr.positions - x0).max()), "tolerance": 1e-12})
    return rows


def crossed_struts(mu: float = 0.5) -> ts.Scene:
    """Rigid strut A (1 m along x, 1 kg ends, radius 1 cm) lying on the ground; rigid strut B (1 m along y)
    0.3 m above it, crossing it at x = 0.2 and thrown down onto it, tumbling; an elastic cable (200 N/m,
    rest length 1.2 m: slack at first) from A's end a1 to B's end b1; ground and member friction ``mu``."""
    r = 0.01
    return ts.Scene.from_dict({
        "gravity": [0, 0, -G], "ground": {"height": 0.0, "friction": mu, "restitution": 0.0},
        "contact": {"kinds": ["strut_strut"], "response": True, "friction": mu, "restitution": 0.0},
        "nodes": [{"name": "a0", "position": [-0.5, 0, r], "mass": 1.0},
                  {"name": "a1", "position": [0.5, 0, r], "mass": 1.0},
                  {"name": "b0", "position": [0.2, -0.5, 0.3], "mass": 1.0, "velocity": [0.3, 0, -0.5]},
                  {"name": "b1", "position": [0.2, 0.5, 0.3], "mass": 1.0, "velocity": [0.3, 0.2, -0.8]}],
        "struts": [{"name": "A", "nodes": ["a0", "a1"], "stiffness": "rigid", "radius": r},
                   {"name": "B", "nodes": ["b0", "b1"], "stiffness": "rigid", "radius": r}],
        "cables": [{"name": "c", "nodes": ["a1", "b1"], "rest_length": 1.2, "stiffness": 200.0, "radius": 0.0}]})


def members(duration: float, repeats: int) -> list[dict]:
    """Steps per second of :func:`crossed_struts` (module docstring): ours compiled (run, step), by the
    numpy reference, and MuJoCo with capsule contacts, in turns; each run's cable reeled in to 0.4 m
    half-way; the struts' gap at the end (B resting on A: about 0)."""
    from bench.mujoco_peer import MujocoPeer
    from tensegrity_sim.methods.contact.detection import contact_geometry

    scene = crossed_struts()
    steps = int(round(duration / 1e-3))
    half = steps // 2
    left = {}   # the compiled runs' steps left to the reference: (member pairs, unsolved blocks)

    def ours(how, compiled=True):
        sim = _simulator(scene, "elastic", None, compiled)   # the scene's detection: its response needs it
        sim.run(steps=2)   # the kernels loaded
        start = time.perf_counter()
        for part in (half - 2, steps - half):
            if how == "run":
                sim.run(steps=part)
            else:
                for _ in range(part):
                    sim.step()
            sim.set_rest_lengths([0.4])
        rate = steps / (time.perf_counter() - start)
        method = sim._method
        left[how, compiled] = (method.member_steps, method.fallbacks)
        return rate, sim.positions

    def mujoco(integrator):
        peer = MujocoPeer(scene, model="elastic", dt=1e-3, integrator=integrator, strut_contacts=True)
        law, tendons = peer.model.tendon_lengthspring[:, 1], peer._tendons
        offset = law[tendons] - scene.cable_rest_lengths
        start = time.perf_counter()
        peer.advance(half)
        law[tendons] = 0.4 + offset
        peer.advance(steps - half)
        return steps / (time.perf_counter() - start), peer.positions(), peer.unstable

    contenders = {"elastic run": lambda: ours("run"), "elastic step": lambda: ours("step"),
                  "elastic run, numpy reference": lambda: ours("run", compiled=False),
                  "mujoco elastic Euler": lambda: mujoco("Euler"),
                  "mujoco elastic implicitfast": lambda: mujoco("implicitfast")}
    best, finals, unstable = {}, {}, {}
    for go in contenders.values():   # warm-up: compile, caches
        go()
    for _ in range(repeats):
        for name, go in contenders.items():
            out = go()
            best[name] = max(best.get(name, 0.0), out[0])
            finals[name] = out[1]
            unstable[name] = unstable.get(name, False) or (bool(out[2]) if len(out) > 2 else False)
    # B above A where they cross (it rests on A, never passes through), and both on the ground
    stable = {name: not unstable[name] and bool(np.isfinite(finals[name]).all())
              and float(finals[name][:, 2].min()) > -1e-3 for name in best}
    peers = [name for name in best if name.startswith("mujoco") and stable[name]]
    peer = max(peers, key=best.get) if peers else None
    rows = []
    for name, rate in best.items():
        rows.append({"case": "strut B across strut A on the ground, response on", "contender": name,
                     "steps_per_s": round(rate),
                     "ratio_to_mujoco": float("nan") if peer is None or name.startswith("mujoco") else rate / best[peer],
                     "mujoco_integrator": "-" if peer is None else peer.split()[2],
                     "final_gap_m": float(contact_geometry(finals[name][None], np.array([0.02]))[3][0]),
                     "lowest_node_z_m": float(finals[name][:, 2].min()), "stable": stable[name], "load": _load()})
    print(f"steps the compiled runs left to the reference (member pairs, unsolved blocks): run {left['run', True]}, "
          f"step {left['step', True]}")
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=2.0, help="simulated s per timed run")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--members", action="store_true", help="the member-contact case alone (ground_members.csv)")
    args = parser.parse_args(argv)
    RESULTS.mkdir(exist_ok=True)
    if args.members:
        rows = members(args.duration, args.repeats)
        write_csv(RESULTS / "ground_members.csv", rows)
        for r in rows:
            print(", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items()))
        return 0
    rows = speed(args.duration, args.repeats)
    rows.append(realtime())
    fields = ["case", "contender", "cables", "steps_per_s", "ratio_to_mujoco", "mujoco_integrator", "real_time_factor",
              "com_moved_m", "com_rose_m", "stable", "load"]
    write_csv(RESULTS / "ground.csv", rows, fields)
    for r in rows:
        print(", ".join(f"{k} {r[k]:.4g}" if isinstance(r[k], float) else f"{k} {r[k]}" for k in fields if k in r))
    exact = exactness()
    write_csv(RESULTS / "ground_exactness.csv", exact)
    for r in exact:
        print(f"{r['closed form']:48s} {r['method']:12s} {r['path']:9s} error {r['relative error']:.3g} "
              f"(tolerance {r['tolerance']:g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
