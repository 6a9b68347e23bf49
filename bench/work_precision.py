"""Work-precision: error against wall time per simulated second, for every case, simulator and step.

For each case and cable model a reference final state is fixed first (closed form; DOP853 restarted
at switches for the elastic model; the step-halving limit of tensegrity_sim for the inextensible one),
then every runner is swept over steps ``dt``: the time is the minimum of ``repeats`` runs after a
warm-up (stepping only), the errors come from one more run with the bookkeeping:

* ``pos_err_m``: largest node-position error at the final time, m;
* ``imp_err_Ns``: largest error of a cable's impulse summed over the run, N*s (it contains the snaps);
* ``energy_err_J``: largest deviation of the total energy from its initial value, J (elastic model
  only: it conserves energy; the inextensible model dissipates at every snap).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import tensegrity_sim as ts
from tensegrity_sim.system import System

from .cases import Case
from .reference import ElasticReference, Final
from .runners import NO_CONTACTS, TensegrityRunner
from .timing import time_runs

__all__ = ["Reference", "reference_for", "reference_rows", "references_from_rows", "halving_limit", "sweep",
           "alternating_sweep",
           "time_to_reach", "FIELDS", "REFERENCE_FIELDS"]

DTS_FULL = (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5)
DTS_MUJOCO_EXTRA = (5e-6, 2e-6)          # MuJoCo is cheap per step: its curves go further down
DTS_QUICK = (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4)
LONG_RUN_S = 3.0          # a run expected to last longer is timed once
MAX_RUN_S = 20.0          # a run expected to last longer is skipped (3 s with --quick)
SHORT_RUN_S = 0.02        # alternating_sweep: a round times a shorter run again, up to this long

FIELDS = ["case", "model", "simulator", "variant", "dt", "steps", "status", "wall_s", "wall_per_sim_s",
          "steps_per_s", "pos_err_m", "imp_err_Ns", "energy_err_J"]
_NAN = {k: math.nan for k in FIELDS[7:]}   # the measured fields of a run that gave none


@dataclass(frozen=True)
class Reference:
    """A reference final state, how it was obtained and how accurate it is (m, estimated).

    ``checks``: rows (check, pos_change_m, imp_change_Ns) comparing it with variations of itself or
    with another way to the same limit; ``halving``: the step-halving rows of tensegrity_sim (see
    :func:`halving_limit`), the reference itself for the inextensible model, a cross-check otherwise."""

    final: Final
    source: str
    accuracy_m: float
    checks: list[dict]
    halving: list[dict]


def halving_limit(runner: TensegrityRunner, case: Case, dt0: float, levels: int) -> tuple[Final, list[dict]]:
    """The step-halving limit of ``runner`` on ``case``: runs at ``dt0 / 2**j``, ``j < levels``.

    Returns the finest run's final state and, per level, the change from the previous level (m, N*s)
    and the observed order ``log2(change_prev / change)``; the finest run's error is estimated by its
    last change divided by ``2**p - 1`` (Richardson), which is what ``accuracy_m`` reports.
    """
    rows, prev, prev_change = [], None, None
    for j in range(levels):
        dt = dt0 / 2 ** j
        final = runner.session(case, dt).measure(samples=1).final
        row = {"dt": dt, "pos_change_m": math.nan, "imp_change_Ns": math.nan, "order": math.nan}
        if prev is not None:
            change = float(np.max(np.linalg.norm(final.positions - prev.positions, axis=1)))
            row["pos_change_m"] = change
            row["imp_change_Ns"] = float(np.max(np.abs(final.impulses - prev.impulses)))
            if prev_change and change > 0:
                row["order"] = math.log2(prev_change / change)
            prev_change = change
        rows.append(row)
        prev = final
    return prev, rows


def _halving_accuracy(rows: list[dict]) -> float:
    last = rows[-1]
    p = last["order"] if np.isfinite(last["order"]) and last["order"] > 0.5 else 1.0
    return last["pos_change_m"] / (2 ** p - 1)


def reference_for(case: Case, model: str, *, quick: bool = False) -> Reference | None:
    """The reference of ``case`` in ``model``, or None when this checkout has no way to make one."""
    if case.exact is not None:
        return Reference(case.exact(model), "closed form", 0.0, [], [])
    if model == "elastic":
        ref = ElasticReference(case.scene)
        final = ref.solve(case.duration)
        checks = []
        for label, kwargs in (("rtol 1e-10", {"rtol": 1e-10, "atol": 1e-10}),
                              ("max_step / 4", {"max_step": 0.025 / _omega(case)})):
            other = ref.solve(case.duration, **kwargs)
            checks.append({"check": label, "pos_change_m": _pos_diff(other, final),
                           "imp_change_Ns": float(np.max(np.abs(other.impulses - final.impulses)))})
        # the simulator's own step-halving limit, as a check of that procedure where DOP853 exists
        levels = 4 if quick else 7
        halved, rows = halving_limit(TensegrityRunner("elastic", "elastic", NO_CONTACTS), case, 1e-3, levels)
        checks.append({"check": f"tensegrity_sim elastic at dt={rows[-1]['dt']:.3g} s (halving limit)",
                       "pos_change_m": _pos_diff(halved, final),
                       "imp_change_Ns": float(np.max(np.abs(halved.impulses - final.impulses)))})
        accuracy = max(c["pos_change_m"] for c in checks[:2])
        return Reference(final, f"DOP853 rtol=atol=1e-12, restarted at {final.switches} switches, "
                                f"rigid-strut drift {ref.strut_drift(final):.1e}", accuracy, checks, rows)
    if model in ts.METHODS:
        final, rows = halving_limit(TensegrityRunner(model, model, NO_CONTACTS), case, 1e-3, 5 if quick else 8)
        return Reference(final, f"step-halving limit of tensegrity_sim {model} (dt -> {rows[-1]['dt']:.3g} s)",
                         _halving_accuracy(rows), [], rows)
    return None


REFERENCE_FIELDS = ["case", "model", "source", "accuracy_m", "check", "dt", "pos_change_m", "imp_change_Ns", "order"]


def references_from_rows(rows: list[dict]) -> dict:
    """The references as :func:`reference_rows` flattened them (without their final states)."""
    out = {}
    for row in rows:
        key = (row["case"], row["model"])
        if key not in out:
            out[key] = Reference(None, row["source"], row["accuracy_m"], [], [])
        check = row.get("check")
        if check == "step halving":
            out[key].halving.append({k: row[k] for k in ("dt", "pos_change_m", "imp_change_Ns", "order")})
        elif isinstance(check, str):
            out[key].checks.append({k: row[k] for k in ("check", "pos_change_m", "imp_change_Ns")})
    return out


def reference_rows(references: dict) -> list[dict]:
    """The references and their checks and halving rows, flat, for a CSV."""
    out = []
    for (case, model), ref in references.items():
        if ref is None:
            continue
        head = {"case": case, "model": model, "source": ref.source, "accuracy_m": ref.accuracy_m}
        out.append(head)
        out += [{**head, **c} for c in ref.checks]
        out += [{**head, "check": "step halving", **h} for h in ref.halving]
    return out


def _omega(case: Case) -> float:
    return System(case.scene).max_frequency(case.scene.positions, include_cables=True)


def _pos_diff(a: Final, b: Final) -> float:
    return float(np.max(np.linalg.norm(a.positions - b.positions, axis=1)))


def sweep(cases, runners, references: dict, *, quick: bool, repeats: int, progress=None) -> list[dict]:
    """Run every runner on every case it has a reference for, at every step of its grid; one row each
    (see :data:`FIELDS`). Steps a method refuses (stability limit) are rows with status ``refused``."""
    jobs = []
    for case in cases:
        for runner in runners:
            if runner.model not in case.models or references.get((case.name, runner.model)) is None:
                continue
            dts = DTS_QUICK if quick else DTS_FULL + (DTS_MUJOCO_EXTRA if runner.simulator == "MuJoCo" else ())
            jobs += [(case, runner, dt) for dt in dts]
    if progress is not None:
        progress.reset(total=len(jobs))
    rows, last = [], {}
    for case, runner, dt in jobs:
        # the time a run will take, from the previous, larger step: over LONG_RUN_S it is timed once (the
        # noise of a long run is small against its length), over the budget it is skipped, so that the
        # full sweep fits in the hour (the QP backends' smallest steps would not)
        key = (case.name, runner.label)
        expected = last[key][0] * last[key][1] / dt if key in last else 0.0
        if expected > (3.0 if quick else MAX_RUN_S):
            rows.append({"case": case.name, "model": runner.model, "simulator": runner.simulator,
                         "variant": runner.variant, "dt": dt, "steps": int(round(case.duration / dt)),
                         "status": f"skipped: expected {expected:.0f} s per run",
                         **_NAN})
            if progress is not None:
                progress.update()
            continue
        row = _one(case, runner, dt, references[(case.name, runner.model)], repeats if expected < LONG_RUN_S else 1)
        rows.append(row)
        if row["status"] == "ok":
            last[key] = (row["wall_s"], dt)
        if progress is not None:
            progress.set_postfix_str(f"{case.name} {runner.label} dt={dt:g}", refresh=False)
            progress.update()
    return rows


def _one(case: Case, runner, dt: float, ref: Reference, repeats: int) -> dict:
    row, session = _open(case, runner, dt)
    if session is None:
        return row
    try:
        wall = time_runs(session.advance, setup=session.reset, warmup=session.warmup, repeats=repeats).best
    except Exception as exc:     # a step that fails (a QP backend's error) is a result, not a crash
        return {**row, "status": f"failed: {type(exc).__name__}: {exc}", **_NAN}
    return _close(row, session, wall, case, ref)


def _open(case: Case, runner, dt: float):
    """The row of a run (its status ``refused`` if the runner refuses ``dt``) and its session (or None)."""
    row = {"case": case.name, "model": runner.model, "simulator": runner.simulator, "variant": runner.variant,
           "dt": dt, "steps": int(round(case.duration / dt))}
    try:
        return row, runner.session(case, dt)
    except ValueError as exc:
        return {**row, "status": f"refused: {exc}", **_NAN}, None


def _close(row: dict, session, wall: float, case: Case, ref: Reference) -> dict:
    """The row of a timed run (``wall`` s, its best time), with the errors of one more, measured, run."""
    try:
        if session.unstable:
            return {**row, "status": "unstable", **_NAN}
        measured = session.measure()
    except Exception as exc:     # a step that fails (a QP backend's error) is a result, not a crash
        return {**row, "status": f"failed: {type(exc).__name__}: {exc}", **_NAN}
    if not np.all(np.isfinite(measured.final.positions)):
        return {**row, "status": "unstable", **_NAN}
    return {**row, "status": "ok", "wall_s": wall, "wall_per_sim_s": wall / case.duration,
            "steps_per_s": row["steps"] / wall,
            "pos_err_m": _pos_diff(measured.final, ref.final),
            "imp_err_Ns": math.nan if case.impulse_note else
            float(np.max(np.abs(measured.final.impulses - ref.final.impulses), initial=0.0)),
            "energy_err_J": measured.energy_error}


def alternating_sweep(case: Case, runners, ref: Reference, dts, *, repeats: int, budget: float,
                      progress=None) -> list[dict]:
    """:func:`sweep` for one case with the contenders taking turns, for a loaded machine: every run is
    timed once (``dts(runner)``: its steps; from the largest down, a run expected to last over
    ``budget`` s is skipped), then ``repeats - 1`` more rounds time every run in turn, so that a slow
    spell of the machine hits all of them alike; each run's time is its best. A round times a short run
    several times back to back (up to ``SHORT_RUN_S`` s of it, at most 50): a run of 100 us otherwise
    has three chances to miss the machine's other processes."""
    jobs, rows = [], []
    for runner in runners:
        last = None
        for dt in sorted(dts(runner), reverse=True):
            if last is not None and last[0] * last[1] / dt > budget:
                rows.append({**_open(case, runner, dt)[0], "status": f"skipped: expected over {budget:g} s",
                             **_NAN})
                continue
            row, session = _open(case, runner, dt)
            if session is None:
                rows.append(row)
                continue
            try:
                best = time_runs(session.advance, setup=session.reset, warmup=session.warmup, repeats=1).best
            except Exception as exc:
                rows.append({**row, "status": f"failed: {type(exc).__name__}: {exc}", **_NAN})
                continue
            jobs.append([row, session, best])
            last = (best, dt)
            if progress is not None:
                progress.update()
    for _ in range(repeats - 1):
        for job in jobs:
            if job[2] < LONG_RUN_S:
                times = min(50, max(1, int(SHORT_RUN_S / job[2])))
                job[2] = min(job[2], time_runs(job[1].advance, setup=job[1].reset, warmup=lambda: None,
                                               repeats=times).best)
    return rows + [_close(row, session, best, case, ref) for row, session, best in jobs]


def time_to_reach(rows: list[dict], error: float, metric: str = "pos_err_m") -> float:
    """Wall time per simulated second (s) a configuration needs to reach ``error``: on its Pareto
    front (points sorted by time, each more accurate than every faster one), log-log interpolated
    between the last point above ``error`` and the first at or below it. NaN if never reached."""
    pts = sorted((r["wall_per_sim_s"], r[metric]) for r in rows
                 if r["status"] == "ok" and np.isfinite(r[metric]) and r[metric] > 0)
    front = []
    for t, e in pts:
        if not front or e < front[-1][1]:
            front.append((t, e))
    for i, (t, e) in enumerate(front):
        if e <= error:
            if i == 0:
                return t
            t0, e0 = front[i - 1]
            w = (math.log(error) - math.log(e0)) / (math.log(e) - math.log(e0))
            return math.exp(math.log(t0) + w * (math.log(t) - math.log(t0)))
    return math.nan


def plot_halving(references: dict, path: Path) -> None:
    """Step-halving convergence of tensegrity_sim on every case that has halving rows: the change of
    the final positions from one step to half of it, against the step."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.0))
    for (case, model), ref in references.items():
        if ref is None or not ref.halving:
            continue
        pts = [(h["dt"], h["pos_change_m"]) for h in ref.halving if np.isfinite(h["pos_change_m"])]
        dt, change = map(np.array, zip(*pts))
        ax.loglog(dt, change, "-o", ms=3.5, label=f"{case} ({model}), last order {ref.halving[-1]['order']:.2f}")
    ax.set_xlabel("dt (s)")
    ax.set_ylabel("|x(dt) - x(2 dt)| at the final time (m)")
    ax.set_title("tensegrity_sim step-halving convergence", fontsize=9)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot(case: Case, model: str, rows: list[dict], ref: Reference, path: Path) -> None:
    """Work-precision diagram of one case and model: position, impulse and energy error against wall
    time per simulated second, one line per configuration, the 1 ms point ringed."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = [("pos_err_m", "final position error (m)"), ("imp_err_Ns", "impulse error (N·s)")]
    if model == "elastic":
        metrics.append(("energy_err_J", "max energy error (J)"))
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.2 * len(metrics), 3.6), squeeze=False)
    labels = sorted({(r["simulator"], r["variant"]) for r in rows})
    for ax, (metric, title) in zip(axes[0], metrics):
        for sim, variant in labels:
            pts = sorted((r["wall_per_sim_s"], r[metric], r["dt"]) for r in rows
                         if (r["simulator"], r["variant"]) == (sim, variant) and r["status"] == "ok"
                         and np.isfinite(r[metric]) and r[metric] > 0)
            if not pts:
                continue
            t, e, dt = map(np.array, zip(*pts))
            style = "-o" if sim == "tensegrity_sim" else "--s"
            line, = ax.loglog(t, e, style, ms=3.5, lw=1.2, label=f"{sim} {variant}")
            ms = np.isclose(dt, 1e-3)
            ax.loglog(t[ms], e[ms], "o", mfc="none", mec=line.get_color(), ms=10)
        if metric == "pos_err_m" and ref.accuracy_m > 0:
            ax.axhline(ref.accuracy_m, color="grey", lw=0.8, ls=":", label="reference accuracy")
        ax.set_xlabel("wall time per simulated second (s)")
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="both", lw=0.3)
    axes[0][0].legend(fontsize=6.5)
    fig.suptitle(f"{case.name} ({model} cables): ringed = dt 1 ms", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
