"""The drivers of the JAX step: :class:`ElasticBatchJax` (what ``BatchSimulator(..., backend="jax")`` steps, the
numba batch's ``ElasticBatch`` interface) and :class:`ElasticMethodJax` (what ``Simulator(..., backend="jax")``
steps: a batch of one behind the stepping contract of ``methods/base.py``).

Both keep the run's carry (the forces at the last step's end) on the device between calls, and hand numpy
arrays back in the numba batch's layouts (batch last). A run is compiled once per number of steps and
``every`` (``jax.jit``'s static arguments), so a driver that calls with the same chunk sizes compiles once.
"""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ...system import System
from ..base import MethodStep, State
from ..elastic.method import ElasticMethod
from ..elastic.batch import ElasticBatch
from .elastic import Carry, elastic_steps, held_inputs, model_arrays, schedule_inputs, start_carry

__all__ = ["DTYPES", "ElasticBatchJax", "ElasticMethodJax"]

DTYPES = {"float64": jnp.float64, "float32": jnp.float32}


def _dtype(dtype: str):
    if dtype not in DTYPES:
        raise ValueError(f"dtype must be one of {sorted(DTYPES)} (the JAX backend's precision), got {dtype!r}")
    return DTYPES[dtype]


class ElasticBatchJax(ElasticBatch):
    """:class:`~tensegrity_sim.methods.elastic.batch.ElasticBatch` (same checks, same ``advance``), stepped by the
    JAX step in ``dtype`` ("float64" or "float32"). The numpy helpers (``prepare``, ``slack``,
    ``strain_energy``) are the numba batch's."""

    backend = "jax"

    def __init__(self, system: System, dt: float, *, dtype: str = "float64"):
        self.dtype = _dtype(dtype)
        super().__init__(system, dt, compiled=False)
        self.model = model_arrays(system, self.rigid, self.dtype)
        self._carry: Carry | None = None
        self.inputs_in_effect = None   # (rest (nc, B), ext (N, 3, B)) of the last step of the last advance

    def invalidate(self) -> None:
        self._carry = None

    def runs_commands(self) -> bool:
        return True

    def summarises(self) -> bool:   # a run keeping no step takes the JAX run's steps as any other
        return False

    def advance(self, x, v, rest_lengths, f_ext, steps: int, commands=None, first_step: int = 0):
        """``steps`` steps of every copy from ``x``, ``v`` (N, 3, B) with rest lengths (n_cables, B) and external
        forces (N, 3, B), held, or with ``commands`` (a ``CommandSchedule``, or one per copy) evaluated inside the
        run at each step's start time ``(first_step + k) dt`` on top of them (``inputs_in_effect`` then has the
        inputs of the last step). Returns every step's positions and velocities (steps, N, 3, B), impulses
        (steps, n_cables, B) N*s and slack cables (steps, n_cables, B), as numpy arrays."""
        f = self.dtype
        inputs = (held_inputs(rest_lengths, f_ext, f) if commands is None
                  else schedule_inputs(commands, rest_lengths, f_ext, f))
        if self._carry is None:
            self._carry = start_carry(self.model, jnp.asarray(x, f), jnp.asarray(v, f), inputs.rest, inputs.ext)
        self._carry, out = elastic_steps(self.model, self._carry, inputs, self.dt, steps, 1, first_step,
                                         scheduled=commands is not None)
        self.inputs_in_effect = (np.asarray(out.rest, dtype=float), np.asarray(out.ext, dtype=float))
        return (*(np.asarray(a, dtype=float) for a in (out.x, out.v, out.impulses)), np.asarray(out.slack))


class ElasticMethodJax(ElasticMethod):
    """The elastic method (plain velocity Verlet, order 2) stepped by the JAX step: a batch of one in ``dtype``.
    The checks, ``prepare``, ``slack`` and ``strain_energy`` are :class:`ElasticMethod`'s."""

    options = ()

    def __init__(self, system: System, dt: float, *, dtype: str = "float64"):
        self.dtype = _dtype(dtype)
        super().__init__(system, dt, compiled=False)
        if system.scene.contact_response.response:
            raise ValueError("backend 'jax' has no member contact response (contact: response: true); use backend "
                             "'numba'")
        self.model = model_arrays(system, self.rigid, self.dtype)
        self._jax_carry: Carry | None = None

    def invalidate(self) -> None:
        super().invalidate()
        self._jax_carry = None

    def has_loop(self) -> bool:
        return True

    def runs_commands(self) -> bool:   # a Simulator's schedule is applied step by step here
        return False

    def carry(self):
        return self._jax_carry

    def restore(self, carry) -> None:   # the carry is immutable (JAX arrays): no copy to make
        self._jax_carry = carry

    def retrace(self, state: State) -> MethodStep | None:
        return self._step_reference(state)

    def advance(self, state: State, steps: int, every: int, positions, velocities, impulses, slack):
        f = self.dtype
        inputs = held_inputs(state.rest_lengths[:, None], state.external_forces[..., None], f)
        if self._jax_carry is None:
            self._jax_carry = start_carry(self.model, jnp.asarray(state.positions[..., None], f),
                                          jnp.asarray(state.velocities[..., None], f), inputs.rest, inputs.ext)
        self._jax_carry, out = elastic_steps(self.model, self._jax_carry, inputs, self.dt, steps, every)
        positions[...], velocities[...] = np.asarray(out.x[..., 0]), np.asarray(out.v[..., 0])
        impulses[...], slack[...] = np.asarray(out.impulses[..., 0]), np.asarray(out.slack[..., 0])
        return np.asarray(self._jax_carry.x[..., 0], dtype=float), np.asarray(self._jax_carry.v[..., 0], dtype=float)

    def _step_impl(self, state: State) -> MethodStep:
        n, nc = state.positions.shape[0], state.rest_lengths.shape[0]
        x, v, imp, slack = np.empty((1, n, 3)), np.empty((1, n, 3)), np.empty((1, nc)), np.empty((1, nc), dtype=bool)
        self.advance(state, 1, 1, x, v, imp, slack)
        return MethodStep(x[0], v[0], imp[0], slack[0])

    def describe(self) -> dict:
        return {**super().describe(), "backend": "jax", "dtype": np.dtype(self.dtype).name}
