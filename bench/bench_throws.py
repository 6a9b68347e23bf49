"""The throw benchmark (issue 47): many random throws of the built-in robots onto a plane over a wide space,
each held to what a well-posed run satisfies (``throw_cases.problems``: no error, a finite state, nothing sunk
beyond 0.1 mm, no energy created where that is a law), and every contact answer the solver accepts checked
against the laws it must meet (:func:`check_answer`).

The space (``--space``): ``fuzz`` (default; ``throw_cases.fuzz_throw``): both methods, the five built-in free
robots (icosahedron, prism3, icosahedron_ground, superball, three_bar), drop heights 1 um to 0.5 m with a third
set down at rest or nearly, velocities to 3 m/s, spins (4 rad/s normal per axis), friction 0-2 (a tenth
frictionless), restitution 0-1 (half plastic), two cable commands mid-run, member contact response on a third
(member friction 0-1), and a sixth of the throws a batch of 2-4 copies stepped by ``BatchSimulator``;
``wide``: the space before (``throw_cases.wide_throw``: three robots, no batches); ``rods``: elastic throws of
the ``wide`` space with the robots' rigid struts carrying their mass as rods (the consistent mass blocks and a
payload each, ``throw_cases.rod_throw``, issue 46), to ``bench/results/throws_rods.csv``.

Throw ``i`` of ``--seed S`` is drawn from ``numpy.random.default_rng([47, S, i])`` (``wide``),
``default_rng([47, S, i, 1])`` (``fuzz``) or ``default_rng([46, S, i])`` (``rods``): any one replays alone
(``--first i --count 1``). Prints every failing case (a dict for ``throw_cases.run_throw``) and writes the
counts per method and robot to ``bench/results/throws.csv`` (``--out``), the last row the total, with the seed,
the throws' index range and the space in every row (written every 25 throws as they stand).

The answers checked: every solve of the ground contacts' frictional problem (``FrictionalSolver.solve``, both
methods' reference path; the elastic method's compiled contact kernels check their own answers and are not
seen here), against the Coulomb law in its projection form (``|f - proj_disc(mu y_n)(f - m v_t)|``), the
normal impulses' sign, and the cable and strut rows' feasibility, sign and complementarity (an inequality row
either carries no impulse or is at its target), each to ``ACCEPT_TOL`` (1e-5) of the momentum in play (the free
nodes' ``sum m |v0|`` or the largest impulse; a velocity residual weighed by the heaviest node's mass): the
tolerance the solver accepts answers to. ``violations`` counts the answers that miss it.

``--budget`` (s of wall time per throw, default none) cuts a throw that runs longer (counted in ``cut``: not a
stopped run, not a completed one).

Run: ``python3 bench/bench_throws.py [--count N] [--seed S] [--first I] [--steps K] [--space fuzz|wide|rods]
[--budget T] [--out PATH]``; ``--throws I J ...`` runs those throws alone (a rerun of earlier failures; their
indices, comma-joined, are the CSV's ``throw_range``); ``--merge A.csv B.csv ... --out PATH`` sums runs over
disjoint throws (chunks run side by side, reruns) into one CSV, its ``throw_range`` the throws in order.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "test")]

import throw_cases  # noqa: E402

from bench.tables import RESULTS, read_csv, write_csv  # noqa: E402
from tensegrity_sim.methods.contact import friction  # noqa: E402

SPACES = {"wide": (throw_cases.wide_throw, 47, ()), "fuzz": (throw_cases.fuzz_throw, 47, (1,)),
          "rods": (throw_cases.rod_throw, 46, ())}


def case_of(seed: int, index: int, steps: int, space: str = "wide") -> dict:
    draw, issue, suffix = SPACES[space]
    return draw(np.random.default_rng([issue, seed, index, *suffix]), steps=steps)


def check_answer(solver: friction.FrictionalSolver, v0, rows, v, y) -> list[str]:
    """What an accepted answer ``(v, y)`` of ``solver`` to ``(v0, rows)`` misses beyond ``ACCEPT_TOL`` of the
    momentum in play (module docstring): the method's rows (feasible, no pull, complementary) and the armed
    contacts' Coulomb law and normal sign. Empty for an answer that meets them."""
    mass = solver._mass
    impulses = solver.last if solver.last is not None else np.zeros((0, 3))
    momentum = max(float(np.sum(mass * np.linalg.norm(v0, axis=1))), float(np.max(np.abs(y), initial=0.0)),
                   float(np.max(np.abs(impulses), initial=0.0)), 1e-300)
    tol = friction.ACCEPT_TOL * momentum
    heaviest = float(mass.max(initial=0.0))
    # the rows at their drift-correcting targets, or all at the pure velocity level (where the solver yielded
    # to it: FrictionalSolver.solve, the drift then stays as it is)
    found = min((_row_misses(r, v, y, heaviest, tol) for r in (rows, friction._velocity_level(rows))), key=len)
    if len(impulses):
        f, yn = impulses[:, :2], impulses[:, 2]
        vt = solver._tangential(solver._velocity(v))
        trial = f - solver._meff[:, None] * vt
        size = np.linalg.norm(trial, axis=1)
        projected = trial * np.minimum(1.0, solver._mu * yn / np.maximum(size, 1e-300))[:, None]
        coulomb = float(np.max(np.linalg.norm(f - projected, axis=1), initial=0.0))
        outside = float(np.max(np.linalg.norm(f, axis=1) - solver._mu * np.maximum(yn, 0.0), initial=0.0))
        if max(coulomb, outside) > tol:
            found.append(f"Coulomb law missed by {max(coulomb, outside):.3g} N*s")
        if float(np.min(yn, initial=0.0)) < -tol:
            found.append(f"a normal impulse pulls: {float(yn.min()):.3g} N*s")
    if found:
        found.append(f"tolerance {tol:.3g} N*s")
    return found


def _row_misses(rows, v, y, heaviest: float, tol: float) -> list[str]:
    """What the answer ``(v, y)`` misses on ``rows`` beyond ``tol`` N*s (a velocity times ``heaviest`` kg):
    an equality off its target, an inequality violated, a pulling impulse, an impulse on a row off its
    target."""
    n_eq = rows.n_eq
    res = rows.rates(v) - rows.targets
    found = []
    if heaviest * float(np.max(np.abs(res[:n_eq]), initial=0.0)) > tol:
        found.append(f"equality row off by {float(np.max(np.abs(res[:n_eq]))):.3g} m/s")
    if heaviest * float(np.max(res[n_eq:], initial=0.0)) > tol:
        found.append(f"inequality row violated by {float(np.max(res[n_eq:])):.3g} m/s")
    if float(np.min(y[n_eq:], initial=0.0)) < -tol:
        found.append(f"a row pulls with {float(np.min(y[n_eq:])):.3g} N*s")
    both = np.minimum(np.abs(y[n_eq:]), heaviest * np.abs(res[n_eq:]))
    if float(np.max(both, initial=0.0)) > tol:
        found.append(f"a row carries an impulse off its target (complementarity {float(both.max()):.3g} N*s)")
    return found


class AnswerChecks:
    """Wraps ``FrictionalSolver.solve`` while in use (a context manager): every accepted answer is checked by
    :func:`check_answer`; ``checked`` counts them, ``violations`` the ones that miss, ``first`` the first
    miss's text."""

    def __enter__(self):
        self.checked, self.violations, self.first = 0, 0, None
        self._solve = solve = friction.FrictionalSolver.solve
        checks = self

        def checked_solve(solver, v0, rows, warm=None):
            v, y = solve(solver, v0, rows, warm)
            checks.checked += 1
            found = check_answer(solver, v0, rows, v, y)
            if found:
                checks.violations += 1
                checks.first = checks.first or "; ".join(found)
            return v, y

        friction.FrictionalSolver.solve = checked_solve
        return self

    def __exit__(self, *exc):
        friction.FrictionalSolver.solve = self._solve


FIELDS = ["method", "robot", "throws", "stopped", "unsound", "cut", "answers_checked", "violations", "set_down",
          "contact_response", "batches", "steps", "seed", "throw_range", "space", "wall_s"]
COUNTS = ("throws", "stopped", "unsound", "cut", "answers_checked", "violations", "set_down", "contact_response",
          "batches", "wall_s")


def write(path: Path, rows: list[dict], *, steps: int, seed: int, ranges: str, space: str) -> dict:
    """The counts ``rows`` per method and robot, then their total (returned), to the CSV ``path``; the throws'
    index ``ranges`` ("first-last", several joined by ";") in every row."""
    rows = sorted(rows, key=lambda r: (r["method"], r["robot"]))
    for r in rows:
        r["throw_range"] = ranges
    total = {"method": "all", "robot": "all", "steps": steps, "seed": seed, "throw_range": ranges, "space": space}
    for key in COUNTS:
        total[key] = sum(r[key] for r in rows)
    write_csv(path, rows + [total], FIELDS)
    return total


def merge(paths: list[Path], out: Path) -> dict:
    """The CSVs ``paths`` of runs over disjoint throw ranges (the same seed, steps and space) summed into ``out``."""
    groups: dict[tuple, dict] = {}
    ranges, kinds = [], set()
    for path in paths:
        rows = read_csv(path)
        ranges.append(str(rows[-1]["throw_range"]))   # (a single rerun throw reads back as a number)
        kinds.add((rows[-1]["seed"], rows[-1]["steps"], rows[-1]["space"]))
        for r in rows[:-1]:
            row = groups.setdefault((r["method"], r["robot"]), dict(r, **{key: 0 for key in COUNTS}))
            for key in COUNTS:
                row[key] += r[key]
    if len(kinds) != 1:
        raise SystemExit(f"cannot merge runs of different seeds, steps or spaces: {sorted(kinds)}")
    seed, steps, space = kinds.pop()
    return write(out, list(groups.values()), steps=steps, seed=seed, ranges=compacted(ranges), space=space)


def compacted(ranges: list[str]) -> str:
    """The throws of ``ranges`` ("a-b", one index, or several of these joined by "," or ";") named in order, consecutive
    throws as one "a-b", the rest alone, ";" between: ["10-19", "0-9", "20,21,40"] gives "0-21;40". Runs to be
    merged cover disjoint throws: a throw in two of them is refused."""
    seen: set[int] = set()
    for r in ranges:
        for part in r.replace(";", ",").split(","):
            first, _, last = part.partition("-")
            span = range(int(first), int(last or first) + 1)
            if seen.intersection(span):
                raise SystemExit(f"throws {sorted(seen.intersection(span))[:5]} are in two of the runs to merge")
            seen.update(span)
    runs: list[list[int]] = []
    for i in sorted(seen):
        if runs and runs[-1][1] + 1 == i:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ";".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--first", type=int, default=0, help="index of the first throw")
    parser.add_argument("--throws", type=int, nargs="+", help="these throws' indices (a rerun of some) in place of "
                        "--first and --count")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--space", choices=sorted(SPACES), default="fuzz")
    parser.add_argument("--budget", type=float, default=None, help="wall-clock seconds per throw (none: no limit)")
    parser.add_argument("--out", type=Path, default=None, help="default bench/results/throws.csv "
                        "(throws_rods.csv with --space rods)")
    parser.add_argument("--merge", type=Path, nargs="+", help="sum these CSVs (disjoint ranges) into --out; no throws")
    args = parser.parse_args(argv)
    if args.out is None:
        args.out = RESULTS / ("throws_rods.csv" if args.space == "rods" else "throws.csv")
    if args.merge:
        total = merge(args.merge, args.out)
        print(f"{total['throws']} throws ({total['throw_range']}): {total['stopped']} stopped, {total['unsound']} "
              f"unsound otherwise, {total['cut']} cut, {total['violations']} of {total['answers_checked']} answers "
              f"violating; {args.out}")
        return 0
    groups: dict[tuple, dict] = {}
    start = time.perf_counter()
    indices = args.throws or list(range(args.first, args.first + args.count))
    label = ",".join(map(str, indices)) if args.throws else f"{indices[0]}-{indices[-1]}"
    for n, i in enumerate(indices, start=1):
        case = case_of(args.seed, i, args.steps, args.space)
        began = time.perf_counter()
        with AnswerChecks() as checks:
            out = throw_cases.run_throw(case, budget=args.budget)
        found = throw_cases.problems(case, out)
        row = groups.setdefault((case["method"], case["robot"]), {
            "method": case["method"], "robot": case["robot"], "steps": args.steps, "seed": args.seed,
            "space": args.space, **{key: 0 for key in COUNTS}})
        row["throws"] += 1
        row["stopped"] += out["error"] is not None
        row["unsound"] += bool(found) and out["error"] is None
        row["cut"] += out["cut"]
        row["answers_checked"] += checks.checked
        row["violations"] += checks.violations
        row["set_down"] += case["height"] < 1e-3
        row["contact_response"] += case.get("response") is not None
        row["batches"] += case.get("batch", 1) > 1
        row["wall_s"] += round(time.perf_counter() - began, 3)
        if found or checks.violations or out["cut"]:
            print(f"throw {i}: {'; '.join(found)}{' cut by the budget' if out['cut'] else ''}"
                  f"{f'; {checks.violations} answers violate: {checks.first}' if checks.violations else ''}"
                  f"\n  case: {case}", flush=True)
        if n % 25 == 0:   # the counts so far, written as they stand
            print(f"{n} throws, {time.perf_counter() - start:.0f} s", flush=True)
            total = write(args.out, list(groups.values()), steps=args.steps, seed=args.seed,
                          ranges=",".join(map(str, indices[:n])) if args.throws else f"{indices[0]}-{i}",
                          space=args.space)
    total = write(args.out, list(groups.values()), steps=args.steps, seed=args.seed,
                  ranges=label, space=args.space)
    print(f"{total['throws']} throws {label} of {args.steps} steps (seed "
          f"{args.seed}, space {args.space}): {total['stopped']} stopped, {total['unsound']} unsound otherwise, "
          f"{total['cut']} cut, {total['violations']} of {total['answers_checked']} answers violating, "
          f"{time.perf_counter() - start:.0f} s; {args.out}")
    return 1 if total["stopped"] or total["unsound"] or total["violations"] else 0


if __name__ == "__main__":
    sys.exit(main())
