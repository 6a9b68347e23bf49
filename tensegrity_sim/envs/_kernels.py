"""The roll task's arithmetic around a control period, compiled: the reel that becomes the period's inputs, and
after the run the copies' centres of mass, rewards and observations, read from the batch's own arrays (batch
last) in one pass each (:class:`~.task.RollTask`'s numpy methods, ``compiled=False``, are their reference: the
same numbers, tested to 1e-12). In numpy these took about a tenth of a 256-copy period: a few dozen array
operations on small trailing axes, and the state's copies with the batch first."""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["observe", "period_end", "reel"]


@njit(cache=True, error_model="numpy")
def reel(rest, actuated, targets, step_reach, out):
    """The period's rest lengths of the actuated cables into ``out`` (S, na, B) m: each motor from where it is
    (``rest`` (nc, B) m, its cable ``actuated`` (na,)) toward ``targets`` (B, na) m, at step ``j`` (from 1) by at
    most ``step_reach * j`` m, as ``motors + clip(target - motors, -reach, reach)``."""
    steps, na, copies = out.shape
    for s in range(steps):
        reach = step_reach * (s + 1)
        for k in range(na):
            cable = actuated[k]
            for c in range(copies):
                motor = rest[cable, c]
                out[s, k, c] = max(min(targets[c, k] - motor, reach), -reach) + motor


@njit(cache=True, error_model="numpy")
def period_end(x, rest, masses, actuated, start, before, goals, effort_cost, centres, rewards):
    """After a control period, each copy's centre of mass (``centres`` (B, 3) m, from node positions ``x``
    (N, 3, B) and ``masses`` (N,)) and reward (``rewards`` (B,): its centre's progress along its goal (``goals``
    (B, 2)) from ``before`` (B, 3) m, less ``effort_cost`` times the metres its motors moved: the actuated
    cables' rest lengths (``actuated`` (na,)) from ``start`` (na, B), the period's start, to ``rest`` (nc, B))."""
    n, _, copies = x.shape
    total = masses.sum()
    for c in range(copies):
        for j in range(3):
            centres[c, j] = 0.0
        rewards[c] = 0.0   # (the effort first)
    for i in range(n):   # the copies innermost (consecutive in x), each copy's sums in the nodes' order
        for j in range(3):
            for c in range(copies):
                centres[c, j] += masses[i] * x[i, j, c]
    for k in range(actuated.shape[0]):
        for c in range(copies):
            rewards[c] += abs(rest[actuated[k], c] - start[k, c])
    for c in range(copies):
        for j in range(3):
            centres[c, j] /= total
        rewards[c] = ((centres[c, 0] - before[c, 0]) * goals[c, 0] + (centres[c, 1] - before[c, 1]) * goals[c, 1]
                      - effort_cost * rewards[c])


@njit(cache=True, error_model="numpy")
def observe(x, v, rest, cable_ends, actuated, centres, goals, out):
    """Each copy's observation into ``out`` (B, n_obs): its cable lengths (``cable_ends`` (nc, 2)) at ``x``
    (N, 3, B), its actuated cables' rest lengths (of ``rest`` (nc, B)), its node positions relative to its centre
    of mass (``centres`` (B, 3)), its node velocities ``v`` (N, 3, B), its goal (``goals`` (B, 2))."""
    n, _, copies = x.shape
    nc = cable_ends.shape[0]
    na = actuated.shape[0]
    at = nc + na
    # the copies innermost: each number's copies are consecutive in the batch's arrays (the square roots vectorised)
    for k in range(nc):
        a = cable_ends[k, 0]
        e = cable_ends[k, 1]
        for c in range(copies):
            d0 = x[e, 0, c] - x[a, 0, c]
            d1 = x[e, 1, c] - x[a, 1, c]
            d2 = x[e, 2, c] - x[a, 2, c]
            out[c, k] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    for k in range(na):
        for c in range(copies):
            out[c, nc + k] = rest[actuated[k], c]
    for i in range(n):
        for j in range(3):
            for c in range(copies):
                out[c, at + 3 * i + j] = x[i, j, c] - centres[c, j]
                out[c, at + 3 * n + 3 * i + j] = v[i, j, c]
    for c in range(copies):
        out[c, at + 6 * n] = goals[c, 0]
        out[c, at + 6 * n + 1] = goals[c, 1]
