"""The one timing utility of the benchmarks: several timed runs after a warm-up."""
from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import Callable

__all__ = ["SETTLE", "Timing", "time_runs", "time_alternating"]

# Steps a contender takes, untimed, after each reset and before a timed run (time_alternating's ``settle``):
# the thrown icosahedron's first inextensible steps take the Python path, ~400 us each for the impact of
# its initial velocities on its locked rows; 8 of them added ~3 us a step to runs of ~1000 steps timed
# from a reset.
SETTLE = 50


@dataclass(frozen=True)
class Timing:
    """Wall times (s) of the timed runs. ``best`` (the minimum) is what comparisons use: on a shared
    machine every disturbance only ever adds time; ``median`` shows how noisy the machine was."""

    runs: tuple[float, ...]

    @property
    def best(self) -> float:
        return min(self.runs)

    @property
    def median(self) -> float:
        return statistics.median(self.runs)

    def per(self, n: int) -> "Timing":
        """The same timings divided by ``n`` (per step)."""
        return Timing(tuple(t / n for t in self.runs))


def time_runs(run: Callable[[], object], *, setup: Callable[[], object] | None = None,
              warmup: Callable[[], object] | None = None, repeats: int = 3) -> Timing:
    """Time ``run()`` ``repeats`` times.

    ``warmup()`` (default: ``setup(); run()``) is called once first and not timed, so caches, lazy
    imports and allocations are warm; ``setup()`` is called, untimed, before every timed run (e.g. a
    reset to the initial state).
    """
    if warmup is None:
        if setup is not None:
            setup()
        run()
    else:
        warmup()
    runs = []
    for _ in range(repeats):
        if setup is not None:
            setup()
        start = time.perf_counter()
        run()
        runs.append(time.perf_counter() - start)
    return Timing(tuple(runs))


def time_alternating(contenders: dict[str, tuple[Callable[[int], object], Callable[[], object]]], *,
                     repeats: int = 3, target: float = 0.25, clock: Callable[[], float] = time.perf_counter,
                     settle: int = 0) -> dict[str, Timing]:
    """Per-step timings of ``{name: (run(n), reset())}``, the contenders taking turns: each repeat times
    every contender once, so that a disturbance of a shared machine hits them alike instead of whoever
    ran at that moment. ``n`` is calibrated per contender (after a warm-up run) so that a run lasts
    about ``target`` seconds of ``clock``; ``reset()`` and then ``run(settle)`` are called, untimed,
    before every run (``settle`` = :data:`SETTLE`: steady stepping after warm-up, not a reset's first
    steps)."""
    sizes = {}
    for name, (run, reset) in contenders.items():
        reset()
        run(5)   # warm-up: caches, lazy imports, compiled kernels
        if settle:
            reset()
            run(settle)
        start = clock()
        run(20)
        sizes[name] = max(20, int(target / max((clock() - start) / 20, 1e-8)))
    runs = {name: [] for name in contenders}
    for _ in range(repeats):
        for name, (run, reset) in contenders.items():
            reset()
            if settle:
                run(settle)
            start = clock()
            run(sizes[name])
            runs[name].append((clock() - start) / sizes[name])
    return {name: Timing(tuple(r)) for name, r in runs.items()}
