"""``M^-1`` in compiled code: the numba form of :class:`~tensegrity_sim.mass.MassOperator` (style.md rule 11).

The kernels carry ``inv_mass`` (N, 2) 1/kg (``MassOperator.kernel_array``): ``[:, 0]`` the diagonal of ``M^-1``,
``[:, 1]`` the cross entry of a node's 2x2 block, non-zero only at the two ends of a moving rigid strut whose
mass is spread along it (so the blocks are found among ``rigid_members``). Each function does the arithmetic of
``MassOperator.solve`` in the same order, so the kernels match the numpy reference to the bit.
"""
from __future__ import annotations

from numba import njit

__all__ = ["solve_forces", "solve_forces_copies", "axial_inverse"]


@njit(cache=True, error_model="numpy", _nrt=False, inline="always")
def axial_inverse(inv_mass, node):
    """1/kg: ``M^-1`` of an equal-and-opposite push along ``node``'s own rigid strut, at ``node``."""
    return inv_mass[node, 0] - inv_mass[node, 1]


@njit(cache=True, error_model="numpy", _nrt=False)
def solve_forces(acc, inv_mass, ends, rigid_members, b):
    """Copy ``b``: ``acc`` (N, 3, B) holds forces (N) and becomes ``M^-1`` of them (m/s^2), in place."""
    for i in range(acc.shape[0]):
        if inv_mass[i, 1] == 0.0:
            for j in range(3):
                acc[i, j, b] *= inv_mass[i, 0]
    for k in range(rigid_members.shape[0]):
        a = ends[rigid_members[k], 0]
        c = ends[rigid_members[k], 1]
        w = inv_mass[a, 1]
        if w != 0.0:
            for j in range(3):
                fa = acc[a, j, b]
                fc = acc[c, j, b]
                acc[a, j, b] = inv_mass[a, 0] * fa + w * fc
                acc[c, j, b] = inv_mass[c, 0] * fc + w * fa


@njit(cache=True, error_model="numpy", _nrt=False)
def solve_forces_copies(acc, inv_mass, ends, rigid_members):
    """:func:`solve_forces` of every copy, the copies innermost."""
    n_copies = acc.shape[2]
    for i in range(acc.shape[0]):
        if inv_mass[i, 1] == 0.0:
            wi = inv_mass[i, 0]
            for j in range(3):
                for b in range(n_copies):
                    acc[i, j, b] *= wi
    for k in range(rigid_members.shape[0]):
        a = ends[rigid_members[k], 0]
        c = ends[rigid_members[k], 1]
        w = inv_mass[a, 1]
        if w != 0.0:
            wa = inv_mass[a, 0]
            wc = inv_mass[c, 0]
            for j in range(3):
                for b in range(n_copies):
                    fa = acc[a, j, b]
                    fc = acc[c, j, b]
                    acc[a, j, b] = wa * fa + w * fc
                    acc[c, j, b] = wc * fc + w * fa
