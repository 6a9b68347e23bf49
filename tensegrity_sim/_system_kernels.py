"""Compiled twins of :class:`.system.System`'s member kinematics (the plain numpy reference, which tests
require this to match to 1e-12), with numba.

The node publishes every cable's length and elongation rate at each publication; computed with
``System.geometry`` and ``System.cable_rates`` that is ~17 us of numpy dispatch on the icosahedron's
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
def member_kinematics(x, v, nodes, weights, length, rate):
    """Lengths (k,) m and elongation rates (k,) m/s of the members whose end ``j`` lies at ``(1 - w) x[nodes[i, j,
    0]] + w x[nodes[i, j, 1]]``, ``w = weights[i, j]`` (``System.cable_nodes``, ``cable_weights``: a node end is
    ``(node, node)`` with ``w = 0``, the very node's numbers), at positions ``x`` (N, 3) m and velocities ``v``
    (N, 3) m/s, written into ``length`` and ``rate``: ``l = |X_b - X_a|``, ``de/dt = n . (V_b - V_a)`` with
    ``n = (X_b - X_a) / l``."""
    for i in range(nodes.shape[0]):
        a0 = nodes[i, 0, 0]
        a1 = nodes[i, 0, 1]
        b0 = nodes[i, 1, 0]
        b1 = nodes[i, 1, 1]
        wa = weights[i, 0]
        wb = weights[i, 1]
        ua = 1.0 - wa
        ub = 1.0 - wb
        d0 = (ub * x[b0, 0] + wb * x[b1, 0]) - (ua * x[a0, 0] + wa * x[a1, 0])
        d1 = (ub * x[b0, 1] + wb * x[b1, 1]) - (ua * x[a0, 1] + wa * x[a1, 1])
        d2 = (ub * x[b0, 2] + wb * x[b1, 2]) - (ua * x[a0, 2] + wa * x[a1, 2])
        li = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        length[i] = li
        u0 = (ub * v[b0, 0] + wb * v[b1, 0]) - (ua * v[a0, 0] + wa * v[a1, 0])
        u1 = (ub * v[b0, 1] + wb * v[b1, 1]) - (ua * v[a0, 1] + wa * v[a1, 1])
        u2 = (ub * v[b0, 2] + wb * v[b1, 2]) - (ua * v[a0, 2] + wa * v[a1, 2])
        rate[i] = u0 * (d0 / li) + u1 * (d1 / li) + u2 * (d2 / li)
