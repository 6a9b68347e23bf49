"""What MCAP logging costs, per step, at 1 kHz stepping and 100 Hz publishing.

Run: ``python bench/bench_log.py [SCENE ...] [--steps N] [--repeats R] [--csv FILE]`` (default: the built-in
scenes; ``--csv`` also writes the per-step times and the steps/s of each configuration, e.g.
``bench/results/node_path.csv``: issue 10's node path is ``run --log`` on the icosahedron).
For each scene (dt = 1 ms, publish_rate = 100 Hz, so one publication every 10 steps; marker_rate 10 Hz,
so markers with every 10th publication) it times, per step, best of ``--repeats`` runs of ``--steps``
steps after a warm-up (the four configurations taking turns):

* ``bare``: ``Simulator.step()`` alone;
* ``node``: the node logic stepping and publishing every output at 100 Hz to a transport that takes
  message objects (as rclpy's publishers do) and drops them: the node without a log;
* ``node+log``: the same, every input and output also written to an MCAP file;
* ``run --log``: the node logic with no transport and a log, as ``tensegrity-sim run --log`` runs;
* ``run --log, templates``: the same with each publication encoded by the plain reference
  (:class:`~tensegrity_sim.ros.publication.PublicationTemplates`: four templates filled in turn)
  instead of the compiled pass (``PublicationCdr``);
* with ``--against REV``: ``run --log @REV``, the same run with this repository's ``tensegrity_sim`` at
  git revision REV (``main``, a commit), imported beside this checkout's as a package of its own, so that
  the two versions are timed in turns in one process (the ratio is the speed-up).

``log`` = node+log - node is the logging cost; it is printed against the node's step time and against the
1 ms a step may take at 1 kHz. Opening a log (run info, schemas, channels) and finishing it (rosbag2
metadata, summary) happen once per file, not per step: they are timed apart (``open+finish``, ms per
file) and left out of the per-step times. Times are CPU time of this process (``time.process_time``),
not wall-clock time, so that other work on a shared machine does not count. Never asserts a time.

``--crash-safety`` instead compares, per step, the log as written before issue 13 (mcap's 1 MiB chunks,
no flush until the end, each message handed to the writer at once) with the crash-safe log
(``log.PENDING_SIZE`` bytes of messages waiting, ``log.CHUNK_SIZE`` chunks, a write-out and fsync every
``log.FLUSH_PERIOD`` s): the difference against the node's step time is the price of bounding what a crash
loses. These are wall-clock times (``time.perf_counter``, an fsync waits for the disk, which CPU time
would not show), best of ``--repeats`` runs taking turns, each run long enough to flush several times.
"""
from __future__ import annotations

import argparse
import importlib
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

import tensegrity_sim as ts  # noqa: E402
from bench.tables import write_csv  # noqa: E402
from tensegrity_sim.ros.log import CHUNK_SIZE, FLUSH_PERIOD, PENDING_SIZE, LogRecorder, LogWriter  # noqa: E402
from tensegrity_sim.ros.node_logic import NodeSettings, SimNodeLogic  # noqa: E402
from tensegrity_sim.ros.publication import PublicationTemplates  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

DT = 1e-3
PUBLISH_RATE = 100.0


def best_per_step(configs: dict, steps: int, repeats: int, clock=time.process_time) -> dict[str, float]:
    """Best time per step, s, on ``clock`` (CPU time by default) of each configuration over ``repeats``
    runs of ``steps`` steps. A configuration is ``make() -> (run, close)``; only ``run(steps)`` is timed.
    The configurations take turns, run by run, so that a machine shared with other work slows them alike."""
    for make in configs.values():  # warm-up
        run, close = make()
        run(min(steps, 500))
        close()
    best = dict.fromkeys(configs, float("inf"))
    for _ in range(repeats):
        for name, make in configs.items():
            run, close = make()
            start = clock()
            run(steps)
            best[name] = min(best[name], clock() - start)
            close()
    return {name: t / steps for name, t in best.items()}


def import_revision(rev: str, folder: Path):
    """This repository's ``tensegrity_sim`` at git revision ``rev`` as a package of its own
    (``tensegrity_sim_<rev>``, extracted into ``folder``); the package imports itself relatively, so the
    two versions live side by side (built-in scenes come from this checkout: the same files)."""
    name = "tensegrity_sim_" + re.sub(r"\W", "_", rev)
    archive = subprocess.run(["git", "archive", rev, "tensegrity_sim"], cwd=ROOT, capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive.stdout, check=True)
    (folder / "tensegrity_sim").rename(folder / name)
    sys.path.insert(0, str(folder))
    return importlib.import_module(name)


def measure(scene: ts.Scene, steps: int, repeats: int, folder: Path, against=None) -> dict[str, float]:
    """Seconds per step of bare, node, node+log, run --log (with the compiled and the reference encoder,
    and with the package ``against`` when given: :func:`import_revision`), and seconds per file of
    open+finish (see the module docstring)."""
    settings = NodeSettings(scene=scene.name, dt=DT, publish_rate=PUBLISH_RATE)
    path = folder / f"{scene.name}.mcap"

    def bare():
        sim = ts.Simulator(scene, dt=DT)

        def run(n):
            for _ in range(n):
                sim.step()
        return run, lambda: None

    def node(transport=True, log=False, templates=False, package=None):
        if package is None:
            logic = SimNodeLogic(ts.Simulator(scene, dt=DT), settings,
                                 transport=(lambda key, message: None) if transport else None)
            recorder = LogRecorder(path, logic.channels(), logic.run_info()) if log else None
        else:  # the other version's node logic and log, as run --log runs them
            other = importlib.import_module(f"{package.__name__}.ros.node_logic")
            logic = other.SimNodeLogic(package.Simulator(package.Scene.from_dict(scene.to_dict()), dt=DT),
                                       other.NodeSettings(scene=scene.name, dt=DT, publish_rate=PUBLISH_RATE))
            recorder = importlib.import_module(f"{package.__name__}.ros.log").LogRecorder(
                path, logic.channels(), logic.run_info())
        if templates:  # the plain reference encoder in place of the compiled pass
            sys_ = logic.sim.system
            logic._cdr = PublicationTemplates(settings.frame_id, sys_.n_nodes, logic.sim.scene.cable_names,
                                              sys_.cable_ends)
        logic.recorder = recorder

        def run(n):
            for _ in range(n):
                logic.step()
                if logic.publication_due:
                    logic.publish()
        return run, (recorder.finish if recorder is not None else lambda: None)

    def open_finish() -> float:
        logic = SimNodeLogic(ts.Simulator(scene, dt=DT), settings)
        start = time.process_time()
        LogRecorder(path, logic.channels(), logic.run_info()).finish()
        return time.process_time() - start

    configs = {"bare": bare, "node": node, "node+log": lambda: node(log=True),
               "run --log": lambda: node(transport=False, log=True),
               "run --log, templates": lambda: node(transport=False, log=True, templates=True)}
    if against is not None:
        configs[f"run --log @{against.__name__.removeprefix('tensegrity_sim_')}"] = lambda: node(transport=False, log=True, package=against)
    times = best_per_step(configs, steps, repeats)
    return {**times, "open+finish": min(open_finish() for _ in range(repeats))}


def crash_safety(scene: ts.Scene, steps: int, repeats: int, folder: Path) -> dict[str, float]:
    """Wall-clock seconds per step of the node without a log, with the log as before issue 13 (1 MiB
    chunks, never flushed) and with the crash-safe log (see the module docstring)."""
    settings = NodeSettings(scene=scene.name, dt=DT, publish_rate=PUBLISH_RATE)
    path = folder / f"{scene.name}.mcap"

    def node(writer_options: dict | None):
        logic = SimNodeLogic(ts.Simulator(scene, dt=DT), settings, transport=lambda key, message: None)
        writer = None
        if writer_options is not None:
            writer = LogWriter(path, logic.channels(), logic.run_info(), **writer_options)
            logic.recorder = SimpleNamespace(record=writer.write_all)  # a LogRecorder without its restarts

        def run(n):
            for _ in range(n):
                logic.step()
                if logic.publication_due:
                    logic.publish()
        return run, (writer.finish if writer is not None else lambda: None)

    configs = {"node": lambda: node(None),
               "before": lambda: node({"chunk_size": 1 << 20, "pending_size": 0, "flush_period": None}),
               "crash-safe": lambda: node({})}
    return best_per_step(configs, steps, repeats, clock=time.perf_counter)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", help="built-in names or YAML files (default: the built-ins)")
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--csv", type=Path, help="also write the times to this CSV file")
    parser.add_argument("--against", metavar="REV",
                        help="also time run --log with tensegrity_sim at this git revision (module docstring)")
    parser.add_argument("--crash-safety", action="store_true",
                        help="compare the log before issue 13 with the crash-safe log (module docstring)")
    args = parser.parse_args()
    names = args.scenes or list(ts.builtin_scenes())
    if args.crash_safety:
        print(f"crash-safe log: {PENDING_SIZE // 1024} KiB of messages waiting, chunks of {CHUNK_SIZE // 1024} KiB, "
              f"written out and synced every {FLUSH_PERIOD:g} s; before: 1 MiB chunks, never flushed. Wall-clock "
              f"per step, best of {args.repeats} x {args.steps} steps")
        print(f"{'scene':<14}{'node':>10}{'before':>10}{'crash-safe':>12}  {'cost/node':>9}")
        with tempfile.TemporaryDirectory() as folder:
            for name in names:
                t = crash_safety(ts.load_scene(name), args.steps, args.repeats, Path(folder))
                print(f"{name:<14}{t['node'] * 1e6:>8.1f}us{t['before'] * 1e6:>8.1f}us{t['crash-safe'] * 1e6:>10.1f}us"
                      f"  {100 * (t['crash-safe'] - t['before']) / t['node']:>8.1f}%", flush=True)
        return
    settings = NodeSettings(dt=DT, publish_rate=PUBLISH_RATE)
    print(f"dt = {DT * 1e3:g} ms, publish every {settings.publish_every} steps, markers every "
          f"{settings.markers_every} publications; times per step, best of {args.repeats} x {args.steps} steps")
    print(f"{'scene':<14}{'bare':>10}{'node':>10}{'node+log':>10}{'log':>10}  {'log/node':>9}  {'log/1ms':>8}"
          f"  {'run --log':>10}  {'open+finish':>12}")
    rows, others = [], []
    with tempfile.TemporaryDirectory() as folder:
        against = import_revision(args.against, Path(folder)) if args.against else None
        for name in names:
            scene = ts.load_scene(name)
            t = measure(scene, args.steps, args.repeats, Path(folder), against)
            rows += [{"scene": scene.name, "configuration": k, "us_per_step": 1e6 * v, "steps_per_s": 1.0 / v}
                     for k, v in t.items() if k != "open+finish"]
            log = t["node+log"] - t["node"]
            print(f"{scene.name:<14}{t['bare'] * 1e6:>8.1f}us{t['node'] * 1e6:>8.1f}us{t['node+log'] * 1e6:>8.1f}us"
                  f"{log * 1e6:>8.1f}us  {100 * log / t['node']:>8.1f}%  {100 * log / DT:>7.2f}%"
                  f"  {t['run --log'] * 1e6:>8.1f}us  {t['open+finish'] * 1e3:>10.1f}ms", flush=True)
            others += [f"{scene.name:<14}run --log {1.0 / t['run --log']:>9,.0f} steps/s; " + "; ".join(
                f"{k[len('run --log'):].lstrip(', ')} {t[k] * 1e6:.1f}us ({t[k] / t['run --log']:.2f}x its time)"
                for k in t if k.startswith("run --log") and k != "run --log")]
    print("\n".join(others))
    if args.csv is not None:
        write_csv(args.csv, rows)


if __name__ == "__main__":
    main()
