"""``tensegrity_sim/Roll-v0``: roll a tensegrity on a ground toward a goal direction (Gymnasium).

:class:`RollEnv` is one robot; :class:`RollVectorEnv` is ``num_envs`` of them stepped in one compiled call of a
:class:`~tensegrity_sim.batch.BatchSimulator` (the environment's ``vector_entry_point``). Both run
:class:`~.task.RollTask` (its docstring has the parameters); each copy of the vector environment is the very
arithmetic of a :class:`RollEnv` with the same seed and actions (``test/test_envs.py``).

* **action** (n_actuated,) in [-1, 1]: each actuated cable's rest-length target, -1 and +1 being
  ``rest_range``'s fractions of its rest length in the scene, reeled toward at ``reel_speed`` m/s.
* **observation** (n_cables + n_actuated + 6 N + 2,) float64: the cables' lengths (m), the actuated cables'
  rest lengths (m, the motors' positions), the nodes' positions relative to the centre of mass (N x 3, m),
  the nodes' velocities (N x 3, m/s) and the goal direction (2, a horizontal unit vector).
* **reward**: the centre of mass's progress along the goal in the control period (m) minus ``effort_cost``
  times the cable reeled in it (m).
* **episode**: never terminated; truncated after ``episode_seconds``, or when the simulator refuses a state
  (``info["refused"]``: the reason; the state stays the last good one).
* **reset options**: ``goal`` (2,), ``yaw`` (rad: the start pose turned about the vertical through its centre
  of mass), ``noise`` (m/s: the standard deviation of random node velocities; default the parameter).
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from gymnasium.utils import seeding

from .task import RollTask

__all__ = ["RollEnv", "RollVectorEnv", "draw_frame"]

RENDER_SIZE = (320, 320)   # pixels of a frame


def draw_frame(task: RollTask, copy: int) -> np.ndarray:
    """A picture (H, W, 3) uint8 of copy ``copy``: struts thick, cables thin, the goal an arrow on the ground."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    x = task.sim.positions[copy]
    centre = task.com(x[None])[0]
    fig = Figure(figsize=(RENDER_SIZE[0] / 80, RENDER_SIZE[1] / 80), dpi=80)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d")
    system = task.sim.system
    for ends, style in ((system.strut_ends, dict(color="0.15", lw=3)),
                        (system.cable_ends, dict(color="tab:blue", lw=1))):
        for a, b in ends:
            ax.plot(*x[[a, b]].T, **style)
    goal = task.goals[copy]
    ground = task.scene.ground.height
    ax.quiver(centre[0], centre[1], ground, goal[0], goal[1], 0.0, color="tab:red", length=0.8)
    span = 1.2
    ax.set(xlim=(centre[0] - span, centre[0] + span), ylim=(centre[1] - span, centre[1] + span),
           zlim=(ground, ground + 2 * span), xlabel="x (m)", ylabel="y (m)")
    ax.set_title(f"t = {task.elapsed[copy] * task.control_dt:.2f} s")
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def _spaces(task: RollTask) -> tuple[gym.spaces.Box, gym.spaces.Box]:
    obs = gym.spaces.Box(-np.inf, np.inf, (task.n_obs,), dtype=np.float64)
    act = gym.spaces.Box(-1.0, 1.0, (len(task.actuated),), dtype=np.float64)
    return obs, act


class RollEnv(gym.Env):
    """One robot rolling toward a goal (see the module docstring); ``params``: :class:`~.task.RollTask`'s."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, render_mode: str | None = None, **params):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.task = RollTask(1, **params)
        self.observation_space, self.action_space = _spaces(self.task)
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.task.control_dt)}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.task.restart(np.array([0]), [self.task.start_state(self.np_random, options)])
        return self.task.observe()[0], self._info()

    def step(self, action):
        a = self.task.check_actions(action, self.action_space.shape)
        reward, limit = self.task.advance(a[None])
        refused = self.task.sim.failures.get(0)
        info = self._info()
        if refused is not None:
            info["refused"] = refused
        return self.task.observe()[0], float(reward[0]), False, bool(limit[0] or refused is not None), info

    def _info(self) -> dict:
        """The copy's time (s since its reset) and centre of mass (3,) m."""
        return {"time": float(self.task.elapsed[0] * self.task.control_dt), "com": self.task.centres[0].copy()}

    def render(self):
        if self.render_mode == "rgb_array":
            return draw_frame(self.task, 0)
        return None


class RollVectorEnv(VectorEnv):
    """``num_envs`` robots rolling toward goals, every copy's control period in one compiled call; autoreset
    as Gymnasium's ``NEXT_STEP`` mode (the step after a copy's episode ends resets it: its action is ignored,
    its observation is the reset's, its reward 0). Seeding as ``SyncVectorEnv``'s: ``reset(seed=s)`` seeds
    copy ``i`` with ``s + i`` (or ``seed`` a list, one per copy). ``options["reset_mask"]`` (num_envs,) bool
    resets only those copies."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"]}

    def __init__(self, num_envs: int, render_mode: str | None = None, **params):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be a whole number >= 1, got {num_envs!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.num_envs = int(num_envs)
        self.render_mode = render_mode
        self.task = RollTask(self.num_envs, **params)
        self.single_observation_space, self.single_action_space = _spaces(self.task)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs = [seeding.np_random()[0] for _ in range(self.num_envs)]
        self._autoreset = np.zeros(self.num_envs, dtype=bool)

    def reset(self, *, seed=None, options: dict | None = None):
        super().reset(seed=seed if isinstance(seed, (int, np.integer)) else None)
        options = {} if options is None else dict(options)
        mask = np.asarray(options.pop("reset_mask", np.ones(self.num_envs, dtype=bool)))
        if mask.shape != (self.num_envs,) or mask.dtype != bool:
            raise ValueError(f"reset options: reset_mask must be {self.num_envs} bools, got {mask!r}")
        if seed is not None:
            seeds = seed if isinstance(seed, (list, tuple)) else [seed + i for i in range(self.num_envs)]
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed: expected one int or a list of {self.num_envs}, got {len(seeds)}")
            for i in np.flatnonzero(mask):
                if seeds[i] is not None:
                    self._rngs[i] = seeding.np_random(int(seeds[i]))[0]
        copies = np.flatnonzero(mask)
        self.task.restart(copies, [self.task.start_state(self._rngs[i], options) for i in copies])
        self._autoreset[copies] = False
        return self.task.observe(), self._infos()

    def step(self, actions):
        a = self.task.check_actions(actions, self.action_space.shape)
        rewards, limit = self.task.advance(a)
        copies = np.flatnonzero(self._autoreset)
        if copies.size:   # the copies whose episodes ended at the last step start again (their actions ignored)
            self.task.restart(copies, [self.task.start_state(self._rngs[i], None) for i in copies])
            rewards[copies] = 0.0
        failed = self.task.sim.failed
        truncated = (limit | failed) & ~self._autoreset
        self._autoreset = truncated.copy()
        return self.task.observe(), rewards, np.zeros(self.num_envs, dtype=bool), truncated, self._infos(failed)

    def _infos(self, failed: np.ndarray | None = None) -> dict:
        """Per copy: time (s since its reset), com (3,) m and, where the simulator refused it, refused (its reason);
        each with Gymnasium's ``_key`` mask of the copies that have it."""
        every = np.ones(self.num_envs, dtype=bool)
        infos = {"time": self.task.elapsed * self.task.control_dt, "_time": every,
                 "com": self.task.centres.copy(), "_com": every.copy()}
        if failed is not None and failed.any():
            reasons = np.full(self.num_envs, None, dtype=object)
            for b, reason in self.task.sim.failures.items():
                reasons[b] = reason
            infos["refused"], infos["_refused"] = reasons, failed.copy()
        return infos

    def render(self):
        if self.render_mode == "rgb_array":
            return tuple(draw_frame(self.task, b) for b in range(self.num_envs))
        return None
