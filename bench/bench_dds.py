"""``tensegrity-sim serve --transport dds`` live: command-to-effect latency and sustained step rate.

Run: ``python bench/bench_dds.py [--scene prism3] [--commands 200] [--step-rate 1000] [--publish-rate 100]``.

The server runs in its own process (over loopback, on a random domain) at ``--step-rate`` ticks/s with
``--publish-rate`` Hz publishing; this process is the controller. The scene gets one extra cable, ``probe``,
between two extra fixed nodes 1 m apart: its tension is ``k (1 m - L)`` from the first step its rest length
``L`` is in effect, with no dynamics in the way, so a state that reflects a command is unambiguous. The
controller sends ``--commands`` rest-length commands to ``probe``, alternately 0.95 m and 0.90 m, at random
moments 60-140 ms apart, and times each from the send until the first ``cable_states`` whose probe
tension is the commanded one (wall-clock ``time.monotonic`` on this host, one clock for both ends). Then
it stops the server and prints the server's own statistics: steps, the achieved real-time factor (so
the sustained step rate), overruns (ticks that ended more than one tick behind the schedule) and the
worst lag. Prints figures; never asserts a time.
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim.ros import messages as M
from tensegrity_sim.ros.dds import Participant

ROOT = Path(__file__).resolve().parents[1]
PROBE_STIFFNESS = 1000.0  # N/m


def rest_command(cable: str, length: float):
    return M.joint_state(M.header(0, ""), [cable], position=[length])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="prism3")
    parser.add_argument("--commands", type=int, default=200)
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--step-rate", type=float, default=1000.0)
    parser.add_argument("--publish-rate", type=float, default=100.0)
    parser.add_argument("--real-time-factor", type=float, default=1.0, help="0: step as fast as possible")
    parser.add_argument("--log", action="store_true", help="the server writes its MCAP log (to a temporary dir)")
    args = parser.parse_args()

    description = ts.load_scene(args.scene).to_dict()
    far = 10.0 + max(abs(c) for n in description["nodes"] for c in n["position"])  # out of everyone's way
    description["nodes"] += [{"name": "probe_a", "position": [far, 0.0, 0.0], "fixed": True},
                             {"name": "probe_b", "position": [far + 1.0, 0.0, 0.0], "fixed": True}]
    description["cables"] = description.get("cables", []) + [
        {"name": "probe", "nodes": ["probe_a", "probe_b"], "stiffness": PROBE_STIFFNESS, "rest_length": 0.95}]
    scene = ts.Scene.from_dict(description)
    workdir = tempfile.TemporaryDirectory()  # the scene file and the log, removed at the end
    scene_file = Path(workdir.name) / f"{args.scene}_probe.yaml"
    scene_file.write_text(scene.to_yaml())
    k = scene.cable_names.index("probe")
    domain = random.SystemRandom().randint(1, 200)
    command = [sys.executable, "-m", "tensegrity_sim.cli", "serve", str(scene_file), "--transport", "dds",
               "--domain-id", str(domain), "--log-path", str(scene_file.parent) if args.log else "", "--dt", str(args.dt), "--step-rate", str(args.step_rate),
               "--publish-rate", str(args.publish_rate), "--real-time-factor", str(args.real_time_factor)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    print("server:", " ".join(command[1:]), flush=True)
    server = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    latencies = []
    states_received = 0
    try:
        with Participant(domain_id=domain) as dds:
            states = dds.reader("/tensegrity_sim/cable_states", "sensor_msgs/msg/JointState")
            writer = dds.writer("/tensegrity_sim/cable_rest_lengths", "sensor_msgs/msg/JointState")
            while not (states.matched and writer.matched):
                if server.poll() is not None:
                    sys.exit(f"the server stopped: {server.stderr.read()}")
                time.sleep(0.01)
            dds.wait(5.0)
            started = time.monotonic()
            rng = np.random.default_rng()
            for i in range(args.commands):
                target = (0.90, 0.95)[i % 2]  # m; the scene starts at 0.95
                tension = PROBE_STIFFNESS * (1.0 - target)
                deadline = time.monotonic() + rng.uniform(0.06, 0.14)
                while time.monotonic() < deadline:  # keep the queue empty while waiting
                    states_received += len(states.take())
                    time.sleep(0.005)
                sent = time.monotonic()
                writer.write(rest_command("probe", target))
                while True:
                    dds.wait(1.0)
                    got = states.take_messages()[0]
                    now = time.monotonic()
                    states_received += len(got)
                    if any(abs(m.effort[k] - tension) < 1e-6 * tension for m in got):
                        latencies.append(now - sent)
                        break
                    if now - sent > 5.0:
                        sys.exit(f"command {i}: no effect within 5 s")
            elapsed = time.monotonic() - started
    finally:
        server.send_signal(signal.SIGINT)
        out, err = server.communicate(timeout=30)
        workdir.cleanup()
    stats = dict(line.split(None, 1) for line in out.splitlines() if line.strip())
    lat = np.array(latencies) * 1e3
    steps = int(stats["steps"])
    rtf = float(stats["real_time_factor_achieved"])
    print(f"scene {args.scene} + probe cable, {args.commands} commands, step rate {args.step_rate:g}/s, "
          f"publishing {args.publish_rate:g} Hz of simulated time, real-time factor {args.real_time_factor:g}, "
          f"log {'on' if args.log else 'off'}")
    print(f"command-to-effect latency: median {np.median(lat):.2f} ms, p95 {np.percentile(lat, 95):.2f} ms, "
          f"min {lat.min():.2f} ms, max {lat.max():.2f} ms (n = {lat.size})")
    print(f"cable_states received during the commands: {states_received / elapsed:.1f} /s")
    print(f"server: {steps} steps, real-time factor {rtf:.4f} -> {rtf / args.dt:.1f} steps/s sustained; "
          f"overruns {stats['overruns']}, max lag {stats['max_lag_ms']} ms, publications {stats['publications']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
