"""Compiled twins of :class:`.system.System`'s member kinematics (the plain numpy reference, which tests
require this to match to 1e-12), with numba.

The node publishes every cable's length and elongation rate at each publication; computed with
``System.geometry`` and ``System.member_rates`` that is ~17 us of numpy dispatch on the icosahedron's
24 cables (fancy indexing and two ``einsum`` calls), and 0.6 us here: most of what a publication cost
besides writing the log. The arithmetic is the reference's, in plain sequential order (numpy's
``einsum`` may sum the three products in another order or with fused multiply-adds, by CPU, so the two
can differ in the last bit).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["member_kinematics"]


@njit(cache=True, _nrt=False)
def member_kinematics(x, v, ends, length, rate):
    """Lengths (k,) m and elongation rates (k,) m/s of the members ``ends`` (k, 2) (node indices a, b) at
    positions ``x`` (N, 3) m and velocities ``v`` (N, 3) m/s, written into ``length`` and ``rate``:
    ``l = |x_b - x_a|``, ``de/dt = n . (v_b - v_a)`` with ``n = (x_b - x_a) / l``."""
    for i in range(ends.shape[0]):
        a = ends[i, 0]
        b = ends[i, 1]
        d0 = x[b, 0] - x[a, 0]
        d1 = x[b, 1] - x[a, 1]
        d2 = x[b, 2] - x[a, 2]
        li = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        length[i] = li
        rate[i] = (v[b, 0] - v[a, 0]) * (d0 / li) + (v[b, 1] - v[a, 1]) * (d1 / li) + (v[b, 2] - v[a, 2]) * (d2 / li)
