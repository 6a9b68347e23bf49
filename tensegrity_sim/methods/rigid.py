"""Rigid struts as bilateral length constraints, enforced with SHAKE (positions) and RATTLE (velocities).

For each rigid strut ``i``: ``g_i(x) = |x_b - x_a|^2 - L_i^2 = 0`` and ``n_i . (v_b - v_a) = 0``.
The corrections are equal and opposite impulses along the strut (pulling ``a`` by ``+gamma n`` and ``b``
by ``-gamma n``), so linear and angular momentum are untouched, and the length holds to round-off.

With ``S`` the strut incidence (``S x = x_b - x_a``) and ``W = S M^-1 S^T`` (constant), a correction of
strength ``gamma`` along the start-of-step directions ``n0`` moves the strut vectors by
``-W (gamma n0)``. In a tensegrity (at most one strut per node) ``W`` is diagonal and each strut's
``gamma`` is the small root of a quadratic, in closed form; a class-k structure couples the struts and
Newton's method solves the coupled system to round-off.
"""
from __future__ import annotations

import numpy as np

from ..system import System

__all__ = ["RigidStruts"]

_NEWTON_TOL = 1e-14   # relative residual |g_i| / L_i^2
_NEWTON_MAX_ITER = 50


class RigidStruts:
    """The rigid struts of a system that constrain at least one free node."""

    def __init__(self, system: System):
        idx = np.flatnonzero(system.rigid)
        ends = system.strut_ends[idx]
        moves = system.inv_mass[ends[:, 0]] + system.inv_mass[ends[:, 1]] > 0
        self.members = idx[moves]   # their rows in the system's member arrays (struts come first)
        self.ends = ends[moves]
        self.length_sq = system.strut_rest[idx][moves] ** 2
        self.count = len(self.ends)
        self._system = system
        # M^-1 of a push along a node's own strut: the diagonal less the block's cross entry (mass.py)
        axial = system.mass.axial_inverse
        self._inv_mass = axial[:, None]
        self._incidence = system.incidence_matrix(self.ends)      # (N, nr): +1 at a, -1 at b
        inc = np.asarray(self._incidence.todense()) if system.sparse else self._incidence
        self.w_matrix = inc.T @ (axial[:, None] * inc)  # W = S M^-1 S^T, (nr, nr)
        self._w = np.diag(self.w_matrix).copy()
        self.coupled = bool(np.any(self.w_matrix - np.diag(self._w)))

    def _push(self, strengths: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Node displacements (or velocity changes) (N, 3) for equal-and-opposite pushes along the struts."""
        return self._inv_mass * (self._incidence @ (strengths[:, None] * directions))

    def project_positions(self, x_start: np.ndarray, x_pred: np.ndarray,
                          directions: np.ndarray | None = None) -> np.ndarray:
        """SHAKE: the displacement (N, 3) that puts ``x_pred`` back on every strut length, applied along
        the strut directions at ``x_start`` (the constraint force acts where the step began).
        ``directions``: those unit vectors (count, 3) if the caller has them already."""
        n0 = self._system.geometry(x_start, self.ends)[2] if directions is None else directions
        r = x_pred[self.ends[:, 1]] - x_pred[self.ends[:, 0]]
        if not self.coupled:
            p = np.einsum("ij,ij->i", r, n0)
            c = np.einsum("ij,ij->i", r, r) - self.length_sq
            # small root of w^2 g^2 - 2 w p g + c = 0, written to avoid cancellation
            gamma = c / (self._w * (p + np.sqrt(np.maximum(p * p - c, 0.0))))
        else:
            gamma = np.zeros(self.count)
            for _ in range(_NEWTON_MAX_ITER):
                r_new = r - self.w_matrix @ (gamma[:, None] * n0)
                g = np.einsum("ij,ij->i", r_new, r_new) - self.length_sq
                if np.max(np.abs(g) / self.length_sq) < _NEWTON_TOL:
                    break
                jac = -2.0 * self.w_matrix * (r_new @ n0.T)
                gamma -= np.linalg.solve(jac, g)
        return self._push(gamma, n0)

    def project_velocities(self, x: np.ndarray, v: np.ndarray, directions: np.ndarray | None = None) -> np.ndarray:
        """RATTLE: the velocity change (N, 3) that zeroes every strut's length rate at ``x``.
        ``directions``: the struts' unit vectors (count, 3) at ``x`` if the caller has them already."""
        n = self._system.geometry(x, self.ends)[2] if directions is None else directions
        rate = self._system.member_rates(v, n, self.ends)
        if not self.coupled:
            mu = rate / self._w
        else:
            mu = np.linalg.solve(self.w_matrix * (n @ n.T), rate)
        return self._push(mu, n)
