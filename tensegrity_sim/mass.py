"""The structure's mass matrix as an operator (physics.md section 4c; style.md rule 11).

``M`` (3N x 3N) is diagonal per node, except for a 2x2 block (times I3) per rigid strut whose mass is spread
along it: a rigid slender rod is exact in its two end nodes' coordinates with its consistent mass matrix
``[[A, B], [B, C]]`` (``Strut.mass_block``), which gives it its mass, centre of mass and moment of inertia
normal to its axis (a uniform rod: ``m L^2 / 12`` about its centre, where half of its mass at each end
gives ``m L^2 / 4``). A slender rod does not spin about its own axis: that motion has no mass and no
coordinate. Every method applies ``M`` and ``M^-1`` through this one operator (``apply``, ``solve``) or
through its kernel form (``kernel_array``), so that a new mass model changes one place.

Two kinds of strut are lumped by the row sums of their block instead (each end carries its share: exactly the
weight, the linear momentum and the total mass; the rotational inertia is then too large):

- an elastic strut, always (the lumped mass is the standard finite-element choice for an axial member, and
  keeps the explicit step's stability bound that of its axial spring between two masses);
- a rigid strut one of whose ends is also the end of another rigid strut (class-k), where the blocks would
  couple, with a :class:`LumpedMassWarning`.

A rigid strut with a fixed end keeps its block's exact form: the free end's mass is its diagonal entry (``C``
for a rod pinned at its first node: ``m / 3``, the physical pendulum's), with no cross term.
"""
from __future__ import annotations

import warnings

import numpy as np

from .scene import LumpedMassWarning, Scene

__all__ = ["MassOperator"]


class MassOperator:
    """``M`` of a scene's free nodes (fixed nodes never move: their rows are zero in ``M^-1``).

    Attributes (shapes; units):
        lumped: (N,) kg, the row sums of ``M`` (each node's weight is ``lumped g``; linear momentum
            ``sum lumped v``).
        diagonal: (N,) kg, ``M``'s diagonal per node (the lumped mass where a node is in no block).
        partner: (N,) int, the other end of a node's block, -1 where it has none.
        cross: (N,) kg, ``M``'s off-diagonal entry of a node's block (0 without one).
        inv_diagonal, inv_cross: (N,) 1/kg, the same entries of ``M^-1`` (0 for fixed nodes).
        blocks: (nb, 2) int, the end nodes of every block, in strut order.
    """

    def __init__(self, scene: Scene, free: np.ndarray):
        index = {n.name: i for i, n in enumerate(scene.nodes)}
        n = len(scene.nodes)
        self.lumped = scene.masses
        rigid_ends: dict[int, int] = {}
        for s in scene.struts:
            if s.rigid:
                for end in s.nodes:
                    rigid_ends[index[end]] = rigid_ends.get(index[end], 0) + 1
        diagonal = self.lumped.copy()
        partner = np.full(n, -1, dtype=np.intp)
        cross = np.zeros(n)
        blocks = []
        shared = []
        with np.errstate(over="ignore", invalid="ignore"):   # a mass beyond the float range is the scene's error
            for s in scene.struts:
                a, c = index[s.nodes[0]], index[s.nodes[1]]
                ma, mb, mc = s.mass_block
                if not s.rigid or mb == 0.0:
                    continue
                if rigid_ends[a] > 1 or rigid_ends[c] > 1:
                    shared.append(s.name)
                    continue
                # the block replaces the strut's row sums on the diagonal: A and C, B off it
                diagonal[a] -= mb
                diagonal[c] -= mb
                if free[a] and free[c]:
                    partner[a], partner[c] = c, a
                    cross[a] = cross[c] = mb
                    blocks.append((a, c))
        if shared:
            warnings.warn(f"{scene.source or scene.name}: struts {shared} share an end with another rigid strut "
                          f"(class-k): their mass is lumped at their ends (row sums), so their rotational inertia is "
                          f"too large", LumpedMassWarning, stacklevel=3)
        self.free = np.asarray(free, dtype=bool)
        self.diagonal = diagonal
        self.partner = partner
        self.cross = cross
        self.blocks = np.array(blocks, dtype=np.intp).reshape(-1, 2)
        det = diagonal * diagonal[np.maximum(partner, 0)] - cross * cross
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            inv_diag = np.where(partner >= 0, diagonal[np.maximum(partner, 0)] / det, 1.0 / diagonal)
            inv_cross = np.where(partner >= 0, -cross / det, 0.0)
        self.inv_diagonal = np.where(self.free, inv_diag, 0.0)
        self.inv_cross = np.where(self.free, inv_cross, 0.0)

    @property
    def consistent(self) -> bool:
        """Whether any rigid strut carries its consistent block (else ``M`` is diagonal)."""
        return len(self.blocks) > 0

    @property
    def axial_inverse(self) -> np.ndarray:
        """(N,) 1/kg: what an equal-and-opposite push along a node's own rigid strut does to it,
        ``M^-1`` of ``(+p, -p)`` on the strut's ends is ``(inv_diagonal - inv_cross) p`` at each."""
        return self.inv_diagonal - self.inv_cross

    @property
    def kernel_array(self) -> np.ndarray:
        """(N, 2) 1/kg, the compiled kernels' form of ``M^-1``: ``[:, 0]`` its diagonal, ``[:, 1]`` the cross
        entry of the node's block (the block's ends are a moving rigid strut's, which the kernels know)."""
        return np.ascontiguousarray(np.stack([self.inv_diagonal, self.inv_cross], axis=1))

    def apply(self, v: np.ndarray) -> np.ndarray:
        """``M v`` for velocities ``v`` (N, 3) m/s (or (N, 3, B)): momenta (N, 3) kg m/s, fixed nodes' zero."""
        diag = (self.diagonal * self.free).reshape((-1,) + (1,) * (v.ndim - 1))
        out = diag * v
        if len(self.blocks):
            a, c = self.blocks[:, 0], self.blocks[:, 1]
            w = self.cross[a].reshape((-1,) + (1,) * (v.ndim - 1))
            out[a] += w * v[c]
            out[c] += w * v[a]
        return out

    def solve(self, f: np.ndarray) -> np.ndarray:
        """``M^-1 f`` for forces ``f`` (N, 3) N (or (N, 3, B)): accelerations (N, 3) m/s^2, fixed nodes' zero."""
        shape = (-1,) + (1,) * (f.ndim - 1)
        out = self.inv_diagonal.reshape(shape) * f
        if len(self.blocks):
            a, c = self.blocks[:, 0], self.blocks[:, 1]
            w = self.inv_cross[a].reshape(shape)
            out[a] += w * f[c]
            out[c] += w * f[a]
        return out

    def kinetic_energy(self, v: np.ndarray) -> float:
        """``v^T M v / 2`` (J) for velocities (N, 3) m/s."""
        return 0.5 * float(np.sum(v * self.apply(v)))

    def momentum(self, x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear (3,) kg m/s and angular momentum about the origin (3,) kg m^2/s: ``sum M v`` and
        ``sum x cross M v``, exact for a rod with its block (``int r x v dm`` in its end nodes' coordinates)."""
        p = self.apply(v)
        return p.sum(axis=0), np.cross(x, p).sum(axis=0)
