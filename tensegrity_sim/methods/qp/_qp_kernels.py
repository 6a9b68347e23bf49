"""Compiled kernels of the QP path (``qp.py``): the constraint matrix, the rows' rates and the answer
check, without a Python-level pass per row. ``qp.py`` keeps the numpy reference of each (``Rows.dense``,
``Rows.rates``, ``QPSolver._residuals_reference``), which tests require these to match.

Rows are generic two-node constraint rows (a member between two free nodes, or a free node and a fixed
one): ``nodes`` (k, 2) int, the free-node index of each end, -1 for a fixed one; ``directions`` (k, 3)
the unit vectors ``n_i`` from end a to end b, so that row ``i`` of ``A`` is ``-n_i`` at end a and
``+n_i`` at end b.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["dense_rows", "add_row", "row_rates", "delassus", "cholesky", "cholesky_dropping", "cho_solve",
           "working_set_answer", "sticking_answer",
           "answer_residuals", "dot3"]

_SWEEPS = 8   # working_set_answer: at most this many refinements of its answer, ...
_SETTLED = 1e-9   # ... the last moving it by at most this fraction of the velocity scale
# The factorisation's inner products may be summed in any order, so that they vectorise:
# summed strictly in order, each waits for the previous addition (a 30-row Cholesky 3.5 -> 1.5 us)
_REASSOCIATE = {"reassoc", "contract"}


@njit(cache=True)
def dot3(a0, a1, a2, b0, b1, b2):
    """``a . b`` of two 3-vectors summed in the order numpy's ``einsum("ij,ij->i")`` uses on contiguous
    rows (measured): the compiled rows are then bitwise those of the reference, which matters on a
    locked structure, where a last-bit change of a row moves DAQP's answer by up to 1e-10."""
    return (a0 * b0 + a2 * b2) + a1 * b1


@njit(cache=True)
def dense_rows(nodes, directions, n_free, column_divisor):
    """The (k, 3 n_free) matrix ``A``, each column divided by ``column_divisor`` (3 n_free,)."""
    k = nodes.shape[0]
    a = np.zeros((k, 3 * n_free))
    for i in range(k):
        na = nodes[i, 0]
        nb = nodes[i, 1]
        for j in range(3):
            if na >= 0:
                a[i, 3 * na + j] = -directions[i, j] / column_divisor[3 * na + j]
            if nb >= 0:
                a[i, 3 * nb + j] = directions[i, j] / column_divisor[3 * nb + j]
    return a


@njit(cache=True)
def _rate(v, nodes, directions, i):
    """Row ``i``'s rate ``A_i v`` (m/s) for free-node velocities ``v`` (n_free, 3)."""
    nb = nodes[i, 1]
    na = nodes[i, 0]
    u0 = (v[nb, 0] if nb >= 0 else 0.0) - (v[na, 0] if na >= 0 else 0.0)
    u1 = (v[nb, 1] if nb >= 0 else 0.0) - (v[na, 1] if na >= 0 else 0.0)
    u2 = (v[nb, 2] if nb >= 0 else 0.0) - (v[na, 2] if na >= 0 else 0.0)
    return dot3(u0, u1, u2, directions[i, 0], directions[i, 1], directions[i, 2])


@njit(cache=True)
def add_row(out, nodes, directions, i, amount):
    """``out`` (n_free, 3) += ``A_i^T amount``: row ``i``'s ``-n_i`` at end a, ``+n_i`` at end b, times
    ``amount`` (a fixed end's entry dropped)."""
    for e in range(2):
        node = nodes[i, e]
        if node >= 0:
            for j in range(3):
                out[node, j] += (2.0 * e - 1.0) * directions[i, j] * amount


@njit(cache=True)
def row_rates(v, nodes, directions):
    """``A v`` (k,) m/s for free-node velocities ``v`` (n_free, 3)."""
    k = nodes.shape[0]
    out = np.empty(k)
    for i in range(k):
        out[i] = _rate(v, nodes, directions, i)
    return out


@njit(cache=True)
def _row_length(inv_mass, nodes, i):
    """The length ``|A_i M^-1/2|`` (kg^-1/2) of row ``i`` in the mass-scaled problem (``inv_mass`` (n_free, 3))."""
    na = nodes[i, 0]
    nb = nodes[i, 1]
    return np.sqrt((inv_mass[na, 0] if na >= 0 else 0.0) + (inv_mass[nb, 0] if nb >= 0 else 0.0))


@njit(cache=True)
def delassus(nodes, directions, rows, inv_mass):
    """The lower triangle (g, g) of ``W = A_R M^-1 A_R^T`` for the rows ``rows`` (g,) int of the member
    rows ``nodes``, ``directions`` (``inv_mass`` (n_free, 3) 1/kg; ones: the Gram matrix ``A_R A_R^T``).
    Two rows couple only where their members share a free node, so it is built node by node."""
    g = rows.shape[0]
    n_free = inv_mass.shape[0]
    start = np.zeros(n_free + 1, dtype=np.int64)   # the rows at each free node (CSR), with their entry's sign
    for r in range(g):
        for e in range(2):
            if nodes[rows[r], e] >= 0:
                start[nodes[rows[r], e] + 1] += 1
    for i in range(n_free):
        start[i + 1] += start[i]
    fill = start[:-1].copy()
    at = np.empty(start[n_free], dtype=np.int64)
    sign = np.empty(start[n_free])
    for r in range(g):
        for e in range(2):
            node = nodes[rows[r], e]
            if node >= 0:
                at[fill[node]] = r
                sign[fill[node]] = 2.0 * e - 1.0
                fill[node] += 1
    w = np.zeros((g, g))
    for node in range(n_free):
        for p in range(start[node], start[node + 1]):
            a = rows[at[p]]   # (the directions read by element: a row's view would be counted in and out)
            for q in range(p, start[node + 1]):
                b = rows[at[q]]
                entry = sign[p] * sign[q] * inv_mass[node, 0] * dot3(directions[a, 0], directions[a, 1],
                                                                     directions[a, 2], directions[b, 0],
                                                                     directions[b, 1], directions[b, 2])
                w[max(at[p], at[q]), min(at[p], at[q])] += entry
    return w


@njit(cache=True, fastmath=_REASSOCIATE)
def cholesky(w, pivot_tol):
    """``w`` (g, g), its lower triangle symmetric positive definite, overwritten by its Cholesky factor
    ``L`` (``w = L L^T``) and ``L^T`` above the diagonal. Returns whether every pivot exceeded
    ``pivot_tol`` times the largest diagonal entry (else ``w`` is left half factorised)."""
    none = w.reshape(-1)[:0]   # no row droppable: an empty view, no allocation (the batches' parallel loops call this)
    return cholesky_dropping(w, pivot_tol, none, none)


@njit(cache=True, fastmath=_REASSOCIATE)
def cholesky_dropping(w, pivot_tol, droppable, dropped):
    """:func:`cholesky`, but a row ``droppable`` (g,) bool whose pivot falls below the tolerance (it depends on
    the rows before it) is left out and marked in ``dropped`` (g,) bool: its row and column of ``L`` zero, its
    pivot 1, so that :func:`cho_solve` gives it 0 for a right-hand side 0. Returns whether every other
    pivot exceeded the tolerance. ``droppable`` may be shorter than g (its missing rows not droppable)."""
    g = w.shape[0]
    largest = 0.0
    for r in range(g):
        largest = max(largest, w[r, r])
    for j in range(g):
        s = w[j, j]
        for p in range(j):
            s -= w[j, p] * w[j, p]
        if not s > pivot_tol * largest:
            if not (j < droppable.shape[0] and droppable[j]):
                return False
            dropped[j] = True
            for p in range(g):
                w[j, p] = 0.0
                w[p, j] = 0.0
            w[j, j] = 1.0
            continue
        w[j, j] = np.sqrt(s)
        for i in range(j + 1, g):
            s = w[i, j]
            for p in range(j):
                s -= w[i, p] * w[j, p]
            w[i, j] = s / w[j, j]
            w[j, i] = w[i, j]   # L^T in the upper triangle: L's columns as rows, for cho_solve
    return True


# By columns: once a row's unknown is known, it is taken from every row after it (before it, going back), L's
# column being L^T's row, consecutive in memory. Each unknown then waits for one product, not for a whole row's
# sum, and the updates are element by element: they vectorise in their strict order, with no licence to
# reassociate (whose sums LLVM may order otherwise where the solve is compiled into another caller), so a batch's
# copy and a single simulator get the same bits. The loops count with unsigned integers: a signed index could be
# negative, which numba wraps around from the end, and that test in every iteration kept them from vectorising
# (a 30-row solve 1.5 -> 0.75 us). error_model "numpy": no test of the pivots, which the factorisation keeps
# positive.
@njit(cache=True, error_model="numpy")
def cho_solve(factor, b):
    """``b`` (g,) overwritten by ``(L L^T)^-1 b`` for the Cholesky factor ``L`` of :func:`cholesky`."""
    g = b.shape[0]
    for r in range(g):
        known = b[r] / factor[r, r]
        b[r] = known
        for i in range(np.uint64(r + 1), np.uint64(g)):
            b[i] -= factor[r, i] * known
    for r in range(g - 1, -1, -1):
        known = b[r] / factor[r, r]
        b[r] = known
        for i in range(np.uint64(r)):
            b[i] -= factor[r, i] * known


@njit(cache=True)
def _refine(w, rows, dropped, nodes, directions, inv_mass, v0, targets, tol):
    """The answer of the equality problem of the working set ``rows`` (g,) int, ``w`` its Delassus matrix's
    Cholesky factor (:func:`cholesky`; rows ``dropped`` (g,) bool: left out as dependent, their multipliers 0):
    ``W y = A_W v0 - r_W`` and ``v = v0 - M^-1 A_W^T y``, refined on the rows' own residual until every
    working row is within ``tol`` (k,) m/s of its target and a correction moves ``v`` by at most
    ``_SETTLED`` of the velocity scale. Returns whether it settled, ``v`` (n_free, 3) and ``y`` (k,)."""
    k = targets.shape[0]
    g = rows.shape[0]
    n_free = v0.shape[0]
    v = v0.copy()
    y = np.zeros(k)
    res = np.empty(g)
    change = np.empty((n_free, 3))
    # Refined on the rows' residual until a correction moves v by at most _SETTLED of the velocity scale
    # (or stops shrinking): nearly dependent rows leave the first solve off by the square of A's
    # conditioning, and each correction shrinks that 4-5 times (the thrown icosahedron's rows, singular
    # values 7e-6 apart: corrections of 1.6, 2.6e-10, 3.6e-11 m/s; two leave v ~4e-11 off quadprog's)
    floor = 0.0
    for i in range(n_free):
        for j in range(3):
            floor = max(floor, abs(v0[i, j]))
    for r in range(g):
        floor = max(floor, abs(targets[rows[r]]))
    floor *= _SETTLED
    moved = previous = np.inf
    for sweep in range(_SWEEPS + 1):
        close = True
        for r in range(g):
            res[r] = 0.0 if dropped[r] else _rate(v, nodes, directions, rows[r]) - targets[rows[r]]
            close &= abs(res[r]) <= tol[rows[r]]
        if close and (moved <= floor or previous < np.inf and moved > 0.5 * previous):
            break
        if sweep == _SWEEPS or moved > previous:
            return False, v, y
        previous = moved
        cho_solve(w, res)
        change[:, :] = 0.0   # M^-1 A_W^T dy, scattered row by row
        for r in range(g):
            y[rows[r]] += res[r]
            add_row(change, nodes, directions, rows[r], res[r])
        moved = 0.0
        for i in range(n_free):
            for j in range(3):
                v[i, j] -= inv_mass[i, j] * change[i, j]
                moved = max(moved, abs(inv_mass[i, j] * change[i, j]))
    return True, v, y


@njit(cache=True)
def working_set_answer(nodes, directions, inv_mass, v0, targets, n_eq, warm, primal_tol, dual_tol, pivot_tol):
    """The QP's answer if its active set is the working set: the ``n_eq`` equality rows and the rows
    ``warm`` (k,) bool (the previous sub-step's active rows), as ``DaqpSolver._working_set_reference``
    computes it in numpy. ``inv_mass`` (n_free, 3) 1/kg, ``v0`` (n_free, 3) m/s, ``targets`` (k,) m/s.

    The working set's Delassus matrix ``W = A_W M^-1 A_W^T`` (two rows couple only where their members
    share a free node, so it is built node by node) is factorised by Cholesky, refused when a pivot falls
    below ``pivot_tol`` times its largest diagonal entry (dependent rows); ``W y = A_W v0 - r_W`` and
    ``v = v0 - M^-1 A_W^T y``, refined on the rows' own residual until every working row is within
    ``primal_tol`` of its target and a correction moves ``v`` by at most ``_SETTLED`` of the velocity
    scale. The answer is the QP's solution when every inequality row of the set pushes (``y_i > 0``)
    and no other row is violated: DAQP, warm-started from the same set, then stops after its first
    iteration with that set, and this is its answer by other arithmetic. Both are measured as DAQP
    measures them, on the mass-scaled rows normalised to unit length, with margins: a row of the set
    must push by more than ``dual_tol`` (a multiplier within round-off of zero is left to DAQP, so that
    which cables hold, ``y > 0``, is DAQP's decision there), and a violation is at most ``primal_tol``
    m/s also where DAQP's normalised measure is wider (so every answer passes ``QPSolver._check``,
    absolute from 1e-12 m/s, which DAQP's tolerances alone did not on a prism hovering at 1e-9 m/s).

    Returns ``ok`` (False: the set is not the active set, or is dependent; nothing else is meaningful),
    ``v`` (n_free, 3) m/s, the multipliers ``y`` (k,) N*s (0 outside the set), the Cholesky factor
    (g, g) of the set's Delassus matrix (``cholesky``'s layout) and the set's rows (g,) int."""
    k = targets.shape[0]
    g = 0
    for i in range(k):
        g += i < n_eq or warm[i]
    rows = np.empty(g, dtype=np.int64)
    g = 0
    for i in range(k):
        if i < n_eq or warm[i]:
            rows[g] = i
            g += 1
    w = delassus(nodes, directions, rows, inv_mass)
    if not cholesky(w, pivot_tol):
        return False, v0, np.zeros(k), w, rows
    length = np.empty(k)   # each row's length in the mass-scaled problem, and its primal tolerance (m/s)
    tol = np.empty(k)
    for i in range(k):
        length[i] = _row_length(inv_mass, nodes, i)
        tol[i] = primal_tol * min(length[i], 1.0)
    refined, v, y = _refine(w, rows, np.zeros(g, dtype=np.bool_), nodes, directions, inv_mass, v0, targets, tol)
    if not refined:
        return False, v, y, w, rows
    for i in range(n_eq, k):
        if warm[i] and not y[i] * length[i] > dual_tol:
            return False, v, y, w, rows
        if not warm[i] and _rate(v, nodes, directions, i) - targets[i] > tol[i]:
            return False, v, y, w, rows
    return True, v, y, w, rows


@njit(cache=True)
def sticking_answer(nodes, directions, inv_mass, v0, targets, n_eq, start, opposite, primal_tol, dual_tol, pivot_tol):
    """:func:`working_set_answer` of a set with sign-free pairs of rows: the ``n_eq`` equality rows and the rows
    ``start`` (k,) bool, among them rows whose ``opposite`` (k,) int is another row (-1: none), the same row
    negated with the negated target (a sticking contact's ``t`` and ``-t`` rows, ``friction.py``). Such a row
    stands for the pair: one that depends on the rows before it is dropped (:func:`cholesky_dropping`; the
    rows of a body that sticks on more contacts than it has tangential freedoms), and one whose multiplier
    comes out negative hands it, negated, to its opposite row, which is then the active one (a friction of
    round-off size changes sign from step to step: the set of the last answer then fails every other step); a
    pair whose multiplier is within ``dual_tol`` of zero is inactive. Checked as :func:`working_set_answer`
    checks: every active inequality row pushes by more than ``dual_tol``, no other row is violated by more
    than ``primal_tol``. Returns ``ok`` (False: not the
    answer, or a row that cannot be dropped depends on the others), ``v`` (n_free, 3) m/s and ``y`` (k,) N*s."""
    k = targets.shape[0]
    g = 0
    for i in range(k):
        g += i < n_eq or start[i]
    rows = np.empty(g, dtype=np.int64)
    droppable = np.empty(g, dtype=np.bool_)
    g = 0
    for i in range(k):
        if i < n_eq or start[i]:
            rows[g] = i
            droppable[g] = opposite[i] >= 0
            g += 1
    w = delassus(nodes, directions, rows, inv_mass)
    dropped = np.zeros(g, dtype=np.bool_)
    if not cholesky_dropping(w, pivot_tol, droppable, dropped):
        return False, v0, np.zeros(k)
    length = np.empty(k)
    tol = np.empty(k)
    for i in range(k):
        length[i] = _row_length(inv_mass, nodes, i)
        tol[i] = primal_tol * min(length[i], 1.0)
    refined, v, y = _refine(w, rows, dropped, nodes, directions, inv_mass, v0, targets, tol)
    if not refined:
        return False, v, y
    active = np.zeros(k, dtype=np.bool_)
    for r in range(g):
        i = rows[r]
        if dropped[r]:
            continue
        if droppable[r] and not abs(y[i]) * length[i] > dual_tol:
            y[i] = 0.0   # a pair that carries nothing: inactive (its rows then checked as the others are)
            continue
        if droppable[r] and y[i] < 0.0:
            y[opposite[i]] = -y[i]
            y[i] = 0.0
            i = opposite[i]
        active[i] = True
    for i in range(n_eq, k):
        if active[i] and not y[i] * length[i] > dual_tol:
            return False, v, y
        if not active[i] and _rate(v, nodes, directions, i) - targets[i] > tol[i]:
            return False, v, y
    return True, v, y


@njit(cache=True)
def answer_residuals(v, y, v0, nodes, directions, targets, n_eq, mass, rel_tol):
    """How far an answer ``v`` (n_free, 3), ``y`` (k,) is from the QP's optimality conditions, in one
    pass: returns ``(scale, violation, impulse, stationarity, smallest inequality impulse, acting row
    short of its target)`` as ``QPSolver._residuals_reference`` does (``mass`` (3 n_free,) kg per
    degree of freedom; ``rel_tol``: the relative impulse under which a row is not acting)."""
    n_free = v.shape[0]
    k = targets.shape[0]
    scale = 0.0
    for i in range(n_free):
        for j in range(3):
            scale = max(scale, abs(v0[i, j]))
    for i in range(k):
        scale = max(scale, abs(targets[i]))
    res = row_rates(v, nodes, directions)
    violation = 0.0
    for i in range(k):
        res[i] -= targets[i]
        violation = max(violation, abs(res[i]) if i < n_eq else res[i])
    # stationarity: M (v - v0) + A^T y, scattered row by row (A is never formed)
    station = np.empty((n_free, 3))
    impulse = 1e-300
    for i in range(n_free):
        for j in range(3):
            m = mass[3 * i + j]
            change = m * (v[i, j] - v0[i, j])
            station[i, j] = change
            impulse = max(impulse, abs(m * v0[i, j]), abs(change))
    smallest = 0.0
    for i in range(k):
        impulse = max(impulse, abs(y[i]))
        if i >= n_eq:
            smallest = min(smallest, y[i])
        na = nodes[i, 0]
        nb = nodes[i, 1]
        for j in range(3):
            if na >= 0:
                station[na, j] -= directions[i, j] * y[i]
            if nb >= 0:
                station[nb, j] += directions[i, j] * y[i]
    stationarity = 0.0
    for i in range(n_free):
        for j in range(3):
            stationarity = max(stationarity, abs(station[i, j]))
    short = 0.0
    for i in range(n_eq, k):
        if y[i] > rel_tol * impulse:
            short = max(short, -res[i])
    return scale, violation, impulse, stationarity, smallest, short
