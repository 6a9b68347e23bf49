"""Optimising what moves a robot (the ``learn`` extra: CMA-ES; the ``jax`` extra: gradients): :mod:`.gait`."""
