"""The ``tensegrity-sim`` command line (contract §3)."""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ._kernel_cache import CompileClock
from .commands import CommandError, CommandSchedule, load_commands
from .methods import StepError
from .methods.qp.solvers import SOLVERS, SPARSE_NODES
from .scene import Scene, SceneError, load_scene
from .simulator import Simulator

__all__ = ["main", "RunSummary", "simulate"]

DEFAULT_SCENE = "prism3"
PROGRESS_MIN_STEPS = 20_000  # runs shorter than this finish too quickly to need a progress bar
_CHUNK = 1000                # steps per Simulator.run call when nothing but commands happens between steps
DEFAULT_LOG_DIR = "bags"     # run --log without a value: bags/<scene>_<time>.mcap
DEFAULT_PLOT_DIR = "plots"   # plot / view without --out: plots/<log name>/
DEMO_SCHEDULE = "prism3_demo.yaml"  # the main job's (run without a scene): tensegrity_sim/schedules/


@dataclass
class RunSummary:
    """What ``run`` prints at the end."""

    scene: str
    method: str
    method_reason: str
    dt: float
    steps: int
    sim_time: float
    wall_time: float
    max_tension: float = 0.0
    max_tension_cable: str = ""
    switches: int = 0
    contacts: int = 0
    contact_begins: int = 0
    contact_pairs: int = 0
    energy_start: float = 0.0
    energy_end: float = 0.0
    commanded: bool = False  # commands did work: the energy change is not a drift
    energy_lost: float = 0.0  # J: what the model removed at its events (massive cables' plates), not a drift
    compile_time: float = 0.0  # s getting the kernels ready (compiling or loading them), not in wall_time
    compiled: bool = False     # numba compiled some (the cache had none): a first run
    extra: dict = field(default_factory=dict)

    def lines(self) -> list[str]:
        rate = self.steps / self.wall_time if self.wall_time > 0 else float("inf")
        drift = self.energy_end + self.energy_lost - self.energy_start
        scale = max(abs(self.energy_start), 1e-300)
        out = [
            f"scene            {self.scene}",
            f"method           {self.method} ({self.method_reason})",
            f"dt               {self.dt:g} s",
            f"simulated        {self.sim_time:.6g} s in {self.steps} steps",
            f"wall time        {self.wall_time:.3f} s ({rate:,.0f} steps/s, real-time factor "
            f"{self.sim_time / self.wall_time if self.wall_time > 0 else float('inf'):.1f})",
            "kernels          " + (f"compiling kernels (first run only): {self.compile_time:.1f} s" if self.compiled
                                    else f"loaded from the cache in {self.compile_time:.2f} s"),
            f"max tension      {self.max_tension:.6g} N ({self.max_tension_cable or '-'})",
            f"slack/taut       {self.switches} switches",
            f"contacts         {self.contacts} events ({self.contact_begins} begin, "
            f"{self.contacts - self.contact_begins} end) between {self.contact_pairs} member pairs",
            f"energy           {self.energy_start:.9g} J -> {self.energy_end:.9g} J "
            + (f"(change {drift:+.3e} J, the commands' work included)" if self.commanded else
               f"(drift {drift:+.3e} J, {drift / scale:+.3e} relative)")
            + (f" after the cable plates' losses of {self.energy_lost:.6g} J" if self.energy_lost else ""),
        ]
        out += [f"{k:<16} {v}" for k, v in self.extra.items()]
        return out


def simulate(sim: Simulator, steps: int, commands: CommandSchedule | None = None, *,
             progress: bool = False, on_step=None, driver=None, clock: CompileClock | None = None) -> RunSummary:
    """Run ``steps`` steps applying ``commands`` before each step; return the summary.

    ``on_step(result)`` sees every step. ``driver``, if given, takes the commands and does the steps
    instead of ``sim`` (same ``set_rest_lengths``/``set_external_forces``/``step``): the node logic's
    :class:`~tensegrity_sim.ros.offline.CommandDriver`, which logs them. ``clock``, if given, is the
    :class:`CompileClock` entered since ``sim`` was made: the summary's ``compile_time`` is what it counted,
    and the time of kernels compiled (or loaded) while stepping is taken out of the ``wall_time``.
    """
    target = sim if driver is None else driver
    base_rest, start_forces = sim.rest_lengths, sim.external_forces
    energy_start, lost_start = sim.energy()["total"], sim.energy_lost
    max_t, max_cable = 0.0, -1
    switches = 0
    contacts, begins, pairs = 0, 0, set()
    slack_prev = sim.slack()
    bar = tqdm(total=steps, unit="step", disable=not progress, mininterval=0.5)
    compile_before = clock.seconds if clock is not None else 0.0
    start = time.perf_counter()
    try:
        def take(traj) -> None:
            """The summary's figures of a chunk run in the method's compiled loop."""
            nonlocal max_t, max_cable, switches, contacts, begins, slack_prev
            if traj.tensions.size:
                peak = traj.tensions.max(axis=1)
                first = int(np.argmax(peak))   # the earliest step reaching the chunk's largest tension
                if peak[first] > max_t:
                    max_t, max_cable = float(peak[first]), int(np.argmax(traj.tensions[first]))
            switches += int(np.count_nonzero(np.diff(traj.slack, axis=0, prepend=slack_prev[None]) != 0))
            slack_prev = traj.slack[-1]
            contacts += len(traj.contacts)
            for event in traj.contacts:
                begins += event.kind == "begin"
                pairs.add(event.members)
            bar.update(len(traj.time))

        # nothing to do between steps but the commands: run in chunks (the method's compiled loop, where it
        # has one; with commands, where it evaluates them inside: Simulator.run)
        chunked = driver is None and on_step is None
        done = 0
        while done < steps:
            if chunked:
                traj = sim.run(steps=min(_CHUNK, steps - done), commands=commands)
                take(traj)
                done += len(traj.time)
                continue
            if commands is not None:
                commands.apply(target, sim.time, base_rest, start_forces)
            r = target.step()
            done += 1
            if r.tensions.size:
                k = int(np.argmax(r.tensions))
                if r.tensions[k] > max_t:
                    max_t, max_cable = float(r.tensions[k]), k
            switches += int(np.count_nonzero(r.slack != slack_prev))
            slack_prev = r.slack
            contacts += len(r.contacts)
            for event in r.contacts:
                begins += event.kind == "begin"
                pairs.add(event.members)
            if on_step is not None:
                on_step(r)
            bar.update()
    finally:
        bar.close()
    wall = time.perf_counter() - start
    compile_time = clock.seconds if clock is not None else 0.0
    wall -= compile_time - compile_before   # the kernels readied while stepping: not the stepping's speed
    return RunSummary(
        scene=sim.scene.name, method=sim.method, method_reason=sim.method_reason, dt=sim.dt,
        steps=steps, sim_time=sim.time, wall_time=wall, max_tension=max_t,
        max_tension_cable=sim.scene.cable_names[max_cable] if max_cable >= 0 else "",
        switches=switches, contacts=contacts, contact_begins=begins, contact_pairs=len(pairs),
        energy_start=energy_start,
        energy_end=sim.energy()["total"], energy_lost=sim.energy_lost - lost_start, compile_time=compile_time,
        compiled=clock is not None and clock.compiling > 0.0,
    )


def _cmd_run(args: argparse.Namespace) -> int:
    demo = args.scene is None  # the main job: the default scene with its schedule
    scene = load_scene(DEFAULT_SCENE if demo else args.scene)
    with CompileClock() as clock:   # from the simulator's making to the run's end: every kernel the run needs
        sim = Simulator(scene, method=args.method, dt=args.dt, contacts=args.contacts, solver=args.solver,
                        order=args.order)
        if demo and args.commands is None:
            with resources.as_file(resources.files("tensegrity_sim.schedules") / DEMO_SCHEDULE) as path:
                commands = load_commands(path, scene)
            args.commands = f"the built-in {DEMO_SCHEDULE} (tensegrity_sim/schedules/)"
        else:
            commands = load_commands(args.commands, scene) if args.commands else None
        if (args.plot or args.view) and args.log is None:
            args.log = DEFAULT_LOG_DIR  # the figures and the page are made from the log
        steps = int(round(args.duration / sim.dt))
        print(f"method: {sim.method_reason}")
        progress = steps >= PROGRESS_MIN_STEPS and not args.quiet
        if args.log is None:
            summary = simulate(sim, steps, commands, progress=progress, clock=clock)
        else:
            from .ros.offline import logged_run  # only logging needs mcap and rosbags

            with logged_run(sim, args.log) as driver:
                summary = simulate(sim, steps, commands, progress=progress, driver=driver, clock=clock)
            summary.extra["log"] = driver.path
    if args.commands:
        summary.extra["commands"] = args.commands
        summary.commanded = True
    if (args.plot or args.view) and driver.logic.publications == 0:
        summary.extra["plots"] = "none: the run ended before its first publication (there is nothing to draw)"
    else:
        if args.plot:
            summary.extra["plots"] = _write_plots(driver.path, _output(args.plot, driver.path, ""))
        if args.view:
            summary.extra["page"] = _write_page(driver.path, _output(args.view, driver.path, ".html"))
    print("\n".join(summary.lines()))
    return 0


def _output(spec: str, log: Path, suffix: str) -> Path:
    """Where ``plot`` (``suffix`` "") or ``view`` (".html") writes for ``log``: ``spec`` itself when it is
    a file name (ends with ``suffix``), else ``spec/<log name><suffix>``."""
    spec = Path(spec)
    return spec if suffix and spec.suffix == suffix else spec / (Path(log).stem + suffix)


def _write_plots(log: Path, out: Path) -> str:
    from .ros.record import read_log, with_energy
    from .viz.plots import plot_run

    paths = plot_run(with_energy(read_log(log)), out)
    return f"{out}/ ({', '.join(sorted({p.stem for p in paths}))}; png and svg)"


def _write_page(log: Path, out: Path) -> str:
    from .ros.record import read_log
    from .viz.page import write_page

    path, frames = write_page(read_log(log), out)
    return f"{path} ({frames} frames, {path.stat().st_size / 1e6:.1f} MB): open it in a browser"


def _cmd_plot(args: argparse.Namespace) -> int:
    if Path(args.source).suffix == ".parquet":
        import pyarrow.parquet as pq

        from .viz.plots import plot_sweep

        try:
            table = pq.read_table(args.source)
        except (OSError, ValueError) as exc:  # pyarrow's errors are both
            raise ValueError(f"{args.source}: cannot read the Parquet table: {exc}") from None
        out = Path(args.out or Path(DEFAULT_PLOT_DIR) / Path(args.source).stem)
        paths = plot_sweep(table, out, x=args.x, y=args.y, by=args.by)
        print("\n".join(f"wrote            {p}" for p in paths))
        return 0
    if args.x or args.by or args.y != "max_tension":
        raise ValueError("--x, --y and --by are for a sweep's Parquet table, not a log")
    out = Path(args.out) if args.out else _output(DEFAULT_PLOT_DIR, Path(args.source), "")
    print(f"plots            {_write_plots(Path(args.source), out)}")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    out = _output(args.out or DEFAULT_PLOT_DIR, Path(args.source), ".html")
    print(f"page             {_write_page(Path(args.source), out)}")
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from .ros.replay import replay

    report = replay(args.log)
    print("\n".join(report.lines()))
    return 0 if report.ok else 1


def _cmd_info(args: argparse.Namespace) -> int:
    from .ros.replay import log_info

    print("\n".join(log_info(args.log)))
    return 0


def _cmd_recover(args: argparse.Namespace) -> int:
    from .ros.log_reader import recover

    copied, unfinished = recover(args.log, args.out)
    print(f"recovered        {copied} messages from {args.log}"
          + (f" ({unfinished})" if unfinished else " (it was finished)"))
    print(f"written          {args.out} (finished: summary, statistics, rosbag2 metadata)")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    from .ros.interface import NodeSettings

    settings = NodeSettings(**{name: getattr(args, name) for name in NodeSettings().parameters})  # checks them
    if args.foxglove is not None:
        if args.transport != "auto" or args.interface is not None:
            raise ValueError("--foxglove streams to Foxglove's WebSocket server: --transport and --interface "
                             "are for the ROS 2 node")
        import logging

        from .ros.foxglove_node import serve_foxglove  # needs the "foxglove" extra (foxglove-sdk)

        logging.basicConfig(level=logging.INFO, format="[%(levelname)s] %(name)s: %(message)s")
        serve_foxglove(settings, port=args.foxglove, host=args.foxglove_host)
        return 0
    rclpy_found = importlib.util.find_spec("rclpy") is not None
    transport = ("rclpy" if rclpy_found else "dds") if args.transport == "auto" else args.transport
    if transport == "rclpy":
        if not rclpy_found:
            raise ValueError("--transport rclpy: rclpy does not import here (source ROS 2 Jazzy, or use "
                             "--transport dds)")
        if args.interface is not None:
            raise ValueError("--interface is for --transport dds (configure the ROS middleware instead)")
        from .ros import rclpy_node

        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
        # The node's parameters as ROS arguments; JSON is YAML, which ROS parses parameter values as.
        rclpy_node.main(["tensegrity-sim", "--ros-args", *[a for name, value in settings.parameters.items()
                                                            for a in ("-p", f"{name}:={json.dumps(value)}")]])
        return 0
    import logging

    from .ros.dds import DEFAULT_INTERFACE
    from .ros.dds_node import serve  # needs the "dds" extra (cyclonedds)

    logging.basicConfig(level=logging.INFO, format="[%(levelname)s] %(name)s: %(message)s")
    serve(settings, domain_id=args.domain_id, interface=args.interface or DEFAULT_INTERFACE)
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from .sweep import load_spec, run_sweep

    spec = load_spec(args.spec)
    summary = run_sweep(spec, args.out, address=args.address, workers=args.workers, progress=not args.quiet,
                        backend=args.backend)
    print("\n".join(summary.lines()))
    return 0


def _cmd_fit(args: argparse.Namespace) -> int:
    try:
        from .methods.jax.fit import LOSSES, spread_over_cores   # imports JAX (the jax extra)
    except ImportError as exc:   # a missing JAX: the message names the extra
        raise ValueError(str(exc)) from None
    spread_over_cores()   # the tangents on every core (this process's JAX, before it runs anything)
    from .ros.fit_log import fit_log, table

    if args.loss not in LOSSES:
        raise ValueError(f"--loss: one of {', '.join(LOSSES)}, got {args.loss!r}")
    out = Path(args.out) if args.out else Path(args.log).with_name(Path(args.log).stem + "_fit.yaml")
    plot = None if args.plot is None else Path(args.plot or Path(DEFAULT_PLOT_DIR) / (Path(args.log).stem + "_fit"))
    result = fit_log(args.log, args.params, scene=args.scene, window=args.window, loss=args.loss,
                     loss_scale=args.loss_scale, prior=args.prior, chord=args.chord, out=out, plot=plot)
    print(f"log              {args.log} ({len(result.grid_steps)} poses on a grid of {result.every} steps)")
    print("\n".join(table(result)))
    print(f"fitted scene     {out}")
    if plot is not None:
        print(f"figures          {plot}")
    return 0


def _cmd_import(args: argparse.Namespace) -> int:
    from .io import import_mjcf, import_ntrt   # io sits around the core; MuJoCo's parser only for MJCF

    source = Path(args.robot)
    if source.suffix.lower() == ".xml":
        if args.length_scale is not None:
            raise ValueError(f"--length-scale: applies to an NTRT YAML file, not to {source} (MJCF is in metres)")
        imported = import_mjcf(source)
    elif source.suffix.lower() in (".yaml", ".yml"):
        imported = import_ntrt(source, args.length_scale)
    else:
        raise ValueError(f"{source}: not a robot file this verb reads (ROBOT.xml: MJCF, ROBOT.yaml: NTRT)")
    out = Path(args.out)
    text = imported.header() + imported.scene.to_yaml()
    # written beside the target and renamed over it: never a half-written scene
    partial = out.with_name(f".{out.name}.partial")
    try:
        partial.write_text(text)
        os.replace(partial, out)
    finally:
        partial.unlink(missing_ok=True)
    scene = imported.scene
    print("\n".join(imported.notes))
    for actuator, cable in imported.actuators.items():
        print(f"actuator {actuator} drives cable {cable}")
    print(f"scene {scene.name}: {len(scene.nodes)} nodes, {len(scene.struts)} struts, {len(scene.cables)} cables"
          f"{', on the ground' if scene.ground is not None else ''} -> {out}")
    return 0


def _add_import(verbs) -> None:
    """``import``: a robot from MuJoCo's MJCF or NTRT's YAML as a scene YAML."""
    imp = verbs.add_parser(
        "import", help="a robot from MJCF (MuJoCo) or NTRT YAML as a scene YAML",
        description="Read ROBOT.xml (MJCF, through MuJoCo's parser: pip install \"tensegrity_sim[io]\") or "
                    "ROBOT.yaml (NTRT's YAML structure format) and write the scene. Prints how each element "
                    "was mapped and which cable each actuator drives (also written as comments at the top of "
                    "the scene); what cannot be mapped is refused, or dropped with a warning (docs/robots.md).")
    imp.add_argument("robot", metavar="ROBOT.xml|ROBOT.yaml", help="the robot file")
    imp.add_argument("--out", required=True, metavar="SCENE.yaml", help="the scene file to write")
    imp.add_argument("--length-scale", type=_positive_float, default=None, metavar="S",
                     help="NTRT: metres per file unit (default: 0.1, NTRT's decimetres)")
    imp.set_defaults(func=_cmd_import)


def _cmd_optimize_gait(args: argparse.Namespace) -> int:
    from .optimize.gait import GaitProblem, cma_search, gradient_search, schedule_yaml

    scene = load_scene(args.scene)
    index = {n: i for i, n in enumerate(scene.cable_names)}
    names = list(scene.cable_names) if args.cables is None else [n for n in args.cables.split(",") if n]
    for n in names:
        if n not in index:
            raise ValueError(f"--cables: unknown cable {n!r} (scene {scene.name!r} has {', '.join(index) or 'none'})")
    goal = np.asarray(args.goal, dtype=float)
    if not np.all(np.isfinite(goal)) or not np.any(goal):
        raise ValueError(f"--goal must be a horizontal direction (not zero, finite), got {args.goal}")
    problem = GaitProblem(scene, [index[n] for n in names], goal / np.linalg.norm(goal), args.duration, args.period,
                          args.knots)
    for name in ("generations", "population", "iterations"):
        if getattr(args, name) < (2 if name == "population" else 0):
            raise ValueError(f"--{name} must be >= {2 if name == 'population' else 0}, got {getattr(args, name)}")
    report = None if args.quiet else print
    gait, lines = None, []
    if args.search in ("cma", "both"):
        try:
            gait = cma_search(problem, generations=args.generations, population=args.population, seed=args.seed,
                              report=report)
        except ImportError as exc:   # a missing cma: the message names the extra
            raise ValueError(f"{exc} (pip install \"tensegrity_sim[learn]\")") from None
        lines.append(f"CMA-ES: {gait.distance:.4f} m in {args.duration:g} s ({args.generations} generations of "
                     f"{args.population})")
    if args.search in ("gradient", "both"):
        # from CMA-ES's best, or from every cable at 75 % (u = 0.5: the robot squats and stays put) nudged by 1 %
        # at random: the gradient there grows a roll (from random knots it starts mid-tumble, and stalls)
        rng = np.random.default_rng(args.seed)
        start = gait.u if gait is not None else np.clip(0.5 + 0.01 * rng.standard_normal((len(names), args.knots)),
                                                        0.0, 1.0)
        try:
            gait = gradient_search(problem, start, iterations=args.iterations, report=report)
        except ImportError as exc:
            raise ValueError(f"{exc} (pip install \"tensegrity_sim[jax]\")") from None
        lines.append(f"gradient: {gait.distance:.4f} m in {args.duration:g} s ({len(gait.history) - 1} steps uphill, "
                     f"at most {args.iterations})")
    comment = (f"tensegrity-sim optimize-gait {args.scene}: {gait.distance:.4f} m along ({goal[0]:g}, {goal[1]:g}) in "
               f"{args.duration:g} s; period {args.period:g} s, {args.knots} knots; search {args.search}\n"
               f"replay: tensegrity-sim run {args.scene} --commands {args.out} --duration {args.duration:g}")
    Path(args.out).write_text(schedule_yaml(problem, gait.u, comment))
    print("\n".join(lines + [f"gait             {args.out}"]))
    return 0


def _add_optimize_gait(verbs) -> None:
    """``optimize-gait``: a periodic rest-length schedule that rolls a scene farthest (CMA-ES, gradient)."""
    gait = verbs.add_parser(
        "optimize-gait", help="optimise a periodic cable schedule for distance rolled (needs the learn extra)",
        description="Search a periodic open-loop rest-length schedule of the actuated cables for the distance the "
                    "centre of mass rolls along --goal in --duration s: CMA-ES (every generation one batch run), "
                    "gradient ascent through the JAX run (the jax extra), or CMA-ES then the gradient. Writes a "
                    "command schedule that tensegrity-sim run --commands replays. Needs "
                    "pip install \"tensegrity_sim[learn]\".")
    gait.add_argument("scene", help="a built-in scene's name or a scene YAML with a ground")
    gait.add_argument("--out", required=True, metavar="GAIT.yaml", help="the command schedule to write")
    gait.add_argument("--search", choices=("cma", "gradient", "both"), default="cma",
                      help="CMA-ES, the gradient (from every knot at 0.5, nudged), or CMA-ES then the gradient "
                           "(default: cma)")
    gait.add_argument("--cables", help="comma-separated actuated cables (default: every cable)")
    gait.add_argument("--goal", nargs=2, type=float, default=(1.0, 0.0), metavar=("X", "Y"),
                      help="the horizontal direction to roll in (default: 1 0)")
    gait.add_argument("--duration", type=float, default=6.0, help="s of rolling the distance is measured over")
    gait.add_argument("--period", type=float, default=2.0, help="s, the gait's period (default 2)")
    gait.add_argument("--knots", type=int, default=4, help="rest lengths per cable and period (default 4)")
    gait.add_argument("--generations", type=int, default=20, help="CMA-ES generations (default 20)")
    gait.add_argument("--population", type=int, default=16, help="CMA-ES candidates per generation (default 16)")
    gait.add_argument("--iterations", type=int, default=10, help="gradient steps (default 10)")
    gait.add_argument("--seed", type=int, default=0, help="CMA-ES's seed and the gradient's random start")
    gait.add_argument("--quiet", action="store_true", help="no line per generation")
    gait.set_defaults(func=_cmd_optimize_gait)


def _add_fit(verbs) -> None:
    """``fit``: scene parameters from a logged run (the JAX backend's gradients)."""
    fit = verbs.add_parser(
        "fit", help="fit scene parameters to a logged run (needs the jax extra)",
        description="Fit scene parameters to a log's node_poses (a run of this project, or a real robot's motion "
                    "capture written in the same topic) by multiple shooting: the log cut into windows, each "
                    "restarted from its own fitted start state, every window one copy of a JAX batch, with the "
                    "commands the run received (cable_rest_lengths, external_wrench) replayed in each; least "
                    "squares with the exact Jacobian. Prints a table (start, fitted, standard deviation), the "
                    "residual before and after and the estimated pose noise; writes the fitted scene YAML. Needs "
                    "JAX: pip install \"tensegrity_sim[jax]\".")
    fit.add_argument("log", help="an MCAP log with node_poses and the embedded scene")
    fit.add_argument("--params", required=True,
                     help="comma-separated: stiffness (every cable's, one factor), damping (every cable's, one "
                          "value), stiffness:CABLE, damping:CABLE, stiffness:each, damping:each (one per cable), "
                          "mass (every mass, one factor), mass:NODE, mass:STRUT, friction, restitution (the "
                          "ground's), reel_speed (the motors', a log of the node with max_rest_length_rate > 0)")
    fit.add_argument("--scene", metavar="SCENE.yaml",
                     help="the nominal model to start from (the log's nodes and cables); default: the log's scene")
    fit.add_argument("--out", metavar="FILE.yaml", help="the fitted scene (default: <log>_fit.yaml beside the log)")
    fit.add_argument("--window", type=int, metavar="N",
                     help="pose intervals per window (default: chosen from the slack/taut switches in the poses)")
    fit.add_argument("--loss", default="linear",
                     help="least squares loss: linear (default), or robust: soft_l1, huber, cauchy, arctan")
    fit.add_argument("--loss-scale", type=float, default=3e-3, metavar="M",
                     help="a robust loss's residual scale, m (default 0.003): larger residuals count less")
    fit.add_argument("--prior", type=float, default=0.0, metavar="SD",
                     help="a prior on each parameter about the scene's value, its relative standard deviation "
                          "(default 0: none), in --loss-scale metres of residual per standard deviation")
    fit.add_argument("--chord", action="store_true",
                     help="reuse the start states' Jacobian between steps while they do what it predicts (it is "
                          "most of a Jacobian's cost; refreshed after a poor step)")
    fit.add_argument("--plot", nargs="?", const="", metavar="DIR",
                     help=f"write the before/after figures into DIR (default {DEFAULT_PLOT_DIR}/<log name>_fit)")
    fit.set_defaults(func=_cmd_fit)


def _add_sweep(verbs) -> None:
    """``sweep``: many runs of a scene with numbers changed, one Parquet row per run."""
    sweep = verbs.add_parser(
        "sweep", help="run a parameter sweep (grid or random designs) into a Parquet table",
        description="Run every combination of the spec's parameters (vary: a grid; samples/ranges: random "
                    "designs) and write one Parquet row per run. Runs of one structure are stepped together. "
                    "Embedded in this process by default; --workers for local processes; --address to submit "
                    "the groups as tasks to a Ray cluster (pip install -e \".[sweep]\"). The spec format is in "
                    "tensegrity_sim/sweep.py and docs/batches.md.")
    sweep.add_argument("spec", help="the sweep spec (YAML)")
    sweep.add_argument("--out", required=True, metavar="RESULTS.parquet", help="the Parquet file to write")
    sweep.add_argument("--address", metavar="HOST:PORT",
                       help="a Ray cluster's address (ray start --head prints it); default: run here")
    sweep.add_argument("--workers", type=int, default=1, help="local processes without --address (default: 1)")
    sweep.add_argument("--quiet", action="store_true", help="no progress bar")
    sweep.add_argument("--backend", choices=("numba", "jax"), default="numba",
                       help="where the elastic runs step: numba (default) or jax (pip install \"tensegrity_sim[jax]\"; "
                            "on whatever device JAX finds)")
    sweep.set_defaults(func=_cmd_sweep)


def _add_serve(verbs) -> None:
    """``serve``: its node parameters are NodeSettings' fields, with their defaults and descriptions."""
    from dataclasses import fields

    from .ros.interface import NodeSettings

    serve = verbs.add_parser(
        "serve", help="run the simulator live as the ROS 2 node (rclpy, or DDS without ROS)",
        description="Run the tensegrity_sim node live: rclpy where it imports, otherwise (or with --transport "
                    "dds) plain DDS that a ROS 2 Jazzy machine on the same domain and network sees as the node. "
                    "Stop with Ctrl-C (the log is finished).")
    serve.add_argument("scene", nargs="?", default=NodeSettings.scene,
                       help=f"a built-in scene name or a YAML file (default: {NodeSettings.scene})")
    for f in fields(NodeSettings):
        if f.name in ("scene", "node_name"):
            continue
        # NodeSettings validates the values (a bad one is a ValueError naming the parameter); a switch is a flag
        kind = {"action": "store_true"} if isinstance(f.default, bool) else {"type": type(f.default)}
        serve.add_argument("--" + f.name.replace("_", "-"), dest=f.name, default=f.default, **kind,
                           help=f"{f.metadata['doc']} (default: {f.default!r})")
    serve.add_argument("--transport", choices=("auto", "rclpy", "dds"), default="auto",
                       help="rclpy if it imports, else DDS (default: auto)")
    serve.add_argument("--domain-id", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0")),
                       help="DDS domain, ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID or 0)")
    serve.add_argument("--interface",
                       help="DDS transport: network interface name or address, or 'auto' (default: lo, this "
                            "host only; a ROS 2 machine elsewhere needs the interface towards it)")
    serve.add_argument("--foxglove", nargs="?", type=int, const=8765, metavar="PORT",
                       help="stream live to Foxglove through its WebSocket server instead (no ROS; extra "
                            "'foxglove'); PORT default 8765, 0 = any free port")
    serve.add_argument("--foxglove-host", default="127.0.0.1",
                       help="address the Foxglove server listens on (default: 127.0.0.1, this host only)")
    serve.set_defaults(func=_cmd_serve)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not np.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text!r}")
    return value


def _contact_kinds(text: str) -> list[str]:
    return [] if text == "none" else text.split(",")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tensegrity-sim",
                                     description="Tensegrity dynamics with slack and snapping cables.")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")

    run = verbs.add_parser("run", help="simulate a scene offline, as fast as possible",
                           description="Simulate a scene offline, as fast as possible, and print a summary.")
    run.add_argument("scene", nargs="?", default=None,
                     help=f"a built-in scene name or a YAML file; without it the main job: {DEFAULT_SCENE} with the "
                          f"schedule tensegrity_sim/schedules/{DEMO_SCHEDULE}, where cables slacken and snap "
                          f"(unless --commands is given)")
    run.add_argument("--method", default="auto", help="elastic | inextensible | massive | auto (default: auto)")
    run.add_argument("--solver", choices=sorted(SOLVERS), default=None,
                     help=f"QP backend of the inextensible method (default: daqp below {SPARSE_NODES} free "
                          f"nodes, sparse from there)")
    run.add_argument("--order", type=int, choices=(2, 4), default=None,
                     help="order of the elastic and massive methods (default: 2; 4 for small errors, docs/methods.md)")
    run.add_argument("--dt", type=_positive_float, default=1e-3, help="step, s (default: 0.001)")
    run.add_argument("--duration", type=_positive_float, default=10.0, help="simulated time, s (default: 10)")
    run.add_argument("--commands", help="a rest-length/force schedule (YAML; see tensegrity_sim.commands)")
    run.add_argument("--contacts", type=_contact_kinds, default=None, metavar="KINDS",
                     help="member pairs to check for contact, comma-separated (strut_strut, strut_cable, "
                          "cable_cable) or 'none' (default: the scene's contact: kinds)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    run.add_argument("--log", nargs="?", const=DEFAULT_LOG_DIR, metavar="FILE",
                     help="write an MCAP log (the node's topics): FILE.mcap, or a directory for a timestamped "
                          f"file; without a value {DEFAULT_LOG_DIR}/<scene>_<time>.mcap (give SCENE before it)")
    run.add_argument("--plot", nargs="?", const=DEFAULT_PLOT_DIR, metavar="DIR",
                     help="write figures of the run (tensions, impulses, energy, contacts; PNG and SVG) into "
                          f"DIR/<log name>/ (without a value {DEFAULT_PLOT_DIR}/<log name>/); implies --log")
    run.add_argument("--view", nargs="?", const=DEFAULT_PLOT_DIR, metavar="DIR|FILE.html",
                     help="write the run's animated 3-D page (one HTML file that opens offline) as FILE.html or "
                          f"DIR/<log name>.html (without a value {DEFAULT_PLOT_DIR}/<log name>.html); implies --log")
    run.set_defaults(func=_cmd_run)

    plot = verbs.add_parser("plot", help="figures of a log, or of a sweep's Parquet table",
                            description="Figures of a log (PNG and SVG): tension per cable with slack spans shaded "
                                        "and snaps marked, impulses, energy terms (recomputed by replaying the log), "
                                        "contacts on a time line. Of a sweep's Parquet table: a result column "
                                        "against a parameter column.")
    plot.add_argument("source", metavar="LOG|TABLE.parquet",
                      help="an MCAP log (run --log or the node) or a sweep's Parquet table")
    plot.add_argument("--out", metavar="DIR",
                      help=f"directory of the figures (default: {DEFAULT_PLOT_DIR}/<name of the log or table>)")
    plot.add_argument("--x", help="table: the parameter column (default: the first numeric column but --y)")
    plot.add_argument("--y", default="max_tension", help="table: the result column (default: max_tension)")
    plot.add_argument("--by", help="table: one line per value of this column")
    plot.set_defaults(func=_cmd_plot)

    view = verbs.add_parser("view", help="an animated 3-D page of a log (HTML, opens offline)",
                            description="Write one self-contained HTML page (no server, no network) with an "
                                        "animated 3-D view of a log: struts, cables coloured by tension, slack "
                                        "cables dashed, contacts; play/pause, speed and a time slider. "
                                        "PAGE.html#t=2.5 opens at 2.5 s.")
    view.add_argument("source", metavar="LOG", help="an MCAP log written by tensegrity-sim run --log or the node")
    view.add_argument("--out", metavar="FILE.html|DIR",
                      help=f"the page (default: {DEFAULT_PLOT_DIR}/<log name>.html)")
    view.set_defaults(func=_cmd_view)

    rep = verbs.add_parser("replay", help="re-simulate a log and check it bit for bit",
                           description="Re-simulate a log from the scene, settings and inputs stored in it and "
                                       "check that every logged state is reproduced bit for bit; on a mismatch, "
                                       "name the first step, topic and field that differ (exit status 1).")
    rep.add_argument("log", help="an MCAP log written by tensegrity-sim run --log or the node")
    rep.set_defaults(func=_cmd_replay)

    info = verbs.add_parser("info", help="summarise a log",
                            description="Summarise a log: scene, settings, duration, topics and message counts, "
                                        "slack/snap and contact statistics.")
    info.add_argument("log", help="an MCAP log written by tensegrity-sim run --log or the node")
    info.set_defaults(func=_cmd_info)

    rec = verbs.add_parser("recover", help="write a finished copy of a log cut off by a crash",
                           description="Copy every complete record of a log that its writer did not finish (killed, "
                                       "power cut, disk full) into a finished log (summary, statistics, rosbag2 "
                                       "metadata) that every MCAP reader opens; a corrupt record stops it (exit 2).")
    rec.add_argument("log", help="the unfinished MCAP log")
    rec.add_argument("out", help="the finished copy to write (.mcap)")
    rec.set_defaults(func=_cmd_recover)
    _add_serve(verbs)
    _add_sweep(verbs)
    _add_fit(verbs)
    _add_import(verbs)
    _add_optimize_gait(verbs)
    return parser


def _one_line(exc: BaseException) -> str:
    """An error's message on one line (a YAML error spans several); an OSError as ``file: reason``."""
    if isinstance(exc, OSError) and exc.strerror:  # (a LogWriteError has a whole message instead)
        text = f"{exc.filename}: {exc.strerror}" if exc.filename is not None else exc.strerror
    else:
        text = str(exc)
    return " ".join(text.split())


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)

    def one_line(message, category, filename, lineno, file=None, line=None):
        # a user needs what happened, not the source line that warned
        print(f"tensegrity-sim {args.verb}: warning: {message}", file=sys.stderr)

    try:
        with warnings.catch_warnings():
            warnings.showwarning = one_line
            return args.func(args)
    except (SceneError, CommandError, ValueError, StepError, OSError) as exc:  # OSError: files, LogWriteError
        print(f"tensegrity-sim {args.verb}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"tensegrity-sim {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
