"""Batched stepping beside MuJoCo's threaded ``rollout`` (issue 12's targets), in one process, taking turns.

    python3 bench/bench_batch.py            # writes bench/results/batch.csv and batch.md, prints both
    python3 bench/bench_batch.py --ground   # the ground case only: bench/results/batch_ground.csv
    python3 bench/bench_batch.py --response # a member contact response: bench/results/batch_response.csv
    python3 bench/bench_batch.py --inextensible  # 256 inextensible, free and resting on the ground, on all
                                                 # cores and on one: bench/results/batch_inextensible.csv

Cases (icosahedron thrown: rigid struts, 613 N/m cables, random node velocities; dt = 1 ms):

* elastic, batch 1024: ``BatchSimulator(method="elastic")`` against MuJoCo's spring tendons (the dead
  band ``springlength="0 L"``, bench/mujoco_peer.py) in ``mujoco.rollout`` with as many threads as cores;
* inextensible, batch 256: ``BatchSimulator(method="inextensible")`` against MuJoCo's limited tendons.

MuJoCo runs its Euler integrator (its cheapest step), sensors off, contacts off, and again with the struts'
capsules colliding with each other (``MujocoPeer(strut_contacts=True)``); we run without contact detection
and with the scene's default strut-strut detection, each against MuJoCo likewise (``ratio_to_mujoco``: to
the MuJoCo row without contacts, or with them for a row with contacts).

* elastic on the ground, batch 1024 (issue 28): ``icosahedron_ground`` rolling (the roll's reel-in of c4,
  c5 and c6 to 60 % held from the start: the robot tips over its base edge and rolls), every copy starting
  afresh in each timed call in both; ours steps the ground in the compiled batch loop on every core, no
  strut-strut detection (the peer's struts touch the plane only); MuJoCo with its plane contacts
  (elliptic cones, impratio 100) and implicitfast (its Euler goes unstable in the roll), as many threads
  as cores. Each contender does ``STEPS`` steps of the
whole batch per timed call; the rate is the best of ``REPEATS`` turns (``SHORT_REPEATS`` for the inextensible
rows' 20-step calls; a shared machine only ever adds time),
scene-steps per second = batch x steps / wall time.

Like for like (issue 47): MuJoCo's rollout writes every step's state (time, qpos, qvel, ...: float64, into an
array allocated once), and so every row of ours keeps every step's state, positions and velocities in float64
(``run(steps, every=1, fields=("positions", "velocities"))``, into arrays the run allocates), unless its
``keeps`` column says otherwise: the elastic case adds rows keeping the state in float32, every field (also
impulses, tensions, slack) and only the last step (``every=steps``: not like for like, rollout cannot keep less).

* ``--response`` (issue 28): ``icosahedron_ground`` rolled as above with a strut-strut contact response
  (``contact: response: true``), 64 copies, against what such a batch did before it stepped in the compiled
  loop, a ``Simulator`` per copy (no peer: MuJoCo has no unilateral member response of this kind); the final
  positions of both must agree, and ``member_steps`` counts the steps either took by the numpy reference.
"""
from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.cases import icosahedron_thrown  # noqa: E402
from bench.mujoco_peer import MujocoPeer  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from bench.timing import time_runs  # noqa: E402
from tensegrity_sim import load_scene  # noqa: E402
from tensegrity_sim.batch import TRAJECTORY_FIELDS, BatchSimulator  # noqa: E402
from tensegrity_sim.methods._copy_blocks import copy_blocks  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
REPEATS = 5
# the inextensible rows' turns: their calls are short (20 steps of 256 copies, ~50 ms), and on the project's 2-core
# machine the best of 5 moved by 0.95-1.22x from run to run; of 15, by 1.04-1.08x (three runs, the free copies)
SHORT_REPEATS = 15
CASES = [  # (cable model, batch, steps per timed call)
    ("elastic", 1024, 100),
    ("inextensible", 256, 20),
]


def _mujoco(scene, model: str, batch: int, steps: int, threads: int, integrator: str = "Euler", rest=None,
            strut_contacts: bool = False):
    """A callable doing ``steps`` steps of ``batch`` copies in ``mujoco.rollout`` with ``threads`` threads;
    ``rest``: the cables' rest lengths (n_cables,) m if not the scene's; ``strut_contacts``: the struts'
    capsules collide (see ``MujocoPeer``)."""
    import mujoco
    from mujoco import rollout

    peer = MujocoPeer(scene, model=model, dt=1e-3, integrator=integrator, strut_contacts=strut_contacts)
    m = peer.model
    if rest is not None:
        m.tendon_lengthspring[peer._tendons, 1] = rest
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, peer.data, state0, spec)
    initial = np.tile(state0, (batch, 1))
    datas = [mujoco.MjData(m) for _ in range(threads)]
    out = np.empty((batch, steps, state0.size))
    pool = rollout.Rollout(nthread=threads)
    return lambda: pool.rollout(m, datas, initial, nstep=steps, state=out), pool


# what a run keeps: (every, dtype, fields) by name; rollout writes every step's state (time, qpos, qvel, ...)
# in float64, and "state" is its like: every step's positions and velocities in float64
KEEPS = {"state": (1, "float64", ("positions", "velocities")),
         "state float32": (1, "float32", ("positions", "velocities")),
         "every field": (1, "float64", TRAJECTORY_FIELDS),
         "last step only": (None, "float64", TRAJECTORY_FIELDS)}


def _ours(scene, method: str, batch: int, steps: int, contacts, keeps: str = "state"):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the inextensible method's prestress warning
        sim = BatchSimulator(scene, batch, method=method, dt=1e-3, contacts=contacts)
    every, dtype, fields = KEEPS[keeps]
    return lambda: sim.run(steps=steps, every=every or steps, dtype=dtype, fields=fields)


def _rolled(scene):
    """The roll's held command: c4, c5, c6 at 60 % of their rest lengths (examples/roll.yaml at 0.3 s)."""
    rest = scene.cable_rest_lengths.copy()
    for name in ("c4", "c5", "c6"):
        rest[scene.cable_names.index(name)] *= 0.6
    return rest


def measure_ground(batch: int = 1024, steps: int = 500) -> list[dict]:
    """Issue 28's batch target: the rolling icosahedron on the ground, ours against mujoco.rollout."""
    scene = load_scene("icosahedron_ground")
    threads = os.cpu_count() or 1
    mujoco_run, pool = _mujoco(scene, "elastic", batch, steps, threads, "implicitfast", _rolled(scene))
    fresh = {}

    def setup():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fresh["sim"] = BatchSimulator(scene, batch, method="elastic", dt=1e-3, contacts=())
        fresh["sim"].set_rest_lengths(_rolled(scene))

    every, dtype, fields = KEEPS["state"]
    contenders = {"mujoco rollout": (mujoco_run, None),
                  "BatchSimulator": (lambda: fresh["sim"].run(steps=steps, every=every, dtype=dtype, fields=fields),
                                     setup)}
    best = {name: float("inf") for name in contenders}
    for name, (run, prepare) in contenders.items():   # warm-up: compile, allocate
        if prepare:
            prepare()
        run()
    for _ in range(REPEATS):
        for name, (run, prepare) in contenders.items():
            best[name] = min(best[name], time_runs(run, setup=prepare, warmup=lambda: None, repeats=1).best)
    pool.close()
    mass = scene.masses
    start = mass @ scene.positions / mass.sum()
    moved = float(np.linalg.norm((mass @ fresh["sim"].positions[0] / mass.sum() - start)[:2]))
    ref = batch * steps / best["mujoco rollout"]
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    return [{"case": "icosahedron_ground rolling elastic", "batch": batch, "steps": steps, "contender": name,
             "threads": threads, "keeps": "every step's state", "scene_steps_per_s": round(batch * steps / t),
             "ratio_to_mujoco": round(batch * steps / t / ref, 3),
             "note": f"ours rolled {moved:.3f} m in {steps} ms; load {load}"} for name, t in best.items()]


def measure_inextensible(batch: int = 256, steps: int = 20, free: bool = True, one_thread: bool = False) -> list[dict]:
    """Issue 47's batch targets: ``batch`` inextensible icosahedra thrown (free; left out with ``free=False``,
    as the whole run measures that case with its others) and resting on the ground (``icosahedron_ground``),
    each against ``mujoco.rollout`` of MuJoCo's limited tendons (Euler; on the ground its plane contacts), as
    many threads as cores, no strut-strut detection on either side, taking turns; ours steps the copies'
    compiled loops over the cores (``InextensibleMethod.advance_copies``). ``one_thread``: both also on one
    thread (numba's threads set to 1 for ours), each ratio to rollout on as many threads: how each uses the
    second core (``--inextensible``)."""
    threads = os.cpu_count() or 1
    rows = []
    cases = [("icosahedron_thrown inextensible", icosahedron_thrown())] if free else []
    for case, scene in cases + [("icosahedron_ground resting inextensible", load_scene("icosahedron_ground"))]:
        mujoco_run, pool = _mujoco(scene, "inextensible", batch, steps, threads)
        contenders = {"mujoco rollout": mujoco_run, "BatchSimulator": _ours(scene, "inextensible", batch, steps, ())}
        pools = [pool]
        if one_thread:
            single_run, single_pool = _mujoco(scene, "inextensible", batch, steps, 1)
            pools.append(single_pool)
            contenders["mujoco rollout, 1 thread"] = single_run
            contenders["BatchSimulator, 1 thread"] = _one_thread(_ours(scene, "inextensible", batch, steps, ()))
        best = {name: float("inf") for name in contenders}
        for run in contenders.values():   # warm-up: compile, allocate
            run()
        for _ in range(SHORT_REPEATS):
            for name, run in contenders.items():
                best[name] = min(best[name], time_runs(run, warmup=lambda: None, repeats=1).best)
        for p in pools:
            p.close()
        load = " ".join(f"{x:.2f}" for x in os.getloadavg())
        for name, t in best.items():
            single = name.endswith(", 1 thread")   # against rollout on as many threads
            rows.append({"case": case, "batch": batch, "steps": steps, "contender": name,
                         "threads": 1 if single else threads, "keeps": "every step's state",
                         "scene_steps_per_s": round(batch * steps / t),
                         "ratio_to_mujoco": round(best["mujoco rollout" + (", 1 thread" if single else "")] / t, 3),
                         "note": f"load {load}"})
    return rows


def _one_thread(run):
    """``run`` with numba's threads set to one, and back after."""
    def single():
        before = numba.get_num_threads()
        numba.set_num_threads(1)
        try:
            return run()
        finally:
            numba.set_num_threads(before)
    return single


def measure_response(batch: int = 64, steps: int = 1000) -> list[dict]:
    """The compiled batch against a ``Simulator`` per copy on a scene with a member contact response."""
    from tensegrity_sim import Scene, Simulator

    mapping = load_scene("icosahedron_ground").to_dict()
    mapping["contact"] = dict(mapping.get("contact") or {}, response=True, kinds=["strut_strut"])
    scene = Scene.from_dict(mapping)
    rest = _rolled(scene)
    made = {}

    def setup_batch():
        made["batch"] = BatchSimulator(scene, batch, method="elastic", dt=1e-3)
        made["batch"].set_rest_lengths(rest)

    def setup_copies():
        made["copies"] = [Simulator(scene, method="elastic", dt=1e-3) for _ in range(batch)]
        for sim in made["copies"]:
            sim.set_rest_lengths(rest)

    contenders = {"BatchSimulator": (lambda: made["batch"].run(steps=steps, every=steps), setup_batch),
                  "a Simulator per copy": (lambda: [c.run(steps=steps, every=steps) for c in made["copies"]],
                                           setup_copies)}
    best = {name: float("inf") for name in contenders}
    for run, prepare in contenders.values():   # warm-up: compile, allocate
        prepare()
        run()
    for _ in range(REPEATS):
        for name, (run, prepare) in contenders.items():
            best[name] = min(best[name], time_runs(run, setup=prepare, warmup=lambda: None, repeats=1).best)
    apart = max(float(np.abs(made["batch"].positions[b] - c.positions).max()) for b, c in enumerate(made["copies"]))
    member_steps = sum(c._method.member_steps for c in made["copies"])
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    return [{"case": "icosahedron_ground rolling elastic, strut-strut response", "batch": batch, "steps": steps,
             "contender": name, "scene_steps_per_s": round(batch * steps / t),
             "ratio_to_copies": round(best["a Simulator per copy"] / t, 3),
             "note": f"final positions {apart:.1e} m apart; member steps {member_steps}; load {load}"}
            for name, t in best.items()]


def measure() -> list[dict]:
    scene = icosahedron_thrown()
    threads = os.cpu_count() or 1
    rows = []
    for model, batch, steps in CASES:
        mujoco_run, pool = _mujoco(scene, model, batch, steps, threads)
        mujoco_contacts, contacts_pool = _mujoco(scene, model, batch, steps, threads, strut_contacts=True)
        contenders = {"mujoco rollout": mujoco_run,
                      "mujoco rollout + strut capsule contacts": mujoco_contacts,
                      "BatchSimulator": _ours(scene, model, batch, steps, ()),
                      "BatchSimulator + contacts": _ours(scene, model, batch, steps, None)}
        if model == "elastic":   # the trajectory's storage: lighter, heavier, none
            contenders.update({f"BatchSimulator, {keeps}": _ours(scene, model, batch, steps, (), keeps)
                               for keeps in KEEPS if keeps != "state"})
        best = {name: float("inf") for name in contenders}
        for name, run in contenders.items():   # warm-up: compile, allocate
            run()
        # turns: the machine's load falls on every contender alike
        for _ in range(REPEATS if model == "elastic" else SHORT_REPEATS):
            for name, run in contenders.items():
                best[name] = min(best[name], time_runs(run, warmup=lambda: None, repeats=1).best)
        pool.close()
        contacts_pool.close()
        for name, t in best.items():
            # like for like: detection on against MuJoCo's contacts on, off against off
            peer = "mujoco rollout + strut capsule contacts" if "contacts" in name else "mujoco rollout"
            rate = batch * steps / t
            keeps = name.partition(", ")[2] or "state"
            rows.append({"case": f"icosahedron_thrown {model}", "batch": batch, "steps": steps,
                         "contender": name, "threads": threads if name.startswith("mujoco") else
                         # the elastic batch: blocks on threads; the inextensible copies: numba's threads
                         len(copy_blocks(batch)) if model == "elastic" else numba.get_num_threads(),
                         "keeps": "every step's state" if keeps == "state" else keeps,
                         "scene_steps_per_s": round(rate),
                         "ratio_to_mujoco": round(best[peer] / t, 3), "load": os.getloadavg()[0],
                         "note": "not like for like: rollout keeps every step" if keeps == "last step only" else ""})
    return rows + measure_ground() + measure_inextensible(free=False)


def write(rows: list[dict]) -> str:
    RESULTS.mkdir(exist_ok=True)
    write_csv(RESULTS / "batch.csv", rows)
    lines = ["## Batches (issues 12, 28)\n",
             "`python3 bench/bench_batch.py`: scene-steps per second of a whole batch (dt = 1 ms, best of "
             f"{REPEATS} turns in one process, {SHORT_REPEATS} for the inextensible rows' short calls), against "
             "`mujoco.rollout` with as many threads as cores (Euler, sensors off; limited tendons for the "
             "inextensible case), the rows with contacts against MuJoCo with the struts' capsules colliding, the "
             "others against MuJoCo with contacts off; the ground rows against MuJoCo's plane contacts "
             "(implicitfast). Like for like, every row keeps every step's state as rollout does (positions and "
             "velocities, float64), but those whose \"keeps\" says otherwise: float32 state, every field (also "
             "impulses, tensions, slack), or only the last step (not like for like). "
             f"Load average {os.getloadavg()[0]:.2f} at the end.\n",
             "| case | batch | contender | threads | keeps | scene-steps/s | ratio to MuJoCo | note |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    lines += [f"| {r['case']} | {r['batch']} | {r['contender']} | {r['threads']} | {r['keeps']} | "
              f"{r['scene_steps_per_s']:,} | "
              f"{r['ratio_to_mujoco']:.2f} | {r['note']} |" for r in rows]
    text = "\n".join(lines) + "\n"
    (RESULTS / "batch.md").write_text(text)
    return text


if __name__ == "__main__":
    # a single case: its own CSV; an unknown flag is refused (it used to run the whole bench)
    single = {"--ground": (measure_ground, "batch_ground.csv"), "--response": (measure_response, "batch_response.csv"),
              "--inextensible": (lambda: measure_inextensible(one_thread=True), "batch_inextensible.csv")}
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    group = parser.add_mutually_exclusive_group()
    for flag, (_, name) in single.items():
        group.add_argument(flag, action="store_true", help=f"that case only: bench/results/{name}")
    args = parser.parse_args()
    chosen = [single[flag] for flag in single if getattr(args, flag[2:])]
    if chosen:
        case, name = chosen[0]
        rows = case()
        RESULTS.mkdir(exist_ok=True)
        write_csv(RESULTS / name, rows)
        for row in rows:
            print(row)
    else:
        print(write(measure()))
