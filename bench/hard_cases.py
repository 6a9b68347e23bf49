"""Stability on hard cases: a table of pass/fail with the figure behind each verdict.

Every case runs for every tensegrity_sim configuration. The verdict depends on what the method
promises: the elastic method conserves energy (it is symplectic: bounded error, no drift), the
inextensible one may only lose energy (snaps are inelastic); both conserve momentum to round-off with
no external load, and both must either run stably or refuse a step with the limit in the message. The
massive method (cables with mass) runs the case where the three differ, the drop onto slack cables.
"""
from __future__ import annotations

import math
import re

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim import formfinding
from tensegrity_sim.system import System

__all__ = ["hard_case_rows", "hard_case_runners", "CASES", "MASSIVE_CASES"]

LIMIT_RE = re.compile(r"dt must be < [0-9.]+/omega_\w+ = ([0-9.eE+-]+) s")


def _random_velocities(mapping: dict, scale: float, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    for node in mapping["nodes"]:
        if not node.get("fixed", False):
            node["velocity"] = [float(c) for c in rng.normal(scale=scale, size=3)]
    return mapping


def _scales(sim: ts.Simulator) -> tuple[float, float]:
    """Momentum scales (linear, angular) of the current state, for relative round-off checks."""
    m = sim.system.masses[:, None]
    v = np.abs(sim.velocities)
    return float(np.sum(m * v)) + 1e-300, float(np.sum(m * np.linalg.norm(sim.positions, axis=1)[:, None] * v)) + 1e-300


def _run(sim: ts.Simulator, steps: int, samples: int = 200, on_step=None) -> dict:
    """Run ``steps`` steps; energy sampled ``samples`` times. Returns the largest energy deviation and
    growth (J) relative to the start, momentum changes relative to their scales, and finiteness.
    ``on_step(k)`` may command the simulator before step ``k`` and returns the energy it injected (J)."""
    e0 = sim.energy()["total"]
    p0, l0 = sim.momentum()
    ps, ls = _scales(sim)
    every = max(1, steps // samples)
    dev, grow, injected, trace, scale = 0.0, -math.inf, 0.0, [], abs(e0)
    for k in range(steps):
        if on_step is not None:
            injected += on_step(k)
        sim.step()
        if (k + 1) % every == 0 or k + 1 == steps:
            e = sim.energy()["total"] - e0 - injected
            dev, grow = max(dev, abs(e)), max(grow, e)
            trace.append(e)
            scale = max(scale, abs(e0 + injected))
    p1, l1 = sim.momentum()
    return {"scale": scale, "energy_dev": dev, "energy_growth": grow, "trace": np.array(trace),
            "dp": float(np.max(np.abs(p1 - p0))) / ps, "dl": float(np.max(np.abs(l1 - l0))) / ls,
            "finite": bool(np.all(np.isfinite(sim.positions)))}


def _energy_verdict(model: str, out: dict, tol: float) -> tuple[bool, str]:
    """Elastic: |E - E_expected| <= tol E. Inextensible: E never above E_expected by more than tol E.
    ``E_expected`` is the initial energy plus what commands injected; ``E`` the largest |E_expected|."""
    scale = out["scale"] + 1e-300
    if model == "elastic":
        return out["energy_dev"] <= tol * scale, f"max |dE|/E = {out['energy_dev'] / scale:.1e}"
    return out["energy_growth"] <= tol * scale, f"max energy growth/E = {max(out['energy_growth'], 0) / scale:.1e}"


# ------------------------------------------------------------------------------------------ cases
def stiffness_ratio(runner, quick: bool) -> list[dict]:
    """Prism with struts of 1e2..1e8 N/m (cables 2e3 N/m), perturbed, dt = 1 ms, 2 s: it must run with a
    bounded energy error, or refuse with the limit; a refused one is then run at 0.9 x the limit."""
    rows = []
    for k in (1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8):
        scene = ts.Scene.from_dict(_random_velocities(formfinding.prism(strut_stiffness=k), 0.1, seed=2))
        setting = f"k_strut = {k:.0e} N/m (x{k / 2e3:.0e} cable)"
        dt = 1e-3
        try:
            sim = runner.simulator_for(scene, dt)
            refused = ""
        except ValueError as exc:
            match = LIMIT_RE.search(str(exc))
            if not match:
                rows.append(_row("stiffness ratio", runner, setting, False, f"refused without a limit: {exc}"))
                continue
            limit = float(match.group(1))
            dt = 0.9 * limit
            sim = runner.simulator_for(scene, dt)
            refused = f"refused at 1 ms, limit {limit:.3g} s; at 0.9 x limit: "
        steps = int(round((0.2 if quick else 2.0) / dt))
        out = _run(sim, steps)
        ok, fig = _energy_verdict(runner.model, out, 0.05)
        ok = ok and out["finite"] and out["dp"] < 1e-9
        rows.append(_row("stiffness ratio", runner, setting, ok, f"{refused}{fig}, |dp|/p = {out['dp']:.0e}"))
    rigid = formfinding.prism()
    for strut in rigid["struts"]:
        strut["stiffness"] = "rigid"
        del strut["rest_length"]        # a rigid strut keeps its initial length; it takes the prestress
    sim = runner.simulator_for(ts.Scene.from_dict(_random_velocities(rigid, 0.1, seed=2)), 1e-3)
    out = _run(sim, 200 if quick else 2000)
    ok, fig = _energy_verdict(runner.model, out, 0.05)
    rows.append(_row("stiffness ratio", runner, "rigid struts", ok and out["finite"], fig))
    return rows


def mass_ratio(runner, quick: bool) -> list[dict]:
    """Prism whose top nodes weigh 1e4 times the bottom ones (0.5 kg and 5000 kg), perturbed, 1 ms."""
    d = formfinding.prism()
    for node in d["nodes"][3:]:
        node["mass"] = 5000.0
    sim = runner.simulator_for(ts.Scene.from_dict(_random_velocities(d, 0.1, seed=3)), 1e-3)
    out = _run(sim, 200 if quick else 5000)
    ok, fig = _energy_verdict(runner.model, out, 1e-2)
    ok = ok and out["finite"] and out["dp"] < 1e-9 and out["dl"] < 1e-9
    return [_row("mass ratio 1e4", runner, "prism, 0.5 kg / 5000 kg nodes", ok,
                 f"{fig}, |dp|/p = {out['dp']:.0e}, |dL|/L = {out['dl']:.0e}")]


def simultaneous_snaps(runner, quick: bool) -> list[dict]:
    """Icosahedron with every cable 2 cm slack and each strut translating outward at 1 m/s: by symmetry
    all 24 cables snap taut in the same step. Energy as the method promises, momentum, and the
    symmetry kept (every cable's impulse equal)."""
    d = ts.load_scene("icosahedron").to_dict()
    x = np.array([n["position"] for n in d["nodes"]])
    index = {n["name"]: i for i, n in enumerate(d["nodes"])}
    for strut in d["struts"]:
        a, b = (index[n] for n in strut["nodes"])
        mid = 0.5 * (x[a] + x[b])
        for p in (a, b):
            d["nodes"][p]["velocity"] = [float(c) for c in mid / np.linalg.norm(mid)]
    for cable in d["cables"]:
        a, b = (index[n] for n in cable["nodes"])
        cable["rest_length"] = float(np.linalg.norm(x[b] - x[a])) + 0.02
    sim = runner.simulator_for(ts.Scene.from_dict(d), 1e-3)
    steps = 300 if quick else 1000
    e0 = sim.energy()["total"]
    p0, _ = sim.momentum()
    taut_now, first_snap, impulses, dev, grow = ~sim.slack(), None, np.zeros(len(d["cables"])), 0.0, -math.inf
    for k in range(steps):
        r = sim.step()
        impulses += r.impulses
        snapped = (~r.slack) & ~taut_now
        if first_snap is None and snapped.any():
            first_snap = int(snapped.sum())
        taut_now = ~r.slack
        e = sim.energy()["total"] - e0
        dev, grow = max(dev, abs(e)), max(grow, e)
    spread = float(np.ptp(impulses) / (np.mean(np.abs(impulses)) + 1e-300))
    dp = float(np.max(np.abs(sim.momentum()[0] - p0)))
    ok_e, fig = _energy_verdict(runner.model, {"scale": abs(e0), "energy_dev": dev, "energy_growth": grow}, 1e-2)
    ok = ok_e and first_snap == len(d["cables"]) and spread < 1e-9 and dp < 1e-12
    return [_row("many simultaneous snaps", runner, "icosahedron, 24 cables", ok,
                 f"{first_snap} cables snap in one step, impulse spread {spread:.0e}, {fig}, |dp| = {dp:.0e}")]


def hovering_cable(runner, quick: bool) -> list[dict]:
    """A prism with no prestress: every member exactly at its rest length. At rest it must stay exactly
    still (no force, no impulse); with 1e-9 m/s of noise the cables flicker between slack and taut at
    zero tension, and the energy must stay as promised."""
    d = formfinding.prism()
    x = np.array([n["position"] for n in d["nodes"]])
    index = {n["name"]: i for i, n in enumerate(d["nodes"])}
    members = d["struts"] + d["cables"]
    ends = np.array([[index[n] for n in member["nodes"]] for member in members])
    # each length as the simulator computes it (System.geometry), not by np.linalg.norm: a BLAS whose dot
    # product rounds otherwise (AVX-512) left a strut one ulp off its rest length, and the prism moved 2e-16 m
    _, lengths, _ = System(ts.Scene.from_dict(d)).geometry(x, ends)
    for member, length in zip(members, lengths):
        member["rest_length"] = float(length)
    steps = 1000 if quick else 10_000
    sim = runner.simulator_for(ts.Scene.from_dict(d), 1e-3)
    x0 = sim.positions
    imp = 0.0
    for _ in range(steps):
        imp = max(imp, float(np.max(np.abs(sim.step().impulses))))
    moved = float(np.max(np.abs(sim.positions - x0)))
    rows = [_row("cable hovering at its rest length", runner, "at rest", moved == 0.0 and imp == 0.0,
                 f"max displacement {moved:.0e} m, max impulse {imp:.0e} N*s over {steps} steps")]
    sim = runner.simulator_for(ts.Scene.from_dict(_random_velocities(d, 1e-9, seed=4)), 1e-3)
    flips, slack = 0, sim.slack()
    e0 = sim.energy()["total"]
    dev = grow = 0.0
    for _ in range(steps):
        r = sim.step()
        flips += int(np.sum(r.slack != slack))
        slack = r.slack
        e = sim.energy()["total"] - e0
        dev, grow = max(dev, abs(e)), max(grow, e)
    ok, fig = _energy_verdict(runner.model, {"scale": abs(e0), "energy_dev": dev, "energy_growth": grow}, 1e-2)
    rows.append(_row("cable hovering at its rest length", runner, "1e-9 m/s noise", ok and np.all(np.isfinite(sim.positions)),
                     f"{flips} slack/taut flips, {fig}"))
    return rows


def rest_length_commands(runner, quick: bool) -> list[dict]:
    """The built-in prism3 with its cables shortened slowly (1 mm/s) and all at once (5 % in one step).
    The energy must change by the motor's work and no more. Elastic cables: a rest-length change at fixed
    positions adds ``strain(new) - strain(old)``, exactly. Inextensible cables: the rest lengths in effect
    follow the command at the motors' speed (``reel_speed``, 1 m/s: the 5 % take 50 ms); each step's
    shortening of them is a reel-in whose work is the cable's impulse times that shortening over the step."""
    rows = []
    scene = ts.load_scene("prism3")
    rest0 = scene.cable_rest_lengths
    duration = 1.0 if quick else 10.0
    elastic = runner.model == "elastic"
    for setting, schedule in (
            ("slow: -1 mm/s on every cable", lambda t: rest0 - 1e-3 * t),
            ("fast: -5 % on every cable in one step", lambda t: rest0 * (0.95 if t >= 0.1 else 1.0))):
        sim = runner.simulator_for(scene, 1e-3)
        e0 = sim.energy()["total"]
        work = dev = 0.0
        grow, scale = -math.inf, abs(e0)
        for k in range(int(round(duration / sim.dt))):
            old, before = sim.applied_rest_lengths, sim.energy()["total"]
            sim.set_rest_lengths(schedule(k * sim.dt))
            jump = sim.energy()["total"] - before
            r = sim.step()
            work += jump if elastic else float(r.impulses @ (old - sim.applied_rest_lengths)) / sim.dt
            e = sim.energy()["total"] - e0 - work
            dev, grow, scale = max(dev, abs(e)), max(grow, e), max(scale, abs(e0 + work))
        ok, fig = _energy_verdict(runner.model, {"scale": scale, "energy_dev": dev, "energy_growth": grow}, 1e-2)
        ok = ok and bool(np.all(np.isfinite(sim.positions)))
        rows.append(_row("rest-length commands", runner, setting, ok,
                         f"{fig} net of the motor's work ({work:.3g} J)"))
    return rows


# The long-horizon row's drift criterion for the elastic method: the mean |dE| over the last tenth of the
# run at most DRIFT_RATIO times that over the first tenth. An error growing like t^p gives a ratio of
# (1 - 0.9^(p+1)) / 0.1^(p+1): 1 for a bounded error (p = 0), 4.6 for a random walk (p = 1/2), 19 for a
# drift (p = 1); 9.5 is p = 3/4, between the last two. Not 3, as it was: symplecticity bounds the energy
# error only for smooth forces, and a cable's kink at every slack/taut switch adds an O(h^2) error of
# either sign, so with constant switching the error random-walks. Measured (issue 15; prism3, 0.5 m/s,
# 1e6 steps at 1 ms, omega_max dt = 0.30, 1000 samples), the signed mean of the tenths (J): seed 5 +3.9e-3
# ... -7.3e-3 (ratio 1.86), seed 6 +1.9e-3 ... -1.4e-3 ... +9.0e-3 (4.68), seed 9 -7.6e-4 ... +1.5e-2 ...
# +1.1e-2 (8.31); seeds 7, 8, 10, 11: 1.18, 0.74, 0.99, 0.49; with the numpy reference instead of the
# compiled kernel (round-off only) seed 5 rose from 3.9e-3 to 1.3e-2 (3.22, which the old limit flagged).
# A trend that changes sign with the seed and with round-off is not a drift of the method; max |dE|/E
# stays 5.9e-4..5.3e-3, within the row's 1e-2, and shrinks with the step (seed 6 at 0.5 ms, 2e6 steps:
# 5.1e-4, ratio 1.35) and the order (order 4 at 1 ms: 4.9e-5, ratio 3.63; seed 9: 1.1e-4, 1.95).
DRIFT_RATIO = 9.5


def long_horizon(runner, quick: bool) -> list[dict]:
    """1e6 steps (1e4 with --quick) at 1 ms of the perturbed prism3 and icosahedron: momentum to
    round-off, energy within 1e-2 E and without a drift (elastic: :data:`DRIFT_RATIO`), rigid strut
    lengths held."""
    rows = []
    steps = 10_000 if quick else 1_000_000
    for name, scale in (("prism3", 0.5), ("icosahedron", 0.5)):
        scene = ts.Scene.from_dict(_random_velocities(ts.load_scene(name).to_dict(), scale, seed=5))
        sim = runner.simulator_for(scene, 1e-3)
        out = _run(sim, steps, samples=1000)
        tr = np.abs(out["trace"])
        tenth = max(1, len(tr) // 10)
        drift = float(tr[-tenth:].mean() / max(tr[:tenth].mean(), 1e-300))
        ok, fig = _energy_verdict(runner.model, out, 1e-2)
        if runner.model == "elastic":   # a drift would make the late error many times the early one
            ok = ok and drift <= DRIFT_RATIO
            fig += f", mean |dE| last/first tenth {drift:.2f}"
        ends, rest = sim.system.strut_ends, sim.system.strut_rest
        lengths = np.linalg.norm(sim.positions[ends[:, 1]] - sim.positions[ends[:, 0]], axis=1)
        strut_err = float(np.max(np.abs(lengths / rest - 1.0)[sim.system.rigid])) if sim.system.rigid.any() else 0.0
        ok = ok and out["finite"] and out["dp"] < 1e-9 and out["dl"] < 1e-9 and strut_err < 1e-9
        rows.append(_row("long horizon", runner, f"{name}, {steps:.0e} steps", ok,
                         f"{fig}, |dp|/p = {out['dp']:.0e}, |dL|/L = {out['dl']:.0e}, rigid strut error {strut_err:.0e}"))
    return rows


def _crossing_scene(speed: float, height: float, tilt: float) -> ts.Scene:
    """A fixed strut A along x (2 m, radius 15 mm) and a free rigid strut B above it, parallel to it but
    for its ends raised and lowered by ``tilt`` m, falling through it at ``speed`` m/s (no gravity, no
    response: detection only)."""
    return ts.Scene.from_dict({"nodes": [
        {"name": "a0", "position": [-1.0, 0.0, 0.0], "fixed": True},
        {"name": "a1", "position": [1.0, 0.0, 0.0], "fixed": True},
        {"name": "b0", "position": [-1.0, 0.0, height - tilt], "mass": 1.0, "velocity": [0.0, 0.0, -speed]},
        {"name": "b1", "position": [1.0, 0.0, height + tilt], "mass": 1.0, "velocity": [0.0, 0.0, -speed]}],
        "struts": [{"name": "A", "nodes": ["a0", "a1"], "stiffness": "rigid", "radius": 0.015},
                   {"name": "B", "nodes": ["b0", "b1"], "stiffness": "rigid", "radius": 0.015}],
        "cables": []})


def member_crossing(runner, quick: bool) -> list[dict]:
    """Member contact on degenerate geometry, against the exact times: a strut falling through another
    at 200 m/s (in contact for 0.3 ms, inside one 1 ms step), near-parallel (1e-6 m tilt over 2 m) and
    exactly parallel struts at 1 m/s. Pass: one begin and one end, each within 1e-8 s of the exact time
    (B's lowest point reaching A's surface, its highest point leaving it)."""
    rows = []
    reach = 0.03   # sum of the radii, m
    for setting, speed, height, tilt in (("fast crossing, 200 m/s", 200.0, 0.5, 0.0),
                                         ("near-parallel, 1e-6 m tilt, 1 m/s", 1.0, 0.1, 1e-6),
                                         ("parallel, 1 m/s", 1.0, 0.1, 0.0)):
        sim = ts.Simulator(_crossing_scene(speed, height, tilt), method=runner.method, dt=1e-3,
                           **{**runner.options, "contacts": ("strut_strut",)})
        exact = ((height - tilt - reach) / speed, (height + tilt + reach) / speed)
        events = []
        for _ in range(int(np.ceil(exact[1] / 1e-3)) + 5):
            events += sim.step().contacts
        kinds = [e.kind for e in events]
        ok = kinds == ["begin", "end"]
        err = max(abs(e.time - t) for e, t in zip(events, exact)) if ok else math.inf
        rows.append(_row("near-parallel / fast-crossing members", runner, setting, ok and err < 1e-8,
                         f"events {kinds}, largest time error {err:.1e} s"))
    return rows


def slack_drop(runner, quick: bool) -> list[dict]:
    """The hard case where the three methods differ (``bench/massive.py``'s drop): prism3 on its fixed bottom
    triangle, every cable 3 cm slack and carrying 0.2 kg, dropped until its top triangle's three cables snap
    taut together. The kinetic energy kept by the first snap against the closed form for the method (elastic:
    all of it; inextensible: a plastic impact; massive: the plates' impact, physics §4b), within 1% of it."""
    from bench.massive import drop_scene, first_snap
    plate = 0.2
    sim = runner.simulator_for(drop_scene(plate), 1e-4)
    row = first_snap(sim, plate)
    ok = row["cables"] == "c3 c4 c5" and abs(row["kept"] - row["closed_form_kept"]) < 0.01
    return [_row("drop onto slack cables", runner, "prism3, cables 3 cm slack, 0.2 kg each", ok,
                 f"{row['cables']} snap: kinetic energy kept {row['kept']:.4f}, closed form "
                 f"{row['closed_form_kept']:.4f}")]


def _row(case: str, runner, setting: str, passed, figure: str) -> dict:
    verdict = "n/a" if passed is None else ("pass" if passed else "FAIL")
    return {"case": case, "simulator": "tensegrity_sim", "variant": runner.variant, "setting": setting,
            "verdict": verdict, "figure": figure}


CASES = (stiffness_ratio, mass_ratio, simultaneous_snaps, hovering_cable, rest_length_commands, member_crossing,
         long_horizon, slack_drop)
# the massive method's: the other cases' scenes have rigid struts, which it does not take yet
MASSIVE_CASES = (slack_drop,)


def _cases(runner) -> tuple:
    return MASSIVE_CASES if runner.method == "massive" else CASES


def hard_case_rows(runners, quick: bool, progress=None) -> list[dict]:
    """Every hard case for every configuration; a case that raises is a failure with the error shown."""
    if progress is not None:
        progress.reset(total=sum(len(_cases(runner)) for runner in runners))
    rows = []
    for runner in runners:
        for case in _cases(runner):
            try:
                rows += case(runner, quick)
            except Exception as exc:     # a crash is a verdict too, and must not hide the other cases
                rows.append(_row(case.__name__.replace("_", " "), runner, "-", False,
                                 f"raised {type(exc).__name__}: {exc}"))
            if progress is not None:
                progress.set_postfix_str(f"{runner.variant} {case.__name__}", refresh=False)
                progress.update()
    return rows


def hard_case_runners() -> list:
    """Each method with its defaults, the massive one too (on :data:`MASSIVE_CASES`)."""
    from bench.runners import NO_CONTACTS, TensegrityRunner, default_runners
    return default_runners() + [TensegrityRunner("massive", "massive", NO_CONTACTS)]


def main(argv=None) -> int:
    """``python3 bench/hard_cases.py [--quick] [--out CSV]``: the table for each method's defaults,
    printed and written (default ``bench/results/hard_cases.csv``, as ``run_all.py`` writes it); exit
    status 1 if a row fails."""
    import argparse
    import warnings
    from pathlib import Path

    from bench.tables import write_csv
    parser = argparse.ArgumentParser(description=main.__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs (1e4 steps for the long horizon)")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "hard_cases.csv")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", ts.LengthOffsetWarning)   # documented: prestressed cables' limits
    rows = hard_case_rows(hard_case_runners(), quick=args.quick)
    for row in rows:
        print(f"{row['verdict']:4} | {row['variant']:12} | {row['case']} | {row['setting']} | {row['figure']}")
    write_csv(args.out, rows)
    return 1 if any(row["verdict"] == "FAIL" for row in rows) else 0


if __name__ == "__main__":
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first
    raise SystemExit(main())
