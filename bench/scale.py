"""Cost per step against structure size, real-time factors, and steps/s beside MuJoCo in one process.

* Scale: towers of 1 to 100 stages (``6 s`` nodes, ``27 s - 15`` members), without gravity (a uniform
  tower of more than 15 stages buckles under its own weight), dt = 1 ms, every tensegrity_sim
  configuration and MuJoCo's Euler and RK4; the growth exponent ``p`` of ``cost ~ members^p`` is the
  least-squares slope in log-log over the towers of 10 stages and more (below that the fixed per-step
  overhead dominates), and over all sizes.
* Real time: the real-time factor (simulated seconds per wall second) of the built-in scenes at
  500 Hz and 1 kHz.
* Throughput: steps/s of both simulators on the same scenes at dt = 1 ms, measured in this process with
  the configurations taking turns, and their ratio; the inextensible method against MuJoCo's limited
  tendons.
"""
from __future__ import annotations

import math

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim import formfinding

from .runners import mujoco_available
from .timing import SETTLE, Timing, time_alternating, time_runs

__all__ = ["STAGES_FULL", "STAGES_QUICK", "tower_scene", "scale_rows", "growth_exponent", "realtime_rows",
           "throughput_rows", "plot_scale"]

STAGES_FULL = (1, 2, 3, 5, 7, 10, 15, 20, 30, 50, 70, 100)
STAGES_QUICK = (1, 3, 10, 30)
TARGET_SECONDS = 0.25      # each timed run lasts about this long
REPEATS = 3


def tower_scene(stages: int) -> ts.Scene:
    return ts.Scene.from_dict(formfinding.tower(stages, gravity=(0.0, 0.0, 0.0)))


def _time_per_step(step_n, reset) -> Timing:
    """Wall times per step (s) of ``REPEATS`` runs of ``step_n(n)``, with ``n`` calibrated so that a
    run lasts about ``TARGET_SECONDS``."""
    reset()
    probe = time_runs(lambda: step_n(5), repeats=1).best / 5
    n = max(5, int(TARGET_SECONDS / max(probe, 1e-7)))
    return time_runs(lambda: step_n(n), setup=reset, repeats=REPEATS).per(n)


def _ours_per_step(sim: ts.Simulator) -> Timing:
    def step_n(n):
        step = sim.step
        for _ in range(n):
            step()
    return _time_per_step(step_n, sim.reset)


def _mujoco_per_step(scene: ts.Scene, dt: float, integrator: str, model: str = "elastic") -> Timing:
    from .mujoco_peer import MujocoPeer
    peer = MujocoPeer(scene, model=model, dt=dt, integrator=integrator)
    return _time_per_step(peer.advance, peer.reset)


def _configs(runners, with_mujoco: bool):
    """(simulator, variant, per_step(scene, dt)) for every configuration timed."""
    out = [("tensegrity_sim", r.variant, lambda scene, dt, r=r: _ours_per_step(r.simulator_for(scene, dt)))
           for r in runners]
    if with_mujoco and mujoco_available():
        out += [("MuJoCo", integ, lambda scene, dt, integ=integ: _mujoco_per_step(scene, dt, integ))
                for integ in ("Euler", "RK4")]
    return out


def scale_rows(runners, stages=STAGES_FULL, progress=None) -> list[dict]:
    """One row per tower size and configuration: stages, nodes, members, us_per_step (NaN if refused)."""
    configs = _configs(runners, with_mujoco=True)
    if progress is not None:
        progress.reset(total=len(stages) * len(configs))
    rows = []
    for s in stages:
        scene = tower_scene(s)
        for simulator, variant, per_step in configs:
            row = {"stages": s, "nodes": len(scene.nodes), "members": len(scene.struts) + len(scene.cables),
                   "simulator": simulator, "variant": variant}
            try:
                timing = per_step(scene, 1e-3)
                row.update(us_per_step=1e6 * timing.best, us_per_step_median=1e6 * timing.median, status="ok")
            except ValueError as exc:
                row.update(us_per_step=math.nan, us_per_step_median=math.nan, status=f"refused: {exc}")
            rows.append(row)
            if progress is not None:
                progress.set_postfix_str(f"tower{s} {simulator} {variant}", refresh=False)
                progress.update()
    return rows


def loglog_slope(pts) -> float:
    """Slope of log(cost) against log(members) of (members, cost) pairs (NaN for fewer than two)."""
    if len(pts) < 2:
        return math.nan
    m, c = map(np.array, zip(*pts))
    return float(np.polyfit(np.log(m), np.log(c), 1)[0])


def growth_exponent(rows: list[dict], simulator: str, variant: str, min_stages: int = 10) -> float:
    """Slope of log(us_per_step) against log(members) over towers of ``min_stages`` stages or more."""
    return loglog_slope([(r["members"], r["us_per_step"]) for r in rows
                         if (r["simulator"], r["variant"]) == (simulator, variant) and r["stages"] >= min_stages
                         and np.isfinite(r["us_per_step"])])


def finish_plot(fig, ax, path) -> None:
    """Grid, legend, layout; save ``fig`` to ``path`` (PNG, 90 dpi) and close it."""
    import matplotlib.pyplot as plt
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def realtime_rows(runners, rates=(500.0, 1000.0)) -> list[dict]:
    """Real-time factor of every built-in scene, configuration and step rate (Hz)."""
    rows = []
    for name in ts.builtin_scenes():
        scene = ts.load_scene(name)
        for r in runners:
            for rate in rates:
                dt = 1.0 / rate
                row = {"scene": name, "simulator": "tensegrity_sim", "variant": r.variant, "rate_hz": rate}
                try:
                    timing = _ours_per_step(r.simulator_for(scene, dt))
                    row.update(us_per_step=1e6 * timing.best, realtime_factor=dt / timing.best,
                               realtime_factor_median=dt / timing.median, status="ok")
                except ValueError as exc:
                    row.update(us_per_step=math.nan, realtime_factor=math.nan, realtime_factor_median=math.nan,
                               status=f"refused: {exc}")
                rows.append(row)
    return rows


def _ours_loop(sim: ts.Simulator):
    """``Simulator.run()`` (its compiled loop where the method has one) keeping the last step only, as
    MuJoCo's ``mj_step(nstep)`` does."""
    return (lambda n: sim.run(steps=n, every=n)), sim.reset


def throughput_rows(scenes: dict, runners, progress=None) -> list[dict]:
    """Steps/s at dt = 1 ms (best and median of the runs) of tensegrity_sim and MuJoCo on each of
    ``scenes`` ({name: Scene}), in this process, all configurations of a scene taking turns
    (:func:`~.timing.time_alternating`), each run ``SETTLE`` steps after a reset (steady stepping). ``ratio`` is tensegrity_sim's best steps/s over that MuJoCo
    configuration's, ``ratio_median`` the same with medians; the elastic method is compared with
    MuJoCo's spring tendons (Euler, implicitfast, RK4), the inextensible one with its limited tendons
    (Euler, RK4; MuJoCo's model of an inextensible cable)."""
    peers = {"elastic": [(integ, integ, "elastic") for integ in ("Euler", "implicitfast", "RK4")],
             "inextensible": [(integ, f"{integ} limited", "inextensible") for integ in ("Euler", "RK4")]}
    if not mujoco_available():
        peers = {"elastic": [], "inextensible": []}
    if progress is not None:
        progress.reset(total=len(scenes))
    rows = []
    for name, scene in scenes.items():
        contenders, ours, theirs = {}, {}, {}
        for r in runners:
            try:
                contenders[("tensegrity_sim", r.variant)] = _ours_loop(r.simulator_for(scene, 1e-3))
                ours[r.variant] = r.method
            except ValueError:
                ours[r.variant] = None
        for method in {m for m in ours.values() if m}:
            for integ, label, model in peers[method]:
                from .mujoco_peer import MujocoPeer
                try:
                    peer = MujocoPeer(scene, model=model, dt=1e-3, integrator=integ)
                except ValueError:   # a structure the peer cannot model (see mujoco_peer)
                    continue
                contenders[("MuJoCo", label)] = (peer.advance, peer.reset)
                theirs[label] = method
        timings = time_alternating(contenders, repeats=REPEATS, target=TARGET_SECONDS, settle=SETTLE)
        nan = Timing((math.nan,))
        for variant in ours:
            t = timings.get(("tensegrity_sim", variant), nan)
            rows.append({"scene": name, "simulator": "tensegrity_sim", "variant": variant,
                         "steps_per_s": 1.0 / t.best, "steps_per_s_median": 1.0 / t.median, "vs": "",
                         "ratio": math.nan, "ratio_median": math.nan})
        for label, method in theirs.items():
            t = timings[("MuJoCo", label)]
            for variant, our_method in ours.items():
                if our_method != method:
                    continue
                mine = timings[("tensegrity_sim", variant)]
                rows.append({"scene": name, "simulator": "MuJoCo", "variant": label, "steps_per_s": 1.0 / t.best,
                             "steps_per_s_median": 1.0 / t.median, "vs": f"tensegrity_sim {variant}",
                             "ratio": t.best / mine.best, "ratio_median": t.median / mine.median})
        if progress is not None:
            progress.update()
    return rows


def plot_scale(rows: list[dict], path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.0))
    for simulator, variant in sorted({(r["simulator"], r["variant"]) for r in rows}):
        pts = sorted((r["members"], r["us_per_step"]) for r in rows
                     if (r["simulator"], r["variant"]) == (simulator, variant) and np.isfinite(r["us_per_step"]))
        if not pts:
            continue
        m, c = map(np.array, zip(*pts))
        p = growth_exponent(rows, simulator, variant)
        style = "-o" if simulator == "tensegrity_sim" else "--s"
        ax.loglog(m, c, style, ms=3.5, label=f"{simulator} {variant} (p = {p:.2f})")
    ax.set_xlabel("members (towers of 1 to 100 stages)")
    ax.set_ylabel("wall time per step (µs)")
    ax.set_title("cost per step, dt = 1 ms; p: slope over >= 10 stages", fontsize=9)
    finish_plot(fig, ax, path)
