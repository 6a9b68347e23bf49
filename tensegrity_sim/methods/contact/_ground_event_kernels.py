"""The ground's contact changes over a chunk of steps, compiled (numba): where ``ground.GroundDetector.step``
would find a node's contact beginning or ending, for K steps of B copies in one pass.

A node touches the ground after a step when its gap (its height less its radius less the ground's height)
is within ``TOUCH_TOL`` or the ground pushed it in that step, and it is free; a change is a step at which
that differs from the step before (for the first, from what the detector knew). ``GroundDetector.step``'s
numpy arithmetic, for one node, step and copy at a time: the tests hold a run's events to those of
stepping one step at a time.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["ground_changes", "changed_steps"]


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _touching(height_z, radius, ground, tol, pushed, free) -> bool:
    """A node in contact after a step: free, and within ``tol`` of the ground or pushed by it."""
    return free and (height_z - radius - ground <= tol or pushed > 0.0)


@njit(cache=True, error_model="numpy", _nrt=False)
def changed_steps(positions, impulses, inside, radii, height, free, tol, changed):
    """``changed`` (K,) bool: whether a node's contact begins or ends at each of the K consecutive steps to
    ``positions`` with the ground's ``impulses`` (K, N, 3) of one copy, from ``inside`` (N,) bool (what the
    detector knew before them); :func:`ground_changes`' test, for ``Simulator.step``'s steps ahead."""
    changed[:] = False
    for p in range(positions.shape[1]):
        was = inside[p]
        for k in range(positions.shape[0]):
            now = _touching(positions[k, p, 2], radii[p], height, tol, impulses[k, p, 2], free[p])
            if now != was:
                changed[k] = True
                was = now


@njit(cache=True, error_model="numpy")
def ground_changes(positions, impulses, inside, radii, height, free, tol, last):
    """The changes in ``positions`` and the ground's ``impulses`` (K, N, 3, B) from ``inside`` (N, B) bool:
    ``(steps, nodes, copies, begins)`` (M,) each, begins True where the contact begins, in the order of
    the copies, then the steps, then the nodes; ``last`` (N, B) bool gets the contacts after the last step.
    Walks each copy's numbers in the order the batch's kernels write them (a copy's steps side by side:
    twice as fast as node by node), counting the changes, then again recording them (the test,
    :func:`_touching`, takes numbers, not the arrays: passing the arrays, their reference counts cost 8 times
    the test)."""
    k_steps, n_nodes, _, n_copies = positions.shape
    was = np.empty(n_nodes, dtype=np.bool_)
    count = 0
    for b in range(n_copies):
        for p in range(n_nodes):
            was[p] = inside[p, b]
        for k in range(k_steps):
            for p in range(n_nodes):
                now = _touching(positions[k, p, 2, b], radii[p], height, tol, impulses[k, p, 2, b], free[p])
                if now != was[p]:
                    count += 1
                    was[p] = now
    steps = np.empty(count, dtype=np.int64)
    nodes = np.empty(count, dtype=np.int64)
    copies = np.empty(count, dtype=np.int64)
    begins = np.empty(count, dtype=np.bool_)
    i = 0
    for b in range(n_copies):
        for p in range(n_nodes):
            was[p] = inside[p, b]
        for k in range(k_steps):
            for p in range(n_nodes):
                now = _touching(positions[k, p, 2, b], radii[p], height, tol, impulses[k, p, 2, b], free[p])
                if now != was[p]:
                    steps[i] = k
                    nodes[i] = p
                    copies[i] = b
                    begins[i] = now
                    i += 1
                    was[p] = now
        for p in range(n_nodes):
            last[p, b] = was[p]
    return steps, nodes, copies, begins
