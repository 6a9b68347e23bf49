"""What a rod's true inertia costs (issue 46): the thrown icosahedron (``bench.cases.icosahedron_thrown``: rigid
struts, snapping cables, no gravity) with each strut's 3.5 kg spread along it (``mass_distribution: uniform``, the
consistent 2x2 block per strut that ``methods/_mass_kernels.py`` applies) beside the same scene with that mass
at its ends (``ends``: the diagonal mass matrix every path took before), elastic method, dt = 1 ms, in one process
taking turns (``bench.timing.time_alternating``): ``run()`` (the compiled loop), ``step()`` one at a time, and a
batch of 1,024 copies. Prints the per-step times and their ratios, writes ``bench/results/mass.csv``. Never asserts
a time. ``--ground``: the same icosahedron dropped from 5 cm onto ground with friction 0.6 under gravity (the
contact blocks with the rods' cross entries, issue 46), ``run()`` and ``step()``; writes
``bench/results/mass_ground.csv``. ``--method inextensible``: the same scenes stepped by the inextensible method
(its QPs in ``BlockMassSolver``'s coordinates; with blocks its Python path, lumped its one-call kernels), the batch
of :data:`INEXTENSIBLE_BATCH` copies; writes ``mass_inextensible.csv`` (``mass_inextensible_ground.csv``).

    python3 bench/bench_mass.py [--repeats 5] [--ground] [--method inextensible]
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import tensegrity_sim as ts  # noqa: E402
from bench.cases import icosahedron_thrown  # noqa: E402
from bench.tables import RESULTS, write_csv  # noqa: E402
from bench.timing import SETTLE, time_alternating  # noqa: E402
from tensegrity_sim.batch import BatchSimulator  # noqa: E402
from tensegrity_sim.methods.inextensible.method import LengthOffsetWarning  # noqa: E402

STRUT_MASS = 3.5   # kg: the built-in icosahedron's struts, which it carries as 1.75 kg on each end node
BATCH = 1024
INEXTENSIBLE_BATCH = 16   # copies: with the rods' blocks the inextensible batch steps copy by copy in Python


def scene(distribution: str, ground: bool = False) -> ts.Scene:
    """The thrown icosahedron with its strut mass on the struts (``distribution``) and 0.05 kg end caps; with
    ``ground``, its lowest node 5 cm above ground with friction 0.6, under gravity."""
    d = icosahedron_thrown(scale=2.0, seed=1).to_dict()
    for node in d["nodes"]:
        node["mass"] = 0.05
    for strut in d["struts"]:
        strut["mass"], strut["mass_distribution"] = STRUT_MASS, distribution
    if ground:
        low = min(node["position"][2] for node in d["nodes"])
        for node in d["nodes"]:
            node["position"][2] += 0.05 - low
        d["gravity"], d["ground"] = [0.0, 0.0, -9.81], {"friction": 0.6, "restitution": 0.0}
    return ts.Scene.from_dict(d)


def contenders(kind: str, distribution: str, ground: bool = False, method: str = "elastic", copies: int = BATCH):
    """``(run(n), reset())`` of one way of stepping the scene."""
    sc = scene(distribution, ground)
    if kind == "batch":
        holder = {}

        def reset():
            holder["sim"] = BatchSimulator(sc, copies, method=method, dt=1e-3)

        return (lambda n: holder["sim"].run(steps=n, every=n)), reset
    holder = {}

    def reset_one():
        holder["sim"] = ts.Simulator(sc, method=method, dt=1e-3)

    if kind == "run":
        return (lambda n: holder["sim"].run(steps=n, every=n)), reset_one

    def steps(n):
        sim = holder["sim"]
        for _ in range(n):
            sim.step()

    return steps, reset_one


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--ground", action="store_true", help="the icosahedron dropped on rough ground")
    parser.add_argument("--method", choices=("elastic", "inextensible"), default="elastic")
    args = parser.parse_args(argv)
    rows = []
    case = "icosahedron_ground" if args.ground else "icosahedron_thrown"
    copies = INEXTENSIBLE_BATCH if args.method == "inextensible" else BATCH
    warnings.simplefilter("ignore", LengthOffsetWarning)   # the inextensible method's prestress offsets, each reset
    for kind in ("run", "step") if args.ground else ("run", "step", "batch"):
        timings = time_alternating({dist: contenders(kind, dist, args.ground, args.method, copies)
                                    for dist in ("ends", "uniform")}, repeats=args.repeats, settle=SETTLE)
        per_copy = copies if kind == "batch" else 1
        lumped, block = timings["ends"].best / per_copy, timings["uniform"].best / per_copy
        rows.append({"case": case, "path": kind, "copies": per_copy,
                     "lumped_us": lumped * 1e6, "consistent_us": block * 1e6, "ratio": block / lumped})
        print(f"{kind:>5}: lumped (ends) {lumped * 1e6:8.3f} us/step, consistent (uniform) {block * 1e6:8.3f} "
              f"us/step{' per copy' if per_copy > 1 else ''}: {block / lumped:.3f}x")
    stem = "mass" if args.method == "elastic" else "mass_inextensible"
    write_csv(RESULTS / (f"{stem}_ground.csv" if args.ground else f"{stem}.csv"), rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
