"""The elastic method in JAX: B copies stepped by one jit-compiled ``lax.scan`` of a ``vmap``-ed step, on
whatever device JAX finds (CPU, GPU), and differentiable (``jax.grad``/``jax.jacfwd`` of a run).

The numba kernels (``methods/elastic/_kernels.py``) stay the default; this backend mirrors them function by
function (brax keeps a backend a subpackage with the same functions): :mod:`.elastic` has
``model_arrays``, ``elastic_forces``, ``verlet_step`` and ``elastic_steps`` (and ``rollout``, the
differentiable run); :mod:`.ground` the ground contact; :mod:`.engine` the drivers
(``BatchSimulator(..., backend="jax")`` and ``Simulator(..., backend="jax")``, a batch of one); :mod:`.fit`
fits scene parameters to a logged run (``tensegrity-sim fit``).

JAX is an optional dependency (the ``jax`` extra): only this subpackage imports it. Importing it turns on
JAX's 64-bit mode (``jax_enable_x64``), so that a run is float64 by default, as the numba path; float32 is
asked for per run.
"""
from __future__ import annotations

try:
    import jax
except ImportError as exc:   # the core runs without JAX; only this backend needs it
    raise ImportError(
        'the JAX backend (backend="jax", tensegrity-sim fit) needs JAX, which is not installed: '
        'pip install "tensegrity_sim[jax]" (CPU), or docs/jax.md for the JAX CUDA wheels on a GPU') from exc

jax.config.update("jax_enable_x64", True)

from .elastic import (ElasticModel, Inputs, elastic_forces, elastic_steps, held_inputs, model_arrays,  # noqa: E402
                      rollout, schedule_inputs, start_carry, verlet_step)

__all__ = ["ElasticModel", "Inputs", "model_arrays", "held_inputs", "schedule_inputs", "start_carry", "elastic_forces",
           "verlet_step", "elastic_steps", "rollout"]
