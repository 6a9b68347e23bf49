"""README's speed table, generated from the benchmarks' CSV files (never typed by hand).

    python3 scripts/readme_table.py           # rewrite the table in README.md from bench/results/
    python3 scripts/readme_table.py --check   # exit 1 when README.md and the CSV files disagree (CI runs this)

The table sits between the markers ``<!-- speed table -->`` and ``<!-- end speed table -->``. Its rows:
the thrown icosahedron's CPU time per step beside MuJoCo's, without and with member contact detection
(``bench/results/head_to_head.csv``, written by ``bench/head_to_head.py``); ``icosahedron_ground`` resting and
rolling beside MuJoCo with its ground contact (``bench/results/ground.csv``, ``bench/bench_ground.py``); and a
batch's scene-steps per second beside ``mujoco.rollout``, both keeping every step's state
(``bench/results/batch.csv``, ``bench/bench_batch.py``); the massive method beside MuJoCo's spring tendons
(``bench/results/massive_speed.csv``, ``bench/massive.py``); the ``Roll-v0`` vector environment beside
Gymnasium's MuJoCo environment (``bench/results/envs.csv``, ``bench/bench_envs.py``). Below it, the real-time
figures: the command line's rolling run (``ground.csv``) and the live node's ticks
(``bench/results/node_tick.csv`` and ``node_in_process.csv``, ``bench/bench_node.py``), and the throw
benchmark's reliability line
(``bench/results/throws.csv``, ``bench/bench_throws.py``). Each CSV's command,
commit and machine are in its ``.json`` sidecar and on the site's benchmarks page.
"""
from __future__ import annotations

import argparse
import difflib
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.tables import RESULTS, cell, provenance, read_csv, select  # noqa: E402

README = ROOT / "README.md"
BEGIN, END = "<!-- speed table -->", "<!-- end speed table -->"


def _one(rows: list[dict], **where) -> dict:
    found = select(rows, where)
    if len(found) != 1:
        raise SystemExit(f"readme_table: {len(found)} rows match {where}, not one")
    return found[0]


def table() -> str:
    """The Markdown table (with its source line) that README shows between the markers."""
    steps = read_csv(RESULTS / "head_to_head.csv")
    ground = read_csv(RESULTS / "ground.csv")
    batches = read_csv(RESULTS / "batch.csv")
    lines = ["| icosahedron, dt = 1 ms | tensegrity_sim | MuJoCo | MuJoCo's time / ours |",
             "| --- | --- | --- | --- |"]
    for method in ("elastic", "inextensible"):
        for call, peer in (("run()", "mj_step(nstep)"), ("step()", "mj_step() loop")):
            row = _one(steps, method=method, ours=f"tensegrity_sim {call}", peer=f"MuJoCo {peer}")
            lines.append(f"| {method}, `{call}` | {cell(row['ours_us'])} µs/step | {cell(row['peer_us'])} µs/step "
                         f"(`{peer.split()[0]}`, {row['peer_model']}) | **{cell(row['ratio'])}** |")
        row = _one(steps, method=method, ours="tensegrity_sim run(), strut-strut detection",
                   peer="MuJoCo mj_step(nstep), strut capsule contacts")
        lines.append(f"| {method}, `run()`, strut-strut detection | {cell(row['ours_us'])} µs/step | "
                     f"{cell(row['peer_us'])} µs/step (capsule contacts) | **{cell(row['ratio'])}** |")
    for case, contender, label, suffix in (
            ("resting", "elastic run", "elastic, resting on the ground, `run()`", ""),
            ("rolling", "elastic run", "elastic, rolling (`examples/roll.yaml`), `run(commands=...)`",
             ", commands in stretches"),
            ("rolling", "elastic step", "elastic, rolling, `step()`", ""),
            ("rolling", "elastic, as run --commands", "elastic, rolling, as `run --commands`",
             ", commands in stretches"),
            ("resting", "inextensible run", "inextensible, resting on the ground, `run()`", ""),
            ("resting", "inextensible step", "inextensible, resting on the ground, `step()`", ""),
            ("rolling", "inextensible run", "inextensible, rolling, `run(commands=...)`", "")):
        row = _one(ground, case=case, contender=contender)
        peer = _one(ground, case=case, contender=f"mujoco {row['cables']} {row['mujoco_integrator']}{suffix}")
        lines.append(f"| {label} | {cell(row['steps_per_s'])} steps/s | {cell(peer['steps_per_s'])} steps/s "
                     f"(ground contact, {row['mujoco_integrator']}) | **{cell(row['ratio_to_mujoco'])}** |")
    for case, label in (("icosahedron_thrown elastic", "elastic, batch of {:,}"),
                        ("icosahedron_thrown inextensible", "inextensible, batch of {:,}"),
                        ("icosahedron_ground resting inextensible", "inextensible, batch of {:,} resting on the ground"),
                        ("icosahedron_ground rolling elastic", "elastic, batch of {:,} rolling on the ground")):
        ours = _one(batches, case=case, contender="BatchSimulator")
        peer = _one(batches, case=case, contender="mujoco rollout")
        lines.append(f"| {label.format(ours['batch'])}, every step kept | {cell(ours['scene_steps_per_s'])} "
                     f"scene-steps/s | {cell(peer['scene_steps_per_s'])} scene-steps/s (`rollout`, "
                     f"{peer['threads']} threads, every step kept) | **{cell(ours['ratio_to_mujoco'])}** |")
    massive = {row["run"]: row for row in read_csv(RESULTS / "massive_speed.csv")}
    ours, peer = massive["massive run() (compiled)"], massive["MuJoCo mj_step(nstep) (spring tendons)"]
    lines.append(f"| massive (cables of 0.05 kg, elastic struts), `run()` | {cell(ours['us_per_step'])} µs/step | "
                 f"{cell(peer['us_per_step'])} µs/step (`mj_step(nstep)`, spring tendons: massless cables) | "
                 f"**{cell(float(peer['us_per_step']) / float(ours['us_per_step']))}** |")
    envs = {row["contender"]: row for row in read_csv(RESULTS / "envs.csv")}
    ours, peer, sync = envs["vector"], envs["mujoco"], envs["mujoco_sync"]
    lines.append(f"| `Roll-v0` (20 ms periods), vector environment of {int(ours['copies']):,} | "
                 f"{cell(ours['env_steps_per_s'])} env-steps/s | {cell(peer['env_steps_per_s'])} env-steps/s "
                 f"(Gymnasium `MujocoEnv`, one by one; its `SyncVectorEnv`: {cell(sync['env_steps_per_s'])}) | "
                 f"**{cell(peer['ratio'])}** |")
    lines += ["", *real_time(ground), "", reliability(read_csv(RESULTS / "throws.csv"))]
    commits = ", ".join(f"`{name}` at {provenance(RESULTS / name)['commit']}"
                        for name in ("head_to_head.csv", "ground.csv", "batch.csv", "massive_speed.csv",
                                     "envs.csv", "throws.csv", "node_tick.csv", "node_in_process.csv"))
    lines += ["", f"Generated from {commits} by `scripts/readme_table.py`; commands and machines: "
                  "[benchmarks](docs/benchmarks.md)."]
    return "\n".join(lines)


def real_time(ground: list[dict]) -> list[str]:
    """The robot on the ground in real time: the command line's real-time factor (``ground.csv``) and the live
    node's ticks (``node_tick.csv``, ``node_in_process.csv``, ``bench/bench_node.py``)."""
    command = "run icosahedron_ground --commands examples/roll.yaml --duration 10 --method elastic"
    rtf = _one(ground, case=command, contender="command line")["real_time_factor"]
    node = {row["scheduler"]: row for row in read_csv(RESULTS / "node_tick.csv")}
    default, fifo = node["default"], next(row for name, row in node.items() if name != "default")
    alone = read_csv(RESULTS / "node_in_process.csv")[0]
    owed = int(alone["catch_up_ticks"])
    return [f"Real time: `tensegrity-sim {command}` runs at **{cell(rtf)}×** real time (as it reports). The "
            f"node (`serve icosahedron_ground --transport dds` driven by `examples/roll_controller.py`, 1 kHz, log "
            f"on, {cell(default['duration_s'])} s) ticks in **{cell(default['tick_p999_ms'])} ms** at p99.9 on the "
            f"default scheduler, **{cell(fifo['tick_p999_ms'])} ms** on {fifo['scheduler']}, never more than "
            f"{max(int(default['max_steps_per_tick']), int(fifo['max_steps_per_tick']))} steps a tick: of its "
            f"{cell(default['burst_ticks'])} and {cell(fifo['burst_ticks'])} ticks of two steps, "
            f"{cell(default['late_wakeups'])} and {cell(fifo['late_wakeups'])} came after the machine woke it over a "
            f"period late, and its own work alone (`--in-process`) owes a second step "
            f"{'once' if owed == 1 else f'{owed} times'} in {cell(alone['turns'])} ticks."]


def reliability(throws: list[dict]) -> str:
    """The throw benchmark's line (``throws.csv``, ``bench/bench_throws.py``): runs stopped, answers checked."""
    total = _one(throws, method="all")
    return (f"Reliability: of {cell(total['throws'])} random throws onto the ground (`bench/bench_throws.py`, "
            f"seed {total['seed']}, throws {total['throw_range'].replace(';', ', ')}, space `{total['space']}`: both "
            f"methods, five robots, batches, friction 0–2, restitution 0–1, spins, commands mid-run) "
            f"**{cell(total['stopped'])} stopped**, and {cell(total['violations'])} of {cell(total['answers_checked'])} "
            f"checked contact answers missed Coulomb's law or the cable complementarity by more than 1e-5 of the "
            f"momentum in play; {cell(total['unsound'])} broke the sink (0.1 mm) or energy checks and "
            f"{cell(total['cut'])} were cut by the time budget per throw (`--budget`).")


def render(readme: str) -> str:
    """``readme`` with the text between the markers replaced by the current table."""
    head, found, rest = readme.partition(BEGIN)
    body, found_end, tail = rest.partition(END)
    if not found or not found_end:
        raise SystemExit(f"readme_table: README.md lacks the markers {BEGIN} ... {END}")
    return f"{head}{BEGIN}\n{table()}\n{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if README.md's table differs from the CSVs")
    args = parser.parse_args(argv)
    current = README.read_text()
    wanted = render(current)
    if wanted == current:
        return 0
    if args.check:
        sys.stderr.writelines(difflib.unified_diff(current.splitlines(True), wanted.splitlines(True),
                                                   "README.md", "from bench/results"))
        print("README.md's speed table disagrees with bench/results/: run python3 scripts/readme_table.py",
              file=sys.stderr)
        return 1
    README.write_text(wanted)
    print("rewrote the speed table in README.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
