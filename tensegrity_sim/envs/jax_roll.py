"""``Roll-v0``'s task as a JAX functional environment (the ``jax`` extra): gymnax's interface, explicit keys,
state and parameters, every function pure, so ``jax.jit`` and ``jax.vmap`` take them (a batch of robots is a
``vmap`` over keys and states) and a policy trains end to end on whatever device JAX finds.

    env = RollJax(episode_seconds=2.0)
    params = env.default_params
    obs, state = env.reset(key, params)
    obs, state, reward, done, info = env.step(key, state, action, params)

The physics is the JAX backend's elastic step (``methods/jax/elastic.py``, the ground's contact solve
included), the task :class:`~.task.RollTask`'s: the same actions, reel, observations (float64) and reward as
:class:`~.roll.RollEnv` (``test/test_envs.py`` holds the two to 1e-9 over an episode from the same start).
Differences a jit-able function imposes: an action is clipped to [-1, 1] (no error can be raised inside
``jit``); a state that is not finite ends the episode (``done``, ``info["finite"]`` False) where ``RollEnv``
truncates with the simulator's reason; ``reset`` draws the start velocities from the key (``jax.random``, not
NumPy's generator), ``reset_to`` starts from given ones.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..methods.jax import elastic as jel
from ..methods.rigid import RigidStruts
from .task import RollTask

__all__ = ["RollJax", "RollParams", "RollState"]

jax.config.update("jax_enable_x64", True)   # the numba environment's float64


class RollParams(NamedTuple):
    """What may change between episodes without compiling again: goal (2,) unit, effort_cost, noise m/s."""

    goal: jax.Array
    effort_cost: jax.Array
    noise: jax.Array


class RollState(NamedTuple):
    """carry: the JAX step's (positions, velocities, forces at the last step's end; batch of one); rest (nc,) m:
    the rest lengths in effect; elapsed: control periods since the reset; goal (2,)."""

    carry: jel.Carry
    rest: jax.Array
    elapsed: jax.Array
    goal: jax.Array


class RollJax:
    """The roll task of :class:`~.task.RollTask` (its parameters) as pure functions of keys, states, params."""

    def __init__(self, **params):
        task = RollTask(1, **params)   # validates the parameters as the Gymnasium environments do
        system = task.sim.system
        self.task = task
        self.model = jel.model_arrays(system, RigidStruts(system))
        self.num_actions = len(task.actuated)
        self.num_observations = task.n_obs
        self._actuated = jnp.asarray(task.actuated)
        self._low, self._high = jnp.asarray(task.low), jnp.asarray(task.high)
        self._rest0 = jnp.asarray(task.rest0)
        self._masses = jnp.asarray(system.masses)
        self._free = jnp.asarray((~task.scene.fixed).astype(float))
        self._x0 = jnp.asarray(task.scene.positions)
        self._ends = np.asarray(system.cable_ends)
        self._rigid = np.asarray(self.model.rigid_ends, dtype=int).reshape(-1, 2)
        self._reach = jnp.asarray(task.reel_speed * task.dt * np.arange(1, task.substeps + 1))
        self._ext = jnp.zeros((len(task.scene.nodes), 3, 1))

    @property
    def default_params(self) -> RollParams:
        t = self.task
        return RollParams(jnp.asarray(t.goal), jnp.asarray(t.effort_cost), jnp.asarray(t.noise))

    def _com(self, x):
        return self._masses @ x / self._masses.sum()

    def _prepared(self, x, v):
        """Velocities (N, 3) without the components that would stretch a rigid strut (``ElasticBatch.prepare``)."""
        if not len(self._rigid):
            return v
        inv_mass, _, w = jel._derived(self.model)
        d = x[self._rigid[:, 1]] - x[self._rigid[:, 0]]
        n = d / jnp.sqrt(jnp.sum(d * d, axis=1))[:, None]
        rate = jnp.sum((v[self._rigid[:, 1]] - v[self._rigid[:, 0]]) * n, axis=1)
        return v + jel._push(self.model, inv_mass, (rate / w)[:, None], n[..., None])[..., 0]

    def reset_to(self, positions, velocities, params: RollParams):
        """The observation and state of a start from ``positions``, ``velocities`` (N, 3) m, m/s."""
        v = self._prepared(positions, velocities)
        carry = jel.start_carry(self.model, positions[..., None], v[..., None], self._rest0[:, None], self._ext)
        state = RollState(carry, self._rest0, jnp.asarray(0), params.goal)
        return self.observe(state), state

    def reset(self, key, params: RollParams):
        """The scene's pose with random node velocities (``params.noise`` m/s standard deviation) from ``key``."""
        v = params.noise * jax.random.normal(key, self._x0.shape, dtype=self._x0.dtype) * self._free[:, None]
        return self.reset_to(self._x0, v, params)

    def observe(self, state: RollState):
        """(n_obs,): cable lengths, actuated rest lengths, positions relative to the centre of mass, velocities,
        goal (:class:`~.roll.RollEnv`'s layout)."""
        x, v = state.carry.x[..., 0], state.carry.v[..., 0]
        d = x[self._ends[:, 1]] - x[self._ends[:, 0]]
        lengths = jnp.sqrt(jnp.sum(d * d, axis=1))
        return jnp.concatenate([lengths, state.rest[self._actuated], (x - self._com(x)).ravel(), v.ravel(),
                                state.goal])

    def step(self, key, state: RollState, action, params: RollParams):
        """One control period: (observation, state, reward, done, info) as gymnax's ``step_env``; ``key`` is
        unused (the step is deterministic) and kept for the interface."""
        del key
        model, h = self.model, self.task.dt
        action = jnp.clip(action, -1.0, 1.0)
        current = state.rest[self._actuated]
        targets = self._low + 0.5 * (action + 1.0) * (self._high - self._low)
        reel = current + jnp.clip(targets - current, -self._reach[:, None], self._reach[:, None])   # (S, na)

        def one(loop, rest_actuated):
            carry, previous = loop
            rest = previous.at[self._actuated].set(rest_actuated)
            # a new input: the forces at the step's start computed with it (the numba run does the same)
            carry = jax.lax.cond(jnp.any(rest != previous),
                                 lambda: jel.start_carry(model, carry.x, carry.v, rest[:, None], self._ext),
                                 lambda: carry)
            carry = jel.verlet_step(model, carry, rest[:, None], self._ext, jnp.asarray(h))[0]
            return (carry, rest), None

        before = self._com(state.carry.x[..., 0])
        (carry, rest), _ = jax.lax.scan(one, (state.carry, state.rest), reel)
        after = self._com(carry.x[..., 0])
        finite = jnp.all(jnp.isfinite(carry.x)) & jnp.all(jnp.isfinite(carry.v))
        reward = (after - before)[:2] @ state.goal - params.effort_cost * jnp.sum(jnp.abs(reel[-1] - current))
        new = RollState(carry, rest, state.elapsed + 1, state.goal)
        done = (new.elapsed >= self.task.periods) | ~finite
        info = {"time": new.elapsed * self.task.control_dt, "com": after, "finite": finite}
        return self.observe(new), new, jnp.where(finite, reward, 0.0), done, info
