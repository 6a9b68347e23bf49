"""The compiled, immutable form of a scene that the stepping methods work on.

Notation follows ``physics.md`` §1: ``N`` nodes, members ``i`` joining nodes ``(a_i, b_i)``; members are
stored struts first, then cables, so ``m = n_struts + n_cables``. A member force ``t_i`` (tension
positive) pulls node ``a_i`` by ``+t_i n_i`` and node ``b_i`` by ``-t_i n_i`` where ``n_i`` is the unit
vector from ``a_i`` to ``b_i``: equal and opposite, along the member, so it conserves linear and angular
momentum.

A cable end may lie on a strut (physics.md section 4c): its position and velocity interpolate the strut's two
nodes, ``(1 - w) x_p + w x_q``, and its force is shared ``(1 - w, w)`` between them, which keeps the total
force and the torque of the pair about any point (``(1 - w) x_p x F + w x_q x F = X x F``): the momenta are
still conserved. ``cable_nodes`` and ``cable_weights`` say where every cable end lies.
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
        strut_ends, cable_ends: views into ``ends``; a cable end on a strut has the strut's first node there
            (``cable_nodes`` places it).
        cable_nodes: (n_cables, 2, 2) int, cable_weights: (n_cables, 2): end ``j`` of cable ``c`` lies at
            ``(1 - w) x[cable_nodes[c, j, 0]] + w x[cable_nodes[c, j, 1]]``, ``w = cable_weights[c, j]``
            (``Scene.cable_points``: a node end is ``(node, node)`` with ``w = 0``).
        attached: (k,) int, the cables with an end strictly inside a strut (``0 < w``), in cable order.
        stiffness: (m,) N/m; zero for rigid struts (their force is a constraint force).
        floor: (m,) elongation floor: -inf for struts, 0 for cables (tension only), so that an elastic
            member's tension is ``stiffness * max(floor, e)``.
        rigid: (n_struts,) bool. cable_damping: (n_cables,) N*s/m.
        strut_rest: (n_struts,) m.
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        self.n_nodes = len(scene.nodes)
        self.n_struts = len(scene.struts)
        self.n_cables = len(scene.cables)
        self.n_members = self.n_struts + self.n_cables
        self.masses = scene.masses
        self.free = ~scene.fixed
        self.mass = MassOperator(scene, self.free)
        self.inv_mass = self.mass.inv_diagonal
        self.gravity_force = (self.masses * self.free)[:, None] * np.asarray(scene.gravity)[None, :]
        self.cable_nodes, self.cable_weights = scene.cable_points()
        self.attached = np.flatnonzero((self.cable_weights > 0).any(axis=1))
        self.ends = np.vstack([scene.member_index(scene.struts), self.cable_nodes[:, :, 0]])
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
        self._incidence = self.incidence_matrix()

    # ------------------------------------------------------------------ algebra
    def incidence_matrix(self, ends: np.ndarray | None = None):
        """(N, k) matrix ``A`` with ``+1`` at ``(a_i, i)`` and ``-1`` at ``(b_i, i)`` of members ``ends``
        (k, 2), or of every member (``ends`` None), a cable end on a strut shared by its weights.

        ``A @ (t[:, None] * n)`` are the node forces of member tensions ``t`` along directions ``n``;
        ``A.T @ x`` is ``-(x_b - x_a)``. Sparse when the structure is large (``self.sparse``).
        """
        if ends is None and len(self.attached):
            nodes, shares = self._member_points()
            vals = shares * np.array([1.0, -1.0])[None, :, None]
            cols = np.repeat(np.arange(self.n_members), 4)
            mat = sp.csr_matrix((vals.reshape(-1), (nodes.reshape(-1), cols)), shape=(self.n_nodes, self.n_members))
            return mat if self.sparse else mat.toarray()
        ends = self.ends if ends is None else ends
        k = len(ends)
        cols = np.repeat(np.arange(k), 2)
        rows = ends.reshape(-1)
        vals = np.tile([1.0, -1.0], k)
        mat = sp.csr_matrix((vals, (rows, cols)), shape=(self.n_nodes, k))
        return mat if self.sparse else mat.toarray()

    def _member_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Every member's ends as node pairs (m, 2, 2) int and their shares ``(1 - w, w)`` (m, 2, 2): a strut's
        end is ``(node, node)`` with shares ``(1, 0)``."""
        nodes = np.concatenate([np.repeat(self.strut_ends[:, :, None], 2, axis=2), self.cable_nodes])
        w = np.concatenate([np.zeros((self.n_struts, 2)), self.cable_weights])
        return nodes, np.stack([1.0 - w, w], axis=2)

    def assemble(self, member_forces: np.ndarray) -> np.ndarray:
        """Node forces (N, 3) N from member force vectors (m, 3) N (``t_i n_i``, pulling ``a_i`` to ``b_i``)."""
        return self._incidence @ member_forces

    def cable_points(self, x: np.ndarray) -> np.ndarray:
        """Where the cables' ends are, (n_cables, 2, 3) m (or (n_cables, 2, 3, B) of ``x`` (N, 3, B)); the same
        of velocities gives the ends' velocities."""
        p = x[self.cable_ends]
        if len(self.attached):
            c = self.attached
            w = self.cable_weights[c].reshape(c.shape + (2,) + (1,) * (x.ndim - 1))
            p[c] = (1.0 - w) * x[self.cable_nodes[c, :, 0]] + w * x[self.cable_nodes[c, :, 1]]
        return p

    def cable_vectors(self, x: np.ndarray) -> np.ndarray:
        """``X_b - X_a`` of every cable at its real ends, (n_cables, 3) (or (n_cables, 3, B))."""
        if not len(self.attached):
            return x[self.cable_ends[:, 1]] - x[self.cable_ends[:, 0]]
        p = self.cable_points(x)
        return p[:, 1] - p[:, 0]

    def member_vectors(self, x: np.ndarray) -> np.ndarray:
        """``X_b - X_a`` of every member (m, 3) (or (m, 3, B)), struts first; cables at their real ends."""
        d = x[self.ends[:, 1]] - x[self.ends[:, 0]]
        if len(self.attached):
            d[self.n_struts:] = self.cable_vectors(x)
        return d

    def geometry(self, x: np.ndarray, ends: np.ndarray | None = None):
        """Member vectors ``d = x_b - x_a`` (k, 3), lengths ``l`` (k,) m and unit vectors ``n`` (k, 3) of the
        members ``ends`` (k, 2) (node ends), or of every member at its real ends (``ends`` None)."""
        d = self.member_vectors(x) if ends is None else x[ends[:, 1]] - x[ends[:, 0]]
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        return d, length, d / length[:, None]

    def cable_rates(self, v: np.ndarray, n: np.ndarray) -> np.ndarray:
        """The cables' elongation rates ``n_c . (V_b - V_a)`` (n_cables,) m/s at their real ends, ``n``
        (n_cables, 3) their unit vectors."""
        return np.einsum("ij,ij->i", self.cable_vectors(v), n)

    def member_rates(self, v: np.ndarray, n: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """Elongation rates ``de/dt = b_i^T v = n_i . (v_b - v_a)`` (k,) m/s of the members ``ends`` (k, 2)."""
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
        _, _, n = self.geometry(x)
        n = n[keep]
        # b_i (3N,) for each kept member: -n at a, +n at b (a cable end on a strut: shared by its weights),
        # scaled by sqrt(k_i / m) per node.
        nodes, shares = self._member_points()
        nodes = nodes[keep].reshape(-1, 4)
        shares = (shares[keep] * np.array([-1.0, 1.0])[None, :, None]).reshape(-1, 4)
        scale = np.sqrt(self.inv_mass)
        rows = (3 * nodes[:, :, None] + np.arange(3)).reshape(-1, 12)
        with np.errstate(over="ignore", invalid="ignore"):  # checked below
            vals = (shares[:, :, None] * scale[nodes][:, :, None] * n[:, None, :]).reshape(-1, 12)
            vals *= np.sqrt(k[keep])[:, None]
        cols = np.repeat(np.arange(len(nodes)), 12)
        b = sp.csr_matrix((vals.ravel(), (rows.ravel(), cols)), shape=(3 * self.n_nodes, len(nodes)))
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
