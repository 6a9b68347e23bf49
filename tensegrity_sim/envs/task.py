"""The roll-toward-a-goal task on B copies of a scene, batch first: what :class:`~.roll.RollEnv` (B = 1) and
:class:`~.roll.RollVectorEnv` (B copies) share. No Gymnasium here: arrays in, arrays out.

One control period (``control_dt``, ``control_dt / dt`` steps of the simulator) of every copy is one compiled
run of a :class:`~tensegrity_sim.batch.BatchSimulator`: each actuated cable's rest length is reeled from where
it is toward its target at the motors' speed ``reel_speed`` (m/s), as a command schedule evaluated inside the
run, the rest length in effect during step ``j`` of the period (``j = 1 .. S``) being the motor's position at
that step's end, ``current + clip(target - current, -reel_speed j dt, reel_speed j dt)``.
"""
from __future__ import annotations

import math

import numpy as np

from ..batch import BatchSimulator
from ..commands import CommandSchedule
from ..methods.rigid import RigidStruts
from ..scene import Scene, load_scene
from . import _kernels

__all__ = ["PARAMETERS", "RollTask"]

# the task's parameters and their defaults (an environment's keyword arguments); see RollTask
PARAMETERS = {
    "scene": "icosahedron_ground",
    "cables": None,
    "goal": (1.0, 0.0),
    "control_dt": 0.02,
    "dt": 1e-3,
    "episode_seconds": 10.0,
    "reel_speed": 1.0,
    "rest_range": (0.5, 1.0),
    "effort_cost": 0.1,
    "noise": 0.01,
}


class _Reel(CommandSchedule):
    """One control period's rest lengths of the actuated cables, every step of every copy: ``reel`` (S, na, B) m,
    the cables ``rest_cables`` (na,). Only what the compiled ground run asks of a batch's schedule (style rule 8:
    one schedule for all copies, its per-copy values on the trailing axis): :meth:`inputs_at` for the S step times
    of the period, ``base`` (nc, B) and ``forces`` (N, 3, B) held; the same numbers as B schedules that name each
    step's value at its start time (``np.interp`` at a point is the point's value), without a Python loop; the
    forces as given (one column where every copy's are the same: the run passes it so)."""

    def __init__(self, cables: np.ndarray, reel: np.ndarray, n_nodes: int):
        super().__init__(cables, (), (), np.zeros(0), np.zeros((0, n_nodes, 3)))
        object.__setattr__(self, "reel", reel)

    def inputs_at(self, times, base, forces):
        steps, copies = len(times), self.reel.shape[2]
        if self.reel.shape[0] != steps or base.ndim != 2:
            raise ValueError(f"a control period of {self.reel.shape[0]} steps asked for {steps} steps' inputs")
        # (the run passes one column where every copy's rest lengths are equal); the reel is laid out as the
        # run's inputs, batch last: itself where it reels every cable in order, else two plain copies (a
        # transposing one took ~0.15 ms of a 256-copy period)
        if len(self.rest_cables) == len(base) and (self.rest_cables == np.arange(len(base))).all():
            return self.reel, np.repeat(forces[None], steps, axis=0)
        rest = np.empty((steps, len(base), copies))
        rest[:] = base
        rest[:, self.rest_cables] = self.reel
        return rest, np.repeat(forces[None], steps, axis=0)


def _positive(name: str, value) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(out) or out <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return out


def unit_goal(goal, name: str = "goal") -> np.ndarray:
    """A horizontal goal direction (2,) made a unit vector; refuses a zero or non-finite one."""
    g = np.asarray(goal, dtype=float) if not isinstance(goal, str) else np.array([])
    if g.shape != (2,) or not np.all(np.isfinite(g)) or not np.any(g):
        raise ValueError(f"{name} must be 2 finite numbers, not both zero (a horizontal direction), got {goal!r}")
    return g / np.linalg.norm(g)


class RollTask:
    """B copies of ``scene`` (a :class:`~tensegrity_sim.Scene` or a scene's name or path) rolling toward a goal.

    ``cables``: the actuated cables' names (default: every cable, the ones ``examples/roll_controller.py`` may
    reel). ``goal``: the horizontal direction (2,) to roll in. ``control_dt``: s per action, a whole number of
    simulator steps of ``dt`` s. ``episode_seconds``: the episode's length, s (a whole number of control
    periods). ``reel_speed``: the motors' speed, m/s of rest length. ``rest_range``: (low, high), the rest
    lengths actions -1 and +1 ask for, as fractions of each cable's rest length in the scene. ``effort_cost``:
    reward lost per metre of cable reeled (in or out). ``noise``: m/s, the standard deviation of a random
    velocity given to every node coordinate at a reset (its components that would stretch a rigid strut
    removed).
    """

    def __init__(self, copies: int, **params):
        unknown = sorted(set(params) - set(PARAMETERS))
        if unknown:
            raise TypeError(f"unknown parameter {unknown[0]!r} (known: {', '.join(PARAMETERS)})")
        p = {**PARAMETERS, **params}
        scene = p["scene"] if isinstance(p["scene"], Scene) else load_scene(p["scene"])
        if scene.ground is None:
            raise ValueError(f"scene {scene.name!r} has no ground: the roll task needs one")
        names = list(scene.cable_names) if p["cables"] is None else p["cables"]
        if isinstance(names, str) or not isinstance(names, (list, tuple)):
            raise ValueError(f"cables must be a list of cable names, got {names!r}")
        if not names:
            raise ValueError(f"cables: no actuated cable (scene {scene.name!r} has {len(scene.cables)} cables)")
        index = {n: i for i, n in enumerate(scene.cable_names)}
        for n in names:
            if n not in index:
                raise ValueError(f"cables: unknown cable {n!r} (scene {scene.name!r} has "
                                 f"{', '.join(scene.cable_names) or 'none'})")
        if len(set(names)) != len(names):
            raise ValueError(f"cables: a cable named twice in {names!r}")
        self.dt = _positive("dt", p["dt"])
        self.control_dt = _positive("control_dt", p["control_dt"])
        self.substeps = round(self.control_dt / self.dt)
        if self.substeps < 1 or abs(self.substeps * self.dt - self.control_dt) > 1e-9 * self.control_dt:
            raise ValueError(f"control_dt ({self.control_dt!r} s) must be a whole number of steps of dt "
                             f"({self.dt!r} s)")
        seconds = _positive("episode_seconds", p["episode_seconds"])
        self.periods = round(seconds / self.control_dt)
        if self.periods < 1 or abs(self.periods * self.control_dt - seconds) > 1e-9 * seconds:
            raise ValueError(f"episode_seconds ({seconds!r}) must be a whole number of control periods "
                             f"({self.control_dt!r} s)")
        self.reel_speed = _positive("reel_speed", p["reel_speed"])
        low, high = self._range(p["rest_range"])
        self.effort_cost = float(p["effort_cost"])
        if not math.isfinite(self.effort_cost) or self.effort_cost < 0:
            raise ValueError(f"effort_cost must be a finite number >= 0, got {p['effort_cost']!r}")
        self.noise = float(p["noise"])
        if not math.isfinite(self.noise) or self.noise < 0:
            raise ValueError(f"noise must be a finite number >= 0, got {p['noise']!r}")
        self.goal = unit_goal(p["goal"])
        self.scene = scene
        self.cables = tuple(names)
        self.actuated = np.array([index[n] for n in names], dtype=np.intp)
        rest = scene.cable_rest_lengths
        self.rest0 = rest.copy()
        self.low, self.high = low * rest[self.actuated], high * rest[self.actuated]
        self.sim = BatchSimulator(scene, copies, method="elastic", dt=self.dt, contacts=())
        if RigidStruts(self.sim.system).coupled:   # stepped by the numpy reference, one step at a time
            raise ValueError(f"scene {scene.name!r}: rigid struts that share a node (class-k) have no compiled run; "
                             f"the environments reel the cables inside one")
        self.masses = self.sim.system.masses
        self.batch = copies
        # the period's reel, rewards and observations by the compiled kernels (envs/_kernels.py); False: by numpy,
        # their reference (the same numbers to round-off)
        self.compiled = True
        n, nc = len(scene.nodes), len(scene.cables)
        self.n_obs = nc + len(names) + 6 * n + 2
        self.goals = np.tile(self.goal, (copies, 1))
        self.elapsed = np.zeros(copies, dtype=np.int64)   # control periods since each copy's reset
        # the copies' centres of mass (B, 3) m now: kept with the state (one computation a control period, the
        # reward's, the observation's and the info's)
        self.centres = self.com(self.sim.positions)

    @staticmethod
    def _range(value) -> tuple[float, float]:
        try:
            low, high = (float(v) for v in value)
        except (TypeError, ValueError):
            raise ValueError(f"rest_range must be two numbers (low, high), got {value!r}") from None
        if not (0 < low < high and math.isfinite(high)):
            raise ValueError(f"rest_range must be 0 < low < high (fractions of rest lengths), got {value!r}")
        return low, high

    # ------------------------------------------------------------------ states
    def com(self, x: np.ndarray) -> np.ndarray:
        """Centres of mass (B, 3) m of node positions (B, N, 3) m."""
        return (self.masses @ x) / self.masses.sum()

    def start_state(self, rng: np.random.Generator, options: dict | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A copy's start: positions, velocities (N, 3) and goal (2,) from ``options`` ("yaw": rad, a turn of
        the scene's pose about the vertical through its centre of mass; "noise": m/s, as the parameter;
        "goal": (2,), as the parameter) and the copy's random generator."""
        options = {} if options is None else dict(options)
        unknown = sorted(set(options) - {"yaw", "noise", "goal", "reset_mask"})
        if unknown:
            raise ValueError(f"reset options: unknown option {unknown[0]!r} (known: goal, noise, yaw)")
        x = self.scene.positions.copy()
        yaw = float(options.get("yaw", 0.0))
        if not math.isfinite(yaw):
            raise ValueError(f"reset options: yaw must be a finite angle in rad, got {options['yaw']!r}")
        if yaw:
            c = self.com(x[None])[0]
            turn = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0, 0, 1.0]])
            x = c + (x - c) @ turn.T
        noise = float(options.get("noise", self.noise))
        if not math.isfinite(noise) or noise < 0:
            raise ValueError(f"reset options: noise must be a finite number >= 0, got {options['noise']!r}")
        v = noise * rng.standard_normal(x.shape) * ~self.scene.fixed[:, None]
        goal = unit_goal(options["goal"], "reset options: goal") if "goal" in options else self.goal
        return x, v, goal

    def restart(self, copies: np.ndarray, starts: list) -> None:
        """Start ``copies`` again from ``starts`` (one :meth:`start_state` each)."""
        self.sim.restart(copies, np.stack([s[0] for s in starts]), np.stack([s[1] for s in starts]),
                         np.tile(self.rest0, (len(copies), 1)))
        self.goals[copies] = np.stack([s[2] for s in starts])
        self.elapsed[copies] = 0
        self.centres[copies] = self.com(np.stack([s[0] for s in starts]))

    def observe(self) -> np.ndarray:
        """(B, n_obs) float64: cable lengths (n_cables) m, the actuated cables' rest lengths (n_actuated) m,
        node positions relative to the centre of mass (N x 3) m, node velocities (N x 3) m/s, goal (2)."""
        state = self.sim.batch_last() if self.compiled else None
        if state is not None:
            out = np.empty((self.batch, self.n_obs))
            _kernels.observe(*state, self.sim.system.cable_ends, self.actuated, self.centres, self.goals, out)
            return out
        x, v = self.sim.positions, self.sim.velocities
        ce = self.sim.system.cable_ends
        b, n, nc, na = self.batch, x.shape[1], len(ce), len(self.actuated)
        out = np.empty((b, self.n_obs))   # each part written in place
        d = x[:, ce[:, 1]] - x[:, ce[:, 0]]
        # np.linalg.norm's arithmetic (its sum of three squares in order) at a sixth of its cost
        lengths = out[:, :nc]
        np.multiply(d[..., 0], d[..., 0], out=lengths)
        lengths += d[..., 1] * d[..., 1]
        lengths += d[..., 2] * d[..., 2]
        np.sqrt(lengths, out=lengths)
        out[:, nc:nc + na] = self.sim.rest_lengths[:, self.actuated]
        at = nc + na
        np.subtract(x, self.centres[:, None], out=out[:, at:at + 3 * n].reshape(b, n, 3))
        out[:, at + 3 * n:at + 6 * n] = v.reshape(b, -1)
        out[:, at + 6 * n:] = self.goals
        return out

    # ------------------------------------------------------------------ stepping
    def check_actions(self, actions, shape: tuple) -> np.ndarray:
        """Actions as a float array of ``shape``, every value finite and in [-1, 1]; else a ValueError."""
        try:
            a = np.asarray(actions, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"action must be numbers of shape {shape}, got {type(actions).__name__}") from None
        if a.shape != shape:
            raise ValueError(f"action must have shape {shape} (one value in [-1, 1] per actuated cable), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action has a value that is not finite at {np.argwhere(~np.isfinite(a))[0].tolist()}")
        out = np.argwhere((a < -1) | (a > 1))
        if out.size:
            raise ValueError(f"action[{', '.join(map(str, out[0]))}] = {float(a[tuple(out[0])])!r} is outside [-1, 1]")
        return a

    def targets(self, actions: np.ndarray) -> np.ndarray:
        """Rest-length targets (B, n_actuated) m of actions (B, n_actuated) in [-1, 1]."""
        return self.low + 0.5 * (actions + 1.0) * (self.high - self.low)

    def advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One control period of every copy from actions (B, n_actuated) in [-1, 1]: rewards (B,) and the copies'
        time limits reached (B,) bool. The copies the simulator refused are in ``sim.failures`` {copy: reason}."""
        sim, s = self.sim, self.substeps
        state = sim.batch_last() if self.compiled else None
        if state is not None:
            before, start = self.centres, state[2][self.actuated]                           # (B, 3), (na, B) m
            rest = np.empty((s, len(self.actuated), self.batch))
            _kernels.reel(state[2], self.actuated, self.targets(actions), self.reel_speed * self.dt, rest)
            sim.run(steps=s, every=s, commands=_Reel(self.actuated, rest, len(self.scene.nodes)), fields=(),
                    ground_events=False)
            x, _, rest_now = sim.batch_last()
            self.centres, rewards = np.empty((self.batch, 3)), np.empty(self.batch)
            _kernels.period_end(x, rest_now, self.masses, self.actuated, start, before, self.goals, self.effort_cost,
                                self.centres, rewards)
            return self._finished(rewards)
        before = self.centres[:, :2]
        current = sim.rest_lengths[:, self.actuated]
        reach = self.reel_speed * self.dt * np.arange(1, s + 1)[:, None, None]          # (S, 1, 1) m
        motors = np.ascontiguousarray(current.T)                                          # (na, B) m
        # motors + clip(target - motors, -reach, reach), (S, na, B): np.clip's broadcast bounds took ~1 ms of a
        # 256-copy period, its minimum and maximum in place a tenth of that (the same numbers)
        rest = np.minimum(np.ascontiguousarray(self.targets(actions).T) - motors, reach)
        np.maximum(rest, -reach, out=rest)
        rest += motors
        # nothing kept but the state (no trajectory, no ground events): what a period's step reads
        sim.run(steps=s, every=s, commands=_Reel(self.actuated, rest, len(self.scene.nodes)), fields=(),
                ground_events=False)
        self.centres = self.com(sim.positions)
        after = self.centres[:, :2]
        effort = np.abs(rest[-1].T - current).sum(axis=1)
        rewards = np.einsum("bk,bk->b", after - before, self.goals) - self.effort_cost * effort
        return self._finished(rewards)

    def _finished(self, rewards: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A control period's end: its rewards (a refused copy's none) and the copies' time limits reached."""
        self.elapsed += 1
        rewards[self.sim.failed] = 0.0   # a refused copy stands still at its last good state
        return rewards, self.elapsed >= self.periods
