"""Cost of member contact detection per step, as the step time with detection over the step time without.

Scenes: the icosahedron and towers of 10 and 50 stages (the 50-stage one without gravity, under which it
would buckle), each shaken by random node velocities so that the members move, in three settings:

- ``far``: the scene's own radii; no member comes near another.
- ``near``: strut radii grown until the closest two struts are 1 mm apart at rest: the shaken struts
  come within reach of each other and some pairs are examined every step.
- ``touching``: strut radii grown until the closest struts overlap by 1 mm at rest: contacts begin and
  end all the time (detection only: nothing pushes the struts apart).

Run: ``python bench/bench_contact.py [--steps N] [--repeats R] [--shake V] [--out DIR]``. Prints a table
and writes ``contact.csv`` (with the load average); never asserts a time. Each row times ``run()`` of
the elastic method without contact detection ("plain") and with it ("detect"), the two taking turns,
best of ``--repeats`` after a warm-up (CPU time); "ratio" is what detection multiplies a step by. The
first row is the thrown icosahedron of ``bench.cases`` with its default detection (issue 28's target:
within 1.3x); then each scene checks struts against struts (the default) and every member kind.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

import tensegrity_sim as ts  # noqa: E402
from bench.cases import icosahedron_thrown  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from bench.timing import time_alternating  # noqa: E402
from tensegrity_sim import formfinding  # noqa: E402
from tensegrity_sim.methods.contact.detection import closest_points  # noqa: E402


def scenes():
    yield "icosahedron", ts.load_scene("icosahedron").to_dict()
    yield "tower10", formfinding.tower(10)
    yield "tower50", formfinding.tower(50, gravity=(0.0, 0.0, 0.0))


def closest_struts(mapping) -> float:
    """Smallest distance (m) between the axes of two struts that share no node, at rest."""
    scene = ts.Scene.from_dict(mapping)
    ends = scene.member_index(scene.struts)
    x = scene.positions
    i, j = np.triu_indices(len(ends), 1)
    apart = ~((ends[i, :, None] == ends[j, None, :]).any(axis=(1, 2)))
    i, j = i[apart], j[apart]
    dist, _, _ = closest_points(x[ends[i, 0]], x[ends[i, 1]], x[ends[j, 0]], x[ends[j, 1]])
    return float(dist.min())


def variant(mapping, setting: str, shake: float, seed: int = 0):
    d = {**mapping, "nodes": [dict(n) for n in mapping["nodes"]],
         "struts": [dict(s) for s in mapping["struts"]]}
    if setting != "far":
        gap = 1e-3 if setting == "near" else -1e-3
        radius = 0.5 * (closest_struts(mapping) - gap)
        for s in d["struts"]:
            s["radius"] = radius
    rng = np.random.default_rng(seed)
    for n in d["nodes"]:
        if not n.get("fixed", False):
            n["velocity"] = list(rng.normal(scale=shake, size=3))
    return ts.Scene.from_dict(d)


def run_times(scene, kinds, steps, repeats, dt):
    """Best time per step (s) of ``run()`` without contact detection and with ``kinds``, the two taking
    turns (``repeats`` each, after a warm-up), the events of a run, and the detector."""
    plain = ts.Simulator(scene, method="elastic", dt=dt, contacts=())
    detected = ts.Simulator(scene, method="elastic", dt=dt, contacts=kinds)
    events = []
    contenders = {"plain": (lambda n: plain.run(steps=n, every=n), plain.reset),
                  "detected": (lambda n: events.append(len(detected.run(steps=n, every=n).contacts)), detected.reset)}
    timings = time_alternating(contenders, repeats=repeats, target=max(0.05, steps * 2e-6),
                               clock=time.process_time)
    detected.reset()
    count = len(detected.run(steps=steps, every=steps).contacts)
    return timings["plain"].best, timings["detected"].best, count, detected._contacts


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--shake", type=float, default=0.05, help="rms node speed added, m/s (default 0.05)")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results")
    args = parser.parse_args()
    warnings.simplefilter("ignore", ts.ClassKWarning)
    load = os.getloadavg()[0]
    print(f"load {load:.2f}")
    print(f"{'scene':<20}{'setting':<9}{'kinds':<7}{'members':>8}{'pairs':>6}{'plain us':>9}{'detect us':>10}"
          f"{'ratio':>7}{'events':>8}")
    cases = [(name, setting, variant(mapping, setting, args.shake)) for name, mapping in scenes()
             for setting in ("far", "near", "touching")]
    cases.insert(0, ("icosahedron_thrown", "default", icosahedron_thrown()))
    rows = []
    for name, setting, scene in cases:
        for label, kinds in (("struts", ("strut_strut",)), ("all", ts.scene.CONTACT_KINDS)):
            if setting == "default" and label == "all":
                continue
            plain, detected, events, detector = run_times(scene, kinds, args.steps, args.repeats, args.dt)
            pairs = detector.pair_count if detector is not None else 0
            rows.append({"scene": name, "setting": setting, "kinds": label,
                         "members": len(scene.struts) + len(scene.cables), "pairs": pairs,
                         "plain_us": 1e6 * plain, "detect_us": 1e6 * detected, "ratio": detected / plain,
                         "events": events, "load": load})
            r = rows[-1]
            print(f"{name:<20}{setting:<9}{label:<7}{r['members']:>8}{pairs:>6}{r['plain_us']:>9.2f}"
                  f"{r['detect_us']:>10.2f}{r['ratio']:>7.2f}{events:>8}", flush=True)
    args.out.mkdir(exist_ok=True)
    write_csv(args.out / "contact.csv", rows)


if __name__ == "__main__":
    main()
