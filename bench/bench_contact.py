"""Cost of member contact detection per step, as the step time with detection over the step time without.

Scenes: the icosahedron and towers of 10 and 50 stages (the 50-stage one without gravity, under which it
would buckle), each shaken by random node velocities so that the members move, in three settings:

- ``far``: the scene's own radii; no member comes near another.
- ``near``: strut radii grown until the closest two struts are 1 mm apart at rest: the shaken struts
  come within reach of each other and some pairs are examined every step.
- ``touching``: strut radii grown until the closest struts overlap by 1 mm at rest: contacts begin and
  end all the time (detection only: nothing pushes the struts apart).

Run: ``python bench/bench_contact.py [--steps N] [--repeats R] [--shake V]``. Prints a table; never
asserts a time. "step" is the step time without detection; "detect" the time spent in the detector per
step, timed around its calls, and "+%" their ratio: what detection adds to a step. The first group
checks struts against struts (the default), the second every member kind. Each figure is the best of
``--repeats`` runs after a warm-up.
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim import formfinding
from tensegrity_sim.contact import closest_points


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


def step_time(scene, steps, repeats, dt):
    """Best time per step (s) without contact detection, over ``repeats`` runs after a warm-up."""
    sim = ts.Simulator(scene, method="elastic", dt=dt, contacts=())
    sim.run(steps=min(steps, 300))
    best = float("inf")
    for _ in range(repeats):
        sim.reset()
        start = time.perf_counter()
        for _ in range(steps):
            sim.step()
        best = min(best, time.perf_counter() - start)
    return best / steps


def detection_time(scene, kinds, steps, repeats, dt):
    """Time per step (s) spent in the detector, timed around its calls (best of ``repeats`` runs, so
    that the noise of a shared machine in the rest of the step does not enter), the events of a run,
    the share of steps in which it looked at its pairs (the others cost one comparison over the nodes)
    and the detector."""
    sim = ts.Simulator(scene, method="elastic", dt=dt, contacts=kinds)
    detector = sim._contacts
    if detector is None:
        return 0.0, 0, 0.0, None
    step, careful = detector.step, detector._careful_step
    spent, looked = [0.0], [0]

    def timed(*args):
        start = time.perf_counter()
        out = step(*args)
        spent[0] += time.perf_counter() - start
        return out

    def counted(*args):
        looked[0] += 1
        return careful(*args)

    detector.step, detector._careful_step = timed, counted
    sim.run(steps=min(steps, 300))
    best = float("inf")
    for _ in range(repeats):
        sim.reset()
        spent[0], looked[0], events = 0.0, 0, 0
        for _ in range(steps):
            events += len(sim.step().contacts)
        best = min(best, spent[0])
    return best / steps, events, looked[0] / steps, detector


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--shake", type=float, default=0.05, help="rms node speed added, m/s (default 0.05)")
    args = parser.parse_args()
    warnings.simplefilter("ignore", ts.ClassKWarning)
    print(f"{'scene':<12}{'setting':<9}{'members':>8}{'step us':>8} |{'pairs':>6}{'detect us':>10}{'+%':>7}"
          f"{'looked':>7}{'events':>7} |{'pairs':>6}{'detect us':>10}{'+%':>7}{'looked':>7}{'events':>7}")
    for name, mapping in scenes():
        for setting in ("far", "near", "touching"):
            scene = variant(mapping, setting, args.shake)
            base = step_time(scene, args.steps, args.repeats, args.dt)
            row = f"{name:<12}{setting:<9}{len(scene.struts) + len(scene.cables):>8}{base * 1e6:>8.1f} |"
            for kinds in (("strut_strut",), ts.scene.CONTACT_KINDS):
                spent, events, looked, detector = detection_time(scene, kinds, args.steps, args.repeats,
                                                                 args.dt)
                pairs = detector.pair_count if detector is not None else 0
                row += (f"{pairs:>6}{spent * 1e6:>10.1f}{100 * spent / base:>6.1f}%{100 * looked:>6.1f}%"
                        f"{events:>7} |")
            print(row[:-2], flush=True)


if __name__ == "__main__":
    main()
