"""The Markdown report of a benchmark run: machine, versions, the closing-note figures, then details."""
from __future__ import annotations

import math
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

import numpy as np

import tensegrity_sim as ts

from .scale import growth_exponent
from .work_precision import time_to_reach

__all__ = ["write"]

ONE_MS = 1e-3


def _g(x, digits=2) -> str:
    """A number for a table: 3 significant digits in scientific notation, '-' for NaN."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{digits}e}"


def _n(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:,.0f}"


def _table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def machine() -> list[str]:
    """The machine, OS, versions and commit, as report lines (taken when the run ends)."""
    cpu = platform.processor() or "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                                text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".", ":!bench/results"],
                               cwd=root, capture_output=True, text=True, check=True).stdout.strip()
        commit += " (with uncommitted changes)" if dirty else ""
    except (OSError, subprocess.CalledProcessError):
        commit = "?"
    versions = []
    for pkg in ("numpy", "scipy", "mujoco", "matplotlib", "daqp", "osqp"):
        try:
            versions.append(f"{pkg} {metadata.version(pkg)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{pkg} (not installed)")
    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return [
        f"- CPU: {cpu}, {os.cpu_count()} logical cores; load average at the end {load[0]:.1f} / {load[1]:.1f} / "
        f"{load[2]:.1f} (1/5/15 min: other work was running, so every time is the minimum of several runs "
        "and comparisons are ratios measured in this one process)",
        f"- {platform.system()} {platform.release()}, Python {platform.python_version()}",
        f"- tensegrity_sim {ts.__version__} at commit {commit}; methods: {', '.join(sorted(ts.METHODS))}; "
        f"QP backends: {', '.join(ts.SOLVERS)}",
        "- " + ", ".join(versions),
    ]


def _order(rows: list[dict], floor: float) -> float:
    """Observed order: slope of log(pos error) against log(dt) over the runs with an error above
    100 x ``floor`` (the reference's accuracy)."""
    pts = [(r["dt"], r["pos_err_m"]) for r in rows if r["status"] == "ok" and np.isfinite(r["pos_err_m"])
           and r["pos_err_m"] > max(100 * floor, 1e-13)]
    if len(pts) < 3:
        return math.nan
    dt, err = map(np.array, zip(*pts))
    return float(np.polyfit(np.log(dt), np.log(err), 1)[0])


def _configs(rows):
    return sorted({(r["simulator"], r["variant"]) for r in rows}, key=lambda c: (c[0] != "tensegrity_sim", c))


def _at(rows, simulator, variant, dt=ONE_MS):
    for r in rows:
        if (r["simulator"], r["variant"]) == (simulator, variant) and math.isclose(r["dt"], dt):
            return r
    return None


def _matched(rows, references, cases) -> list[dict]:
    """Per case and model, for each tensegrity_sim configuration: the wall time it needs for its own
    1-ms error and for 1e-6 m, the best MuJoCo integrator's time for the same errors, and the ratio."""
    out = []
    for case in cases:
        for model in case.models:
            sub = [r for r in rows if r["case"] == case.name and r["model"] == model]
            peers = [c for c in _configs(sub) if c[0] == "MuJoCo"]
            for sim, variant in [c for c in _configs(sub) if c[0] == "tensegrity_sim"]:
                mine = [r for r in sub if (r["simulator"], r["variant"]) == (sim, variant)]
                at = _at(mine, sim, variant)
                levels = [("its 1 ms error", at["pos_err_m"] if at and at["status"] == "ok" else math.nan), ("1e-6 m", 1e-6)]
                accuracy = references[(case.name, model)].accuracy_m
                for label, eps in levels:
                    if not math.isfinite(eps):
                        continue
                    t_mine = time_to_reach(mine, eps)
                    best = (math.nan, "-")
                    for p in peers:
                        t = time_to_reach([r for r in sub if (r["simulator"], r["variant"]) == p], eps)
                        if math.isfinite(t) and not t >= best[0]:
                            best = (t, p[1])
                    if eps < 3 * accuracy:
                        verdict = f"unresolved: the reference is good to {_g(accuracy)} m"
                    elif math.isfinite(best[0]) and math.isfinite(t_mine):
                        verdict = f"{t_mine / best[0]:.1f}"
                    else:
                        verdict = "not reached"
                    out.append({"case": case.name, "model": model, "variant": variant, "level": label, "error": eps,
                                "t_mine": t_mine, "t_peer": best[0], "peer": best[1], "ratio": verdict})
    return out


def write(path: Path, *, meta: dict, cases, references, rows, throughput, size_rows, realtime, hard) -> None:
    """The report of a run from its tables (as read back from the CSV files) and ``meta`` (run_all's
    meta.json: quick, date, elapsed_s, machine lines, peer_checks)."""
    quick, peer_checks = meta["quick"], meta["peer_checks"]
    w = []
    cmd = "python3 bench/run_all.py" + (" --quick" if quick else "")
    w.append("# Benchmark report\n")
    w.append(f"Generated by `{cmd}` on {meta['date']} in {meta['elapsed_s'] / 60:.1f} min. Every figure "
             "below comes from this run; the CSV files beside this report hold all of them "
             "(`python3 bench/run_all.py --report-only` rewrites this file from them).\n")
    if quick:
        w.append("**Quick run: coarse step grids, few sizes, short horizons. A sanity check, not the published "
                 "figures.**\n")
    w.append("## Machine and versions\n")
    w.append("\n".join(meta["machine"]))

    # ------------------------------------------------------------------ closing-note figures
    w.append("\n## Summary\n")
    w.append("### Error at dt = 1 ms and the time it takes\n")
    w.append("Errors against each case's reference (below); time = wall time per simulated second, the "
             "minimum of several runs after a warm-up, stepping only.\n\n")
    body = []
    for case in cases:
        for model in case.models:
            sub = [r for r in rows if r["case"] == case.name and r["model"] == model]
            for sim, variant in _configs(sub):
                r = _at(sub, sim, variant)
                if r is None:
                    continue
                if r["status"] != "ok":
                    body.append([case.name, model, f"{sim} {variant}", r["status"].split(":")[0], "", "", "", ""])
                    continue
                body.append([case.name, model, f"{sim} {variant}", _g(r["pos_err_m"]), _g(r["imp_err_Ns"]),
                             _g(r["energy_err_J"]), _g(r["wall_per_sim_s"]), _n(r["steps_per_s"])])
    w.append(_table(["case", "cables", "configuration", "position error (m)", "impulse error (N·s)",
                     "energy error (J)", "wall s per sim s", "steps/s"], body))

    matched = _matched(rows, references, cases)
    w.append("\n### Matched-error wall time against MuJoCo\n")
    w.append("The wall time per simulated second tensegrity_sim needs to reach an error (its own error at "
             "1 ms, and 1e-6 m), against the fastest MuJoCo integrator to reach the same error (log-log "
             "interpolation on each configuration's Pareto front). Ratio > 1: MuJoCo is faster. An error within "
             "3x of the reference's own accuracy is not resolved and gets no ratio.\n\n")
    w.append(_table(["case", "cables", "configuration", "error level", "error (m)", "tensegrity_sim (s)",
                     "MuJoCo (s)", "MuJoCo integrator", "ratio"],
                    [[m["case"], m["model"], m["variant"], m["level"], _g(m["error"]), _g(m["t_mine"]),
                      _g(m["t_peer"]), m["peer"], m["ratio"]]
                     for m in matched]))

    w.append("\n### Steps per second beside MuJoCo (dt = 1 ms, same process)\n")
    w.append("Steps/s: best of 3 runs of about 0.25 s each (median in brackets), the configurations of a scene "
             "taking turns; ratio = tensegrity_sim's steps/s / MuJoCo's (< 1: MuJoCo takes more steps per "
             "second), from the best runs (medians in brackets). The elastic method beside MuJoCo's spring "
             "tendons, the inextensible one beside its limited tendons ('limited'). Both run many steps per "
             "call: `Simulator.run()` (the elastic method's compiled loop) and `mj_step(model, data, nstep)`; "
             "`bench/head_to_head.py` also times single steps from Python. '+contacts': member-contact detection on for every member kind "
             "(MuJoCo's is off).\n\n")
    peers = sorted({t["variant"] for t in throughput if t["simulator"] == "MuJoCo"},
                   key=lambda v: (("Euler", "implicitfast", "RK4", "Euler limited", "RK4 limited").index(v)
                                  if v in ("Euler", "implicitfast", "RK4", "Euler limited", "RK4 limited") else 9))
    body = []
    for t in [t for t in throughput if t["simulator"] != "MuJoCo"]:
        row = [t["scene"], f"{t['simulator']} {t['variant']}", f"{_n(t['steps_per_s'])} ({_n(t['steps_per_s_median'])})"]
        for peer in peers:
            match = [u for u in throughput if u["simulator"] == "MuJoCo" and u["variant"] == peer
                     and u["scene"] == t["scene"] and u["vs"] == f"{t['simulator']} {t['variant']}"]
            row.append(f"{_n(match[0]['steps_per_s'])}: {match[0]['ratio']:.3f} ({match[0]['ratio_median']:.3f})"
                       if match else "-")
        body.append(row)
    w.append(_table(["scene", "configuration", "steps/s"] + [f"MuJoCo {p} steps/s: ratio" for p in peers], body))

    w.append("\n### Growth exponents\n")
    w.append("Cost per step ~ members^p on towers (see Scale): p fitted over towers of 10 stages or more, "
             "and over all sizes.\n\n")
    body = []
    for sim, variant in sorted({(r["simulator"], r["variant"]) for r in size_rows}):
        body.append([f"{sim} {variant}", f"{growth_exponent(size_rows, sim, variant):.2f}",
                     f"{growth_exponent(size_rows, sim, variant, min_stages=0):.2f}"])
    w.append(_table(["configuration", "p (>= 10 stages)", "p (all)"], body))

    w.append("\n### Hard cases that fail\n")
    fails = [h for h in hard if h["verdict"] == "FAIL"]
    lines = [f"- {h['case']} ({h['variant']}, {h['setting']}): {h['figure']}" for h in fails] or \
        ["None of the cases run failed."]
    lines += [f"- not run: {h['case']} ({h['variant']}): {h['figure']}" for h in hard if h["verdict"] == "n/a"]
    w.append("\n".join(lines))
    if "inextensible" not in ts.METHODS:
        w.append("Not in this checkout, so not measured: the inextensible method and its QP backends "
                 "(issue 3): its sweeps, references by step halving and hard-case rows. They plug in as "
                 "extra runners in `bench/runners.py`.")

    # ------------------------------------------------------------------ details
    w.append("\n## Work-precision\n")
    w.append("Each case runs every configuration over steps from 10 ms down (where stable) to 10 µs "
             "(MuJoCo to 2 µs), skipping a step whose run would take over 20 s (the slow QP backends' "
             "smallest steps). Errors: largest node-position error at the final time; largest error of a "
             "cable's impulse summed over the run (it contains every snap); largest deviation of the total "
             "energy (elastic cables only: the model conserves it). Ringed points: dt = 1 ms.\n")
    for case in cases:
        for model in case.models:
            ref = references.get((case.name, model))
            sub = [r for r in rows if r["case"] == case.name and r["model"] == model]
            if not sub:
                continue
            w.append(f"\n### {case.name}, {model} cables\n")
            w.append(f"{case.summary}. Duration {case.duration:g} s. Reference: {ref.source}"
                     + (f", accuracy about {_g(ref.accuracy_m)} m" if ref.accuracy_m else "") + "."
                     + (f" Impulses: {case.impulse_note}." if case.impulse_note else "") + "\n\n")
            w.append(f"![{case.name} {model}](wp_{case.name}_{model}.png)\n\n")
            body = []
            for sim, variant in _configs(sub):
                mine = [r for r in sub if (r["simulator"], r["variant"]) == (sim, variant)]
                ok = [r for r in mine if r["status"] == "ok"]
                best = min(ok, key=lambda r: r["pos_err_m"]) if ok else None
                failed = sorted({r["status"].split(":")[0] + f" at {r['dt']:g}" for r in mine if r["status"] != "ok"})
                body.append([f"{sim} {variant}", f"{_order(mine, ref.accuracy_m):.2f}",
                             _g(best["pos_err_m"]) if best else "-", f"{best['dt']:g}" if best else "-",
                             ", ".join(failed) or ""])
            w.append(_table(["configuration", "observed order", "smallest error (m)", "at dt (s)", "not run"], body))

    w.append("\n## References\n")
    w.append("Elastic cables: scipy's DOP853 (rtol = atol = 1e-12) with the set of taut cables fixed between "
             "switches and restarted at every switch (`bench/reference.py`); rigid struts by Lagrange "
             "multipliers at the acceleration level. Checks: the same with rtol 1e-10, with a quarter of the "
             "step bound, and tensegrity_sim's own step-halving limit, whose convergence is plotted below "
             "(for the inextensible model that limit is the reference).\n\n")
    body = []
    for (case, model), ref in references.items():
        if ref is None or not ref.checks:
            continue
        for c in ref.checks:
            body.append([case, model, c["check"], _g(c["pos_change_m"]), _g(c["imp_change_Ns"])])
    w.append(_table(["case", "cables", "compared with", "position difference (m)", "impulse difference (N·s)"], body))
    w.append("\n![step halving](reference_convergence.png)\n")

    w.append("\n## The MuJoCo peer\n")
    w.append("`bench/mujoco_peer.py` runs `Scene.to_mjcf()` (`tensegrity_sim/io/mjcf.py`): rigid struts are free "
             "bodies with the strut's mass, centre of mass and inertia normal to its axis; other nodes "
             "are point masses on three slide joints; elastic struts are tendon springs; elastic cables are "
             "tendons with a dead band `springlength=\"0 L\"`; inextensible cables are limited tendons "
             "`range=\"0 L\"` (soft constraints, `solreflimit=\"2dt zeta\"`); contacts off, no damping. "
             "`test/test_peers.py` asserts that both simulators converge to the same trajectory.\n\n")
    notes = []
    if peer_checks:
        eff = ", ".join(f"{float(k):g}: {_g(v)} m" for k, v in peer_checks["axial_inertia"].items())
        notes.append(f"- Axial inertia of a rigid strut (MuJoCo needs it > 0; relative to the transverse one): final "
                 f"positions of the thrown icosahedron after 1 s differ from the 1e-3 run by {eff}. No tendon "
                 "acts off a strut's axis, so it has no effect beyond round-off.")
        notes.append(f"- MuJoCo's semi-implicit Euler and tensegrity_sim's velocity Verlet obey the same two-step "
                 f"recurrence for positions; from a state of zero acceleration they coincide: on the kicked tower "
                 f"(1 s, 1 ms, hundreds of switches) the final positions differ by {_g(peer_checks['euler_verlet_gap_m'])} m. "
                 "Their velocities differ by half a step, hence Euler's first-order energy error.")
    notes.append("- Limited tendons with MuJoCo's default damping ratio 1 rebound from a snap with a restitution of "
             "about 0.1 whatever the step (the soft constraint's time constant scales with dt); a damping ratio "
             "of 30 is close to inelastic. Both are in the sweeps, with Euler and RK4 (implicitfast is Euler to the "
             "bit when nothing depends on velocity, as the elastic sweeps show). Impulses are integrated from "
             "MuJoCo's tendon sensors at each step's start; a limit cable's impulse under RK4, whose four "
             "stages' forces MuJoCo does not keep, is not measured.")
    w.append("\n".join(notes))

    w.append("\n## Scale and real time\n")
    w.append("![scale](scale.png)\n\n")
    configs = sorted({(r["simulator"], r["variant"]) for r in size_rows})
    stages = sorted({r["stages"] for r in size_rows})
    body = []
    for s in stages:
        sub = {(r["simulator"], r["variant"]): r for r in size_rows if r["stages"] == s}
        first = next(iter(sub.values()))
        body.append([s, first["nodes"], first["members"]] + [_n(sub[c]["us_per_step"]) if c in sub else "-" for c in configs])
    w.append(_table(["stages", "nodes", "members"] + [f"{a} {b} (µs/step)" for a, b in configs], body))
    w.append("\nReal-time factor (simulated s per wall s; best of 3, median in brackets) of the built-in "
             "scenes:\n\n")
    w.append(_table(["scene", "configuration", "rate (Hz)", "µs/step", "real-time factor"],
                    [[r["scene"], f"{r['simulator']} {r['variant']}", f"{r['rate_hz']:g}", _n(r["us_per_step"]),
                      f"{r['realtime_factor']:.1f} ({r['realtime_factor_median']:.1f})" if r["status"] == "ok"
                      else r["status"][:80]] for r in realtime]))

    w.append("\n## Hard cases\n")
    w.append("`bench/hard_cases.py`: each verdict and the figure behind it.\n\n")
    w.append(_table(["case", "configuration", "setting", "verdict", "figure"],
                    [[h["case"], f"{h['simulator']} {h['variant']}", h["setting"], h["verdict"], h["figure"]]
                     for h in hard]))
    w += _separate_runs(path.parent)
    for extra in ("batch.md", "sweep.md"):   # bench/bench_batch.py's and bench_sweep.py's, measured on their own
        if (path.parent / extra).exists():
            w.append((path.parent / extra).read_text())
    path.write_text("\n\n".join(x.strip("\n") for x in w) + "\n")


def _separate_runs(results: Path) -> list[str]:
    """The sections of the benchmarks run on their own (issue 20), from their CSV files when present:
    the tensions of locked structures (``bench/prestress_tensions.py``) and the Siconos peer
    (``bench/siconos_peer.py``)."""
    from .tables import read_csv
    w = []
    if (results / "prestress.csv").exists():
        w.append("\n## Tensions of locked structures\n")
        w.append("`python3 bench/prestress_tensions.py` (run on its own, not by `run_all.py`): 0.3 s of a thrown "
                 "locked structure (rigid struts; random node velocities, which hit the cables at t = 0). The "
                 "inextensible method publishes the reference prestress projected onto the step's self-stress plus "
                 "the minimum-norm dynamic impulses (`methods/inextensible/self_stress.py`); 'QP multipliers' is the "
                 "same run "
                 "publishing the solver's multipliers (before issue 20); the elastic twin is the same scene with "
                 "613 N/m (icosahedron) or 2000 N/m (prism) cables. Tensions are impulse / dt over every cable and "
                 "step: 'max' includes the first step's impact (an impulse, so its tension grows like 1/dt), 'max "
                 "after' leaves it out. 'residual': the largest node impulse (N·s) the published impulses leave "
                 "out, the solver's share along a nearly dependent direction (see the module's docstring).\n\n")
        body = [[r["scene"], r["configuration"], f"{r['dt'] * 1e3:g}", f"{r['median_N']:.4g}", f"{r['p99_N']:.4g}",
                 f"{r['max_N']:.4g}", f"{r['max_after_first_N']:.4g}", r["switches"], _g(r["residual_Ns"])]
                for r in read_csv(results / "prestress.csv")]
        w.append(_table(["scene", "configuration", "dt (ms)", "median (N)", "p99 (N)", "max (N)", "max after (N)",
                         "slack/taut switches", "residual (N·s)"], body))
    if (results / "prestress_cost.csv").exists():
        w.append("\nCost of the rule: µs per step of the inextensible method with the rule and publishing the "
                 "solver's multipliers, best of 15 runs of 200 steps taking turns in one process (a loaded 2-core "
                 "machine: compare the ratio). A structure whose members have no self-stress at load (the prism "
                 "with elastic struts) never evaluates it.\n\n")
        body = [[r["scene"], f"{r['dt'] * 1e3:g}", _n(r["us_per_step_rule"]), _n(r["us_per_step_qp_only"]),
                 f"{r['ratio']:.2f}"] for r in read_csv(results / "prestress_cost.csv")]
        w.append(_table(["scene", "dt (ms)", "µs/step with the rule", "µs/step, multipliers", "ratio"], body))
    if (results / "siconos.csv").exists():
        w.append("\n## The Siconos peer (inextensible cases)\n")
        w.append("`python3 bench/siconos_peer.py` (run on its own): Siconos 4.4 (Debian's `python3-siconos`, "
                 "Moreau–Jean θ = 0.5, cables `NewtonImpactNSL(e = 0)`, rigid struts `EqualityConditionNSL`, "
                 "`LagrangianLinearTIR` relations re-linearised at every step; `bench/siconos_driver.py`, run by "
                 "`/usr/bin/python3`) beside tensegrity_sim. Errors at the final time against the closed form "
                 "(snap pair, sling) or, for the thrown prism, against tensegrity_sim at dt = 12.5 µs, its impulses "
                 "compared on their part orthogonal to the prism's self-stress (the part every solver must "
                 "agree on). Overshoot: a cable's largest length beyond its limit at a step's end; strut error: "
                 "a rigid strut's largest length error.\n\n")
        body = [[r["case"], r["simulator"], f"{r['dt'] * 1e3:g}", _g(r["pos_err_m"]), _g(r["imp_err_Ns"]),
                 _g(r["cable_overshoot_m"]), _g(r["strut_error_m"]), f"{r['wall_s']:.2f}"]
                for r in read_csv(results / "siconos.csv")]
        w.append(_table(["case", "simulator", "dt (ms)", "position error (m)", "impulse error (N·s)",
                         "cable overshoot (m)", "strut error (m)", "wall (s)"], body))
    return w

