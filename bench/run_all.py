"""Every benchmark in one command: work-precision against references and MuJoCo, steps/s beside
MuJoCo, scale and real time, hard cases; CSV, PNG and a Markdown report in ``bench/results/``.

Run from the repository root: ``python3 bench/run_all.py`` (about half an hour on 2 cores) or
``python3 bench/run_all.py --quick`` (a sanity run of a few minutes: coarser step grids, fewer sizes,
shorter horizons; its figures are not the published ones). Needs the "bench" extra
(``pip install -e ".[bench]"``: matplotlib, mujoco); without mujoco the peer columns are left out.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # run as a script: this checkout first

from tqdm import tqdm  # noqa: E402

import tensegrity_sim as ts  # noqa: E402
from bench import hard_cases, report, scale, work_precision  # noqa: E402
from bench.cases import work_precision_cases  # noqa: E402
from bench.mujoco_peer import axial_inertia_effect  # noqa: E402
from bench.runners import (default_runners, mujoco_available, mujoco_runners, scale_runners,  # noqa: E402
                           tensegrity_runners)

RESULTS = Path(__file__).resolve().parent / "results"


def _peer_checks(cases) -> dict:
    """Modelling checks of the MuJoCo peer for the report: the axial-inertia artefact, and the identity
    of MuJoCo's Euler positions with the simulator's Verlet on point-mass scenes."""
    if not mujoco_available():
        return {}
    from bench.mujoco_peer import MujocoPeer
    by_name = {c.name: c for c in cases if "elastic" in c.models}
    ico, tower = by_name["icosahedron_thrown"], by_name["tower_kicked"]
    effect = axial_inertia_effect(ico.scene, ico.duration, 1e-3)
    sim = ts.Simulator(tower.scene, method="elastic", dt=1e-3)
    sim.run(duration=tower.duration)
    peer = MujocoPeer(tower.scene, dt=1e-3, integrator="Euler")
    peer.advance(int(round(tower.duration / 1e-3)))
    euler_gap = float(abs(sim.positions - peer.positions()).max())
    return {"axial_inertia": effect, "euler_verlet_gap_m": euler_gap}


@contextlib.contextmanager
def _quiet_stdout():
    """OSQP's C library prints to the process's stdout on every solve; the progress bar is on stderr."""
    sys.stdout.flush()
    saved, devnull = os.dup(1), os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    try:
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a fast sanity run (not the published figures)")
    parser.add_argument("--out", type=Path, default=RESULTS, help="output directory (default: bench/results)")
    args = parser.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    # expected and documented (physics.md §3): the inextensible method lengthens the prestressed cables'
    # limits by their stretch at load time, and says so for every simulator it makes
    warnings.simplefilter("ignore", ts.LengthOffsetWarning)
    start = time.time()
    with _quiet_stdout():
        report_kwargs = _run(args, out, start)
    report.write(out / "REPORT.md", **report_kwargs)
    print(f"wrote {out}/REPORT.md in {(time.time() - start) / 60:.1f} min")
    return 0


def _run(args, out: Path, start: float) -> dict:
    """Every study, writing its CSV and PNG files; returns what the report needs."""
    ours = tensegrity_runners()
    peers = mujoco_runners()
    cases = work_precision_cases()
    bar = tqdm(total=1, unit="run", dynamic_ncols=True)
    if mujoco_available():
        import mujoco
        # MuJoCo prints a warning when a run diverges; the sweep records it as "unstable" instead
        mujoco.set_mju_user_warning(lambda message: None)

    bar.set_description("references")
    keys = [(c, m) for c in cases for m in c.models]
    bar.reset(total=len(keys))
    references = {}
    for case, model in keys:
        bar.set_postfix_str(f"{case.name} {model}", refresh=False)
        references[(case.name, model)] = work_precision.reference_for(case, model, quick=args.quick)
        bar.update()

    bar.set_description("work-precision")
    bar.set_postfix_str("")
    rows = work_precision.sweep(cases, ours + peers, references, quick=args.quick,
                                repeats=2 if args.quick else 3, progress=bar)
    work_precision.write_csv(out / "work_precision.csv", rows, work_precision.FIELDS)
    for case in cases:
        for model in case.models:
            sub = [r for r in rows if r["case"] == case.name and r["model"] == model]
            if sub:
                work_precision.plot(case, model, sub, references[(case.name, model)], out / f"wp_{case.name}_{model}.png")
    work_precision.plot_halving(references, out / "reference_convergence.png")
    work_precision.write_csv(out / "references.csv", work_precision.reference_rows(references),
                             work_precision.REFERENCE_FIELDS)

    bar.set_description("steps/s")
    bar.set_postfix_str("")
    scenes = {name: ts.load_scene(name) for name in ts.builtin_scenes()}
    scenes.update({c.name: c.scene for c in cases if c.exact is None})
    throughput = scale.throughput_rows(scenes, scale_runners(), progress=bar)
    work_precision.write_csv(out / "throughput.csv", throughput, list(throughput[0]))

    bar.set_description("scale")
    bar.set_postfix_str("")
    size_rows = scale.scale_rows(scale_runners(), scale.STAGES_QUICK if args.quick else scale.STAGES_FULL,
                                 progress=bar)
    work_precision.write_csv(out / "scale.csv", size_rows, list(size_rows[0]))
    scale.plot_scale(size_rows, out / "scale.png")
    realtime = scale.realtime_rows(scale_runners())
    work_precision.write_csv(out / "realtime.csv", realtime, list(realtime[0]))

    bar.set_description("hard cases")
    bar.set_postfix_str("")
    hard = hard_cases.hard_case_rows(default_runners(), quick=args.quick, progress=bar)
    work_precision.write_csv(out / "hard_cases.csv", hard, list(hard[0]))

    bar.set_description("report")
    bar.set_postfix_str("")
    peer_checks = _peer_checks(cases)
    bar.close()
    return dict(quick=args.quick, elapsed_s=time.time() - start, cases=cases, references=references, rows=rows,
                throughput=throughput, size_rows=size_rows, realtime=realtime, hard=hard, peer_checks=peer_checks)


if __name__ == "__main__":
    raise SystemExit(main())
