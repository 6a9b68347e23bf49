"""``tensegrity-sim serve --transport dds`` live: command-to-effect latency and sustained step rate.

Run: ``python bench/bench_dds.py [--scene prism3] [--commands 200] [--step-rate 1000] [--publish-rate 100]``.

The server runs in its own process (over loopback, on a random domain) at ``--step-rate`` ticks/s with
``--publish-rate`` Hz publishing; this process is the controller. It sends ``--commands`` rest-length
commands to one cable, alternately 0.97 L and 0.94 L of its scene rest length L, at random moments
60-140 ms apart; the scene's cables get ``--damping`` so that the structure settles between commands and
the cable stays taut (a slack cable's state shows no rest length at all), and times each from the send until the first ``cable_states`` that
reflects it: whose rest length implied by the published length, length rate and tension,
``l - (T - c dl/dt)/k`` (a taut damped cable's law), is the commanded one (within a quarter of the step between the two; the estimate's own error, half a step's
change of length, is far below that). Wall-clock ``time.monotonic`` on this host, one clock for both. Then it stops the server and prints the server's own statistics:
steps, the achieved real-time factor (so the step rate), overruns (ticks that ended more than one tick
behind the schedule) and the worst lag. Prints figures; never asserts a time.
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
from tensegrity_sim.ros.dds import Participant
from tensegrity_sim.ros.messages import TYPESTORE

ROOT = Path(__file__).resolve().parents[1]
T = TYPESTORE.types


def rest_command(cable: str, length: float):
    h = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="")
    return T["sensor_msgs/msg/JointState"](header=h, name=[cable], position=np.array([length]),
                                           velocity=np.array([]), effort=np.array([]))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="prism3")
    parser.add_argument("--cable", default=None, help="the cable to command (default: the scene's first)")
    parser.add_argument("--commands", type=int, default=200)
    parser.add_argument("--damping", type=float, default=30.0, help="cable damping, N s/m (default: 30)")
    parser.add_argument("--dt", type=float, default=1e-3)
    parser.add_argument("--step-rate", type=float, default=1000.0)
    parser.add_argument("--publish-rate", type=float, default=100.0)
    args = parser.parse_args()

    description = ts.load_scene(args.scene).to_dict()
    for c in description["cables"]:
        c["damping"] = args.damping
    scene = ts.Scene.from_dict(description)
    scene_file = Path(tempfile.mkdtemp()) / f"{args.scene}_damped.yaml"
    scene_file.write_text(scene.to_yaml())
    cable = args.cable or scene.cable_names[0]
    k = scene.cable_names.index(cable)
    rest = scene.cables[k].rest_length
    domain = random.SystemRandom().randint(1, 200)
    command = [sys.executable, "-m", "tensegrity_sim.cli", "serve", str(scene_file), "--transport", "dds",
               "--domain-id", str(domain), "--log-path", "", "--dt", str(args.dt), "--step-rate", str(args.step_rate),
               "--publish-rate", str(args.publish_rate)]
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
            stiffness = scene.cables[k].stiffness
            targets = (0.97 * rest, 0.94 * rest)
            tolerance = 0.25 * abs(targets[0] - targets[1])
            for i in range(args.commands):
                target = targets[i % 2]
                deadline = time.monotonic() + rng.uniform(0.06, 0.14)
                while time.monotonic() < deadline:  # keep the queue empty while waiting
                    states_received += len(states.take())
                    time.sleep(0.005)
                sent = time.monotonic()
                writer.write(rest_command(cable, target))
                while True:
                    dds.wait(1.0)
                    got = states.take_messages()[0]
                    now = time.monotonic()
                    states_received += len(got)
                    implied = [m.position[k] - (m.effort[k] - args.damping * m.velocity[k]) / stiffness
                               for m in got if m.effort[k] > 0]
                    if any(abs(r - target) < tolerance for r in implied):
                        latencies.append(now - sent)
                        break
                    if now - sent > 5.0:
                        sys.exit(f"command {i}: no effect within 5 s")
            elapsed = time.monotonic() - started
    finally:
        server.send_signal(signal.SIGINT)
        out, err = server.communicate(timeout=30)
    stats = dict(line.split(None, 1) for line in out.splitlines() if line.strip())
    lat = np.array(latencies) * 1e3
    steps = int(stats["steps"])
    rtf = float(stats["real_time_factor_achieved"])
    print(f"scene {args.scene} (cable damping {args.damping:g} N s/m), cable {cable}, {args.commands} commands, step rate {args.step_rate:g}/s, "
          f"publishing {args.publish_rate:g} Hz")
    print(f"command-to-effect latency: median {np.median(lat):.2f} ms, p95 {np.percentile(lat, 95):.2f} ms, "
          f"min {lat.min():.2f} ms, max {lat.max():.2f} ms (n = {lat.size})")
    print(f"cable_states received during the commands: {states_received / elapsed:.1f} /s")
    print(f"server: {steps} steps, real-time factor {rtf:.4f} -> {rtf / args.dt:.1f} steps/s sustained; "
          f"overruns {stats['overruns']}, max lag {stats['max_lag_ms']} ms, publications {stats['publications']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
