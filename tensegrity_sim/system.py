"""The compiled, immutable form of a scene that the stepping methods work on.

Notation follows ``physics.md`` §1: ``N`` nodes, members ``i`` joining nodes ``(a_i, b_i)``; members are
stored struts first, then cables, so ``m = n_struts + n_cables``. A member force ``t_i`` (tension
positive) pulls node ``a_i`` by ``+t_i n_i`` and node ``b_i`` by ``-t_i n_i`` where ``n_i`` is the unit
vector from ``a_i`` to ``b_i``: equal and opposite, along the member, so it conserves linear and angular
momentum.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh

from .mass import MassOperator
from .scene import Scene, SceneError

__all__ = ["System", "SPARSE_THRESHOLD"]

# Above this many incidence-matrix entries (N * m) the force assembly uses a sparse matrix; below it
# a dense matmul is faster (measured with bench/bench_steps.py: the crossover is near a 10-stage tower).
SPARSE_THRESHOLD = 20_000


class System:
    """Topology, masses and stiffnesses of a scene as arrays (never changes during a run).

    Attributes (shapes; units):
        n_nodes, n_struts, n_cables, n_members: counts.
        mass: the mass matrix ``M`` as an operator (:class:`~tensegrity_sim.mass.MassOperator`: a 2x2 block
            per rigid strut with its mass spread along it, diagonal elsewhere); apply ``M^-1`` through it.
        masses: (N,) kg, lumped (``M``'s row sums: weights, linear momentum). inv_mass: (N,) 1/kg, the diagonal
            of ``M^-1`` (``1 / masses`` where ``M`` has no block), zero for fixed nodes (they never move).
        free: (N,) bool. gravity_force: (N, 3) N, ``m g`` on free nodes (``m`` the lumped masses).
        ends: (m, 2) int node indices of every member, struts first.
        strut_ends, cable_ends: views into ``ends``.
        stiffness: (m,) N/m; zero for rigid struts (their force is a constraint force).
        floor: (m,) elongation floor: -inf for struts, 0 for cables (tension only), so that an elastic
            member's tension is ``stiffness * max(floor, e)``.
        rigid: (n_struts,) bool. cable_damping: (n_cables,) N*s/m.
        strut_rest: (n_struts,) m.
    """

    def __init__(self, scene: Scene, consistent_mass: bool = True):
        self.scene = scene
        self.n_nodes = len(scene.nodes)
        self.n_struts = len(scene.struts)
        self.n_cables = len(scene.cables)
        self.n_members = self.n_struts + self.n_cables
        self.masses = scene.masses
        self.free = ~scene.fixed
        self.mass = MassOperator(scene, self.free, consistent_mass)
        self.inv_mass = self.mass.inv_diagonal
        self.gravity_force = (self.masses * self.free)[:, None] * np.asarray(scene.gravity)[None, :]
        self.ends = np.vstack([scene.member_index(scene.struts), scene.member_index(scene.cables)])
        self.strut_ends = self.ends[: self.n_struts]
        self.cable_ends = self.ends[self.n_struts:]
        self.rigid = np.array([s.rigid for s in scene.struts], dtype=bool)
        strut_k = np.array([0.0 if s.rigid else s.stiffness for s in scene.struts], dtype=float)
        cable_k = np.array([np.nan if c.stiffness is None else c.stiffness for c in scene.cables], dtype=float)
        self.stiffness = np.concatenate([strut_k, cable_k])
        self.floor = np.concatenate([np.full(self.n_struts, -np.inf), np.zeros(self.n_cables)])
        self.strut_rest = np.array([s.rest_length for s in scene.struts], dtype=float)
        self.cable_damping = np.array([c.damping for c in scene.cables], dtype=float)
        self.sparse = self.n_nodes * max(self.n_members, 1) > SPARSE_THRESHOLD
        self._incidence = self.incidence_matrix(self.ends)

    def lumped(self) -> "System":
        """This system with every strut's mass lumped at its ends by row sums (itself if it has no mass block):
        for a method or a path that takes a diagonal ``M`` only."""
        return System(self.scene, consistent_mass=False) if self.mass.consistent else self

    # ------------------------------------------------------------------ algebra
    def incidence_matrix(self, ends: np.ndarray):
        """(N, k) matrix ``A`` with ``+1`` at ``(a_i, i)`` and ``-1`` at ``(b_i, i)``.

        ``A @ (t[:, None] * n)`` are the node forces of member tensions ``t`` along directions ``n``;
        ``A.T @ x`` is ``-(x_b - x_a)``. Sparse when the structure is large (``self.sparse``).
        """
        k = len(ends)
        cols = np.repeat(np.arange(k), 2)
        rows = ends.reshape(-1)
        vals = np.tile([1.0, -1.0], k)
        mat = sp.csr_matrix((vals, (rows, cols)), shape=(self.n_nodes, k))
        return mat if self.sparse else mat.toarray()

    def assemble(self, member_forces: np.ndarray) -> np.ndarray:
        """Node forces (N, 3) N from member force vectors (m, 3) N (``t_i n_i``, pulling ``a_i`` to ``b_i``)."""
        return self._incidence @ member_forces

    def geometry(self, x: np.ndarray, ends: np.ndarray | None = None):
        """Member vectors ``d = x_b - x_a`` (k, 3), lengths ``l`` (k,) m and unit vectors ``n`` (k, 3)."""
        ends = self.ends if ends is None else ends
        d = x[ends[:, 1]] - x[ends[:, 0]]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        return d, length, d / length[:, None]

    def member_rates(self, v: np.ndarray, n: np.ndarray, ends: np.ndarray | None = None) -> np.ndarray:
        """Elongation rates ``de/dt = b_i^T v = n_i . (v_b - v_a)`` (k,) m/s."""
        ends = self.ends if ends is None else ends
        return np.einsum("ij,ij->i", v[ends[:, 1]] - v[ends[:, 0]], n)

    # ------------------------------------------------------------------ stability
    def max_frequency(self, x: np.ndarray, include_cables: bool, include_struts: bool = True) -> float:
        """Highest natural angular frequency (rad/s) of the elastic members at configuration ``x``.

        The axial stiffness matrix ``K = sum_i k_i b_i b_i^T`` of the elastic struts (unless not
        ``include_struts``) and of every cable with a stiffness, as if taut (when ``include_cables``),
        mass-scaled to ``M^-1/2 K M^-1/2`` on the free nodes; its largest eigenvalue is ``omega_max^2``.
        An explicit central-difference or midpoint step is stable only for ``dt < 2 / omega_max``.
        """
        k = self.stiffness.copy()
        if not include_cables:
            k[self.n_struts:] = 0.0
        if not include_struts:
            k[: self.n_struts] = 0.0
        k = np.nan_to_num(k, nan=0.0)
        keep = k > 0
        if not keep.any():
            return 0.0
        ends = self.ends[keep]
        _, _, n = self.geometry(x, ends)
        # b_i (3N,) for each kept member: -n at a, +n at b, scaled by sqrt(k_i / m) per node.
        scale = np.sqrt(self.inv_mass)
        rows = np.concatenate([3 * ends[:, 0:1] + np.arange(3), 3 * ends[:, 1:2] + np.arange(3)], axis=1)
        with np.errstate(over="ignore", invalid="ignore"):  # checked below
            vals = np.concatenate([-n * scale[ends[:, 0], None], n * scale[ends[:, 1], None]], axis=1)
            vals *= np.sqrt(k[keep])[:, None]
        cols = np.repeat(np.arange(len(ends)), 6)
        b = sp.csr_matrix((vals.ravel(), (rows.ravel(), cols)), shape=(3 * self.n_nodes, len(ends)))
        with np.errstate(over="ignore", invalid="ignore"):
            kmat = (b @ b.T).tocsr()
        try:
            if not np.all(np.isfinite(kmat.data)):
                raise np.linalg.LinAlgError
            if kmat.shape[0] <= 600:
                lam = float(np.linalg.eigvalsh(kmat.toarray())[-1])
            else:
                lam = float(eigsh(kmat, k=1, which="LA", return_eigenvectors=False)[0])
        except (np.linalg.LinAlgError, RuntimeError):  # ARPACK reports no convergence as a RuntimeError
            lam = math.nan
        if not math.isfinite(lam):
            light = int(np.argmin(np.where(self.free, self.masses, np.inf)))
            raise SceneError(f"{self.scene.source or self.scene.name}: the members' stiffness/mass ratios are "
                             f"beyond the float range (stiffness up to {float(np.max(k)):.3g} N/m; lightest free "
                             f"node {self.scene.nodes[light].name!r}, {float(self.masses[light]):.3g} kg)")
        return float(np.sqrt(max(lam, 0.0)))
