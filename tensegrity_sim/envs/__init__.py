"""Gymnasium environments (the ``learn`` extra): importing this package registers them.

* ``tensegrity_sim/Roll-v0``: roll a scene with a ground toward a goal direction by reeling its actuated
  cables (:class:`~.roll.RollEnv`); ``gymnasium.make_vec(ID, num_envs=N, vectorization_mode="vector_entry_point")``
  builds :class:`~.roll.RollVectorEnv`, N copies stepped in one compiled call.
* :mod:`.jax_roll` (the ``jax`` extra, imported on its own): the same task as a JAX functional environment
  (gymnax's ``reset``/``step`` with explicit keys, state and parameters; jit-able, vmap-able).

    import gymnasium as gym
    import tensegrity_sim.envs  # registers
    env = gym.make("tensegrity_sim/Roll-v0", goal=(0.0, 1.0))

(``gym.make("tensegrity_sim.envs:tensegrity_sim/Roll-v0")`` imports this package itself.)
"""
from gymnasium.envs.registration import register, registry

from .roll import RollEnv, RollVectorEnv
from .task import PARAMETERS, RollTask

__all__ = ["ROLL_ID", "PARAMETERS", "RollEnv", "RollTask", "RollVectorEnv"]

ROLL_ID = "tensegrity_sim/Roll-v0"

if ROLL_ID not in registry:
    register(id=ROLL_ID, entry_point="tensegrity_sim.envs.roll:RollEnv",
             vector_entry_point="tensegrity_sim.envs.roll:RollVectorEnv", disable_env_checker=False)
