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

**Flags.** A cable is slack when it is shorter than its limit *and* carried no impulse over the step
(:meth:`~.inextensible.InextensibleMethod.slack`), so a cable at its limit that carries prestress is taut.
"""
from __future__ import annotations

import warnings

import numpy as np
from scipy.linalg import LinAlgWarning, lu_factor as _lu_factor, lu_solve as _lu_solve

from . import _self_stress_kernels as kernels
from ._c_calls import scipy_lapack
from .qp import Rows

__all__ = ["RANK_TOL", "TAUT_TOL", "SelfStress", "reference_tensions", "self_stress_space"]

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
    time (the rigid struts, then the cables ``load_cables`` (int), those with a free end)."""

    def __init__(self, n_free: int, reference: np.ndarray, rows_at_load: Rows, load_cables: np.ndarray):
        self.n_free = n_free
        self.reference = reference
        self._load_basis, _, self._load_largest = self_stress_space(rows_at_load.dense(n_free).T)
        self._load_members = np.asarray(load_cables).tobytes()
        self.possible = self._load_basis.shape[1] > 0
        self.residual = 0.0   # N*s: the largest node impulse dropped with a near-null share (module docstring)
        self.refine = True    # False: an SVD at every step (the reference the refinement must match)
        self.compiled = True  # the rule in one numba kernel (_self_stress_kernels.py); False: the numpy reference
        self._load_cables = np.ascontiguousarray(load_cables, dtype=np.int64)
        self._lu = (scipy_lapack("dgetrf"), scipy_lapack("dgetrs"))   # the kernel's refinement (one LU, two solves)

    def _space(self, a_t: np.ndarray, members: bytes) -> np.ndarray:
        """The self-stress basis (k, d) of ``a_t`` (3 n_free, k). When the binding rows are all the
        members of the load time (a locked structure), the load time's basis refined by two steps of
        inverse iteration on ``A A^T`` (its self-stress singular values are ~1e-4 of the next ones: each
        step divides the error by ~1e8) is ~8 times cheaper than an SVD, and like the SVD it depends on
        this step alone (a replay, a twin that saw other commands: the same bits). It is kept if it is
        still below ``RANK_TOL``; any other set of rows gets an SVD."""
        basis = self._load_basis
        if self.refine and members == self._load_members:
            if np.linalg.norm(a_t @ basis, axis=0).max() <= _EXACT * self._load_largest:
                return basis   # an exact self-stress (a structure at rest in its load shape)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("error", LinAlgWarning)   # an exactly singular A A^T: the SVD below
                    lu = _lu_factor(a_t.T @ a_t, check_finite=False)
                for _ in range(2):
                    basis, _ = np.linalg.qr(_lu_solve(lu, basis, check_finite=False))
            except LinAlgWarning:
                basis = None
            if basis is not None and np.linalg.norm(a_t @ basis, axis=0).max() < RANK_TOL * self._load_largest:
                return basis
        return self_stress_space(a_t)[0]

    def impulses(self, rows: Rows, cables: np.ndarray, at_limit: np.ndarray, y: np.ndarray,
                 tau: float) -> np.ndarray:
        """The published impulses (k,) N*s of a QP answer: ``rows`` (k rows, the first ``rows.n_eq``
        rigid struts, then the cables ``cables`` (k - n_eq,) int), its multipliers ``y`` (k,) N*s, over a
        sub-step of ``tau`` s (0 for an impact); ``at_limit`` (k - n_eq,) bool: the cables that end it at
        their limit. ``y`` itself (the same array) when the rows carry no self-stress."""
        if not self.possible:
            return y
        if self.compiled:
            return self._impulses_compiled(rows, cables, at_limit, y, tau)
        return self._impulses_reference(rows, cables, at_limit, y, tau)

    def _impulses_compiled(self, rows, cables, at_limit, y, tau):
        """:meth:`impulses` in the kernels of ``_self_stress_kernels.py`` (see there for what stays numpy)."""
        space = kernels.locked_space(rows.nodes, rows.directions, self.n_free, rows.n_eq, cables, at_limit, y,
                                     *self.load_space)
        return self.locked_impulses(*space, y, tau, rows.n_eq)

    @property
    def load_space(self) -> tuple:
        """What ``_self_stress_kernels.locked_space`` takes after the QP answer: the load time's basis
        (k_load, d), cables (int) and largest singular value, ``refine``, the tolerances and the LU
        routines' addresses."""
        return self._load_basis, self._load_cables, self._load_largest, self.refine, RANK_TOL, _EXACT, *self._lu

    def locked_impulses(self, binding, members, a_t, basis, y, tau, n_eq):
        """:meth:`impulses` from the result of ``locked_space`` (``binding`` (k,) bool, the binding cables
        ``members``, ``A_B^T``, the basis or None for an SVD) for multipliers ``y`` (k,) N*s over ``tau`` s."""
        if basis is None:
            basis = self_stress_space(a_t)[0]
        if not basis.shape[1]:
            return y
        y_b = y[binding]
        share = basis.T @ y_b
        return self._fit(basis, y_b - basis @ share, y, binding, a_t, self.reference[members] * tau, n_eq)

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
        if np.any(out[n_eq:] < 0.0):
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
