"""QP backends for the velocity step of the inextensible method, picked by name from :data:`SOLVERS`.

Every backend solves the same problem (physics.md §3, written around the free velocity)::

    min_v  1/2 (v - v0)^T M (v - v0)   s.t.   A[:n_eq] v = r[:n_eq],   A[n_eq:] v <= r[n_eq:]

over the velocities ``v`` of the free nodes, with ``M`` the lumped (diagonal) mass and
``v0 = v_i + h M^-1 F_m`` the free velocity, so the linear term is the seed's ``-(M v_i + h F_m)^T v``.
Each row ``i`` of ``A`` is a member's compatibility vector ``b_i^T``: ``-n_i`` at node ``a_i``, ``+n_i`` at
node ``b_i``. A backend returns ``v`` and the multipliers ``y`` with ``M (v - v0) = -A^T y`` and ``y >= 0``
on the inequality rows: a row's multiplier is its member's impulse (N*s, tension positive).

The problem is often degenerate, and every backend must cope: a prestressed structure with all members
taut has a self-stress, i.e. dependent rows and a singular Delassus matrix ``W = A M^-1 A^T``, and so has
a scene with duplicated cables. ``v`` is then unique but ``y`` is not.

Measured with ``python bench/bench_steps.py --accuracy`` (the QPs of rattling built-in scenes, node
masses 1e4 apart, each solved again by quadprog): DAQP, a dual active-set method warm-started from the
previous step's active set, agrees to 4e-16..2e-10 relative in velocity and is the fastest per QP on
the built-ins (15-450 us), so it is the default; its tolerances are tightened (see :class:`DaqpSolver`).
The Delassus problem as non-negative least squares agrees to 6e-11..3e-9 on well-conditioned problems
but only to 3e-2 on the near-singular ones of a locked structure (forming ``W`` squares the
conditioning), and is 2-60 times slower. OSQP (ADMM) with eps 1e-10 and polishing reaches 3e-13..1e-8
but stops at its iteration limit, or reports a false infeasibility, on the icosahedron; at its default
tolerances it is off by 0.1..0.8. Both stay available by name. DAQP is dense: on a 50-stage tower
(1335 rows) sparse OSQP steps 6 times faster.

A backend that fails (infeasible rows, iteration limit) raises :class:`QPError` with a status and a
message. The answers of the backends with ``verify`` (DAQP, OSQP, NNLS; the sparse backend verifies its
guesses itself) are checked against the optimality conditions, to ``1e-7`` relative, and refused if they
fail them. The check and DAQP's dense rows are numba kernels (``_qp_kernels.py``: one pass over the rows,
``A`` never formed for the check), beside their numpy reference (``compiled = False``); the compiled
path calls DAQP's C function ``daqp_quadprog`` itself, with the inputs ``daqp.solve`` would pass it
(``_daqp_kernels.py``: the same answer to the bit).

**The working set first** (issue 10): DAQP is warm-started from the rows that held in the previous
sub-step, and on a moving structure that set is almost always the active set, so DAQP stops after one
iteration; but ``daqp_quadprog`` sets the whole problem up again each call (the thrown icosahedron's
30 rows: 16 us a QP, one iteration). :class:`DaqpSolver` therefore first solves the working set's
equality problem itself (``_qp_kernels.working_set_answer``: its Delassus matrix built node by node,
Cholesky, refined) and keeps the answer only where DAQP would stop there too: every row of the set
pushing by more than DAQP's ``dual_tol``, none outside violated by more than its ``primal_tol``; else
DAQP answers. The thrown icosahedron's QP: 5.7 against 16.8 us (CPU time, the two called in turn on the
same QP), its velocities DAQP's to 4e-13 m/s, its multipliers to 2e-9 N*s of 2.9 N*s along the nearly
dependent direction that the self-stress rule then replaces (``self_stress.py``). A row whose
multiplier is at round-off of zero goes to DAQP, so which cables hold (``y > 0``) stays DAQP's decision
there. Like DAQP itself, the kernel is part of the backend in both configurations (``compiled`` or
not); its numpy reference, :meth:`DaqpSolver._working_set_reference`, is held to it in ``test_qp.py``.
The ground's QPs keep DAQP alone (:attr:`DaqpSolver.working_set`), but where contacts stick: the friction
modes (``friction.FrictionalSolver._qp`` and its compiled ``ground_modes``) first try the set of the method's
warm rows, the loaded normal rows and each sticking contact's tangential rows as sign-free pairs
(``_qp_kernels.sticking_answer``, issue 47), checked as this set is. The inextensible icosahedron resting on
the ground: its 45-row QP 22 -> 9-12 us (load 3.4), no DAQP factorisation; the velocities DAQP's to 1e-15 m/s,
the multipliers to 1e-9 of the impulse scale (``test_sticking_pairs.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as scipy_linalg

from . import _daqp_kernels as daqp_kernels, _qp_kernels as kernels
from ._qp_kernels import _SETTLED, _SWEEPS
from ._superlu_kernels import factor_arrays, symmetric_lu
from ..base import StepError

__all__ = ["Rows", "QPError", "QPSolver", "DaqpSolver", "OsqpSolver", "NnlsSolver", "SparseSolver", "MassWrapper",
           "BlockMassSolver", "SOLVERS",
           "SPARSE_NODES", "DUAL_NODES", "choose_solver", "make_solver"]

# A returned answer may miss the optimality conditions by at most _FEASIBILITY_TOL relative to the
# problem's velocity (impulse) scale, plus _VELOCITY_FLOOR m/s, before it is refused.
_FEASIBILITY_TOL = 1e-7
_VELOCITY_FLOOR = 1e-12
# DAQP's statuses after which a warm-started solve is run again from the empty working set (DaqpSolver.solve)
_RESTARTED = ("cycling", "iteration limit")


@dataclass
class Rows:
    """Constraint rows of one QP (k rows, equality rows first).

    nodes: (k, 2) int, the free-node index of each member end, -1 for a fixed node.
    directions: (k, 3) unit vectors ``n_i`` (from end a to end b).
    targets: (k,) m/s, the right-hand sides ``r``.
    n_eq: how many leading rows are equalities.
    weights: None for member rows (entries ``-n_i`` at ``nodes[:, 0]``, ``+n_i`` at ``nodes[:, 1]``: the
    compiled kernels' fast path), or (k, m) for general rows, such as a contact between two members whose
    rate is that of a point inside each: ``nodes`` is then (k, m) (-1: no node) and the row is
    ``sum_j weights[i, j] n_i . v[nodes[i, j]]``.
    """

    nodes: np.ndarray
    directions: np.ndarray
    targets: np.ndarray
    n_eq: int
    weights: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.targets)

    def _columns(self, n_free: int) -> np.ndarray:
        """(k, m, 3) column of each entry; a fixed end's entries go to a scratch block ``n_free``."""
        return 3 * np.where(self.nodes < 0, n_free, self.nodes)[:, :, None] + np.arange(3)

    def _entries(self) -> np.ndarray:
        """(k, m, 3) the row's entry at each of its nodes."""
        if self.weights is None:
            return np.stack([-self.directions, self.directions], axis=1)
        return self.weights[:, :, None] * self.directions[:, None, :]

    def dense(self, n_free: int) -> np.ndarray:
        """The (k, 3 n_free) matrix ``A``."""
        k = len(self.targets)
        a = np.zeros((k, 3 * n_free + 3))
        cols = self._columns(n_free)
        row = np.arange(k)[:, None]
        if self.weights is None:
            a[row, cols[:, 0]] = -self.directions
            a[row, cols[:, 1]] = self.directions
        else:   # summed: a row may hold one node twice (a padding -1, or both ends of a member fixed)
            np.add.at(a, (np.repeat(row, cols.shape[1] * 3, axis=1), cols.reshape(k, -1)),
                      self._entries().reshape(k, -1))
        return np.ascontiguousarray(a[:, :-3])

    def sparse(self, n_free: int):
        """``A`` as a scipy CSR matrix that stores all entries of every row (six for member rows), even
        exact zeros, so its pattern depends only on which members the rows are."""
        import scipy.sparse as sp
        k = len(self.targets)
        cols = self._columns(n_free).reshape(k, -1)
        vals = self._entries().reshape(k, -1)
        keep = cols < 3 * n_free
        indptr = np.concatenate([[0], np.cumsum(keep.sum(axis=1))])
        a = sp.csr_matrix((vals[keep], cols[keep], indptr), shape=(k, 3 * n_free))
        if self.weights is not None:
            a.sum_duplicates()
        return a

    def rates(self, v: np.ndarray) -> np.ndarray:
        """``A v`` (k,) m/s for velocities ``v`` (n_free, 3) of the free nodes."""
        vv = np.vstack([v, np.zeros((1, 3))])
        if self.weights is None:
            return np.einsum("ij,ij->i", vv[self.nodes[:, 1]] - vv[self.nodes[:, 0]], self.directions)
        return np.einsum("ij,ij->i", np.einsum("ij,ijk->ik", self.weights, vv[self.nodes]), self.directions)

    def subset(self, index: np.ndarray, targets: np.ndarray, n_eq: int) -> "Rows":
        """The rows ``index`` with ``targets`` and ``n_eq`` equalities."""
        weights = None if self.weights is None else self.weights[index]
        return Rows(self.nodes[index], self.directions[index], targets, n_eq, weights)


class QPError(StepError):
    """A QP backend failed; ``status`` is the backend's status, the message says what happened."""

    def __init__(self, solver: str, status: str, message: str):
        super().__init__(f"QP solver {solver!r} failed ({status}): {message}")
        self.solver = solver
        self.status = status
        self.detail = message


class QPSolver:
    """Base class of the backends. ``mass``: (n_free,) kg of the free nodes, fixed for a run."""

    name = ""
    verify = True   # recheck feasibility of every answer (backends that may return a poor one)
    compiled = True   # build rows and check answers with the numba kernels (False: the numpy reference)
    # the inextensible method warms the last sub-step of a step cut at snaps with the cables that held in
    # the last sub-step of the previous such step (InextensibleMethod._last_hint), not the sub-step before
    last_hint = False
    # the mass matrix is the diagonal ``mass`` (False: ``inverse`` applies a general one, e.g. rods' blocks)
    diagonal = True

    def __init__(self, mass: np.ndarray):
        self.n_free = len(mass)
        self.mass = np.repeat(np.asarray(mass, dtype=float), 3)   # (3 n_free,) per degree of freedom
        self.inv_mass = 1.0 / self.mass

    def solve(self, v0: np.ndarray, rows: Rows, warm: np.ndarray | None = None):
        """Solve the QP. ``v0``: (n_free, 3) m/s. ``warm``: (k,) bool, rows believed active (a hint).

        Returns ``v`` (n_free, 3) m/s and ``y`` (k,) N*s. Raises :class:`QPError` on failure.
        """
        v, y = self._solve(v0.reshape(-1), rows, warm)
        v = v.reshape(-1, 3)
        self._check(v, y, v0, rows)
        return v, y

    def _solve(self, v0: np.ndarray, rows: Rows, warm):
        """Backend-specific: ``v`` (3 n_free,) and ``y`` (k,)."""
        raise NotImplementedError

    def inverse(self, p: np.ndarray) -> np.ndarray:
        """``M^-1 p`` for impulses ``p`` (3 n_free, ...) N*s (a node's components together): velocities, m/s."""
        return self.inv_mass.reshape((-1,) + (1,) * (p.ndim - 1)) * p

    def _check(self, v, y, v0, rows: Rows) -> None:
        """Refuse non-finite output, and (if ``verify``) output that is not a solution: infeasible
        velocities, or multipliers that are not impulses along the rows (stationarity), pull on an
        inequality row or act on a row that is not at its target (complementarity)."""
        if not (np.isfinite(v).all() and np.isfinite(y).all()):
            raise QPError(self.name, "non-finite", "the solution contains NaN or inf")
        if not self.verify:
            return
        if self.compiled and rows.weights is None:
            residuals = kernels.answer_residuals(v, y, v0, rows.nodes, rows.directions, rows.targets, rows.n_eq,
                                                 self.mass, _FEASIBILITY_TOL)
        else:
            residuals = self._residuals_reference(v, y, v0, rows)
        scale, viol, impulse, stationarity, smallest, slack = residuals
        tol = _FEASIBILITY_TOL * scale + _VELOCITY_FLOOR
        if viol > tol:
            raise QPError(self.name, "infeasible output",
                          f"the returned velocities violate a constraint by {viol:.3g} m/s "
                          f"(velocity scale {scale:.3g} m/s)")
        if stationarity > _FEASIBILITY_TOL * impulse or smallest < -_FEASIBILITY_TOL * impulse or slack > tol:
            raise QPError(self.name, "inaccurate output",
                          f"not a solution: impulses off the rows by {stationarity:.3g} N*s, smallest inequality "
                          f"impulse {smallest:.3g} N*s, an acting row {slack:.3g} m/s "
                          f"short of its target (impulse scale {impulse:.3g} N*s, velocity scale {scale:.3g} m/s)")

    def _residuals_reference(self, v, y, v0, rows: Rows, acting_floor: float = 0.0):
        """The numpy reference of ``_qp_kernels.answer_residuals``: the velocity scale (m/s), the
        largest constraint violation (m/s), the impulse scale (N*s), the stationarity residual (N*s),
        the smallest inequality impulse (N*s, at most 0) and how far an acting row is short of its
        target (m/s); a row acts where its impulse exceeds ``acting_floor`` (N*s) too."""
        n_eq = rows.n_eq
        scale = max(float(np.max(np.abs(v0), initial=0.0)), float(np.max(np.abs(rows.targets), initial=0.0)))
        res = rows.rates(v) - rows.targets
        viol = max(float(np.max(np.abs(res[:n_eq]), initial=0.0)), float(np.max(res[n_eq:], initial=0.0)))
        change = self.mass * (v.ravel() - v0.ravel())
        impulse = max(float(np.max(np.abs(self.mass * v0.ravel()), initial=0.0)),
                      float(np.max(np.abs(change), initial=0.0)), float(np.max(np.abs(y), initial=0.0)), 1e-300)
        stationarity = float(np.max(np.abs(change + rows.dense(self.n_free).T @ y), initial=0.0))
        acting = y[n_eq:] > max(_FEASIBILITY_TOL * impulse, acting_floor)
        slack = float(np.max(-res[n_eq:][acting], initial=0.0))
        return scale, viol, impulse, stationarity, float(np.min(y[n_eq:], initial=0.0)), slack

    def describe(self) -> dict:
        return {"solver": self.name}


class DaqpSolver(QPSolver):
    """DAQP (dual active set, recursive LDL^T updates), warm-started from the previous active set.

    The problem is passed mass-scaled (``z = M^1/2 v``, Hessian = identity) so DAQP's setup factorises a
    trivial matrix. ``primal_tol`` is tightened from DAQP's 1e-6 to 1e-12 m/s: a row violated by less
    than ``primal_tol`` is never activated, and that error goes straight into the velocities.
    """

    name = "daqp"
    # Its exit flag is not enough: reeling in a cable of a moving locked structure (near-singular
    # working set) it has reported success with tensions of 1e18 N; the optimality check refuses that.
    verify = True
    settings = {"primal_tol": 1e-12, "dual_tol": 1e-12, "sing_tol": 1e-14, "iter_limit": 10_000, "cycle_tol": 100}
    # the warm start's working set answered directly when it is the active set (_qp_kernels.working_set_answer)
    # before DAQP is called; off for the ground's QPs (friction.ContactSet), whose sticking nodes stop at
    # exactly 0 m/s in DAQP's arithmetic (test_ground.py) and at round-off of it in the working set's
    working_set = True
    _STATUS = {-1: "infeasible", -2: "cycling", -3: "unbounded", -4: "iteration limit",
               -5: "non-convex", -6: "initial working set overdetermined", -7: "time limit"}

    def __init__(self, mass):
        import daqp  # imported here so that a broken optional backend fails only when it is asked for
        super().__init__(mass)
        self._daqp = daqp
        self._sqrt_mass = np.sqrt(self.mass)
        self._hessian = np.eye(len(self.mass))
        # daqp_quadprog itself, for the compiled path: daqp.solve's answer bit for bit (_daqp_kernels.py)
        self._entry, self._raw_settings = daqp_kernels.entry_point(daqp, self.settings)
        self._fallbacks = None   # the FALLBACKS backends, made when DAQP first fails
        self.fallbacks: dict[str, int] = {}   # solves answered by a fallback backend, by its name

    def _solve(self, v0, rows, warm, unit: float = 1.0):
        """The working set ``warm`` if it is the active set, else DAQP, on the problem divided by ``unit``
        (m/s), the answer scaled back."""
        k, n_eq, r = len(rows), rows.n_eq, rows.targets
        warm = np.zeros(k, dtype=bool) if warm is None else warm
        if self.compiled and rows.weights is None:
            v, y, flag, iterations, _, _ = daqp_kernels.solve_rows(
                self._entry, self._raw_settings, self._hessian, self._sqrt_mass, self.mass, rows.nodes,
                rows.directions, self.n_free, v0, r, n_eq, warm, unit, self.working_set)
            if flag < 1:
                raise self._failure(flag, iterations, k)
            return v, y
        if self.working_set and rows.weights is None:   # the kernel's working-set answer, then DAQP's wrapper
            guessed, v, y, _, _ = kernels.working_set_answer(
                rows.nodes, rows.directions, self.inv_mass.reshape(-1, 3), (v0 / unit).reshape(-1, 3), r / unit,
                n_eq, warm, self.settings["primal_tol"], self.settings["dual_tol"], self.settings["sing_tol"])
            if guessed:
                return v.reshape(-1) * unit, unit * y
        lower = np.full(k, -1e30)
        lower[:n_eq] = r[:n_eq]
        sense = warm.astype(np.int32)   # 1: start active
        sense[:n_eq] = 5
        a_scaled = rows.dense(self.n_free) / self._sqrt_mass
        lower[:n_eq] /= unit
        z, _, flag, info = self._daqp.solve(self._hessian, -self._sqrt_mass * (v0 / unit), a_scaled,
                                            r / unit, lower, sense, **self.settings)
        if flag < 1:
            raise self._failure(flag, info["iterations"], k)
        return (z / self._sqrt_mass) * unit, unit * np.asarray(info["lam"], dtype=float)

    def _working_set_reference(self, v0, rows: Rows, warm):
        """The numpy reference of ``_qp_kernels.working_set_answer``: ``(v, y)`` (3 n_free,) m/s and (k,)
        N*s when the equality rows and the rows ``warm`` are the QP's active set (their Cholesky-factorised
        Delassus matrix, refined on the rows' residual until a correction moves ``v`` by at most
        ``_SETTLED`` of the velocity scale; ``primal_tol`` and ``dual_tol`` on unit-length mass-scaled
        rows, the primal one at most ``primal_tol`` m/s), else None."""
        k, n_eq = len(rows), rows.n_eq
        work = np.flatnonzero((np.arange(k) < n_eq) | warm)
        a = rows.dense(self.n_free)
        a_w = a[work]
        delassus = (a_w * self.inv_mass) @ a_w.T
        largest = float(np.max(np.diag(delassus), initial=0.0))
        try:
            factor = np.linalg.cholesky(delassus)
        except np.linalg.LinAlgError:
            return None
        if len(work) and not np.min(np.diag(factor)) ** 2 > self.settings["sing_tol"] * largest:
            return None
        length = np.sqrt((a * a) @ self.inv_mass)   # each row's length in z = M^1/2 v
        tol = self.settings["primal_tol"] * np.minimum(length, 1.0)
        floor = _SETTLED * max(float(np.max(np.abs(v0), initial=0.0)),
                               float(np.max(np.abs(rows.targets[work]), initial=0.0)))
        v, y = v0.copy(), np.zeros(k)
        moved = previous = np.inf
        for sweep in range(_SWEEPS + 1):
            res = a_w @ v - rows.targets[work]
            if np.all(np.abs(res) <= tol[work]) and (moved <= floor or previous < np.inf and moved > 0.5 * previous):
                break
            if sweep == _SWEEPS or moved > previous:
                return None
            step = scipy_linalg.cho_solve((factor, True), res)
            y[work] += step
            change = self.inv_mass * (a_w.T @ step)
            v -= change
            previous, moved = moved, float(np.max(np.abs(change), initial=0.0))
        inequality = np.arange(k) >= n_eq
        if np.any(inequality & warm & ~(y * length > self.settings["dual_tol"])):
            return None
        if np.any(inequality & ~warm & (a @ v - rows.targets > tol)):
            return None
        return v, y

    @property
    def c_call(self) -> tuple:
        """What a kernel needs to solve as :meth:`_solve` does (``_inextensible_kernels``): the address of
        ``daqp_quadprog``, the settings struct, the identity Hessian, ``sqrt(mass)`` and the mass per
        degree of freedom (3 n_free,)."""
        return self._entry, self._raw_settings, self._hessian, self._sqrt_mass, self.mass

    def _failure(self, flag: int, iterations: int, k: int) -> QPError:
        """The error of DAQP's exit ``flag`` < 1 after ``iterations`` on ``k`` rows."""
        return QPError(self.name, self._STATUS.get(flag, f"exitflag {flag}"),
                       f"after {iterations} iterations on {k} rows")

    def solve(self, v0, rows, warm=None):
        """:meth:`QPSolver.solve`; an answer the check refuses as inaccurate is solved again at unit
        velocity scale if the problem is slower than 1 m/s. DAQP's tolerances are absolute, the check's
        relative: a prism moving at 1e-9 m/s (the hard cases' hovering cable) got a warm-started row
        dropped with a multiplier of -4e-13 N*s, inside ``dual_tol`` but 4e-4 of the impulse scale. Not
        every problem is rescaled: tighter effective tolerances made DAQP call the dependent rows of a
        moving locked icosahedron infeasible (test_inextensible.py).

        Where DAQP still fails (its exit flag, or an answer the check refuses), the problem goes to the
        other dense backends in :data:`FALLBACKS` order, each answer verified by the same check, and the
        first verified answer is returned (counted in :attr:`fallbacks`); only if none answers is DAQP's
        error raised. Measured (``bench/bench_throws.py``, issue 47): a locked icosahedron set down on
        the ground, its 30 dependent member rows and a ground row all met by ``v = 0`` (every target 0),
        which DAQP called infeasible from every start while NNLS and OSQP answer it.

        DAQP that cycles (or runs out of iterations) from a warm start is first run again from the empty
        working set (counted in :attr:`fallbacks` as ``"daqp cold"``), and if that fails too, its error is the
        one raised: the warm start's rows can hold a dependent subset (a locked structure's self-stress with
        sticking ground rows) on which DAQP's working-set changes loop, while from no hint it decides the
        problem. Measured (``bench/bench_throws.py --first 1430 --count 1``, issue 47): three_bar, inextensible,
        set down on three sticking nodes, 27 rows of rank 18 whose drift-correcting targets (1e-9 m/s) no
        velocity meets: warm, "cycling" after 656 iterations; cold, "infeasible" after 33, which the friction
        modes answer by letting the targets yield (``friction.FrictionalSolver._qp``)."""
        try:
            return self._solve_checked(v0, rows, warm)
        except QPError as exc:
            if not (np.all(np.isfinite(v0)) and np.all(np.isfinite(rows.targets))
                    and np.all(np.isfinite(rows.directions))):
                raise   # not a problem another backend could answer: a state gone non-finite
            if exc.status in _RESTARTED and warm is not None and warm.any():
                try:
                    answer = self._solve_checked(v0, rows, None)
                    self.fallbacks["daqp cold"] = self.fallbacks.get("daqp cold", 0) + 1
                    return answer
                except QPError as cold:
                    exc = cold
            for backend in self._fallback_backends():
                try:
                    answer = backend.solve(v0, rows, warm)
                except QPError:
                    continue
                self.fallbacks[backend.name] = self.fallbacks.get(backend.name, 0) + 1
                return answer
            raise exc

    def _solve_checked(self, v0, rows, warm):
        """DAQP's verified answer, solved again at unit velocity scale where that helps (:meth:`solve`)."""
        try:
            return super().solve(v0, rows, warm)
        except QPError as exc:
            scale = max(float(np.max(np.abs(v0), initial=0.0)), float(np.max(np.abs(rows.targets), initial=0.0)))
            if exc.status != "inaccurate output" or not 0.0 < scale < 1.0:
                raise
        v, y = self._solve(v0.reshape(-1), rows, warm, unit=scale)
        v = v.reshape(-1, 3)
        self._check(v, y, v0, rows)
        return v, y

    def _fallback_backends(self):
        """The backends of :data:`FALLBACKS`, made on first use for this backend's masses."""
        if self._fallbacks is None:
            self._fallbacks = [SOLVERS[name](self.mass[::3]) for name in FALLBACKS]
            for backend in self._fallbacks:
                backend.compiled = self.compiled
        return self._fallbacks

    def describe(self) -> dict:
        return {"solver": self.name, **self.settings}


class OsqpSolver(QPSolver):
    """OSQP (ADMM, sparse), tightened: eps 1e-10, polishing, warm start from the previous solution, and
    ``update()`` of the matrix values (a numerical re-factorisation, no new symbolic one) whenever the
    rows are the same members as in the previous call. OSQP 1.1 prints "Polishing not needed" on every
    solve without active rows, whatever ``verbose`` says (osqp/osqp#785)."""

    name = "osqp"
    settings = {"eps_abs": 1e-10, "eps_rel": 1e-10, "polishing": True, "max_iter": 200_000,
                "warm_starting": True}

    def __init__(self, mass):
        import osqp
        import scipy.sparse as sp
        super().__init__(mass)
        self._osqp = osqp
        self._hessian = sp.diags(self.mass).tocsc()
        self._workspace = None
        self._pattern = None

    def _solve(self, v0, rows, warm):
        r, n_eq = rows.targets, rows.n_eq
        lower = np.full(len(r), -np.inf)
        lower[:n_eq] = r[:n_eq]
        a = rows.sparse(self.n_free).tocsc()
        pattern = (a.shape, a.indptr.tobytes(), a.indices.tobytes())
        q = -self.mass * v0
        if self._workspace is None or pattern != self._pattern:
            self._workspace = self._osqp.OSQP()
            self._workspace.setup(self._hessian, q, a, lower, r, verbose=False, **self.settings)
            self._pattern = pattern
        else:
            self._workspace.update(q=q, l=lower, u=r, Ax=a.data)
        res = self._workspace.solve(raise_error=False)   # failures are judged from the status below
        if res.info.status_val not in (1, 2):  # solved / solved inaccurate (then _check judges it)
            raise QPError(self.name, res.info.status, f"after {res.info.iter} ADMM iterations")
        return np.asarray(res.x, dtype=float), np.asarray(res.y, dtype=float)

    def describe(self) -> dict:
        return {"solver": self.name, **self.settings}


class NnlsSolver(QPSolver):
    """The dual (Delassus) problem as non-negative least squares.

    With ``W = A M^-1 A^T`` and ``c = A v0 - r`` the multipliers solve ``min 1/2 y^T W y - c^T y``,
    ``y >= 0`` on the inequality rows. The equality rows are eliminated by a Schur complement; the rest,
    ``min 1/2 l^T S l - c^T l`` with ``S = R^T R``, is ``min |R l - d|``, ``l >= 0``, ``R^T d = c``
    (scipy's Lawson-Hanson NNLS). ``S`` is singular for every prestressed structure (its self-stress)
    and for duplicated cables, and ``c`` need not lie in its range, so ``S`` is regularised by
    ``regularisation * mean(diag S)`` before its Cholesky factor is taken: that moves the multipliers
    only along ``S``'s null space (which does not change ``v``) and ``v`` by a relative amount of the
    order of the regularisation.
    """

    name = "nnls"
    regularisation = 1e-13

    def __init__(self, mass):
        import scipy.linalg as sl
        from scipy.optimize import nnls
        super().__init__(mass)
        self._nnls = nnls
        self._cholesky = sl.cholesky
        self._triangular = sl.solve_triangular

    def _regularised(self, s):
        return s + (self.regularisation * max(float(np.mean(np.diag(s))), 1e-300)) * np.eye(len(s))

    def _solve(self, v0, rows, warm):
        r, n_eq = rows.targets, rows.n_eq
        a = rows.dense(self.n_free)
        w = (a * self.inv_mass) @ a.T
        c = a @ v0 - r
        y = np.zeros(len(r))
        if n_eq:
            w_ee_inv = np.linalg.inv(self._regularised(w[:n_eq, :n_eq]))
            x = w_ee_inv @ w[:n_eq, n_eq:]
            s = w[n_eq:, n_eq:] - w[n_eq:, :n_eq] @ x
            ct = c[n_eq:] - x.T @ c[:n_eq]
        else:
            s, ct = w, c
        if len(r) > n_eq:
            root = self._cholesky(self._regularised(0.5 * (s + s.T)))
            y[n_eq:], _ = self._nnls(root, self._triangular(root, ct, trans="T"), maxiter=50 * len(r))
        if n_eq:
            y[:n_eq] = w_ee_inv @ (c[:n_eq] - w[:n_eq, n_eq:] @ y[n_eq:])
        return v0 - self.inv_mass * (a.T @ y), y

    def describe(self) -> dict:
        return {"solver": self.name, "regularisation": self.regularisation}


class SparseSolver(QPSolver):
    """Guess and verify, sparse, then a sparse dual active-set method, in front of DAQP: the active set
    is guessed, the equality-constrained problem of that guess solved exactly with a sparse
    factorisation, and the answer kept only if it meets every optimality condition of the QP; otherwise
    the dual active-set method (:meth:`_dual_active_set`) solves it, and DAQP only if that fails.

    The guess is the hint ``warm`` (the rows active at the end of the previous sub-step). With the
    guessed rows ``G``, the Delassus matrix ``W_GG = A_G M^-1 A_G^T`` (sparse: two rows couple only
    where their members share a free node) is factorised by SuperLU, ``y_G`` solves
    ``W_GG y_G = A_G v0 - r_G`` and ``v = v0 - M^-1 A_G^T y_G``, refined on the rows' own residual
    ``A_G v - r_G`` until a refinement moves ``v`` by less than the tolerance (so ``v`` keeps the
    accuracy of ``A``, not the squared conditioning of ``W``; a refinement that does not get there, as
    for a nearly dependent guess, refuses the guess). With the tolerance ``tol * scale + tol_floor``
    (m/s; ``scale`` the largest free velocity or target; DAQP's own ``primal_tol`` is 1e-12 m/s), the
    answer is the QP's solution when

    * no row outside the guess is violated: ``A_i v - r_i <= tolerance`` (primal feasibility; the
      guessed rows are at their targets by construction, complementarity holds as ``y = 0`` outside),
    * no guessed inequality row pulls: ``y_i W_ii >= -tolerance``, its impulse measured by what it
      does to its own member's rate (dual feasibility, independent of the masses' scale).

    When a check fails, the guess is corrected by what it found (violated rows in, pulling rows out)
    and tried again, at most ``tries`` guesses in all. A singular ``W_GG`` (dependent rows: a
    self-stress among the guessed members, a duplicated cable) ends the guessing. The factorisation is
    reused while the guessed rows are the same members in the same directions (the method's repeated
    solves within a sub-step change only the targets).

    Then, from ``DUAL_NODES`` free nodes (``dual``; below, or False: DAQP, warm-started from the hint),
    Goldfarb and Idnani's dual method, which keeps an independent working set as DAQP does, on a sparse
    factor of its ``W_AA`` that a Schur complement updates row by row (:class:`_WorkingSet`); its answer
    is verified by the same checks as a guess. It is what the towers' QPs needed: the guess's corrections add every violated row at once,
    which makes the set dependent (a 30-stage tower's QP: 500 rows held, 19 violated, the corrected set
    singular), so ~30 % of them went to dense DAQP. On the QPs of a moving 30-stage tower that went to
    DAQP, its velocities are DAQP's to 1e-16 where DAQP meets the constraints, and better where DAQP does
    not (a row violated by 9.4e-7 m/s in DAQP's answer, 1e-17 in its own, the objective 4e-7 lower);
    its cost per QP is 0.3x DAQP's warm-started from a good hint (15-40 ms against 50-80 ms) and 1-2x
    from a poor one (1100-1450 working-set changes on a 50-stage tower, ~0.5 ms each). Tried on top and
    not kept: starting it from the previous QP's active set, from the hint with the rows that depend on
    the others removed (pivots of a sparse LU) and the pulling rows dropped one at a time, and keeping
    the hint across a sub-step cut at a snap (a short sub-step holds few rows, and the next QP adds
    ~600 rows one by one): each still took ~1000 changes (dropping a row makes others pull), and the
    step cost the same (1.0-1.1 s on a moving 50-stage tower, separate runs). Tried again with the
    compiled steps below (the rest of a step after a snap hinted with the rows that held at the step's
    start too): a 100-stage tower's sub-step took 1603 changes instead of 2375, but at one QP in ~160
    the method then ended on a working set whose solve from scratch failed, DAQP took it (8.6 s) and
    the velocities moved by DAQP's tolerance; with the narrow hint none did in 24 steps: not kept.

    The dual method's steps between two factorisations of its base run in a numba kernel
    (``_dual_kernels.dual_steps``; ``compiled = False``: :meth:`_dual_steps_reference`, its numpy
    reference): on 63 QPs captured from moving 30-, 50- and 100-stage towers the 25 that reach it took
    1.94 s against 3.73 s (the two in turn, one process), the answers the same bits (the final working
    set is solved again from scratch either way); a working-set change of a 100-stage tower's sub-step
    costs ~150 us, two thirds of it the two triangular solves and the Schur complement.

    ``counts`` tallies the QPs answered by a guess, by the dual method and by DAQP.

    **Replacements tried for issue 10 (moving towers), none kept.** Measured on the moving 10-stage
    tower (random 0.05 m/s node velocities, no gravity, dt = 1 ms, 20 steps, CPU time, contenders
    taking turns in one process, ``OPENBLAS_NUM_THREADS=1``): DAQP alone 68 ms/step; this backend
    81 ms/step (82 QPs answered by a guess, 43 by DAQP). Each candidate below kept this backend's
    verified, regularised equality solve (``W_GG + 1e-10 diag(W_GG)``, refined on ``A_G v - r_G``):

    * primal-dual active set (Hintermueller-Ito-Kunisch: every violated row in, every pulling row out at
      once, up to 30 updates): 250 ms/step, 84 guessed / 41 DAQP, 1651 updates. It oscillates: the
      tower has more cables than degrees of freedom, so adding every violated row overdetermines the set
      (197 rows on 171 degrees of freedom), its targets disagree along a self-stress, the impulses blow
      up along it and half the set is dropped; the set swings between ~110 and ~190 rows;
    * Bertsekas' projected Newton on the dual (epsilon-active sets, Armijo search on the dual objective):
      231 ms/step, 70 / 55;
    * proximal PDAS (``rho/2 |y - y_k|^2_D`` added to the dual, ``rho`` = 1, 1e-2, 1e-4 then 0): 282
      ms/step, 85 / 40 (it settles for ``rho`` >= 1e-2, then swings again);
    * PDAS adding only the most violated quarter of the violated rows and dropping one row of a set
      whose refinement diverges: 3 of 4 captured failing QPs solved, after 20-48 factorisations each;
    * projected Gauss-Seidel as the warm start (compiled, row by row): on a captured failing QP (225 rows,
      171 degrees of freedom; its solution has 156 independent active rows, smallest singular value
      0.054 of 2.45, every active impulse >= 1e-3 of the largest: not degenerate) 10 / 50 / 200 / 1000
      sweeps from zero leave 54 / 23 / 12 / 6 rows on the wrong side (velocities off by 1.9e-2 /
      6.9e-3 / 1.8e-3 / 1.4e-5 m/s), too slow to polish from;
    * QPALM 1.3 (proximal augmented Lagrangian, sparse LDL^T with low-rank updates; PyPI ``qpalm``) as
      the proposer of the active set, polished by this backend's exact solve of that set started from
      QPALM's multipliers: 5-9 ms per QP of the 10-stage tower (DAQP 50-100 ms), but on 20 steps only
      9 of 42 QPs the guess could not answer were polished, 33 still went to DAQP: 169 ms/step. At eps
      1e-10 it reaches its 1000-iteration limit on most of them; at 1e-8 its velocities are within
      2e-8 m/s of DAQP's, yet its active set (multipliers above 1e-6 of the largest, or rows within
      1e-7 of their target) is off by 10-45 rows: these QPs are nearly degenerate, many rows end within
      1e-8 m/s of their target without an impulse. Not kept (a dependency for 20 % of the fallbacks).

    The tower's QPs are what makes this hard: more cables than degrees of freedom (exact self-stresses,
    e.g. the first stage's top triangle depends on the six cables that tie it to the fixed nodes) and
    many nearly binding rows. The dual active-set method above is the piece that was missing (scipy
    has no sparse factor update: the Schur complement stands in for one, and the base is factorised
    again every ``_WorkingSet.BORDER`` changes).
    """

    name = "sparse"
    verify = False   # the guess and the dual method are verified by the conditions above, DAQP is trusted
    # On a moving tower the last sub-step of a step holds ~3x the rows of any other (the cables still
    # snapping after MAX_EVENTS stop at their limits there), step after step: warmed with the sub-step
    # before (~500 rows of ~1700 on a 100-stage tower) its guess failed and the dual method added ~1200
    # rows one by one (~390 ms); warmed with the previous step's last sub-step, steps took 0.79x at 100
    # stages, 0.84x at 50 and 0.90x at 20 (best of 3-8 x 3 steps, in turn, one process), no QP going to
    # DAQP; the QPs' answers are the same (the same bits over 35 steps at 100 stages; at 50, positions
    # 1.7e-10 m apart after 35 steps: last bits of other paths, grown by the tower's chaotic rattle).
    last_hint = True
    # tries: 12 rather than 3 on moving towers (random 0.05 m/s node velocities, dt = 1 ms, CPU time per
    # step): 20 stages 203 -> 155 ms (QPs answered by a guess 5% -> 71%), 30 stages 657 -> 421 ms.
    # Regularising W_GG (proximal refinement) and dropping the pulling rows of a dependent guess instead
    # of giving up on it answered no more QPs (they then ran out of tries): not kept.
    settings = {"tries": 12, "tol": 1e-12, "tol_floor": 1e-12, "refinements": 3, "dual_iter": 4000,
                "dependent": 1e-10}

    def __init__(self, mass):
        super().__init__(mass)
        self.fallback = DaqpSolver(mass)
        self._factor = None   # (nodes, directions, weights, A_G, A_G^T, diag W_GG, SuperLU factor) of the last guess
        self._start = None    # (guess, v, y) of the last guess that pulled on no row (see _attempt)
        # the dual active-set method between the guess and DAQP from DUAL_NODES free nodes (False: DAQP)
        self.dual = self.n_free >= DUAL_NODES
        self.counts = {"guessed": 0, "dual": 0, "daqp": 0}

    @property
    def compiled(self) -> bool:
        return self.fallback.compiled

    @compiled.setter
    def compiled(self, value: bool) -> None:
        self.fallback.compiled = bool(value)

    def _solve(self, v0, rows, warm):
        active = np.zeros(len(rows), dtype=bool) if warm is None else warm.copy()
        self._start = None
        for _ in range(self.settings["tries"]):
            active[: rows.n_eq] = True
            v, y, active = self._attempt(v0, rows, active)
            if v is not None:
                self.counts["guessed"] += 1
                return v, y
            if active is None:
                break
        if self.dual:
            answer = self._dual_active_set(v0, rows, warm)
            if answer is not None:
                self.counts["dual"] += 1
                return answer
        self.counts["daqp"] += 1
        try:
            return self.fallback._solve(v0, rows, warm)
        except QPError as exc:
            raise QPError(self.name, exc.status, f"{exc.detail} (DAQP, after the guess failed)") from exc

    def _factorise(self, rows: Rows, guess: np.ndarray):
        """``A_G`` (CSR), ``A_G^T`` (CSC), the diagonal of ``W_GG`` and its SuperLU factor (None if
        ``W_GG`` is exactly singular), reused while the guessed rows are the same members."""
        nodes, directions = rows.nodes[guess], rows.directions[guess]
        weights = None if rows.weights is None else rows.weights[guess]
        cached = self._factor
        if (cached is not None and np.array_equal(cached[0], nodes) and np.array_equal(cached[1], directions)
                and (weights is None) == (cached[2] is None) and (weights is None or np.array_equal(cached[2], weights))):
            return cached[3:]
        a = rows.subset(guess, rows.targets[guess], 0).sparse(self.n_free)
        scaled = a.copy()
        scaled.data *= self.inv_mass[a.indices]
        w = scaled @ a.T   # CSR; symmetric, so its transpose is the same matrix in CSC, as SuperLU wants
        lu = symmetric_lu(w.T)   # W_GG is symmetric positive (semi)definite; None: exactly singular
        self._factor = (nodes, directions, weights, a, a.T, w.diagonal(), lu)
        return self._factor[3:]

    def _attempt(self, v0, rows: Rows, active: np.ndarray):
        """The solution of guess ``active`` (k,) bool: ``(v, y, None)`` if it solves the QP; else
        ``(None, None, corrected guess)``, or ``(None, None, None)`` when it cannot be solved exactly.
        The equality solution of the last guess that pulled on no row (``v``, ``y``: a dual feasible
        start for :meth:`_dual_active_set`) is kept in ``self._start``."""
        r, n_eq = rows.targets, rows.n_eq
        scale = max(float(np.max(np.abs(v0), initial=0.0)), float(np.max(np.abs(r), initial=0.0)))
        tol = self.settings["tol"] * scale + self.settings["tol_floor"]
        guess = np.flatnonzero(active)
        y = np.zeros(len(r))
        v = v0
        pulling = np.zeros(len(r), dtype=bool)
        if len(guess):
            a, a_t, w, lu = self._factorise(rows, guess)
            if lu is None:
                return None, None, None
            r_g = r[guess]
            y_g = np.zeros(len(guess))
            residual = a @ v - r_g
            for solve in range(1 + self.settings["refinements"]):
                step = lu.solve(residual)
                change = self.inv_mass * (a_t @ step)
                y_g += step
                v = v - change
                residual = a @ v - r_g
                # converged when a refinement moves v by less than tol: the error left
                if solve and np.max(np.abs(change)) <= tol:
                    break
            else:
                return None, None, None
            y[guess] = y_g
            # a row pulls when its impulse changes its own rate (by y_i W_ii) by more than tol
            pulling[guess] = y_g * w < -tol
            pulling[:n_eq] = False
        violated = ~active & (rows.rates(v.reshape(-1, 3)) - r > tol)
        if not pulling.any():
            self._start = (active.copy(), v, y)
        if violated.any() or pulling.any():
            return None, None, (active & ~pulling) | violated
        return v, y, None

    def _dual_active_set(self, v0, rows: Rows, warm):
        """Goldfarb and Idnani's dual method from the last guess that pulled on no row (or from the
        equality rows alone), its working set's ``W_AA`` a sparse factor updated by a Schur complement
        (:class:`_WorkingSet`): the most violated row joins; while a row of the set would pull first, a
        partial step drops it; a row that depends on the set (a self-stress: ``W_AA`` would be
        singular) moves the multipliers along that self-stress only, until one drops. The set stays
        independent, the velocities are those of the set's equality problem with impulses >= 0, and a
        row joins only when nothing is violated less. The final set is solved again from scratch and
        verified by :meth:`_attempt`; None if it does not pass, or after ``dual_iter`` changes."""
        k, n_eq, r = len(rows), rows.n_eq, rows.targets
        if self._start is None:   # the hint, without the rows it pulls on; else the equality rows alone
            active = np.zeros(k, dtype=bool) if warm is None else warm.copy()
            for _ in range(self.settings["tries"]):
                active[:n_eq] = True
                _, _, corrected = self._attempt(v0, rows, active)
                if self._start is not None or corrected is None:
                    break
                active &= corrected
            if self._start is None:
                active[n_eq:] = False
                self._attempt(v0, rows, active)
                if self._start is None:
                    return None
        active, v, y = self._start
        active, v, y = active.copy(), v.copy(), y.copy()
        a = rows.sparse(self.n_free)
        scale = max(float(np.max(np.abs(v0), initial=0.0)), float(np.max(np.abs(r), initial=0.0)))
        tol = self.settings["tol"] * scale + self.settings["tol_floor"]
        scaled = a.copy()
        scaled.data *= self.inv_mass[a.indices]
        w_all = (scaled @ a.T).tocsr()   # W = A M^-1 A^T, whose rows the steps read
        steps = self._dual_steps if self.compiled else self._dual_steps_reference
        if not steps(a, w_all, r, n_eq, tol, v, y, active):
            return None
        answer = self._attempt(v0, rows, active)
        return None if answer[0] is None else answer[:2]

    def _dual_steps(self, a, w_all, r, n_eq, tol, v, y, active) -> bool:
        """:meth:`_dual_steps_reference` in the compiled kernel (``_dual_kernels.dual_steps``), called
        again after each factorisation of the working set's base."""
        from . import _dual_kernels as kernels
        index = np.int64
        a_arrays = (a.indptr.astype(index), a.indices.astype(index), a.data)
        w_arrays = (w_all.indptr.astype(index), w_all.indices.astype(index), w_all.data)
        p, budget = -1, self.settings["dual_iter"]
        while True:
            base = np.flatnonzero(active)
            lu = symmetric_lu(w_all[base][:, base]) if len(base) else None
            factor = (factor_arrays(lu) if lu is not None else
                      (np.zeros(1, dtype=index), np.zeros(0, dtype=index), np.zeros(0)) * 2
                      + (np.zeros(0), np.zeros(0, dtype=index), np.zeros(0, dtype=index)))
            singular = len(base) > 0 and lu is None   # exactly singular: the start was not independent
            status, p, changes = kernels.dual_steps(
                *a_arrays, *w_arrays, self.inv_mass, r, n_eq, tol, self.settings["dependent"], _WorkingSet.BORDER,
                v, y, active, p, budget, base, singular, *factor)
            budget -= changes
            if status != kernels.REBASE:
                return status == kernels.CONVERGED

    def _dual_steps_reference(self, a, w_all, r, n_eq, tol, v, y, active) -> bool:
        """The steps of :meth:`_dual_active_set` from the working set ``active`` (k,) bool with velocities
        ``v`` and multipliers ``y`` (all three updated in place) until no row is violated beyond ``tol``
        (True) or the method fails (False); the numpy reference of :meth:`_dual_steps`."""
        k = len(r)
        work = _WorkingSet(w_all, np.flatnonzero(active))
        if work.lu is False:
            return False
        a_t = a.T
        p = -1   # the row joining the set (it keeps its partial multiplier until it has joined)
        for _ in range(self.settings["dual_iter"]):
            if p < 0:
                violation = np.where(active, -np.inf, a @ v - r)   # the equality rows are in the set already
                p = int(np.argmax(violation))
                if violation[p] <= tol:
                    return True
                a_p = _dense_row(a, p)
                m_p = self.inv_mass * a_p
                w_p = _dense_row(w_all, p)             # W_ip of every row i
            r_vec = work.solve(np.where(active, w_p, 0.0))
            if r_vec is None:
                return False
            pivot = float(w_p[p] - w_p @ r_vec)      # W_pp - W_pA W_AA^-1 W_Ap: 0 for a dependent row
            full = (float(a_p @ v) - r[p]) / pivot if pivot > self.settings["dependent"] * w_p[p] else np.inf
            ratio = np.full(k, np.inf)
            dropping = active & (r_vec > 0.0)
            dropping[:n_eq] = False
            ratio[dropping] = y[dropping] / r_vec[dropping]
            j = int(np.argmin(ratio))
            step = min(full, ratio[j])
            if not np.isfinite(step):
                return False   # dependent and nothing can drop: the rows are infeasible (DAQP says how)
            if np.isfinite(full):
                v += step * (self.inv_mass * (a_t @ r_vec) - m_p)
            y -= step * r_vec
            y[p] += step
            if full <= ratio[j]:
                active[p] = True
                work.add(p)
                p = -1
            else:
                active[j] = False
                y[j] = 0.0
                work.drop(j)
        return False

    def describe(self) -> dict:
        return {"solver": self.name, **self.settings, "fallback": self.fallback.describe()}


def _dense_row(a, i: int) -> np.ndarray:
    """Row ``i`` of the CSR matrix ``a`` as a dense vector (its column indices unique within a row, as
    :meth:`Rows.sparse` and a sparse product leave them)."""
    out = np.zeros(a.shape[1])
    span = slice(a.indptr[i], a.indptr[i + 1])
    out[a.indices[span]] = a.data[span]
    return out


class _WorkingSet:
    """Solves with ``W_AA = A_A M^-1 A_A^T`` of a working set ``A`` that changes one row at a time: a
    SuperLU factor of a base set ``B`` and a dense Schur complement of the rows added since (``E``) and
    the base rows dropped since (``D``, held at zero by a multiplier of their own), i.e. the bordered
    system ``[[W_BB, V], [V^T, C]]`` with ``V = [W_BE, I_BD]``. After ``BORDER`` changes the base is
    factorised again (the complement grows as their square)."""

    BORDER = 60

    def __init__(self, w, base: np.ndarray):
        self.w = w   # W = A M^-1 A^T of every row (CSR)
        self._rebase(base)

    def _rebase(self, base: np.ndarray) -> None:
        self.base = base
        self.where = np.full(self.w.shape[0], -1)   # each row's place in the base (-1: not in it)
        self.where[base] = np.arange(len(base))
        self.m = 0                                  # the items: an added row, or a dropped base row
        self._rows = np.zeros(self.BORDER, dtype=int)
        self._added = np.zeros(self.BORDER, dtype=bool)
        self._v = np.zeros((len(base), self.BORDER))   # V, W_BB^-1 V and the Schur complement, by item
        self._y = np.zeros((len(base), self.BORDER))
        self._c = np.zeros((self.BORDER, self.BORDER))
        self.lu = None
        if len(base):   # False if exactly singular: the caller's start was not independent
            self.lu = symmetric_lu(self.w[base][:, base]) or False

    def _members(self) -> np.ndarray:
        """The working set's rows, the base's still in it and the added ones."""
        rows, added = self._rows[: self.m], self._added[: self.m]
        return np.concatenate([np.setdiff1d(self.base, rows[~added]), rows[added]])

    def _append(self, row: int, added: bool) -> None:
        if self.lu is False:   # a singular base: solve() says so
            return
        m = self.m
        if added:
            w_col = _dense_row(self.w, row)
            col = w_col[self.base]
            c_new = np.where(self._added[:m], w_col[self._rows[:m]], 0.0)
        else:
            col = np.zeros(len(self.base))
            col[self.where[row]] = 1.0
            c_new = np.zeros(m)
        solved = self.lu.solve(col) if len(self.base) else col
        schur_col = c_new - self._v[:, :m].T @ solved
        self._v[:, m] = col
        self._y[:, m] = solved
        self._c[:m, m] = self._c[m, :m] = schur_col
        self._c[m, m] = (w_col[row] if added else 0.0) - col @ solved
        self._rows[m], self._added[m] = row, added
        self.m = m + 1

    def _remove(self, index: int) -> None:
        m = self.m
        keep = np.flatnonzero(np.arange(m) != index)
        for block in (self._v, self._y):
            block[:, : m - 1] = block[:, keep]
        self._c[: m - 1, : m - 1] = self._c[np.ix_(keep, keep)]
        self._rows[: m - 1], self._added[: m - 1] = self._rows[keep], self._added[keep]
        self.m = m - 1

    def _change(self, row: int, added: bool) -> None:
        undone = np.flatnonzero(self._rows[: self.m] == row)
        if len(undone):   # a change undone
            self._remove(int(undone[0]))
            return
        if self.m >= self.BORDER:
            rows = self._members()
            self._rebase(np.sort(np.append(rows, row) if added else rows[rows != row]))
            return
        self._append(row, added)

    def add(self, row: int) -> None:
        self._change(row, True)

    def drop(self, row: int) -> None:
        self._change(row, False)

    def solve(self, b: np.ndarray):
        """``x`` (k,) with ``W_AA x_A = b_A`` and zero outside ``A`` (``b`` (k,)); None if the base is singular."""
        if self.lu is False:
            return None
        x = np.zeros(len(b))
        x_b = self.lu.solve(b[self.base]) if len(self.base) else np.zeros(0)
        m = self.m
        if m:
            rows, added = self._rows[:m], self._added[:m]
            rhs = np.where(added, b[rows], 0.0) - self._v[:, :m].T @ x_b
            z = np.linalg.solve(self._c[:m, :m], rhs)
            x_b = x_b - self._y[:, :m] @ z
            x[self.base] = x_b
            x[rows] = np.where(added, z, 0.0)
        else:
            x[self.base] = x_b
        return x


SOLVERS: dict[str, type[QPSolver]] = {
    DaqpSolver.name: DaqpSolver,
    OsqpSolver.name: OsqpSolver,
    NnlsSolver.name: NnlsSolver,
    SparseSolver.name: SparseSolver,
}
# From this many free nodes on, the default backend is the sparse one (dense DAQP below). Measured on
# towers (steady CPU time per step after 10 steps, best of 5 x 4 steps, the two taking turns in one
# process, OPENBLAS_NUM_THREADS=1), daqp / sparse: moving (0.05 m/s) 0.22, 0.19, 0.23, 0.65, 0.89 at
# 3, 15, 27, 57, 87 free nodes (1, 3, 5, 10, 15 stages) and 0.99 at 117 (20 stages); at rest 0.81, 0.49,
# 0.88, 1.51, 2.44, 2.48. A moving structure pays most for a failing guess: the switch is where they cross.
# Again with the dual active-set method (``bench/head_to_head.py --configs qp=daqp,qp=sparse``, best of 3
# x 5 steps): moving 0.15, 0.33, 0.52, 0.83 at 5, 10, 15, 20 stages, at rest 1.0, 1.6, 2.2, 3.2; from 30
# stages the sparse backend wins moving too (the dual method 2.1x faster than its DAQP fallback at 50
# stages). The switch stays here, between the moving and the resting crossings.
SPARSE_NODES = 100
# From this many free nodes on, the sparse backend's dual active-set method answers what its guess cannot
# (DAQP below). Measured on moving towers (0.05 m/s, ``bench/head_to_head.py --configs default,main``
# and the two alone, CPU time per steady step), with / without it: 1.47x at 20 stages (117 free nodes),
# 0.97-1.0x at 30 (177), 0.47x at 50 (297), with the dual method in Python; compiled
# (``_dual_kernels.py``), the two in turn in one process, best of 4 x 3 steps after 11: 0.77x at 18
# stages (105 free nodes), 0.71x at 20, 0.59x at 25 (147), the velocities then the dual method's
# verified answers instead of DAQP's (positions 3e-11 to 5e-10 m apart after 23 steps, DAQP's
# tolerance). So the sparse backend always has it; a smaller structure that names it does not.
DUAL_NODES = SPARSE_NODES


# What answers where DAQP fails (DaqpSolver.solve), in this order: NNLS on the Delassus problem (its
# regularisation copes with dependent rows) and OSQP (ADMM); each answer verified by the same check
FALLBACKS = ("nnls", "osqp")


class MassWrapper(QPSolver):
    """A QP of a non-diagonal mass matrix answered by a diagonal backend ``inner`` in other coordinates (the
    subclasses say which): its compiled paths and checks are the backend's."""

    diagonal = False
    inner: QPSolver

    @property
    def compiled(self) -> bool:
        return self.inner.compiled

    @compiled.setter
    def compiled(self, value: bool) -> None:
        self.inner.compiled = bool(value)

    @property
    def verify(self) -> bool:
        return self.inner.verify


class BlockMassSolver(MassWrapper):
    """The QP of a mass matrix with 2x2 blocks (rigid rods' consistent mass, ``tensegrity_sim.mass``; its full,
    non-diagonal Hessian) answered exactly by a diagonal backend, in coordinates where ``M`` is diagonal: for a
    block ``[[A, B], [B, C]]`` (times I3) on free nodes ``(a, c)``, ``A`` the larger diagonal entry (the pivot),
    ``u_a = v_a + beta v_c`` and ``u_c = v_c`` with ``beta = B / A`` (``|beta| < 1``), so that ``v^T M v =
    A |u_a|^2 + (C - B^2 / A) |u_c|^2`` (Schur's complement; ``v = T u``). A row ``sum_j w_j n . v_j`` is the
    general row on ``u`` with the slot ``(c, -beta w_j)`` beside each slot at a pivot; its multiplier is the
    same (``T^T M T (u - u0) = -T^T A^T y`` is ``M (v - v0) = -A^T y``), and the inner backend's optimality
    check on ``u`` is the check on ``v``. ``mass`` and ``inv_mass`` are a node's effective mass ``1 /
    (M^-1)_pp`` and ``M^-1``'s diagonal (the scales of the contacts' projection form); :meth:`inverse` applies
    the whole ``M^-1``."""

    def __init__(self, operator, free: np.ndarray, name: str | None = None):
        fi = np.flatnonzero(free)
        index = np.full(len(free), -1)
        index[fi] = np.arange(len(fi))
        diagonal, partner, cross = operator.diagonal[fi], operator.partner[fi], operator.cross[fi]
        inv_diagonal, inv_cross = operator.inv_diagonal[fi], operator.inv_cross[fi]
        partner = np.where(partner >= 0, index[np.maximum(partner, 0)], -1)
        # the pivot of each block: its end with the larger diagonal entry (the other end on ties: the first)
        pivot = (partner >= 0) & ((diagonal > diagonal[np.maximum(partner, 0)])
                                  | ((diagonal == diagonal[np.maximum(partner, 0)])
                                     & (np.arange(len(fi)) < partner)))
        self._pivot, self._other = np.flatnonzero(pivot), partner[pivot]
        self._beta = cross[pivot] / diagonal[pivot]
        schur = diagonal.copy()
        schur[self._other] = diagonal[self._other] - cross[pivot] * self._beta
        self.inner = make_solver(name, schur)
        self.name = self.inner.name
        self.n_free = len(fi)
        self.inv_mass = np.repeat(inv_diagonal, 3)
        self.mass = 1.0 / self.inv_mass
        self._inv_cross, self._partner = inv_cross, partner

    def inverse(self, p: np.ndarray) -> np.ndarray:
        shape = p.shape
        q = p.reshape((self.n_free, 3) + shape[1:])
        out = self.inv_mass[::3].reshape((-1, 1) + (1,) * (q.ndim - 2)) * q
        blocked = np.flatnonzero(self._partner >= 0)
        out[blocked] += self._inv_cross[blocked].reshape((-1, 1) + (1,) * (q.ndim - 2)) * q[self._partner[blocked]]
        return out.reshape(shape)

    def to_inner(self, v: np.ndarray) -> np.ndarray:
        """``u = T^-1 v`` for velocities ``v`` (n_free, 3) m/s."""
        u = np.array(v, dtype=float).reshape(-1, 3)
        u[self._pivot] += self._beta[:, None] * u[self._other]
        return u

    def from_inner(self, u: np.ndarray) -> np.ndarray:
        """``v = T u`` (n_free, 3) m/s."""
        v = np.array(u, dtype=float).reshape(-1, 3)
        v[self._pivot] -= self._beta[:, None] * v[self._other]
        return v

    def inner_rows(self, rows: Rows) -> Rows:
        """``rows`` on ``u``: general rows, a pivot's slot followed by its partner's ``-beta`` share."""
        k = len(rows)
        if rows.weights is None:
            nodes, weights = rows.nodes, np.tile([-1.0, 1.0], (k, 1))
        else:
            nodes, weights = rows.nodes, rows.weights
        factor = np.zeros(self.n_free + 1)
        factor[self._pivot] = -self._beta
        other = np.full(self.n_free + 1, -1)
        other[self._pivot] = self._other
        at = np.where(nodes < 0, self.n_free, nodes)
        shared = factor[at] != 0.0
        extra_nodes = np.where(shared, other[at], -1)
        return Rows(np.concatenate([nodes, extra_nodes], axis=1), rows.directions, rows.targets, rows.n_eq,
                    np.concatenate([weights, np.where(shared, factor[at] * weights, 0.0)], axis=1))

    def solve(self, v0, rows, warm=None):
        u, y = self.inner.solve(self.to_inner(v0), self.inner_rows(rows), warm)
        return self.from_inner(u), y

    def _check(self, v, y, v0, rows: Rows) -> None:
        self.inner._check(self.to_inner(v), y, self.to_inner(v0), self.inner_rows(rows))

    def _residuals_reference(self, v, y, v0, rows: Rows, acting_floor: float = 0.0):
        return self.inner._residuals_reference(self.to_inner(v), y, self.to_inner(v0), self.inner_rows(rows),
                                               acting_floor)

    def describe(self) -> dict:
        return {**self.inner.describe(), "mass": "2x2 blocks (rigid rods), Schur coordinates"}


def choose_solver(n_free: int) -> tuple[str, str]:
    """The default backend for ``n_free`` free nodes, and the reason in one sentence."""
    if n_free >= SPARSE_NODES:
        return SparseSolver.name, f"{SparseSolver.name}: {n_free} free nodes >= {SPARSE_NODES}"
    return DaqpSolver.name, f"{DaqpSolver.name}: {n_free} free nodes < {SPARSE_NODES}"


def make_solver(name: str | None, mass: np.ndarray, operator=None) -> QPSolver:
    """The backend called ``name`` (default: :func:`choose_solver`) for free-node masses ``mass`` (kg); given the
    scene's mass ``operator`` (``tensegrity_sim.mass.MassOperator``) with rigid rods' blocks, that backend in
    :class:`BlockMassSolver`'s coordinates, for the operator's free nodes."""
    if operator is not None and operator.consistent:
        return BlockMassSolver(operator, operator.free, name)
    name = choose_solver(len(mass))[0] if name is None else name
    if name not in SOLVERS:
        raise ValueError(f"solver must be one of {sorted(SOLVERS)}, got {name!r}")
    return SOLVERS[name](mass)
