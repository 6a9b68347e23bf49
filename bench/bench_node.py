"""The live node holding 1 kHz while a robot rolls: ``tensegrity-sim serve icosahedron_ground --transport dds``
with its MCAP log on, driven by ``examples/roll_controller.py`` (issue 28: tick p99.9 <= 1 ms over 60 s, no
catch-up burst).

Run: ``python3 bench/bench_node.py [--duration 60] [--scene icosahedron_ground] [--step-rate 1000]
[--thread-priorities 0,50] [--csv FILE]`` (default CSV: ``bench/results/node_tick.csv``): one run per
``thread_priority`` in turn, 0 the default scheduler, 50 ``SCHED_FIFO`` (the server says if the OS refused it).
``--in-process``: the node's own work alone (:func:`in_process`; default CSV ``bench/results/node_in_process.csv``),
what the live runs' catch-up ticks are held to.

The server runs in its own process over loopback on a random domain, logging to a temporary folder; the
roll controller runs in another, as a user runs it (``examples/roll_controller.py --domain-id D``), with
more cycles than ``--duration`` allows, so it is still rolling when both are stopped with SIGINT (the server
then finishes its log and prints its statistics). The figures are the server's own (``SimNodeLogic``'s
statistics, over its whole run): steps, the achieved real-time factor, overruns and the worst lag, the
wall-clock duration of its ticks (p50, p99, p99.9, max), the most steps a tick ran and the ticks that ran
more than their nominal share (catch-up bursts), those of them the node's own work caused (over a tick period
of the stepping thread's CPU time before them, ``own_burst_ticks``: the others the machine's; a virtual
machine counts its host's pauses as the running thread's CPU time, so some of these are the machine's too:
``bench/bench_wakeups.py`` counts them on a thread that never sleeps), beside the
wake-ups that came over a tick period late (the operating system's, each owing a tick a step more); and the
work done between ticks, in the loop's idle time (the markers and contact events of the publications,
``idle_send_*``, and the steps up to the next publication, ``idle_look_aheads``). Whether the robot rolled:
the command cycles the controller started and how far the centre of mass moved horizontally between the first
and the last ``node_poses`` of the log. The load average (1 min) before and after goes beside them (other work on the
machine takes the node's CPU). Prints figures; never asserts a time.
"""
from __future__ import annotations

import argparse
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

from bench.tables import RESULTS, ROOT, write_csv  # noqa: E402
from tensegrity_sim.ros import messages as M  # noqa: E402
from tensegrity_sim.ros.log_reader import LogReader  # noqa: E402

CONTROLLER = ROOT / "examples" / "roll_controller.py"
STOP_TIMEOUT = 60.0  # s for a stopped process to finish (the server finishes its log)


def start_server(args, priority: int, domain: int, log_dir: str, env: dict) -> tuple[subprocess.Popen, list[str]]:
    """The server, and the lines of its stderr (read by a thread, so that a chatty server never blocks on a
    full pipe); returns once it says it is serving."""
    command = [sys.executable, "-m", "tensegrity_sim.cli", "serve", args.scene, "--transport", "dds",
               "--domain-id", str(domain), "--log-path", log_dir, "--dt", str(args.dt),
               "--step-rate", str(args.step_rate), "--publish-rate", str(args.publish_rate),
               "--thread-priority", str(priority)]
    print("server:", " ".join(command[1:]), flush=True)
    server = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    lines: list[str] = []
    serving = threading.Event()

    def drain():
        for line in server.stderr:
            lines.append(line)
            if "serving" in line:
                serving.set()
        serving.set()   # it ended without serving: main() reports it

    threading.Thread(target=drain, daemon=True).start()
    serving.wait()
    if server.poll() is not None:
        sys.exit(f"the server stopped before serving:\n{''.join(lines)}")
    return server, lines


def stop(process: subprocess.Popen) -> str:
    """SIGINT, then its stdout once it has ended."""
    process.send_signal(signal.SIGINT)
    out, _ = process.communicate(timeout=STOP_TIMEOUT)
    return out


def read_log(path: str) -> tuple[float, float, list[dict[str, str]]]:
    """From the log at ``path``: the horizontal distance (m) between the mean node position of the first and
    of the last ``node_poses`` (the centre of mass of the built-in robots, whose nodes have equal masses), the
    simulated time (s) between them, and the values of every periodic ``/diagnostics`` report (1 Hz of
    wall-clock time: the node's statistics so far), in order."""
    first = last = None
    reports = []
    with LogReader(path) as reader:
        for m in reader.messages():
            if m.topic.endswith("/node_poses"):
                last = m
                first = first or m
            elif m.topic == "/diagnostics":
                status = M.deserialize(m.data, "diagnostic_msgs/msg/DiagnosticArray").status[0]
                if status.values:   # a failed step's report has none
                    reports.append({kv.key: kv.value for kv in status.values})

    def position(message) -> np.ndarray:
        poses = M.deserialize(message.data, "geometry_msgs/msg/PoseArray").poses
        return np.array([[p.position.x, p.position.y] for p in poses]).mean(axis=0)

    return (float(np.linalg.norm(position(last) - position(first))), 1e-9 * (last.log_time - first.log_time),
            reports)


def after_start(reports: list[dict[str, str]], stats: dict[str, str]) -> dict[str, int]:
    """The ticks, overruns, catch-up bursts and late wake-ups after the node's first diagnostics report (1 s into its
    run): the final counts less that report's, so the start (kernels loaded from the cache, the first
    messages serialised) is left out; -1 if there was no report."""
    first = reports[0] if reports else None
    return {f"{k}_after_1s": int(stats[k]) - int(first[k]) if first else -1
            for k in ("ticks", "overruns", "burst_ticks", "own_burst_ticks", "late_wakeups")}


def run(args, priority: int) -> dict:
    """One run of the server at ``thread_priority`` ``priority`` driven by the controller: its CSV row,
    printed."""
    domain = random.SystemRandom().randint(1, 200)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as log_dir:
        server, server_err = start_server(args, priority, domain, log_dir, env)
        controller = None
        try:
            cycles = int(args.duration / 2.0) + 10   # a cycle takes about 3 s: still rolling when stopped
            controller = subprocess.Popen(
                [sys.executable, str(CONTROLLER), "--domain-id", str(domain), "--scene", args.scene,
                 "--cycles", str(cycles)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
            time.sleep(args.duration)
            if controller.poll() is not None:
                sys.exit(f"the controller stopped early:\n{controller.communicate()[0]}")
        finally:
            controller_out = stop(controller) if controller is not None else ""
            server_out = stop(server)
        load_after = os.getloadavg()[0]
        stats = dict(line.split(None, 1) for line in server_out.splitlines() if len(line.split(None, 1)) == 2)
        if "steps" not in stats or "log" not in stats:
            sys.exit(f"no summary from the server:\n{server_out}{''.join(server_err)}")
        travel, simulated, reports = read_log(stats["log"])
    err = "".join(server_err)
    method = re.search(r"serving \S+ \((\w+),", err).group(1)
    policy = "default" if priority == 0 or "refused SCHED_FIFO" in err else f"SCHED_FIFO {priority}"
    started = [int(n) for n in re.findall(r"^cycle (\d+):", controller_out, flags=re.MULTILINE)]
    ints = ("steps", "overruns", "ticks", "max_steps_per_tick", "burst_ticks", "own_burst_ticks", "late_wakeups",
            "idle_sends", "idle_look_aheads", "failed_steps", "refused_rest_lengths")
    floats = ("real_time_factor_achieved", "max_lag_ms", "tick_p50_ms", "tick_p99_ms", "tick_p999_ms", "tick_max_ms",
              "max_wakeup_delay_ms", "idle_send_p999_ms", "idle_send_max_ms")
    row = {"scene": args.scene, "method": method, "thread_priority": priority, "scheduler": policy,
           "duration_s": args.duration, "step_rate_hz": args.step_rate,
           "dt_s": args.dt, "publish_rate_hz": args.publish_rate, "log": "on",
           **{k: int(stats[k]) for k in ints}, **{k: float(stats[k]) for k in floats}, **after_start(reports, stats),
           "cycles_started": max(started, default=-1) + 1, "com_travel_m": travel, "logged_s": simulated,
           "load_1min_before": load_before, "load_1min_after": load_after}
    print(f"{args.scene} ({method}), serve --transport dds at {args.step_rate:g} ticks/s, dt = {args.dt * 1e3:g} ms, "
          f"publishing {args.publish_rate:g} Hz, log on, stepping thread on the {policy} scheduler, driven by "
          f"examples/roll_controller.py for {args.duration:g} s; load average (1 min) {load_before:.2f} before, "
          f"{load_after:.2f} after")
    print(f"server: {row['steps']} steps in {row['ticks']} ticks, real-time factor {row['real_time_factor_achieved']}, "
          f"overruns {row['overruns']}, max lag {row['max_lag_ms']} ms, failed steps {row['failed_steps']}")
    print(f"tick: p50 {row['tick_p50_ms']} ms, p99 {row['tick_p99_ms']} ms, p99.9 {row['tick_p999_ms']} ms "
          f"(target <= 1 ms), max {row['tick_max_ms']} ms; most steps in a tick {row['max_steps_per_tick']}, "
          f"ticks over their nominal share (catch-up bursts) {row['burst_ticks']}, of which {row['own_burst_ticks']} "
          f"after over a period of the thread's CPU time (its own work, or a pause of the host counted as its CPU "
          f"time); the others the machine's")
    print(f"wake-ups over a tick period late (the OS: each owes the next tick a step) {row['late_wakeups']}, the "
          f"latest {row['max_wakeup_delay_ms']} ms")
    print(f"idle time: {row['idle_sends']} publications' markers and contact events sent between ticks, p99.9 "
          f"{row['idle_send_p999_ms']} ms, max {row['idle_send_max_ms']} ms; steps computed ahead "
          f"{row['idle_look_aheads']} times")
    print(f"after the first second (start-up left out): {row['ticks_after_1s']} ticks, {row['overruns_after_1s']} "
          f"overruns, {row['burst_ticks_after_1s']} catch-up bursts ({row['own_burst_ticks_after_1s']} after over a "
          f"period of CPU time), {row['late_wakeups_after_1s']} late wake-ups")
    print(f"robot: {row['cycles_started']} roll cycles started, centre of mass moved {travel:.3f} m over "
          f"{simulated:.1f} s of logged simulated time; {row['refused_rest_lengths']} commands refused", flush=True)
    return row


def in_process(args) -> dict:
    """The node's own work with nothing else on the machine's clock (``--in-process``): the same node (log on,
    outputs encoded for a raw transport, the idle work of ``live.spin``) turned in this process for
    ``--duration`` s of simulated time, the roll controller answering each publication, without sleeping or
    DDS. Each turn as the live loop's on a machine that never makes it wait, its CPU time standing for the
    clock: the tick (its step, and the publication if due), the idle work by the loop's own rule
    (``live.idle_work``: markers and contact events, the steps ahead, ``/diagnostics`` once a second of
    simulated time, waiting ``DIAGNOSTICS_WAIT`` at most, the log's write-out), then the controller's answer
    to the last publication, which arrives between ticks, taken as the live loop takes it
    (``live.take_between_ticks``: the step after it computed ahead if time is left). A turn that runs past the
    next tick's time makes that tick start late; a tick that starts a whole period late owes two steps: a
    catch-up tick the node's own work causes on a perfect machine (``catch_up_ticks``). Its row: those, and the
    CPU time (``time.thread_time``) of the turns' ticks and of whole turns, p50/p99/p99.9/max, with how many of
    each took over a tick period. The CPU clock is this machine's, which on a virtual machine counts the
    host's pauses as the running thread's time (``bench/bench_wakeups.py``): a turn of a few ms may be one."""
    import gc

    from tensegrity_sim import Simulator, load_scene
    from tensegrity_sim.ros.live import DIAGNOSTICS_WAIT, idle_work, take_between_ticks
    from tensegrity_sim.ros.log import LogRecorder, log_file_path
    from tensegrity_sim.ros.node_logic import NodeSettings, SimNodeLogic

    sys.path.insert(0, str(CONTROLLER.parent))
    import roll_controller as rc

    loaded = load_scene(args.scene)
    sim = Simulator(loaded, method="auto", dt=args.dt)
    poses = []
    settings = NodeSettings(scene=args.scene, dt=args.dt, step_rate=args.step_rate, publish_rate=args.publish_rate,
                            log_path="")
    logic = SimNodeLogic(sim, settings, transport=lambda key, data: poses.append(data) if key == "node_poses" else None,
                         raw_transport=True)
    controller = rc.RollController(rc.planner_for(loaded), dict(zip(loaded.cable_names, loaded.cable_rest_lengths)),
                                   (1.0, 0.0))
    turns = round(args.duration / args.dt)
    ticks, whole = np.empty(turns), np.empty(turns)
    with tempfile.TemporaryDirectory() as log_dir:
        with LogRecorder(log_file_path(log_dir, args.scene), logic.channels(), logic.run_info()) as recorder:
            logic.recorder = recorder
            logic.warm_up()
            gc.collect()
            gc.freeze()
            logic.idle_outputs = True
            command = diagnostics_due = None
            late, catch_up = 0.0, 0   # s the turn starts after its tick's time; ticks that owed two steps
            period = 1.0 / args.step_rate
            second, wait = round(1.0 / args.dt), round(DIAGNOSTICS_WAIT / args.dt)
            try:
                for k in range(turns):
                    start = time.thread_time()
                    if late >= period:   # this tick runs the step it owes beside its own
                        catch_up += 1
                        late -= period
                    logic._advance()
                    ticks[k] = time.thread_time() - start
                    if k % second == 0:
                        diagnostics_due = k
                    due = diagnostics_due is not None

                    def left():
                        return period - late - (time.thread_time() - start)

                    if idle_work(logic, left, period, due, due and k - diagnostics_due >= wait):
                        diagnostics_due = None
                    if command:
                        message = M.joint_state(M.header(0, ""), list(command), position=list(command.values()))
                        take_between_ticks(logic, lambda: logic.receive("cable_rest_lengths", message), left, period)
                        command = None
                    whole[k] = time.thread_time() - start
                    late = max(0.0, late + whole[k] - period)   # how late the next tick starts
                    if poses:   # the controller's answer, in the next turn (not timed: another process's work)
                        msg = M.deserialize(poses.pop(), "geometry_msgs/msg/PoseArray")
                        x = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses])
                        command = controller.update(sim.time, x)
            finally:
                gc.unfreeze()
    row = {"scene": args.scene, "method": sim.method, "turns": turns, "dt_s": args.dt,
           "publish_rate_hz": args.publish_rate, "log": "on", "cycles_started": controller.cycle + 1,
           "idle_look_aheads": logic.idle_look_aheads, "catch_up_ticks": catch_up}
    for name, cpu in (("tick", ticks), ("turn", whole)):
        for q, label in ((50, "p50"), (99, "p99"), (99.9, "p999")):
            row[f"{name}_cpu_{label}_ms"] = round(1e3 * float(np.percentile(cpu, q)), 3)
        row[f"{name}_cpu_max_ms"] = round(1e3 * float(cpu.max()), 3)
        row[f"{name}s_over_a_period"] = int((cpu > period).sum())
    print(f"{args.scene} ({sim.method}) in this process, {turns} turns of the live loop (log on, idle work, the roll "
          f"controller answering each publication: {row['cycles_started']} cycles started)")
    for name, what in (("tick", "tick"), ("turn", "whole turn (with the idle work and the input)")):
        print(f"{what}: CPU p50 {row[f'{name}_cpu_p50_ms']} ms, p99 {row[f'{name}_cpu_p99_ms']} ms, p99.9 "
              f"{row[f'{name}_cpu_p999_ms']} ms, max {row[f'{name}_cpu_max_ms']} ms; over a tick period: "
              f"{row[f'{name}s_over_a_period']}", flush=True)
    print(f"catch-up ticks (two steps owed) on a perfect machine: {catch_up}")
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="s of wall-clock time the controller drives")
    parser.add_argument("--scene", default="icosahedron_ground")
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--step-rate", type=float, default=1000.0)
    parser.add_argument("--publish-rate", type=float, default=100.0)
    parser.add_argument("--thread-priorities", type=lambda text: [int(p) for p in text.split(",")], default=[0, 50],
                        help="the server's thread_priority of each run, in turn (default: 0,50)")
    parser.add_argument("--in-process", action="store_true",
                        help="the node's own work alone: its loop turned in this process (default CSV: "
                             "bench/results/node_in_process.csv)")
    parser.add_argument("--csv", type=Path, default=None)
    args = parser.parse_args()
    if args.in_process:
        args.csv = args.csv or RESULTS / "node_in_process.csv"
        write_csv(args.csv, [in_process(args)])
    else:
        args.csv = args.csv or RESULTS / "node_tick.csv"
        write_csv(args.csv, [run(args, priority) for priority in args.thread_priorities])
    print(f"wrote {args.csv}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
