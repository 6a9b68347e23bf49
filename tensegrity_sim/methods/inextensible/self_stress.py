"""The impulses the inextensible method publishes when its rows carry a self-stress (issue 20).

Rigid struts and taut inextensible cables that lock a structure (the built-in icosahedron, a prism with
rigid struts) give a QP whose rows are dependent: the velocities are unique, the multipliers are not,
and any multiple of a self-stress ``s`` (``A^T s = 0``) can be added to them. At the midpoint geometry
the rows are only *nearly* dependent (the smallest singular value of ``A^T`` is ~1e-5 of the largest
on the thrown icosahedron against ~0.2 for the next one), so the solver returns one particular,
unbounded multiple: it grows like 1/dt and changes sign from step to step.

**The rule.** With ``B`` the rows at their limit after the sub-step (the equality rows, every cable that
ends within ``TAUT_TOL`` of its limit, and every row that carries an impulse) and ``A_B^T = U S V^T``, the singular directions with
``S < RANK_TOL * S_max`` span the self-stress space ``N`` of the step. The published impulses are::

    y = (I - N N^T) y_QP  +  N alpha,     alpha = argmin |N_c alpha - t_ref,c tau|

the solver's impulses with their self-stress share removed (the minimum-norm impulses that give the
step's velocity change, the part the issue measured to agree with Siconos) plus the self-stress that
best matches the scene's reference tensions ``t_ref`` (N, its form-finding prestress) over the
sub-step ``tau``: the *cable* components of ``N alpha`` are the least-squares fit to ``t_ref tau`` (a
rigid strut has no reference force of its own: its share follows from equilibrium). For an impact
(``tau = 0``) the self-stress share is zero. When a cable would pull (``y < 0``) the self-stress share
is the closest one that keeps every cable impulse >= 0 (a small QP in ``alpha``).

**Why this rule.** It is the stiff limit of the elastic twin: with stiffnesses ``k -> infinity`` and the
members held at their limits, the member strains of a locked structure are those of the form-finding,
so its self-stress keeps the prestress, and the dynamic part is the impulses that change the motion
(the minimum Euclidean norm stands in for the minimum complementary energy ``sum y^2 / k``, which would
weight each member by its compliance; with rigid struts that weight is zero and the problem degenerate).
The velocities are the QP's, untouched: the rule only chooses among impulses.

**What it leaves out.** ``S`` of the self-stress direction is not zero at the midpoint (the geometry is
not exactly the locked one), so the solver's share moves the nodes by ``A_B^T N N^T y_QP``: it stops
the velocity of the structure's infinitesimal mechanism, which a prestress-stable structure cannot
follow (in the elastic twin this is a vibration of its prestress stiffness). That node impulse is not in
the published impulses; its largest component (N*s) is recorded in :attr:`SelfStress.residual` and
reported by ``bench/prestress_tensions.py``: 0.2 N*s on the icosahedron thrown at 0.3 m/s, at its first
step (the impact of its incompatible initial velocity), the same at dt = 1, 0.5 and 0.25 ms; after
10 ms at most 1.5e-4 N*s per step at dt = 1 ms and 3.7e-3 N*s at 0.25 ms (80 % of the run's sum is in
the first step). The row targets are not changed to be consistent along the self-stress (the issue suggested
it): the rigid struts' targets (the reversal of their rate, which keeps the constraint work zero) and
the cables' landing targets disagree along it by design, by ~1e-4 of the targets, and making them agree
would change the motion, which this rule leaves exactly as it is.

**Cost.** Only a structure whose members (rigid struts and every cable) have a self-stress at load
time can lock (``SelfStress.possible``); for every other structure the rule is never evaluated and the
impulses are the QP's, bit for bit. A locked step pays one SVD of ``A_B^T`` (k_B x 3 n_free) when its
binding rows are not all of the load time's members, else two inverse iterations from the load time's
basis (cheaper, and as history-free as the SVD); measured by
``bench/prestress_tensions.py``. The rows' matrix and that refinement run in a numba kernel
(``_self_stress_kernels.py``; ``compiled = False``: the numpy reference), the SVD and the share's fit
in numpy (see the kernel's module for why), except in the inextensible method's one-call step
(``_inextensible_kernels.step``), which fits a one-dimensional self-stress with numpy's own BLAS
functions (``_numpy_blas.py``: numpy's products to the bit); on the rattling rigid prism of
``test_inextensible.py::test_free_prestressed_structure_momentum_and_energy`` a step costs 0.64 of what
it did with the rule all numpy (CPU time, the two taking turns on the loaded 2-core machine).

**Large structures (issue 10).** From ``SPARSE_NODES`` free nodes the rule runs on sparse matrices
(``SelfStress.sparse``; False: the dense rule above, its reference) and publishes the same impulses by
other arithmetic; the velocities are the QP's either way, so the trajectory is the same to the bit:

* few self-stresses (at most ``_IMPLICIT`` more binding rows than degrees of freedom: a moving
  structure; an impact; any call a cable would pull on): an explicit basis of
  ``N`` by :func:`sparse_self_stress_space` (block inverse iteration on ``A_B A_B^T`` with a sparse LU,
  the eigenvectors below ``RANK_TOL^2`` of its largest eigenvalue, i.e. the same threshold on the same
  singular values, on a block as wide as the space, counted first), then the dense rule's own fit
  (:meth:`SelfStress._fit`, its nonnegative QP included);
* many (a structure at rest: 114 self-stresses on a 20-stage tower, ~450 on a 50-stage one): the space
  kept implicit (:class:`SparseSpace`: ``A_B^T s`` in the span of the near-null eigenvectors of
  ``A_B^T A_B``, two KKT systems by sparse LU), unless a cable would pull (then the explicit basis).
  The space and its factors are kept while the binding rows are the same to the bit (a structure at
  rest, also after a command that holds it): a 50-stage tower's step at rest 45 ms -> 4.2 ms; and,
  answering for the new rows to round-off, while they have moved by round-off only (``_MOVED``).

Below ``SPARSE_NODES``, from ``MOVING_NODES`` free nodes (``SelfStress.moving``), the dense rule takes the
basis of binding rows that are not the load time's (a moving structure) from
:func:`sparse_self_stress_space` too, instead of an SVD (its own fit after it; the SVD if the iteration
does not settle). A call neither resolves goes to the dense rule (counted in ``SelfStress.counts``).
Agreement with the dense rule, the published impulses over the largest multiplier of a call
(``test_prestress.py::test_sparse_rule_matches_the_dense``): 4e-13 on the rattling built-in tower, 2e-15
on the thrown icosahedron and rigid prism, 6e-15 on a 30-stage tower at rest; 1.6e-11 over 44 calls of a
moving 20-stage tower. One call in 32 of a moving 30-stage tower differed by 2e-8: its nonnegative share
is DAQP's, at DAQP's default tolerances, in both paths, and the two bases (equal to 1e-12) steer it to
answers 4e-9 N*s apart; with DAQP's tolerances at 1e-12 the two answers differ by 0.09 N*s (the QP in
the share is degenerate: 55 unknowns, many more active rows), a limit of the rule's nonnegative fit itself,
left as it is.

*The threshold.* Singular values at the threshold are ill-defined whichever the path: a 30-stage tower
at rest has one at 0.95e-3 of the largest, a moving 10-stage tower one at 1.02e-3. The sparse path
decides on the same singular values, squared (Ritz values converged to 1e-14 of the largest
eigenvalue, ARPACK's to 1e-13: ~1e-8 relative at the threshold), so it takes the same side unless one
sits that close to it. The threshold stays ``RANK_TOL``: making it relative to the gap would change the
dense rule's answers on the built-in scenes, which must keep their bits. The implicit space resolves
singular values down to ~1e-6 of the largest (``_SHIFT``: in ``A_B^T A_B`` a mechanism's zero and a
smaller singular value cannot be told apart), and gives a call with an eigenvalue in that blind band to
the explicit basis (``A_B A_B^T`` has no mechanisms).

*Switch point*, measured (``bench/head_to_head.py --configs rule=dense,rule=sparse``, CPU time per steady
step, the two taking turns, ``OPENBLAS_NUM_THREADS=1``), dense / sparse: at rest 6.3 / 27.9 ms (15
stages, 87 free nodes), 3.0 / 43.6 (20 stages, 117), 4.3 / 62.9 (25, 147), 171 / 24 (30, 177: the dense
rule's refinement fails there, the singular value at 0.95e-3); moving (0.05 m/s) 209 / 183, 458 / 375,
596 / 586, 824 / 516. Hence ``SPARSE_NODES`` = 150.

**Flags.** A cable is slack when it is shorter than its limit *and* carried no impulse over the step
(:meth:`~.inextensible.InextensibleMethod.slack`), so a cable at its limit that carries prestress is taut.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import LinAlgError, cho_factor as _cho_factor, cho_solve as _cho_solve

from . import _self_stress_kernels as kernels
from ..qp.solvers import Rows

__all__ = ["MOVING_NODES", "RANK_TOL", "SPARSE_NODES", "TAUT_TOL", "SelfStress", "reference_tensions",
           "self_stress_space", "sparse_self_stress_space", "SparseSpace"]

# Singular values of A_B^T below RANK_TOL * the largest span the self-stress space. Measured on the
# thrown icosahedron (bench/prestress_tensions.py): 2e-5 for the self-stress against 0.18 for the next
# direction at dt = 1 ms, so 1e-3 has two decades of margin on either side.
RANK_TOL = 1e-3
# Relative: in a structure that can lock, a cable this close to its limit at a step's end is at it (taut
# for the flags, a row of the self-stress for the rule). The QP cannot land every member of a nearly
# dependent set exactly (its targets disagree along the self-stress), and one of them is left up to
# (tau/2)^2 |u|^2 / 2L short: 4e-9..7e-8 L on the tumbling rigid prism (0.5 m/s, dt 1..0.25 ms), which
# then flickered slack at 0 N while the rest stayed locked.
TAUT_TOL = 1e-6
# A basis whose |A^T s| is below _EXACT times the largest singular value is a self-stress to round-off.
_EXACT = 1e-13
# From this many free nodes on, the rule runs on sparse matrices (module docstring: measured between 25
# and 30 stages of a tower, where the dense rule's refinement stops working at rest)
SPARSE_NODES = 150
# From this many free nodes on, the dense rule takes the basis of binding rows that are not the load
# time's (a moving structure) from the sparse block inverse iteration rather than an SVD. Measured per
# call on moving towers (0.05 m/s, the rule's calls of 3-4 steps replayed, CPU time, the two in turn):
# SVD / sparse 1.3-6.4 / 2.1-7.2 ms at 57 free nodes (10 stages, even), 9.7-13.6 / 3.7-6.3 ms at 87 (15
# stages), 22-27 / 5.6-10.6 ms at 117 (20 stages). Again with the compiled solves, Cholesky's QR and the
# start from the step's previous call (whole steps, the two in turn, best of 4 x 5 after 11), SVD / block:
# 2.8 / 6.1 ms a step at 27 free nodes (5 stages), 21.6 / 28.0 at 45 (8), 41.5 / 42.4 at 57 (10), 75.8 /
# 64.1 at 75 (13); the trajectories the same bits.
MOVING_NODES = 64
# The sparse path, relative to the largest eigenvalue of A_B^T A_B: the regularisation of the KKT
# systems' multiplier block (refined away), and the floor below which an eigenvalue is a mechanism's zero
# (the round-off of a zero eigenvalue of the squared matrix is ~1e-16; a singular value of 1e-6 of the
# largest is 1e-12 here).
_SHIFT = 1e-12
# Up to this many more binding rows than degrees of freedom, the sparse path computes an explicit basis of
# the self-stress space (sparse_self_stress_space) first; beyond, it keeps the space implicit first
# (SparseSpace): a 30-stage tower at rest (264 more) took 85 ms a step with an explicit basis, ~3 with
# the implicit space it keeps.
_IMPLICIT = 64
# The explicit basis holds at most this many self-stresses beyond that excess (mechanisms add to it: a
# moving 100-stage tower had 92 self-stresses with 16 rows more than degrees of freedom; at 64 its calls
# went to the dense SVD, 21 s a step).
_EXPLICIT = 256
_GUARD = 8           # the block's columns beyond the space, at least (sparse_self_stress_space: a quarter of it)
_BLOCK_ITER = 16
_RITZ_TOL = 1e-14    # of the largest eigenvalue: a kept Ritz pair's residual |W x - theta x| at convergence
# _rayleigh_ritz takes Cholesky's QR of a block whose R spans at most this on its diagonal (its loss of
# orthogonality grows as the square of the condition number): measured 1.0-3.9 on the second and later
# iterations of a moving 100-stage tower's calls, leaving the basis orthonormal to 4e-15
_CHOLESKY_QR = 10.0
_REFINEMENTS = 8     # refinements of a KKT solve before the sparse path gives the step to the SVD ...
# ... unless one moves the answer by less than this, relative: the regularisation's error shrinks by
# _SHIFT / RANK_TOL^2 = 1e-6 a refinement, and what is left is round-off amplified by the near-null
# directions (measured: 1e-16 on the towers, 1.3e-13 on the thrown icosahedron, sigma 3e-5 of the largest)
_REFINE_TOL = 1e-10
# locked_space's QP working set and factor where the caller has none: the refinement factorises itself
_NO_FACTOR = (np.zeros(0, dtype=np.int64), np.zeros((0, 0)))
# Rows of the implicit space's members whose entries (the members' unit directions) moved by at most this
# since the space was built keep it (SparseSpace.moved): a 100-stage tower at rest, whose round-off
# velocities (up to 4e-13 m/s after 30 steps) move its rows' last bits, rebuilt it at 8 to 19 of 30 steps
# (~100 ms each, against ~4 for a kept one), depending on its round-off history
_MOVED = 1e-12


def reference_tensions(stiffness: np.ndarray, length_offsets: np.ndarray) -> np.ndarray:
    """The cables' reference tensions (n_cables,) N: stiffness (N/m) times the prestress stretch the
    method turned into a length offset (m); zero for a cable without a stiffness or a stretch. The
    offsets are kept when rest lengths are commanded, and so are these tensions."""
    return np.where(np.isfinite(stiffness), stiffness, 0.0) * length_offsets


def self_stress_space(a_t: np.ndarray, rank_tol: float = RANK_TOL):
    """Self-stresses of the rows whose transposed matrix is ``a_t`` (3 n_free, k): an orthonormal basis
    (k, d) of the right singular vectors with singular values below ``rank_tol`` times the largest,
    those singular values (d,), and the largest."""
    if not a_t.size:
        return np.zeros((a_t.shape[1], 0)), np.zeros(0), 0.0
    _, s, vt = np.linalg.svd(a_t, full_matrices=True)
    largest = float(s[0])
    s = np.concatenate([s, np.zeros(max(a_t.shape[1] - len(s), 0))])   # more rows than dofs: exact zeros
    null = s < rank_tol * largest
    return vt[null].T, s[null], largest


class SelfStress:
    """The publishing rule of the module docstring for one system.

    ``n_free``: free nodes; ``reference``: (n_cables,) N; ``rows_at_load``: every member's row at load
    time (the rigid struts, then the cables ``load_cables`` (int), those with a free end); ``mass``
    (n_free,) kg: the free nodes' masses (when they are all equal, the compiled refinement iterates on
    the QP's Delassus matrix, a multiple of ``A A^T``, and takes the QP's own factor of it: ``weight``)."""

    def __init__(self, n_free: int, reference: np.ndarray, rows_at_load: Rows, load_cables: np.ndarray,
                 mass: np.ndarray):
        self.n_free = n_free
        self.reference = reference
        self._rows_at_load = rows_at_load
        self._load = None     # (basis, largest singular value) of the load time's rows, when first needed
        self._load_members = np.asarray(load_cables).tobytes()
        # more rows than degrees of freedom always carry a self-stress (the SVD pads its zeros): a large
        # structure needs no dense SVD to know
        self.possible = len(rows_at_load) > 3 * n_free or self._load_basis.shape[1] > 0
        self.residual = 0.0   # N*s: the largest node impulse dropped with a near-null share (module docstring)
        self.refine = True    # False: an SVD at every step (the reference the refinement must match)
        self.compiled = True  # the rule in one numba kernel (_self_stress_kernels.py); False: the numpy reference
        # the sparse path (_impulses_sparse) from SPARSE_NODES free nodes on; False: the dense rule (its reference)
        self.sparse = n_free >= SPARSE_NODES
        # below, the dense rule's basis of binding rows that are not the load time's by the sparse block
        # inverse iteration from MOVING_NODES free nodes on (_moving_space); False: the SVD
        self.moving = n_free >= MOVING_NODES
        self.counts = {"sparse": 0, "dense": 0}   # calls of a structure that can lock, by the path that answered
        self._kept = None     # (rows' pattern, entries, SparseSpace) of the last implicit space (_implicit)
        self._settled = None  # the binding cables of the sparse path's last sub-step whose share pulled on none
        self._pulled = False  # whether the last fit's least-squares share pulled on a cable (_fit)
        self._block = None    # (member ids, final block) of this step's last block inverse iteration (_basis)
        self._load_cables = np.ascontiguousarray(load_cables, dtype=np.int64)
        # the inverse masses per degree of freedom as the QP backend computes them (1 / its mass, (n_free, 3))
        inverse = 1.0 / np.repeat(np.asarray(mass, dtype=float), 3).reshape(-1, 3)
        self._shared = bool(np.all(inverse == inverse.flat[0])) if inverse.size else False
        self.weight = inverse if self._shared else np.ones((n_free, 3))

    @property
    def _load_basis(self) -> np.ndarray:
        """The self-stress basis (k_load, d) of the load time's rows (one SVD, on first use)."""
        if self._load is None:
            basis, _, largest = self_stress_space(self._rows_at_load.dense(self.n_free).T)
            self._load = (basis, largest)
        return self._load[0]

    @property
    def _load_largest(self) -> float:
        """The largest singular value of the load time's rows."""
        self._load_basis   # computes it
        return self._load[1]

    def _space(self, a_t: np.ndarray, members: bytes) -> np.ndarray:
        """The self-stress basis (k, d) of ``a_t`` (3 n_free, k). When the binding rows are all the
        members of the load time (a locked structure), the load time's basis refined by two steps of
        inverse iteration on ``A A^T`` (its self-stress singular values are ~1e-4 of the next ones: each
        step divides the error by ~1e8) is ~8 times cheaper than an SVD, and like the SVD it depends on
        this step alone (a replay, a twin that saw other commands: the same bits). It is kept if it is
        still below ``RANK_TOL``; any other set of rows gets an SVD, and so does an ``A A^T`` that is not
        positive definite in floating point (a tower at its load geometry, with twelve self-stresses)."""
        basis = self._load_basis
        if self.refine and members == self._load_members:
            if np.linalg.norm(a_t @ basis, axis=0).max() <= _EXACT * self._load_largest:
                return basis   # an exact self-stress (a structure at rest in its load shape)
            try:
                factor = _cho_factor(a_t.T @ a_t, lower=True, check_finite=False)
                for _ in range(2):
                    basis, _ = np.linalg.qr(_cho_solve(factor, basis, check_finite=False))
            except LinAlgError:
                basis = None
            if basis is not None and np.linalg.norm(a_t @ basis, axis=0).max() < RANK_TOL * self._load_largest:
                return basis
        return self_stress_space(a_t)[0]

    def forget(self) -> None:
        """A reset: the spaces and starts kept from earlier calls and the largest dropped impulse go, as in
        a fresh rule."""
        self._kept = self._settled = self._block = None
        self.residual = 0.0

    def begin_step(self) -> None:
        """A step starts: the block inverse iteration's start from the step's previous call is forgotten, so
        that what a step publishes depends on that step alone (a reset, a refused command or a failed
        step leave nothing behind)."""
        self._block = None

    def _basis(self, a, n_eq: int, cables: np.ndarray):
        """:func:`sparse_self_stress_space` of the rows ``a`` (scipy sparse): the ``n_eq`` rigid struts, then
        the cables ``cables`` (int), started from the final block of this step's previous call (a sub-step
        or an impact of the same step: the space moves little between them), its rows matched by member
        (zero for a member new to the rows); that call's block is then this one's."""
        ids = np.concatenate([np.arange(n_eq), n_eq + cables])   # the members: struts, then n_eq + cable
        start = None
        if self._block is not None:
            before, block = self._block
            where = np.full(max(int(before.max(initial=0)), int(ids.max(initial=0))) + 1, -1)
            where[before] = np.arange(len(before))
            rows = where[ids]
            start = np.zeros((len(ids), block.shape[1]))
            start[rows >= 0] = block[rows[rows >= 0]]
        basis, block = _block_space(a, RANK_TOL, start)
        self._block = None if block is None else (ids, block)
        return basis

    def impulses(self, rows: Rows, cables: np.ndarray, at_limit: np.ndarray, y: np.ndarray,
                 tau: float) -> np.ndarray:
        """The published impulses (k,) N*s of a QP answer: ``rows`` (k rows, the first ``rows.n_eq``
        rigid struts, then the cables ``cables`` (k - n_eq,) int), its multipliers ``y`` (k,) N*s, over a
        sub-step of ``tau`` s (0 for an impact); ``at_limit`` (k - n_eq,) bool: the cables that end it at
        their limit. ``y`` itself (the same array) when the rows carry no self-stress."""
        if not self.possible:
            return y
        if self.sparse:
            published = self._impulses_sparse(rows, cables, at_limit, y, tau)
            if published is not None:
                self.counts["sparse"] += 1
                return published
        self.counts["dense"] += 1
        if self.compiled:
            return self._impulses_compiled(rows, cables, at_limit, y, tau)
        return self._impulses_reference(rows, cables, at_limit, y, tau)

    def _impulses_sparse(self, rows, cables, at_limit, y, tau):
        """:meth:`impulses` on sparse matrices, or None where the dense rule must answer. A sub-step's
        many self-stresses (more than ``_IMPLICIT`` more rows than degrees of freedom: a structure at
        rest) are first kept implicit (:class:`SparseSpace`), which answers unless a cable would pull (the
        nonnegative share is a QP over the whole space); otherwise an explicit basis
        (:func:`sparse_self_stress_space`) goes through the dense rule's own fit (:meth:`_fit`), the
        nonnegative one included. None where neither resolves the space."""
        n_eq = rows.n_eq
        binding = np.concatenate([np.ones(n_eq, dtype=bool), at_limit]) | (y != 0.0)
        index = np.flatnonzero(binding)
        a = rows.subset(index, rows.targets[index], 0).sparse(self.n_free)
        y_b = y[binding]
        ref = self.reference[cables[binding[n_eq:]]] * tau
        members = cables[binding[n_eq:]].tobytes()
        # an impact's share (tau = 0: no reference to fit) pulled on some cable at every impact of the
        # moving towers: it goes straight to the explicit basis; so does a sub-step's unless its members
        # are the load time's or those of the last sub-step whose share pulled on none (a structure at
        # rest): on moving 50- and 100-stage towers every implicit share pulled, and the attempts took
        # a sixth of the rule's time (0.73 of 4.37 s over 2 steps of the 100-stage tower)
        if (tau > 0.0 and len(index) - a.shape[1] > _IMPLICIT
                and members in (self._load_members, self._settled)):
            out = self._implicit(a, y_b, ref, n_eq)
            if out is not None:
                self.residual = max(self.residual, float(np.max(np.abs(a.T @ (out - y_b)), initial=0.0)))
                published = y.copy()
                published[binding] = out
                return published
        basis = self._basis(a, n_eq, cables[binding[n_eq:]])
        if basis is None:
            return None
        if not basis.shape[1]:
            return y
        published = self._fit(basis, y_b - basis @ (basis.T @ y_b), y, binding, a.T, ref, n_eq)
        if tau > 0.0:
            self._settled = None if self._pulled else members
        return published

    def _implicit(self, a, y_b, ref, n_eq):
        """The published impulses (k_b,) N*s of the binding rows ``a`` with multipliers ``y_b`` through
        :class:`SparseSpace`, or None (a cable would pull, or the space is not resolved). The space and
        its factorisations are kept while the rows are the same to the bit (a structure at rest), so
        the answer still depends on this call's arguments alone; and for rows moved by round-off since
        (the same members, no entry moved by more than ``_MOVED``: a structure at rest, whose round-off
        velocities move its rows' last bits), :meth:`SparseSpace.moved` answers for the new rows to
        round-off, with the kept space's vectors and factors."""
        pattern = (a.indptr.tobytes(), a.indices.tobytes())
        kept = self._kept
        if kept is not None and kept[0] == pattern and np.array_equal(kept[1], a.data):
            space = kept[2]
        elif (kept is not None and kept[0] == pattern and kept[2] is not None
              and np.max(np.abs(a.data - kept[1]), initial=0.0) <= _MOVED):
            space = kept[2].moved(a)
        else:
            space = SparseSpace.of(a)
            self._kept = (pattern, a.data.copy(), space)
        if space is None:
            return None
        share = space.fit(np.ones(len(y_b)), y_b)
        cable = np.zeros(len(y_b))
        cable[n_eq:] = 1.0
        fitted = space.fit(cable, np.concatenate([np.zeros(n_eq), ref]))
        if share is None or fitted is None:
            return None
        out = (y_b - share) + fitted
        return None if np.any(out[n_eq:] < 0.0) else out

    def _impulses_compiled(self, rows, cables, at_limit, y, tau):
        """:meth:`impulses` in the kernels of ``_self_stress_kernels.py`` (see there for what stays numpy)."""
        space = kernels.locked_space(rows.nodes, rows.directions, self.n_free, rows.n_eq, cables, at_limit, y,
                                     *self.load_space, *_NO_FACTOR)
        return self.locked_impulses(*space, y, tau, rows.n_eq)

    @property
    def load_space(self) -> tuple:
        """What ``_self_stress_kernels.locked_space`` takes after the QP answer: the load time's basis
        (k_load, d), cables (int) and largest singular value, ``refine``, the tolerances, the refinement's
        ``weight`` and whether it is the QP's (equal masses)."""
        return (self._load_basis, self._load_cables, self._load_largest, self.refine, RANK_TOL, _EXACT, self.weight,
                self._shared)

    def locked_impulses(self, binding, members, a_t, basis, y, tau, n_eq):
        """:meth:`impulses` from the result of ``locked_space`` (``binding`` (k,) bool, the binding cables
        ``members``, ``A_B^T``, the basis or None for an SVD) for multipliers ``y`` (k,) N*s over ``tau`` s."""
        if basis is None:
            basis = self._moving_space(a_t, n_eq, members)
        if not basis.shape[1]:
            return y
        y_b = y[binding]
        share = basis.T @ y_b
        return self._fit(basis, y_b - basis @ share, y, binding, a_t, self.reference[members] * tau, n_eq)

    def _moving_space(self, a_t: np.ndarray, n_eq: int, cables: np.ndarray) -> np.ndarray:
        """The self-stress basis of binding rows ``a_t`` (``A_B^T``) that are not the load time's (or whose
        refinement failed; ``n_eq`` rigid struts, then the cables ``cables``): the SVD's, or from
        ``MOVING_NODES`` free nodes (``moving``) the sparse block inverse iteration's
        (:func:`sparse_self_stress_space`, the same space to round-off), unless it does not settle."""
        if self.moving:
            from scipy.sparse import csr_matrix
            basis = self._basis(csr_matrix(a_t.T), n_eq, cables)
            if basis is not None:
                return basis
        return self_stress_space(a_t)[0]

    def _impulses_reference(self, rows, cables, at_limit, y, tau):
        """The numpy reference of :meth:`impulses` (for a structure that can lock)."""
        n_eq = rows.n_eq
        binding = np.concatenate([np.ones(n_eq, dtype=bool), at_limit]) | (y != 0.0)
        a_t = rows.dense(self.n_free)[binding].T
        cable_rows = binding[n_eq:]
        basis = self._space(a_t, cables[cable_rows].tobytes())
        if not basis.shape[1]:
            return y
        y_b = y[binding]
        share = basis.T @ y_b
        dynamic = y_b - basis @ share
        return self._fit(basis, dynamic, y, binding, a_t, self.reference[cables[cable_rows]] * tau, n_eq)

    def _fit(self, basis, dynamic, y, binding, a_t, ref, n_eq):
        """The published impulses (k,) N*s: the ``dynamic`` part (k_b,) of the binding rows' multipliers
        plus the self-stress share (``basis`` (k_b, d)) closest to ``ref`` (the binding cables' reference
        tensions times the sub-step, N*s), no cable pulling; ``y`` (k,) outside ``binding``."""
        n_c = basis[n_eq:]          # the cable components of the self-stresses
        # least squares by the normal equations: d is 1 or 2, and n_c holds most of each self-stress
        gram, rhs = n_c.T @ n_c, n_c.T @ ref
        # d = 1 (the usual case): the one division LAPACK's 1 x 1 solve makes (the same bits, measured)
        alpha = rhs / gram[0] if len(gram) == 1 else np.linalg.solve(gram, rhs)
        out = dynamic + basis @ alpha
        self._pulled = bool(np.any(out[n_eq:] < 0.0))
        if self._pulled:
            alpha = self._nonnegative(n_c, dynamic[n_eq:], ref, alpha)
            out = dynamic + basis @ alpha
        out[n_eq:] = np.maximum(out[n_eq:], 0.0)    # round-off below zero
        self.residual = max(self.residual, float(np.max(np.abs(a_t @ (out - y[binding])))))
        published = y.copy()
        published[binding] = out
        return published

    @staticmethod
    def _nonnegative(n_c, dynamic_c, ref, alpha):
        """The self-stress share closest to the reference that keeps every cable impulse >= 0:
        ``min |N_c a - ref|^2`` s.t. ``dynamic_c + N_c a >= 0`` (d unknowns, solved by DAQP)."""
        import daqp
        h = n_c.T @ n_c
        f = -(n_c.T @ ref)
        upper = np.full(len(dynamic_c), 1e30)
        z, _, flag, _ = daqp.solve(h, f, np.ascontiguousarray(n_c), upper, -dynamic_c,
                                   np.zeros(len(dynamic_c), dtype=np.int32))
        return z if flag >= 1 else alpha


def sparse_self_stress_space(a, rank_tol: float = RANK_TOL):
    """:func:`self_stress_space`'s basis (k, d) for the rows ``a`` (scipy sparse, k x 3 n_free) from sparse
    matrices: the eigenvectors of ``W = A_B A_B^T`` with eigenvalues below ``rank_tol^2`` times the largest
    (the squared singular values), by block inverse iteration with a sparse LU of ``W + delta I``
    (``delta`` = ``_SHIFT`` times the largest) and a Rayleigh-Ritz step each time, on a quarter more
    columns than the space has vectors (at least ``_GUARD``), until the kept Ritz pairs' residuals are
    round-off. The space's size is counted first (:func:`_space_size`, one more sparse LU), so the block
    starts at its final width: started at the excess of rows over degrees of freedom and doubled while
    too narrow, it ended up to 1.8x wider than the space (a moving 100-stage tower's sub-step: 339
    self-stresses, 622 columns, 4 iterations). The guard sets how well the residual test pins the space
    down when a kept singular value sits near the threshold: with 8 columns, a moving 100-stage tower's
    sub-step (380 self-stresses, the largest kept singular value 0.62e-3 of the largest, the next 1.08e-3)
    ended on a projector 1.2e-11 from the SVD's after 5 iterations, and the nonnegative share (a
    degenerate QP) turned that into published impulses 0.45 of the largest multiplier from the dense
    rule's; with a quarter (95), 7e-13 after 3 iterations, and 2.3e-12 from the dense rule (the doubled
    block's: 6.7e-13 and 2.9e-12). Replayed, the rule's calls of moving 30-, 50- and 100-stage towers (2
    steps each) took 0.68x, 0.81x and 0.81x the time of the doubled block's (the implicit attempts that
    moving towers no longer make included). Each iteration solves with the factor in a kernel
    (``_superlu_kernels.lu_solve``) and, after the first, orthonormalises by Cholesky's QR inside the
    Rayleigh-Ritz step (:func:`_rayleigh_ritz`): on the 12 calls of two steps of a moving 100-stage tower
    (208-341 self-stresses) 3.5 s against 5.6 s with SuperLU's solve and Householder's QR at every
    iteration (the two in turn, one process), the projectors 3e-13 apart (1e-11 at the two calls with
    a kept singular value near the threshold); on a moving 30-stage tower's calls 1.4e-14 from the SVD's
    against 3.1e-13 before. Single-vector
    Lanczos (ARPACK's shift-invert) is not used: it cannot resolve the null space's multiplicity (it
    returned 1-9 vectors that were not self-stresses among 13-49 on a moving 10-stage tower). None
    when that does not settle within ``_BLOCK_ITER`` iterations or the space outgrows ``_EXPLICIT`` plus
    the excess of rows over degrees of freedom (known from the count, before any iteration)."""
    return _block_space(a, rank_tol)[0]


def _block_space(a, rank_tol: float, start: np.ndarray | None = None):
    """:func:`sparse_self_stress_space`'s basis (or None) and the iteration's final block of Ritz vectors
    (k, b), eigenvalues ascending (None with no basis). ``start`` (k, b'), a block to try first instead of
    the random one (``SelfStress._basis``: the step's previous call's block, matched by member): its
    columns are taken as Ritz vectors (Cholesky's QR at once where their solves allow), cut or widened
    (random columns) to the counted space and its guard, and its answer kept only where it ends on as
    many eigenvalues below the threshold as the count gives, within ``_BLOCK_ITER`` iterations; the random
    start otherwise. The answer is verified either way by every kept Ritz pair's residual (round-off),
    the started one also by the count: on the calls of two steps of a moving 100-stage tower, the 7
    started from the step's previous block (the same members) settled in one iteration instead of two,
    on bases 1.2e-14 from the random start's."""
    from scipy.sparse import identity
    from scipy.sparse.linalg import ArpackNoConvergence, eigsh, splu

    from ..qp._superlu_kernels import factor_arrays
    k, n3 = a.shape
    if k < 3:   # too small for ARPACK (its k < n - 1): the dense SVD of a tiny matrix
        return self_stress_space(a.T.toarray(), rank_tol)[0], None
    w = (a @ a.T).tocsc()
    try:
        largest = float(eigsh(w, k=1, which="LA", v0=np.ones(k), tol=1e-10, return_eigenvectors=False)[0])
        lu = splu((w + _SHIFT * largest * identity(k)).tocsc(), permc_spec="MMD_AT_PLUS_A")
    except (ArpackNoConvergence, RuntimeError):
        return None, None
    thr = rank_tol * rank_tol * largest
    most = max(k - n3, 0) + _EXPLICIT
    size = _space_size(w, thr)
    counted = size is not None
    if size is None:
        size = max(k - n3, 0)
    elif size > most:
        return None, None
    width = min(size + max(_GUARD, size // 4), k)
    iterate = (a.T.tocsr(), w, factor_arrays(lu), thr, largest, min(most, k))
    if start is not None and counted:
        if start.shape[1] < width:
            more = np.random.default_rng(start.shape[1]).standard_normal((k, width - start.shape[1]))
            start = np.hstack([start, more])
        found = _block_iteration(start[:, :width], True, _BLOCK_ITER, *iterate)
        if found[0] is not None and found[0].shape[1] == size:
            return found
    # a fixed start block, so that a replay has the same bits
    return _block_iteration(np.random.default_rng(0).standard_normal((k, width)), False, _BLOCK_ITER, *iterate)


def _block_iteration(x, ritz, iterations, a_t, w, factor, thr, largest, most):
    """The block inverse iteration of :func:`_block_space` from ``x`` (k, b) (``ritz``: its columns are
    Ritz vectors already), at most ``iterations`` times: (the kept Ritz vectors, the final block), or
    (None, None) if it does not settle or the block would outgrow ``most`` columns. Converged Ritz
    vectors are locked as they come: the kept vectors, in ascending order up to the first whose residual
    is not yet round-off, leave the block, which goes on orthogonal to them (the solves projected off
    them twice), so that the iterations a vector near the threshold needs are paid on the few columns
    still moving (a moving 100-stage tower's sub-step: 4 iterations on 396 columns, ~290 of them
    converged after the second)."""
    from ..qp._superlu_kernels import lu_solve
    k = x.shape[0]
    locked = np.zeros((k, 0))
    for _ in range(iterations):
        y = lu_solve(x, *factor)
        for _ in range(2 if locked.shape[1] else 0):
            y -= locked @ (locked.T @ y)
        theta, x = _rayleigh_ritz(a_t, y, ritz)
        ritz = True
        kept = theta < thr
        if kept.all():   # the block is too small to hold the space and a guard: twice the columns
            held = locked.shape[1] + x.shape[1]
            if held >= most:
                return None, None
            more = min(held, most - held, k - held)
            x = np.hstack([x, np.random.default_rng(held).standard_normal((k, more))])
            ritz = False
            continue
        converged = np.linalg.norm(w @ x[:, kept] - x[:, kept] * theta[kept], axis=0) <= _RITZ_TOL * largest
        if converged.all():
            return np.hstack([locked, x[:, kept]]), np.hstack([locked, x])
        lock = int(np.argmin(converged))   # the converged vectors before the first that is not
        locked, x = np.hstack([locked, x[:, :lock]]), x[:, lock:]
    return None, None


def _rayleigh_ritz(a_t, y: np.ndarray, ritz: bool):
    """The Ritz pairs ``(theta, x)`` of ``W = A A^T`` (``a_t``: ``A^T``, scipy sparse) on the span of ``y``'s
    columns (k, b): ``theta`` ascending, ``x`` (k, b) orthonormal. The span's orthonormal basis is
    Householder's QR of ``y``, or, where ``ritz`` (``y`` solves ``W + delta I`` on Ritz vectors, so its
    columns scaled to unit length are nearly orthonormal), Cholesky's QR ``y = Q R``, whose ``R^-1`` goes
    into the Ritz rotation: ``x = y (R^-1 q)``, one product instead of Householder's Q and a rotation of
    it, if ``R``'s diagonal spans at most ``_CHOLESKY_QR`` (Householder's otherwise). ``W``'s projection is
    a symmetric product of the narrower ``A^T y`` (3 n_free, b), then ``R^-T (.) R^-1`` (b x b)."""
    from scipy.linalg import cholesky, solve_triangular
    if ritz:
        unit = y / np.linalg.norm(y, axis=0)
        try:
            r = cholesky(unit.T @ unit)
        except LinAlgError:
            r = None
        diagonal = None if r is None else np.abs(np.diag(r))
        if diagonal is not None and diagonal.max() <= _CHOLESKY_QR * diagonal.min():
            r_inv = solve_triangular(r, np.eye(len(r)))
            z = a_t @ unit
            theta, q = np.linalg.eigh(r_inv.T @ (z.T @ z) @ r_inv)
            return theta, unit @ (r_inv @ q)
    x, _ = np.linalg.qr(y)
    z = a_t @ x
    theta, q = np.linalg.eigh(z.T @ z)
    return theta, x @ q


def _space_size(w, thr: float):
    """How many eigenvalues of ``w`` (symmetric, scipy CSC) lie below ``thr``, by Sylvester's law of
    inertia: the negative pivots of ``w - thr I`` factorised as ``L D L^T`` (SuperLU with a symmetric
    ordering and no pivoting, ``U = D L^T``); None if that factorisation meets an exact zero pivot."""
    from scipy.sparse import identity

    from ..qp._superlu_kernels import symmetric_lu
    lu = symmetric_lu(w - thr * identity(w.shape[0]))
    return None if lu is None else int(np.count_nonzero(lu.U.diagonal() < 0.0))


class SparseSpace:
    """The self-stress space ``N`` of the rule for rows ``A_B`` (k, 3 n_free), kept implicit: every
    ``s`` with ``A_B^T s`` in the span of ``U``, where ``U`` (3 n_free, m) holds the eigenvectors of
    ``G = A_B^T A_B`` whose eigenvalues lie between the mechanisms' zeros and ``RANK_TOL^2`` times the
    largest (the near-null singular directions ``v = A_B u / sigma``; the exact null space of
    ``A_B^T`` needs no basis). Built by :meth:`of`; :meth:`fit` is the rule's least squares over ``N``.
    """

    def __init__(self, a, u: np.ndarray, largest: float):
        self.a = a.tocsc()
        self.u = u
        self.largest = largest      # the largest eigenvalue of G (the squared largest singular value)
        self._factors = {}          # the KKT systems' matrices and LU factors, by weight

    @classmethod
    def of(cls, a, rank_tol: float = RANK_TOL):
        """The space of ``a`` (scipy sparse, k x 3 n_free), or None when its spectrum is not resolved
        here: an eigenvalue of ``G`` between 1e-2 of the mechanisms' floor (``_SHIFT``) and the floor,
        where a singular value of ~1e-6 of the largest and a mechanism cannot be told apart in ``G``, or
        a near-null pair that ARPACK did not converge to 1e-10 of the largest eigenvalue (single-vector
        Lanczos can return a wrong pair among clustered eigenvalues: ``sparse_self_stress_space``)."""
        from scipy.sparse.linalg import ArpackNoConvergence, eigsh
        g = (a.T @ a).tocsc()
        n = g.shape[0]
        start = np.ones(n)   # ARPACK's start vector: fixed, so that a replay has the same bits
        try:
            largest = float(eigsh(g, k=1, which="LA", v0=start, tol=1e-10, return_eigenvectors=False)[0])
            thr = rank_tol * rank_tol * largest
            # shift-invert at half the threshold: every eigenvalue in (0, thr) is nearer to the shift than
            # the mechanisms' zeros and than anything above thr, so the nearest m hold them all as soon
            # as one of the m is not among them
            m = 4
            while True:
                m = min(m, n - 2)
                lam, vec = eigsh(g, k=m, sigma=0.5 * thr, which="LM", v0=start, tol=1e-13)
                band = (lam > _SHIFT * largest) & (lam < thr)
                if not band.all() or m == n - 2:
                    break
                m *= 2
        except (ArpackNoConvergence, RuntimeError):
            return None
        if np.any((lam > 1e-2 * _SHIFT * largest) & (lam <= _SHIFT * largest)):
            return None
        u = np.ascontiguousarray(vec[:, band])
        if np.linalg.norm(g @ u - u * lam[band], axis=0).max(initial=0.0) > 1e-10 * largest:
            return None
        return cls(a, u, largest)

    def moved(self, a) -> "SparseSpace":
        """The space of rows ``a`` (scipy sparse) that are this one's moved by round-off (the same
        pattern): this one's near-null vectors ``U`` and LU factors, the KKT matrices of ``a`` (which
        :meth:`fit`'s refinement solves), so the answers are ``a``'s own to round-off."""
        space = SparseSpace(a, self.u, self.largest)
        space._factors = {key: (space._kkt(np.frombuffer(key)), lu) for key, (_, lu) in self._factors.items()}
        return space

    def _kkt(self, weight: np.ndarray):
        """The KKT matrix of :meth:`fit` for ``weight`` (CSC)."""
        import scipy.sparse as sp
        a, u = self.a, self.u
        m, n3 = u.shape[1], a.shape[1]
        dense_u = sp.csc_matrix(u)
        return sp.bmat([[sp.diags(weight), None, a],
                        [None, sp.csc_matrix((m, m)), -dense_u.T],
                        [a.T, -dense_u, sp.csc_matrix((n3, n3))]], format="csc")

    def _factorise(self, weight: np.ndarray):
        """The KKT matrix of :meth:`fit` for ``weight`` and the LU factor of its regularised form (None
        if that is exactly singular)."""
        import scipy.sparse as sp
        from scipy.sparse.linalg import splu
        k, n3 = self.a.shape
        m = self.u.shape[1]
        exact = self._kkt(weight)
        shifted = exact - sp.diags(np.concatenate([np.zeros(k + m), np.full(n3, _SHIFT * self.largest)]))
        try:
            return exact, splu(shifted, permc_spec="MMD_AT_PLUS_A")   # 0.7x the time of COLAMD's (tower30)
        except RuntimeError:   # exactly singular
            return exact, None

    def fit(self, weight: np.ndarray, target: np.ndarray):
        """``s = argmin |W (s - target)|`` over ``s`` in ``N`` (``weight`` (k,) 0 or 1, the diagonal of
        ``W``, nonzero on every self-stress), by the KKT system of ``min 1/2 |W(s - t)|^2`` s.t.
        ``A_B^T s = U c``; its multiplier block is regularised by ``_SHIFT`` times the largest
        eigenvalue (a mechanism makes it singular) and refined on the exact system. None if the
        refinement does not settle."""
        k, n3 = self.a.shape
        m = self.u.shape[1]
        key = weight.tobytes()
        if key not in self._factors:
            self._factors[key] = self._factorise(weight)
        exact, lu = self._factors[key]
        if lu is None:
            return None
        b = np.concatenate([weight * target, np.zeros(m + n3)])
        x = lu.solve(b)
        size = max(float(np.max(np.abs(target), initial=0.0)), 1e-300)
        for _ in range(_REFINEMENTS):
            step = lu.solve(b - exact @ x)
            x += step
            if np.max(np.abs(step[:k]), initial=0.0) <= _REFINE_TOL * size:
                return x[:k]
        return None
