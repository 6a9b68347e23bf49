"""The elastic method's frictional contact problem, one independent block at a time, compiled (numba).

With elastic cables the velocity problem of a contact step (``methods/contact/friction.py``'s ``ContactSet``)
couples only the nodes that a rigid strut joins: it falls apart into independent *blocks*, a moving
rigid strut with the contacts of its two ends (its length row and a normal and two friction unknowns per
contact: at most 7 unknowns), or a node on no rigid strut with its own contact (a closed form). This
module solves one block exactly, with the exact Coulomb disc; ``friction_blocks.py`` is the plain numpy
implementation of the same algorithm (tests hold the two to 1e-12, and both to the QP fixed point of
``friction.py`` on the ground scenes).

**The block.** Its rows map the two ends' velocities ``v`` (2, 3) to ``u = G v`` (q,): the strut's length
rate ``n . (v_1 - v_0)`` (an equality, target 0) and, per contact, the end's ``(v_x, v_y, v_z)``. Its
unknowns ``z`` (q,) N*s are the strut's impulse and each contact's ``(f_x, f_y, y_n)``; ``v = v0 + M^-1 G^T z``
and ``u = u0 + W z``, ``W = G M^-1 G^T`` (the Delassus matrix). The conditions, in the Alart–Curnier form
with ``rho`` the end's mass (the contact's) and ``1 / W_00`` (the strut's):

    strut:    phi_0 = rho_0 u_0
    normal:   phi_n = y_n - max(0, y_n - rho (u_n - w))
    friction: phi_t = f - proj_disc(mu max(0, y_n - rho (u_n - w))) (f - rho u_t)

``phi = 0`` is exactly the law of ``friction.py`` (``y_n >= 0``, ``u_n >= w``, complementary; ``f`` in the
disc, ``u_t = 0`` inside it, ``f = -mu y_n u_t / |u_t|`` on its edge).

**The solver: a semismooth Newton on ``phi`` with Levenberg–Marquardt damping and an Armijo line search**
on ``|phi|^2 / 2``. Why this: the generalised Jacobian of ``phi`` is singular exactly where a robot rests
most often: a rigid strut lying on the ground and sticking at both ends (the friction along the strut is
statically indeterminate: the two ends can trade it), so a plain Newton step is not defined there. The
damped step ``(J^T J + nu I) d = -J^T phi`` with ``nu = (|phi| / S)^2`` (``S`` the block's impulse scale)
is always defined, is a descent direction of the merit, and becomes Newton's step as ``phi -> 0``
(Yamashita–Fukushima: superlinear under a local error bound, which holds for the indeterminate
case); ``nu`` is kept within ``[1e-20, 1e-2]`` so that a poor warm start still takes near-Newton steps
and ``J^T J + nu I`` stays definite where ``J`` is singular (in exact arithmetic: where round-off leaves a
pivot of its factor non-positive, ``nu`` is raised tenthousandfold until it is definite, and the
block is left unsolved, not answered with NaN, where it is not even at ``nu = 1e-2``).
Each iteration tries Newton's own step first (``nu = 0``), where the factor of ``J^T J`` has every
pivot above ``_NEWTON_PIVOT`` of its diagonal entry, and takes it whole where it meets the Armijo condition;
otherwise the damped step, with its line search. Why: ``phi`` is piecewise linear wherever the contacts stick
or separate, so from a warm start in the answer's modes Newton's step lands on the answer, while the damped
one stops short by about ``nu`` times the step (at the median block of the rolling icosahedron ``nu`` is
1e-6, leaving ``|phi|`` at 3e-9 S) and the block takes a second iteration to meet ``BLOCK_TOL``. Measured on
``Roll-v0``'s vector environment (64 copies, 25 periods of random reel actions; 11k of its blocks, each a
strut with one end on the ground, 2.8 a copy-step): 2.03 iterations a block with the damped step alone,
1.26 with Newton's first (a sticking block: 1; a sliding one, its disc's edge curved: 2).
At an iterate where every contact sticks (pressed, inside its disc) ``phi = R (u - t)`` is linear with
``J = R W`` (``R`` the rows' ``rho``, ``t`` the targets), so Newton's step is the sticking mode's own linear
system ``W d = t - u``, without the Jacobian and ``J^T J``: in closed form for a strut with one contact
(eliminating the contact's rows, on which ``W`` is the end's inverse mass), else with ``W``'s factor (pivots
above ``_NEWTON_PIVOT``, else as above), and taken whole where it meets the Armijo condition (its slope is
``-|phi|^2``); where it does not (a contact starts to slide or lifts), the damped step. With the factor's
``L D L^T`` form (:func:`_factor_solve`) and the ground step's arming only where needed, that environment's
compiled run (256 copies, 1 thread, ``bench/bench_env_period.py`` in turns with the tree before): 17.0 ms CPU
a period against 19.3 (best of 5 runs each).
Enumerating the 3^2 contact modes instead would need an inner iteration anyway (a sliding end's
direction is coupled to the other end's through the strut), and the QP fixed point of ``friction.py``
costs QPs per iterate. Measured: 1-3 iterations a block for the resting and sliding scenes, warm-started
from the node's last impulse. The answer is accepted when ``max |phi| <= BLOCK_TOL S``, which is the
projection form's natural residual (``friction.py``'s check with ``rho = m``) within that tolerance, or,
where the Newton stalls at round-off's level (a strut lying on the ground under another, its friction
indeterminate: 3e-12 S), at ``RELAXED_TOL S``, ten times tighter than ``friction.py``'s answers.

**Coupled blocks** (:func:`solve_coupled`): member contacts (``contact: response: true``) join the bodies
they touch, so a block becomes the struts and lone nodes a chain of touching pairs joins, with their ground
contacts and the pairs' contacts: general rows on the nodes, a pair's contact the rows ``(t1, t2, n)`` of
its frame times its four nodes' weights (``methods/contact/member.py``), scaled by its effective mass
``1 / W_nn``. The same Newton solves it (:func:`_newton`), up to ``MAX_COUPLED`` rows.

Scratch: ``work`` (6, 7, 7) float64 (:func:`block_work`; a coupled block's (6, 48, 48), :func:`coupled_work`);
the kernels allocate nothing per block.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["BLOCK_TOL", "MAX_NEWTON", "MAX_COUPLED", "block_work", "coupled_work", "solve_block", "solve_coupled",
           "lone_contact"]

BLOCK_TOL = 1e-13      # relative to the block's impulse scale: max |phi| at the answer ...
RELAXED_TOL = 1e-11    # ... or, where the Newton stalls at round-off's level, at its last iterate (friction.py's
                       # answers meet FIXED_POINT_TOL = 1e-10)
MAX_NEWTON = 60        # damped Newton iterations before a block is declared unsolved
_ARMIJO = 1e-4         # sufficient decrease of the merit |phi|^2 / 2
_MIN_STEP = 2.0 ** -40  # the line search's smallest step
_MAX_DAMPING = 1e-2    # Levenberg–Marquardt's nu, at most (far from the answer: a step near Newton's) ...
_MIN_DAMPING = 1e-20   # ... and at least (near it, where J may be singular: J^T J + nu I stays definite) ...
_DAMPING_GROWTH = 1e4  # ... raised by this factor where round-off leaves it not definite (up to _MAX_DAMPING)
_NEWTON_PIVOT = 1e-2   # J^T J's factor's pivots above this fraction of their diagonal entries: Newton's own step
MAX_ROWS = 7           # a strut's row and two contacts
MAX_COUPLED = 48       # the rows of a coupled block (struts, contacts) beyond which the reference takes the step


def block_work() -> np.ndarray:
    """The scratch of :func:`solve_block`: (6, MAX_ROWS, MAX_ROWS) float64."""
    return np.zeros((6, MAX_ROWS, MAX_ROWS))


def coupled_work() -> np.ndarray:
    """The scratch of :func:`solve_coupled`: (6, MAX_COUPLED, MAX_COUPLED) float64."""
    return np.zeros((6, MAX_COUPLED, MAX_COUPLED))


@njit(cache=True, error_model="numpy", _nrt=False)
def lone_contact(inv, v, target, mu, z):
    """The closed form of a node on no rigid strut with a contact: ``W = I / m`` decouples the rows, so
    ``y_n = max(0, m (w - v_z))`` and ``f = proj_disc(mu y_n)(-m v_t)``. ``v`` (3,) m/s changes in place;
    ``z`` (3,) N*s gets ``(f_x, f_y, y_n)``."""
    m = 1.0 / inv
    y = max(0.0, m * (target - v[2]))
    fx = -m * v[0]
    fy = -m * v[1]
    size = np.sqrt(fx * fx + fy * fy)
    bound = mu * y
    if size > bound:
        scale = bound / size
        fx *= scale
        fy *= scale
    z[0] = fx
    z[1] = fy
    z[2] = y
    v[0] += inv * fx
    v[1] += inv * fy
    v[2] += inv * y


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _residual(q, s, k, target, work, z, up, ur, pp, pr):
    """``u = u0 + W z`` into ``work[up, ur]`` and ``phi`` (q,) into ``work[pp, pr]`` (module docstring;
    ``work``'s layout in :func:`_newton`); ``s`` strut rows first, then ``k`` contacts. Returns ``|phi|^2 / 2``.
    The scratch is indexed, not sliced: a view per array costs more than the arithmetic of a small block."""
    for i in range(q):
        acc = work[4, 0, i]
        for j in range(q):
            acc += work[1, i, j] * z[j]
        work[up, ur, i] = acc
    for i in range(s):
        work[pp, pr, i] = work[4, 6, i] * work[up, ur, i]
    for c in range(k):
        o = s + 3 * c
        r = work[4, 6, o]
        n = o + 2
        yp = max(z[n] - r * (work[up, ur, n] - target[c]), 0.0)
        work[pp, pr, n] = z[n] - yp
        t0 = z[o] - r * work[up, ur, o]
        t1 = z[o + 1] - r * work[up, ur, o + 1]
        size = np.sqrt(t0 * t0 + t1 * t1)
        bound = work[5, 2, c] * yp
        if size <= bound:   # inside the disc: P = q_t, phi_t = r u_t
            work[pp, pr, o] = z[o] - t0
            work[pp, pr, o + 1] = z[o + 1] - t1
        else:               # on the edge: P = bound q_t / |q_t|
            work[pp, pr, o] = z[o] - bound * (t0 / size)
            work[pp, pr, o + 1] = z[o + 1] - bound * (t1 / size)
    total = 0.0
    for i in range(q):
        total += work[pp, pr, i] * work[pp, pr, i]
    return 0.5 * total


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _jacobian(q, s, k, target, work, z):
    """The generalised Jacobian (q, q) of ``phi`` at ``z`` into ``work[2]``, from its ``u`` in ``work[4, 1]``
    (:func:`_residual`'s, same arithmetic): computed only where the Newton takes a step from ``z``, not at
    every trial of its line search nor at the answer."""
    for i in range(s):   # every row is written whole (a normal's row is zeroed only where it is e_n)
        r0 = work[4, 6, i]
        for j in range(q):
            work[2, i, j] = r0 * work[1, i, j]
    for c in range(k):
        o = s + 3 * c
        r = work[4, 6, o]
        mu = work[5, 2, c]
        n = o + 2
        qn = z[n] - r * (work[4, 1, n] - target[c])
        yp = max(qn, 0.0)
        # d yp / dz: the row e_n - r W[n] where qn > 0
        if qn > 0.0:
            for j in range(q):
                work[2, n, j] = r * work[1, n, j]
        else:
            for j in range(q):
                work[2, n, j] = 0.0
            work[2, n, n] = 1.0
        t0 = z[o] - r * work[4, 1, o]
        t1 = z[o + 1] - r * work[4, 1, o + 1]
        size = np.sqrt(t0 * t0 + t1 * t1)
        bound = mu * yp
        if size <= bound:   # inside the disc
            for j in range(q):
                work[2, o, j] = r * work[1, o, j]
                work[2, o + 1, j] = r * work[1, o + 1, j]
        else:               # on the edge
            h0 = t0 / size
            h1 = t1 / size
            ratio = bound / size
            for j in range(q):
                d0 = -r * work[1, o, j]
                d1 = -r * work[1, o + 1, j]
                if j == o:
                    d0 += 1.0
                if j == o + 1:
                    d1 += 1.0
                along = h0 * d0 + h1 * d1
                dyp = 0.0
                if qn > 0.0:
                    dyp = -r * work[1, n, j]
                    if j == n:
                        dyp += 1.0
                work[2, o, j] = -(ratio * (d0 - h0 * along) + h0 * mu * dyp)
                work[2, o + 1, j] = -(ratio * (d1 - h1 * along) + h1 * mu * dyp)
            work[2, o, o] += 1.0
            work[2, o + 1, o + 1] += 1.0


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _sticking(q, s, k, target, work, z):
    """Whether every contact of the block sticks at ``z`` (its ``u`` in ``work[4, 1]``, :func:`_residual`'s): pressed
    (``y_n - rho (u_n - w) > 0``) with its friction inside the disc, where ``phi`` is linear (``R (u - t)``)."""
    for c in range(k):
        o = s + 3 * c
        r = work[4, 6, o]
        n = o + 2
        qn = z[n] - r * (work[4, 1, n] - target[c])
        t0 = z[o] - r * work[4, 1, o]
        t1 = z[o + 1] - r * work[4, 1, o + 1]
        if not (qn > 0.0 and np.sqrt(t0 * t0 + t1 * t1) <= work[5, 2, c] * qn):
            return False
    return True


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _strut_contact_solve(work):
    """``work[4, 4] = W^-1 work[4, 3]`` for a strut's block with one ground contact (:func:`solve_block`: the strut's
    row, then the contact's three rows, on which ``W`` is its end's inverse mass ``1 / rho`` times I), by
    eliminating the contact's rows: the strut's row keeps ``S = W_00 - rho |W_0c|^2`` (the strut's inverse mass
    along itself with that end held). Returns False, solving nothing, where ``S`` is not above ``_NEWTON_PIVOT``
    times ``W_00`` (the other end fixed, or nearly: the strut's row nearly the contact's)."""
    rho = work[4, 6, 1]
    w00 = work[1, 0, 0]
    along = 0.0   # |W_0c|^2
    push = 0.0    # W_0c . r_c
    for j in range(3):
        along += work[1, 0, 1 + j] * work[1, 0, 1 + j]
        push += work[1, 0, 1 + j] * work[4, 3, 1 + j]
    schur = w00 - rho * along
    if not schur > _NEWTON_PIVOT * w00:
        return False
    d0 = (work[4, 3, 0] - rho * push) / schur
    work[4, 4, 0] = d0
    for j in range(3):
        work[4, 4, 1 + j] = rho * (work[4, 3, 1 + j] - work[1, 0, 1 + j] * d0)
    return True


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _factor_solve(q, work, floor):
    """``work[4, 4] = work[3]^-1 work[4, 3]`` for the symmetric positive definite ``work[3]`` (q, q), factored
    in place as ``L D L^T`` (its strict lower triangle gets ``L``'s, its diagonal ``1 / D``; ``D`` in
    ``work[5, 4]``, ``work[5, 5]`` scratch): the Cholesky factor's pivots squared, with no square root and one
    division a pivot (a small block's factor is a chain of them). Returns False, solving nothing, where a pivot
    is not above ``floor`` times its diagonal entry: with ``floor`` 0, where it is not positive (``J^T J + nu I``
    with ``J`` singular and ``nu`` below its round-off, a strut resting on the ground, sticking at both ends,
    when ``|phi|`` is already small, is not definite in floating point); with ``_NEWTON_PIVOT``, where ``J^T J``
    is not comfortably definite."""
    for j in range(q):
        d = work[3, j, j]
        for p in range(j):
            scaled = work[3, j, p] * work[5, 4, p]   # L_jp D_p
            work[5, 5, p] = scaled
            d -= work[3, j, p] * scaled
        if not d > floor * work[3, j, j]:
            return False
        work[5, 4, j] = d
        inverse = 1.0 / d
        work[3, j, j] = inverse
        for i in range(j + 1, q):
            e = work[3, i, j]
            for p in range(j):
                e -= work[3, i, p] * work[5, 5, p]
            work[3, i, j] = e * inverse
    for i in range(q):
        e = work[4, 3, i]
        for p in range(i):
            e -= work[3, i, p] * work[4, 4, p]
        work[4, 4, i] = e
    for i in range(q):
        work[4, 4, i] *= work[3, i, i]
    for i in range(q - 1, -1, -1):
        e = work[4, 4, i]
        for p in range(i + 1, q):
            e -= work[3, p, i] * work[4, 4, p]
        work[4, 4, i] = e
    return True


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _newton(q, s, k, target, work, z, scale, ground):
    """The damped semismooth Newton (module docstring) on the block set up in ``work``, from ``z`` (q,) N*s,
    in place; ``ground``: a strut's block of :func:`solve_block` (its sticking step in closed form where it has
    one contact: :func:`_strut_contact_solve`). Returns the iterations taken, or -1 if ``phi`` did not reach
    ``BLOCK_TOL`` times the impulse ``scale`` (nor ``RELAXED_TOL`` times it where it stalled: then
    ``MAX_NEWTON``).

    ``work`` (6, M, M), M >= max(q, 7): [1] W, [2] the Jacobian, [3] the damped normal matrix (or W, for a
    sticking iterate's step); rows of [4]: u0, u, phi, -J^T phi (or t - u), the step, the trial z, rho (each
    row's); rows of [5]: the trial's u and phi, each contact's Coulomb coefficient, the diagonal of J^T J, and
    :func:`_factor_solve`'s D and scratch."""
    tol = BLOCK_TOL * scale
    merit = _residual(q, s, k, target, work, z, 4, 1, 4, 2)
    for it in range(MAX_NEWTON + 1):
        worst = 0.0
        for i in range(q):
            worst = max(worst, abs(work[4, 2, i]))
        if worst <= tol:
            return it
        if it == MAX_NEWTON:
            break
        # every contact sticking: phi = R (u - t) is linear, J = R W, and Newton's step solves W d = t - u (the
        # sticking mode's own system: no Jacobian, no J^T J), where W is comfortably definite; taken whole if it
        # decreases the merit enough (the slope along Newton's step is -|phi|^2 = -2 merit)
        tried = False
        accepted = False
        if _sticking(q, s, k, target, work, z):
            for i in range(q):
                work[4, 3, i] = -work[4, 1, i]
            for c in range(k):
                work[4, 3, s + 3 * c + 2] += target[c]
            if ground and s == 1 and k == 1:
                tried = _strut_contact_solve(work)
            else:
                for i in range(q):
                    for j in range(q):
                        work[3, i, j] = work[1, i, j]
                tried = _factor_solve(q, work, _NEWTON_PIVOT)
            if tried:
                for i in range(q):
                    work[4, 5, i] = z[i] + work[4, 4, i]
                new = _residual(q, s, k, target, work, work[4, 5], 5, 0, 5, 1)
                accepted = new <= merit + _ARMIJO * (-2.0 * merit)
        if not accepted:
            _jacobian(q, s, k, target, work, z)
            for i in range(q):
                acc = 0.0
                for p in range(q):
                    acc += work[2, p, i] * work[4, 2, p]
                work[4, 3, i] = -acc
                for j in range(i + 1):   # J^T J is symmetric: each entry's sum once, mirrored
                    acc = 0.0
                    for p in range(q):
                        acc += work[2, p, i] * work[2, p, j]
                    work[3, i, j] = acc
                    work[3, j, i] = acc
                work[5, 3, i] = work[3, i, i]
        # otherwise Newton's own step where J^T J is comfortably definite (unless it is the step just tried),
        # taken whole if it decreases the merit enough (module docstring)
        if not accepted and not tried:
            accepted = _factor_solve(q, work, _NEWTON_PIVOT)
            if accepted:
                slope = 0.0
                for i in range(q):
                    slope -= work[4, 3, i] * work[4, 4, i]    # row 3 holds -J^T phi
                    work[4, 5, i] = z[i] + work[4, 4, i]
                new = _residual(q, s, k, target, work, work[4, 5], 5, 0, 5, 1)
                accepted = new <= merit + _ARMIJO * slope
        if not accepted:   # the damped step, with the line search
            nu = min(2.0 * merit / (scale * scale), _MAX_DAMPING) + _MIN_DAMPING
            definite = False
            while True:
                for i in range(q):   # J^T J + nu I (a factor tried before overwrote the lower triangle)
                    work[3, i, i] = work[5, 3, i] + nu
                    for j in range(i):
                        work[3, i, j] = work[3, j, i]
                definite = _factor_solve(q, work, 0.0)
                if definite or nu >= _MAX_DAMPING:
                    break
                nu = min(nu * _DAMPING_GROWTH, _MAX_DAMPING)   # damped more where round-off leaves it not definite
            if not definite:
                break
            slope = 0.0
            for i in range(q):
                slope -= work[4, 3, i] * work[4, 4, i]
            step = 1.0
            while True:
                for i in range(q):
                    work[4, 5, i] = z[i] + step * work[4, 4, i]
                new = _residual(q, s, k, target, work, work[4, 5], 5, 0, 5, 1)
                if new <= merit + _ARMIJO * step * slope or step <= _MIN_STEP:
                    break
                step *= 0.5
        for i in range(q):   # the accepted trial's z, u and phi
            z[i] = work[4, 5, i]
            work[4, 1, i] = work[5, 0, i]
            work[4, 2, i] = work[5, 1, i]
        merit = new
    worst = 0.0   # stalled: the last iterate (the best: the merit only falls) if it meets the relaxed tolerance
    for i in range(q):
        worst = max(worst, abs(work[4, 2, i]))
    return MAX_NEWTON if worst <= RELAXED_TOL * scale else -1


@njit(cache=True, error_model="numpy", _nrt=False)
def solve_block(inv, strut, direction, ends, target, k, mu, v, z, work):
    """One block (module docstring), in place: ``v`` (2, 3) m/s the two ends' velocities (the second
    unused without a strut), ``z`` (MAX_ROWS,) N*s the unknowns (in: a warm start for the contacts'; the
    strut's is recomputed), ``inv`` (3,) 1/kg ``M^-1``'s diagonal at each end and its cross entry (a rigid rod's
    consistent mass block, ``tensegrity_sim.mass``; 0 where the ends' masses are lumped), ``strut`` whether the
    block has the strut row along the
    unit ``direction`` (3,) (end 0 to end 1), ``ends`` (k,) which end each contact is at, ``target`` (k,)
    m/s its normal target, ``mu`` its Coulomb coefficient. Returns the iterations taken, or -1 if
    ``phi`` did not reach ``BLOCK_TOL`` or the damped normal matrix is not definite in floating point (``v``
    then unchanged). ``work`` (6, 7, 7): :func:`_newton`'s."""
    s = 1 if strut else 0
    q = s + 3 * k
    cross = inv[2]
    # u0 = G v and W = G M^-1 G^T written out (G's strut row is (-n, n), a contact's rows the unit vectors at
    # its end): the sums of the general product in its order, less its terms that are exactly zero, so the
    # very same numbers at a fraction of the cost (most blocks are answered by their warm start)
    for i in range(q):
        for j in range(q):
            work[1, i, j] = 0.0
    if s:
        acc = 0.0
        for j in range(3):
            acc += -direction[j] * v[0, j]
        for j in range(3):
            acc += direction[j] * v[1, j]
        work[4, 0, 0] = acc
        acc = 0.0
        for e in range(2):
            for j in range(3):
                acc += direction[j] * inv[e] * direction[j]
        if cross != 0.0:
            for j in range(3):
                acc -= 2.0 * (direction[j] * cross * direction[j])
        work[1, 0, 0] = acc
    for c in range(k):
        e = ends[c]
        work[5, 2, c] = mu
        for j in range(3):
            row = s + 3 * c + j
            work[4, 0, row] = v[e, j]
            work[1, row, row] = inv[e]
            if s:   # the strut row (-n, n) through M^-1's column of end e: (inv_e - cross) at its own sign
                work[1, 0, row] = work[1, row, 0] = (direction[j] if e else -direction[j]) * (inv[e] - cross)
        for d in range(c):   # the other end's contact: M^-1's cross entry between the same components
            if ends[d] != e:
                for j in range(3):
                    work[1, s + 3 * c + j, s + 3 * d + j] = cross
                    work[1, s + 3 * d + j, s + 3 * c + j] = cross
    # the impulse scale: each end's momentum, each contact's target momentum and warm start
    scale = 1e-300
    for e in range(2):   # max |v| / inv: one division an end (dividing by inv > 0 keeps the order)
        if inv[e] > 0.0:
            scale = max(scale, max(abs(v[e, 0]), abs(v[e, 1]), abs(v[e, 2])) / inv[e])
    for c in range(k):
        r = 1.0 / inv[ends[c]]
        work[4, 6, s + 3 * c] = r
        work[4, 6, s + 3 * c + 1] = r
        work[4, 6, s + 3 * c + 2] = r
        scale = max(scale, abs(target[c]) * r)
        for j in range(3):
            scale = max(scale, abs(z[s + 3 * c + j]))   # the warm start's impulses
    if s:
        work[4, 6, 0] = 1.0 / work[1, 0, 0]
        # the strut's impulse that meets its row for the contacts' warm start
        acc = work[4, 0, 0]
        for j in range(1, q):
            acc += work[1, 0, j] * z[j]
        z[0] = -acc / work[1, 0, 0]
    done = _newton(q, s, k, target, work, z, scale, True)
    if done < 0:
        return -1
    for j in range(3):   # v += M^-1 G^T z, G^T z's sums as the product's
        push0 = 0.0
        push1 = 0.0
        if s:
            push0 += -direction[j] * z[0]
            push1 += direction[j] * z[0]
        for c in range(k):
            if ends[c] == 0:
                push0 += z[s + 3 * c + j]
            else:
                push1 += z[s + 3 * c + j]
        v[0, j] += inv[0] * push0 + cross * push1
        v[1, j] += inv[1] * push1 + cross * push0
    return done


@njit(cache=True, error_model="numpy", _nrt=False)
def solve_coupled(inv, g, nb, s, k, target, mu, v, z, work):
    """A coupled block, in place: the rigid struts and lone nodes that member contacts join, with their ground and
    member contacts (``elastic/_ground_kernels.py``). ``nb`` nodes, ``inv`` (nb, 2) 1/kg ``M^-1``'s kernel form
    (``_mass_kernels.py``: the diagonal, and the cross entry with the strut's other end, node ``i ^ 1``, for the ``2
    s`` struts' ends first; 0 for the lone nodes), ``v`` (nb, 3) m/s their velocities; ``g`` (q, 3 nb) the rows, ``u
    = g v`` with the node's component ``j`` in column ``3 i + j``: ``s`` strut length rows first (equalities, target
    0; no two struts share a node), then ``k`` contacts of three rows each (two tangents, then the normal; a ground
    contact's are the unit vectors at its node, a member contact's its frame times the four nodes' weights);
    ``target`` (k,) m/s the normal targets, ``mu`` (k,) the Coulomb coefficients. ``z`` (q,) N*s the unknowns (in:
    the contacts' warm starts; the struts' are recomputed). Each row is scaled by its effective mass ``1 / W_ii`` (a
    contact's rows by its normal's: the node's mass on the ground). Returns the iterations taken, or -1 as
    :func:`solve_block` (``v`` then unchanged). ``work`` (6, M, M): :func:`_newton`'s."""
    q = s + 3 * k
    cols = 3 * nb
    for i in range(q):   # u0 = G v, W = G M^-1 G^T
        acc = 0.0
        for col in range(cols):
            acc += g[i, col] * v[col // 3, col % 3]
        work[4, 0, i] = acc
        for j in range(i + 1):
            acc = 0.0
            for col in range(cols):
                acc += g[i, col] * inv[col // 3, 0] * g[j, col]
            for col in range(6 * s):   # the struts' ends: the cross entry with the other end's same component
                acc += g[i, col] * inv[col // 3, 1] * g[j, 3 * ((col // 3) ^ 1) + col % 3]
            work[1, i, j] = acc
            work[1, j, i] = acc
    scale = 1e-300
    for i in range(nb):
        if inv[i, 0] > 0.0:
            for j in range(3):
                scale = max(scale, abs(v[i, j]) / inv[i, 0])
    for i in range(s):
        work[4, 6, i] = 1.0 / work[1, i, i]
    for c in range(k):
        o = s + 3 * c
        r = 1.0 / work[1, o + 2, o + 2]
        work[4, 6, o] = r
        work[4, 6, o + 1] = r
        work[4, 6, o + 2] = r
        work[5, 2, c] = mu[c]
        scale = max(scale, abs(target[c]) * r)
        for j in range(3):
            scale = max(scale, abs(z[o + j]))
    for i in range(s):   # each strut's impulse that meets its row for the contacts' warm start
        acc = work[4, 0, i]
        for j in range(s, q):
            acc += work[1, i, j] * z[j]
        z[i] = -acc / work[1, i, i]
    done = _newton(q, s, k, target, work, z, scale, False)
    if done < 0:
        return -1
    for col in range(cols):   # v += M^-1 G^T z
        acc = 0.0
        for i in range(q):
            acc += g[i, col] * z[i]
        step = inv[col // 3, 0] * acc
        if col < 6 * s:
            other = 3 * ((col // 3) ^ 1) + col % 3
            acc = 0.0
            for i in range(q):
                acc += g[i, other] * z[i]
            step += inv[col // 3, 1] * acc
        v[col // 3, col % 3] += step
    return done
