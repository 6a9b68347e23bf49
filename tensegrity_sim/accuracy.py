"""The cheapest elastic configuration for a requested error: :func:`choose_accuracy`.

The located options (``methods/elastic/composition.py``) make the error of the elastic method predictable:
every halving of ``dt`` divides it by 4 (order 2, switches located; 3.3 to 4.8 measured on the closed
forms) or by 16 (order 4; 12 or more measured), where plain Verlet's ratios scatter (1.5 to 44 on the
bungee) because a switch's error depends on where in the step it falls. So two runs, at ``h`` and
``h / 2``, estimate the error of the second (Richardson: their difference over ``2^p - 1``) and the
step that meets a tolerance: ``dt = h / 2 * (tol / error)^(1/p)``. The cost of a configuration is
counted in force evaluations (one per Verlet step, five per order-4 step: a located split adds
parts only to the few steps that contain a switch), deterministic and close to the measured wall time
of the compiled kernels (bench/elastic_options.py).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .checks import real, time_step
from .methods.elastic.composition import STABILITY
from .scene import Scene
from .simulator import Simulator
from .system import System

__all__ = ["AccuracyChoice", "choose_accuracy"]

SAFETY = 0.5        # the step is chosen for SAFETY * tol: the estimate is itself an estimate
_STAGES = {2: 1, 4: 5}   # force evaluations per step


class AccuracyChoice(NamedTuple):
    """What :func:`choose_accuracy` picked: the elastic method's ``order``, ``locate_switches`` (always
    True: the estimate needs the predictable error), the step ``dt`` (s, dividing the duration), the
    estimated final-position error there (m), the cost (force evaluations over the duration) and why."""

    order: int
    locate_switches: bool
    dt: float
    estimated_error: float
    cost: int
    reason: str

    def options(self) -> dict:
        """``Simulator`` keyword arguments for this choice: ``Simulator(scene, **choice.options())``."""
        return {"method": "elastic", "dt": self.dt, "order": self.order, "locate_switches": self.locate_switches}


def _final(scene: Scene, order: int, dt: float, duration: float) -> np.ndarray:
    sim = Simulator(scene, method="elastic", dt=dt, order=order, locate_switches=True, contacts=())
    steps = max(1, round(duration / dt))
    sim.run(steps=steps, every=steps)
    return sim.positions


def choose_accuracy(scene: Scene, tol: float, duration: float, *, max_dt: float = 1e-3) -> AccuracyChoice:
    """The cheapest elastic configuration (order 2 or 4, switches located, and the step) whose
    final-position error after ``duration`` s is estimated at most ``tol`` m, from two runs of the
    scene per order at ``h`` and ``h / 2`` (``h``: ``max_dt`` s, or half the order's stability limit if
    that is smaller; the chosen step is never larger than ``h``, where the estimate was made). Costs
    about three runs of ``duration`` at ``h`` per order; use a representative shorter ``duration`` for a
    long run (the error grows with the horizon, so re-check at the full one)."""
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a Scene (see load_scene), got {type(scene).__name__}")
    tol = real(tol, "tol")
    if not tol > 0:
        raise ValueError(f"tol must be a final-position error > 0 (m), got {tol!r}")
    duration = real(duration, "duration")
    if not duration > 0:
        raise ValueError(f"duration must be > 0 (s), got {duration!r}")
    dt = time_step(max_dt, "max_dt")
    system = System(scene)
    omega = system.max_frequency(scene.positions, include_cables=True)
    choices = []
    for order, stages in _STAGES.items():
        h = min(dt, 0.5 * STABILITY[order] / omega) if omega > 0 else dt
        error = float(np.max(np.linalg.norm(_final(scene, order, h, duration) - _final(scene, order, h / 2, duration),
                                            axis=1))) / (2 ** order - 1)
        step = h if error == 0.0 else min(h, 0.5 * h * (SAFETY * tol / error) ** (1.0 / order))
        steps = math.ceil(duration / step)
        step = duration / steps
        estimate = error * (step / (0.5 * h)) ** order
        choices.append(AccuracyChoice(order, True, step, estimate, steps * stages,
                                      f"order {order}, located: error {error:.2g} m at dt = {h / 2:.3g} s, so "
                                      f"{estimate:.2g} m at dt = {step:.3g} s ({steps} steps, {steps * stages} "
                                      f"force evaluations)"))
    best = min(choices, key=lambda c: (c.cost, c.order))
    other = [c for c in choices if c is not best][0]
    return best._replace(reason=f"{best.reason}; cheaper than {other.reason}")
