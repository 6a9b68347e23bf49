"""The one timing utility of the benchmarks: the best of several runs after a warm-up."""
from __future__ import annotations

import time
from typing import Callable

__all__ = ["best_time"]


def best_time(run: Callable[[], object], *, setup: Callable[[], object] | None = None,
              warmup: Callable[[], object] | None = None, repeats: int = 3) -> float:
    """Minimum wall time (s) of ``run()`` over ``repeats`` calls.

    ``warmup()`` (default: ``setup(); run()``) is called once first and not timed, so caches, lazy
    imports and branch predictors are warm; ``setup()`` is called, untimed, before every timed run
    (e.g. a reset to the initial state). The minimum, not the mean, because on a shared machine every
    disturbance only ever adds time.
    """
    if warmup is None:
        if setup is not None:
            setup()
        run()
    else:
        warmup()
    best = float("inf")
    for _ in range(repeats):
        if setup is not None:
            setup()
        start = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - start)
    return best
