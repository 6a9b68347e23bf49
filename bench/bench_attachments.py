"""What cables attached along a rod cost (issue 46): the thrown icosahedron (``bench.cases.icosahedron_thrown``:
rigid struts, snapping cables, no gravity) as built in (every cable between two nodes) beside the same scene with
eight of its 24 cables moved from a strut's end node to a point along that strut (four by both ends: the kernels'
separate loop over such cables, ``_kernels._attached_force``), elastic method, dt = 1 ms, in one process taking
turns (``bench.timing.time_alternating``): ``run()`` (the compiled loop) and a batch of 1,024 copies. Prints the
per-step times and their ratios, writes ``bench/results/attachments.csv``. Never asserts a time.

    python3 bench/bench_attachments.py [--repeats 5]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import tensegrity_sim as ts  # noqa: E402
from bench.cases import icosahedron_thrown  # noqa: E402
from bench.tables import RESULTS, write_csv  # noqa: E402
from bench.timing import SETTLE, time_alternating  # noqa: E402
from tensegrity_sim.batch import BatchSimulator  # noqa: E402

BATCH = 1024
MOVED = 8   # cables attached along a strut


def scene(attached: bool) -> ts.Scene:
    """The thrown icosahedron; ``attached``: its first ``MOVED`` cables end along the struts, 0.12 to 0.26 of
    the way in from the node they named."""
    d = icosahedron_thrown(scale=2.0, seed=1).to_dict()
    if attached:
        on = {}
        for s in d["struts"]:
            on[s["nodes"][0]], on[s["nodes"][1]] = (s["name"], 0.0), (s["name"], 1.0)
        for i, c in enumerate(d["cables"][:MOVED]):
            for j in ([1] if i % 2 else [0, 1]):
                strut, end = on[c["nodes"][j]]
                c["nodes"][j] = {"strut": strut, "at": abs(end - 0.12 - 0.02 * i)}
    return ts.Scene.from_dict(d)


def contenders(kind: str, attached: bool):
    """``(run(n), reset())`` of one way of stepping the scene."""
    sc = scene(attached)
    holder = {}

    def reset():
        holder["sim"] = (BatchSimulator(sc, BATCH, method="elastic", dt=1e-3) if kind == "batch"
                         else ts.Simulator(sc, method="elastic", dt=1e-3))

    return (lambda n: holder["sim"].run(steps=n, every=n)), reset


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    rows = []
    for kind in ("run", "batch"):
        timings = time_alternating({name: contenders(kind, name == "attached") for name in ("nodes", "attached")},
                                   repeats=args.repeats, settle=SETTLE)
        per_copy = BATCH if kind == "batch" else 1
        plain, attached = timings["nodes"].best / per_copy, timings["attached"].best / per_copy
        rows.append({"case": "icosahedron_thrown", "path": kind, "copies": per_copy, "attached_cables": MOVED,
                     "nodes_us": plain * 1e6, "attached_us": attached * 1e6, "ratio": attached / plain})
        print(f"{kind:>5}: cables between nodes {plain * 1e6:8.3f} us/step, {MOVED} attached along struts "
              f"{attached * 1e6:8.3f} us/step{' per copy' if per_copy > 1 else ''}: {attached / plain:.3f}x")
    write_csv(RESULTS / "attachments.csv", rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
