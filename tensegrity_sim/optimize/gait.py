"""Periodic open-loop gaits: a rest-length schedule per actuated cable, optimised for the distance the centre of
mass rolls along a goal direction in a set time (``tensegrity-sim optimize-gait``).

A gait is ``knots`` values per actuated cable and ``period`` (s): at times ``period / knots``, ``2 period /
knots``, ... each cable's rest length is ``low + u (high - low)`` times its rest length in the scene, ``u`` in
[0, 1] the knot's value (knot ``j mod knots`` at the ``j``-th time), linear between them, from the scene's rest
length at time 0: a :class:`~tensegrity_sim.commands.CommandSchedule` (:meth:`GaitProblem.schedule`, written as YAML by
:func:`schedule_yaml`) that ``tensegrity-sim run --commands`` replays. Its fastest reel is ``(high - low)`` times
the longest actuated rest length per ``period / knots`` (the defaults: under 1 m/s on the icosahedron).

Two searches, on the same objective (:func:`distances`: every candidate of a generation one copy of one
:class:`~tensegrity_sim.batch.BatchSimulator` run):

* :func:`cma_search`: CMA-ES (the ``cma`` package, the ``learn`` extra) over ``u`` in the box [0, 1];
* :func:`gradient_search`: gradient ascent on ``u`` with ``jax.grad`` through the JAX backend's run (the
  ``jax`` extra; the gradient of the discrete run, which jumps where a cable's slack/taut switch or a ground
  contact moves from one step to another: docs/jax.md), a line search along it projected on the box in one
  numba batch run, each step kept only if it rolls farther.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import yaml

from ..batch import BatchSimulator
from ..commands import CommandSchedule
from ..scene import Scene

__all__ = ["Gait", "GaitProblem", "cma_search", "distances", "gradient_search", "schedule_yaml"]


@dataclass(frozen=True)
class Gait:
    """What a search found: the actuated cables' indices, ``u`` (n_cables, knots) in [0, 1], the distance (m)
    it rolls along the goal in ``duration`` s, and per generation (or gradient step) the best distance so far."""

    cables: np.ndarray
    u: np.ndarray
    distance: float
    history: list


class GaitProblem:
    """The objective's settings: ``scene`` (a ground), ``cables`` (indices), ``goal`` (2,) unit, ``duration``
    s, ``period`` s, ``knots``, ``rest_range`` (low, high) fractions of rest lengths, ``dt`` s."""

    def __init__(self, scene: Scene, cables, goal, duration: float, period: float, knots: int,
                 rest_range=(0.5, 1.0), dt: float = 1e-3):
        if scene.ground is None:
            raise ValueError(f"scene {scene.name!r} has no ground: a gait rolls on one")
        for name, value in (("duration", duration), ("period", period), ("dt", dt)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a number of seconds > 0, got {value!r}")
        if isinstance(knots, bool) or not isinstance(knots, int) or knots < 1:
            raise ValueError(f"knots must be a whole number >= 1, got {knots!r}")
        self.scene, self.cables = scene, np.asarray(cables, dtype=np.intp)
        if not len(self.cables):
            raise ValueError("no actuated cable")
        self.goal = np.asarray(goal, dtype=float)
        self.duration, self.period, self.knots, self.dt = float(duration), float(period), knots, float(dt)
        self.low, self.high = rest_range
        self.steps = round(self.duration / self.dt)
        # the knots' times (0 excluded) up to the duration's end, and which knot each is
        spacing = self.period / self.knots
        count = math.ceil(self.duration / spacing)
        self.times = np.concatenate([[0.0], spacing * np.arange(1, count + 1)])
        self.which = np.arange(count) % self.knots
        self.rest0 = scene.cable_rest_lengths[self.cables]
        self.masses = scene.masses

    def values(self, u: np.ndarray) -> np.ndarray:
        """Each actuated cable's rest lengths (n_actuated, points) m at :attr:`times` for knot values ``u``."""
        frac = self.low + u[:, self.which] * (self.high - self.low)
        return np.concatenate([self.rest0[:, None], frac * self.rest0[:, None]], axis=1)

    def schedule(self, u: np.ndarray) -> CommandSchedule:
        values = self.values(u)
        return CommandSchedule(self.cables, (self.times,) * len(self.cables), tuple(values),
                               np.zeros(0), np.zeros((0, len(self.scene.nodes), 3)))

    def com_xy(self, x: np.ndarray) -> np.ndarray:
        return (np.einsum("n,...nk->...k", self.masses, x) / self.masses.sum())[..., :2]



def schedule_yaml(problem: GaitProblem, u: np.ndarray, comment: str = "") -> str:
    """The schedule as the YAML ``tensegrity-sim run --commands`` reads (one point per knot time)."""
    values = problem.values(u)
    names = [problem.scene.cable_names[c] for c in problem.cables]
    points = [{"time": float(t), "rest_lengths": {n: float(v) for n, v in zip(names, values[:, k])}}
              for k, t in enumerate(problem.times)]
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    return head + yaml.safe_dump(points, sort_keys=False)


def distances(problem: GaitProblem, us) -> np.ndarray:
    """The distance (m) the centre of mass rolls along the goal in ``duration`` for each of ``us`` (P of
    (n_actuated, knots)): one batch run of P copies (a refused copy: -inf)."""
    us = list(us)
    sim = BatchSimulator(problem.scene, len(us), method="elastic", dt=problem.dt, contacts=())
    start = problem.com_xy(problem.scene.positions)
    run = sim.run(steps=problem.steps, every=problem.steps, commands=[problem.schedule(u) for u in us])
    out = (problem.com_xy(run.positions[:, -1]) - start) @ problem.goal
    out[list(run.failures)] = -np.inf
    return out


def cma_search(problem: GaitProblem, *, generations: int, population: int, seed: int = 0, sigma: float = 0.3,
               start=None, report=None) -> Gait:
    """CMA-ES over the knot values in [0, 1] (the ``cma`` package): one generation is one batch run of
    ``population`` copies. ``start`` (n_actuated, knots): the first mean (default 0.5 everywhere)."""
    import cma   # the learn extra: only here

    shape = (len(problem.cables), problem.knots)
    x0 = np.full(shape, 0.5) if start is None else np.asarray(start, dtype=float)
    es = cma.CMAEvolutionStrategy(x0.ravel(), sigma, {"bounds": [0.0, 1.0], "popsize": population, "seed": seed + 1,
                                                      "verbose": -9})
    best, best_u, history = -np.inf, x0, []
    for g in range(generations):
        candidates = es.ask()
        found = distances(problem, [np.reshape(c, shape) for c in candidates])
        es.tell(candidates, [-d if np.isfinite(d) else 1e9 for d in found])
        k = int(np.argmax(found))
        if found[k] > best:
            best, best_u = float(found[k]), np.reshape(candidates[k], shape).copy()
        history.append(best)
        if report is not None:
            report(f"generation {g + 1}: best {found[k]:.4f} m, so far {best:.4f} m")
    return Gait(problem.cables, best_u, best, history)


def gradient_search(problem: GaitProblem, start, *, iterations: int, rates=(0.4, 0.2, 0.1, 0.05, 0.025, 0.0125),
                    report=None) -> Gait:
    """Gradient ascent on the knot values from ``start`` (n_actuated, knots): ``jax.grad`` of the JAX run's
    distance, then a line search along the gradient's direction (normalised: its size jumps at switches) at each
    of ``rates``, projected on [0, 1], all in one numba batch run; the best is kept if it rolls farther, else the
    search stops (no step along the gradient helps)."""
    import jax
    import jax.numpy as jnp

    from ..methods.jax import elastic as jel
    from ..methods.rigid import RigidStruts
    from ..system import System

    jax.config.update("jax_enable_x64", True)
    system = System(problem.scene)
    model = jel.model_arrays(system, RigidStruts(system))
    x0 = jnp.asarray(problem.scene.positions[..., None])
    v0 = jnp.asarray(problem.scene.velocities[..., None])
    u = np.asarray(start, dtype=float)
    inputs = jel.schedule_inputs(problem.schedule(u), problem.scene.cable_rest_lengths[:, None], np.zeros_like(x0))
    order = np.argsort(problem.cables)   # the Inputs hold the scheduled cables sorted by index
    rest0 = jnp.asarray(problem.rest0[order])
    which = jnp.asarray(problem.which)
    masses = jnp.asarray(problem.masses)
    goal = jnp.asarray(problem.goal)
    start_xy = jnp.asarray(problem.com_xy(problem.scene.positions))

    def distance(u_sorted):
        frac = problem.low + u_sorted[:, which] * (problem.high - problem.low)
        values = jnp.concatenate([rest0[:, None], frac * rest0[:, None]], axis=1)[None]
        out = jel.rollout(model, x0, v0, inputs._replace(rest_values=values), problem.dt, problem.steps,
                          problem.steps, scheduled=True)
        com = jnp.einsum("n,nk->k", masses, out.x[-1, :, :, 0]) / masses.sum()
        return (com[:2] - start_xy) @ goal

    grad = jax.jit(jax.grad(distance))
    best = float(distances(problem, [u])[0])
    history = [best]
    for i in range(iterations):
        g = np.asarray(grad(jnp.asarray(u[order])))[np.argsort(order)]
        norm = float(np.linalg.norm(g))
        if not np.isfinite(norm) or norm == 0:
            break
        trials = [np.clip(u + r * g / norm, 0.0, 1.0) for r in rates]
        found = distances(problem, trials)
        k = int(np.argmax(found))
        if report is not None:
            report(f"gradient step {i + 1}: {found[k]:.4f} m at rate {rates[k]:g}, best before {best:.4f} m")
        if found[k] <= best:
            break
        u, best = trials[k], float(found[k])
        history.append(best)
    return Gait(problem.cables, u, best, history)
