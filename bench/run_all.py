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
import datetime
import json
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
from bench.runners import (mujoco_available, mujoco_runners, scale_runners,  # noqa: E402
                           tensegrity_runners)
from bench.tables import read_csv, write_csv  # noqa: E402

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
    return {"axial_inertia": {f"{k:g}": v for k, v in effect.items()}, "euler_verlet_gap_m": euler_gap}


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
    parser.add_argument("--report-only", action="store_true",
                        help="only rewrite REPORT.md from the CSV files and meta.json of a previous run")
    args = parser.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    if not args.report_only:
        # expected and documented (physics.md §3): the inextensible method lengthens the prestressed
        # cables' limits by their stretch at load time, and says so for every simulator it makes
        warnings.simplefilter("ignore", ts.LengthOffsetWarning)
        start = time.time()
        with _quiet_stdout():
            peer_checks = _run(args, out)
        meta = {"quick": args.quick, "date": datetime.date.today().isoformat(), "elapsed_s": time.time() - start,
                "machine": report.machine(), "peer_checks": peer_checks}
        (out / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
    _write_report(out)
    print(f"wrote {out / 'REPORT.md'}")
    return 0


def _write_report(out: Path) -> None:
    """REPORT.md from what the run wrote: the report shows exactly the published tables."""
    references = work_precision.references_from_rows(read_csv(out / "references.csv"))
    cases = [c for c in work_precision_cases() if any((c.name, m) in references for m in c.models)]
    report.write(out / "REPORT.md", meta=json.loads((out / "meta.json").read_text()), cases=cases,
                 references=references, rows=read_csv(out / "work_precision.csv"),
                 throughput=read_csv(out / "throughput.csv"), size_rows=read_csv(out / "scale.csv"),
                 realtime=read_csv(out / "realtime.csv"), hard=read_csv(out / "hard_cases.csv"))


def _run(args, out: Path) -> dict:
    """Every study, writing its CSV and PNG files; returns the MuJoCo modelling checks."""
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
        ref = work_precision.reference_for(case, model, quick=args.quick)
        if ref is not None:
            references[(case.name, model)] = ref
        bar.update()

    bar.set_description("work-precision")
    bar.set_postfix_str("")
    rows = work_precision.sweep(cases, ours + peers, references, quick=args.quick,
                                repeats=2 if args.quick else 3, progress=bar)
    write_csv(out / "work_precision.csv", rows, work_precision.FIELDS)
    for case in cases:
        for model in case.models:
            sub = [r for r in rows if r["case"] == case.name and r["model"] == model]
            if sub:
                work_precision.plot(case, model, sub, references[(case.name, model)], out / f"wp_{case.name}_{model}.png")
    work_precision.plot_halving(references, out / "reference_convergence.png")
    write_csv(out / "references.csv", work_precision.reference_rows(references), work_precision.REFERENCE_FIELDS)

    bar.set_description("steps/s")
    bar.set_postfix_str("")
    scenes = {name: ts.load_scene(name) for name in ts.builtin_scenes()}
    scenes.update({c.name: c.scene for c in cases if c.exact is None})
    write_csv(out / "throughput.csv", scale.throughput_rows(scenes, scale_runners(), progress=bar))

    bar.set_description("scale")
    bar.set_postfix_str("")
    size_rows = scale.scale_rows(scale_runners(), scale.STAGES_QUICK if args.quick else scale.STAGES_FULL,
                                 progress=bar)
    write_csv(out / "scale.csv", size_rows)
    scale.plot_scale(size_rows, out / "scale.png")
    write_csv(out / "realtime.csv", scale.realtime_rows(scale_runners()))

    bar.set_description("hard cases")
    bar.set_postfix_str("")
    write_csv(out / "hard_cases.csv", hard_cases.hard_case_rows(hard_cases.hard_case_runners(), quick=args.quick,
                                                                progress=bar))

    bar.set_description("MuJoCo checks")
    bar.set_postfix_str("")
    peer_checks = _peer_checks(cases)
    bar.close()
    return peer_checks


if __name__ == "__main__":
    raise SystemExit(main())
