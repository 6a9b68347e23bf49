"""Ground contact with exact Coulomb friction, at the velocity level, for both methods (physics.md §6).

**Model.** The ground is the plane ``z = height`` with Coulomb coefficient ``mu`` (static = kinetic) and
Newton restitution ``e``. A free node ``p`` touches it at ``z_p - r_p``, ``r_p`` the largest radius of its
members, so its *gap* is ``g_p = z_p - r_p - height``. A node in contact receives an impulse
``P = y_n ẑ + f`` over a step: a normal part ``y_n >= 0`` and a tangential (friction) part ``f`` in the
plane with the Coulomb law

    |f| <= mu y_n;   |f| < mu y_n  =>  v_t = 0 (sticking);   v_t != 0  =>  f = -mu y_n v_t / |v_t| (sliding)

on the node's tangential velocity ``v_t`` at the end of the step (Moreau–Jean).

**The velocity problem.** The contact rows join the method's own rows (the inextensible method's cable
and rigid-strut rows, the elastic method's rigid struts) in the QP of ``methods/qp/solvers.py``: the normal row
of a node is ``v_z >= w`` with the target ``w`` below, an inequality with multiplier ``y_n``. Friction
cannot be a QP row as it stands (its bound ``mu y_n`` is another multiplier: that coupling is what makes
the frictional problem an LCP). :class:`FrictionalSolver` solves it as a fixed point over the *friction
mode* of each contact, each iterate an ordinary QP answered (and verified) by the method's backend:

* a *sticking* contact gets two tangential rows ``±t·v <= 0`` for each of ``t = x̂, ŷ`` (a pair of
  inequalities rather than an equality, so that rows which depend on the rigid struts' rows, as for a
  rigid strut lying on the ground, leave the backend a consistent working set); its friction impulse
  ``f`` is their multipliers';
* a *sliding* contact gets no tangential row; its friction ``-mu ŷ_n d`` is a known impulse added to the
  free velocity, with ``ŷ_n`` the normal impulse and ``d`` the slip direction of the previous iterate.

After each solve: a sticking contact whose ``|f|`` exceeds ``mu y_n`` slides along ``-f/|f|``; a sliding
contact whose velocity turned against ``d`` sticks (one mode change per solve, the worst violation
first: changing all at once can cycle); a sliding contact takes the new ``y_n`` and, if it
moves, ``d = v_t/|v_t|`` (one that stopped is at rest on the disc's edge, a valid Coulomb state: that
is how the friction of a statically indeterminate body, such as a rigid strut on both its ends, is
shared when the backend's split of the sticking impulses would overload one end). The iteration stops
when no mode changes and ``ŷ_n`` and ``d`` agree with the solution to ``FIXED_POINT_TOL`` (relative to
the impulse scale). Every answer is then checked against the Coulomb law in its projection form,
``f = proj_disc(mu y_n)(f - m v_t)`` to twice that tolerance (:class:`FrictionError` otherwise); the
normal rows are checked by the backend like the cables'. If the modes cycle (three contacts of a locked body
that slide a little each way; a robot whose cable pulls a
node harder into the ground the harder it slides), the whole problem is solved at once by a semismooth
Newton method on its Alart–Curnier equation with a line search (:meth:`FrictionalSolver._newton`, as
Siconos and Rible.jl do; physics.md §6), its answer checked the same way. The disc is exact: no pyramid,
no polygonal cone.

Why this and not the alternatives. What was measured is this method (``test/test_ground.py``: the closed
forms to 1e-6 relative and better, no creep, no lift) and, for the last point, a plain projected fixed
point; the first three follow from the alternatives' definitions and were not implemented here:

* *The convex relaxation* (Anitescu: cone-complementarity, one convex QP/SOCP) lifts a sliding node by
  ``mu |v_t| h`` per step (a strut sliding at 2 m/s with mu = 0.5: 1 mm per 1 ms step) — it would fail
  the height test outright; correcting it needs the same fixed point on ``y_n``.
* *A friction pyramid/box in the QP's dual* with the bound ``mu ŷ_n`` iterated on ``ŷ_n`` is the same
  fixed point, but the box's corners make the friction anisotropic: a strut sliding at 45° to the box's
  axes feels ``sqrt(2) mu y_n``, 41 % too much; aligning the box with the slip only fixes the sliding
  case. Modes with the exact disc cost the same QPs.
* *Projected Gauss–Seidel* over all rows (NSGS, as in Bullet and MuJoCo's PGS) handles the disc exactly
  per contact but converges linearly on the coupled rows of a locked structure (a self-stress, rigid
  struts), and would replace the backends' verified active-set solves.
* *The projection form iterated on the QP* (``f <- proj(f - m v_t)``, one QP per iterate): measured on a
  slack icosahedron landing on three nodes, it crawls at a rate near ``1 - m_node/m_body`` (0.92) and
  Anderson acceleration does not stabilise it. Its Newton-like version on the QP's affine model (the
  derivatives by one nudged QP per friction component, the law solved on the model by projected
  Gauss–Seidel), the fallback before the semismooth Newton method, left 3 of 30 random throws of the
  built-in robots unsolved (issue 28): its model is only as good as the QP's piecewise-constant
  derivatives, with no line search. The semismooth Newton method on the whole problem is what is
  measured now (``scripts/throws.py --count 200 --seed 3`` and ``--count 400 --seed 4``: every start of
  one of the 600 throws' problems ended 5e-10 N*s from the law against a tolerance of 4e-11, so the best
  answer found is taken where it meets the law to ``ACCEPT_TOL`` of the momentum in play (a physical
  scale: at rest the structure's weight times the step), and counted in ``FrictionalSolver.relaxed``;
  beyond that the problem has no solution). Where no start comes that near, the rows may depend on each other
  (a rod lying on the ground on both ends) and the solution lie far along the Delassus matrix's null space:
  NSGS with steps along it takes it there (``drift`` in :meth:`FrictionalSolver._newton`; measured on a
  ``three_bar`` reeling three cables, ~150 sweeps where NSGS alone needs 1e5). The modes' answers are accepted
  the same way, else the Newton method takes the problem. Measured cost of the modes: 2 QPs per
  solve for the sliding strut, 1 for the resting icosahedron (``bench/bench_ground.py`` times them).

**Targets.** A contact is armed when its node can reach the ground by the sub-step's end
(``g_m - tau/2 |v0_z| <= 0``). Its target lands it exactly on the ground at the end,
``w = -2 g_m / tau`` in Moreau's midpoint scheme (``-g / h`` in the elastic method's drift), the
cables' stabiliser: no sinking, no rebound. Like the cables' it is capped so that it never asks for more
than the reversal of the node's normal velocity at the sub-step's start (the impulse then does no
positive work), so that ``v_f = -v_i`` meets every row as it does the cables': a node that starts
inside the ground is not pushed out faster than it came in. The elastic method floors the targets too, as
the member pairs' (``floored``): no target lets a node sink past ``TOUCH_TOL`` deep, nor deeper where it is
already past it, where it is not pushed out either (the cap alone let a node
that left the ground upwards, kicked down by its members within the step, sink by as much as it rose: 0.13 mm
in a throw of ``scripts/throws.py``); the inextensible method keeps the cap alone, which does no positive work
(its energy law). Sticking rows are the exception (they ask
for ``v_t = 0``): when sticking contacts hold a locked structure still and that misses a cable's or
rigid strut's drift-correcting target, the QP is infeasible and is solved again with those targets at
the pure velocity level (equalities 0, inequalities at least 0), which ``v = 0`` meets.

**Impacts** are located inside the step like the cables' snaps (:meth:`GroundResponse.first_impact`:
the node's free path, a parabola, crosses ``g = 0``); at the impact Newton's law
``v_z+ >= -e v_z-`` with Coulomb friction is one more problem of the same form, solved together with
the snapping cables so that a robot landing while its cables go taut is a single inelastic impact. The nodes
a sub-step was cut for take that law at the cut even where the members' impulses left them a few nm off the
ground (:meth:`ContactSet.landed`): landed by a target instead, a node's normal velocity is reversed.
"""
from __future__ import annotations

import numpy as np

from ...system import System
from .member import Armed, MemberContacts, tangents
from . import _friction_kernels as kernels, _newton_kernels as newton_kernels
from ..qp import _daqp_kernels as daqp_kernels
from ..qp.solvers import (_FEASIBILITY_TOL, _VELOCITY_FLOOR, DaqpSolver, MassWrapper, QPError,
                          QPSolver, Rows)

__all__ = ["ContactSet", "FrictionalSolver", "FrictionError", "FIXED_POINT_TOL", "TOUCH_TOL"]

FIXED_POINT_TOL = 1e-10   # relative to the impulse scale: friction modes, slip directions and y_n agree
MAX_MODE_ITER = 30        # QPs of the mode fixed point before the semismooth Newton method takes over ...
MAX_NEWTON_ITER = 100     # ... and its iterations before the problem is declared to have no solution
_LINE_SEARCH = 30         # halvings of the Newton step before the line search gives it up ...
_NSGS_SWEEPS = (100, 300, 600, 4000)   # NSGS sweeps between Newton's further starts (5000 in all) ...
_CHAINS = 2               # Newton's first iterates (the modes' and zero's) the NSGS sweeps go on from ...
_RESTARTS = 64            # Newton's starts from random impulses where it stops at a merit's local minimum ...
_DRIFT_SWEEPS, _DRIFT_ROUNDS = 50, 400   # ... then NSGS rounds of sweeps with steps along W's null space
_CONTINUATION_STEP = 0.1  # the first step in t of Newton's continuation along t mu from the frictionless problem, ...
_CONTINUATION_ITER = 8    # ... Newton's iterations at each t before the step is halved ...
_CONTINUATION_MIN = 1e-3  # ... and the step below which it is given up
_CONE_EDGES = 8           # the polygon's edges that stand for each disc in the polyhedral cone's start ...
_CONE_BOUND = 100.0       # ... its impulses bounded by this many times the problem's impulse scale ...
_CONE_SECONDS = 10.0      # ... HiGHS' time limit for it ...
_CONE_TURNS = 6           # ... and its tries, each polygon turned to point an edge against the last one's slip
# Where no answer meets the law to FIXED_POINT_TOL of the contacts' own impulse scale, the best one found is
# taken if it meets it to ACCEPT_TOL of the momentum in play (FrictionalSolver._physical_tol: the free nodes'
# sum m |v0|, at rest the weight times the step) and counted in FrictionalSolver.relaxed; beyond it the problem
# has no solution. Measured (issue 47, bench/bench_throws.py): prism3 set down at mu = 1.9, the best of 3292
# Newton iterations 4.7e-8 N*s from the law, 1.7e-7 of its 0.28 N*s in play; a prism dropped 5 cm, 2.6e-13 N*s
# against a contact scale of 9e-6 N*s. The old bound, 1e3 times FIXED_POINT_TOL of the contacts' scale, refused
# both. 1e-5 rather than 1e-6: a locked icosahedron set down on three nodes (bench_throws.py --space wide --seed
# 0, throw 68) has dependent rows, and the Newton answer stays 3.7e-7 m/s off a cable's row (the heaviest node's
# mass times it, 3e-6 of the momentum in play: a force error of 3e-6 of the weight); the mode QPs started from
# its modes cycle as before, and QPs at its modes with its friction known miss the law by 8e-7 N*s
ACCEPT_TOL = 1e-5
_LM_DAMPINGS = 20         # ... for Levenberg–Marquardt steps, their damping raised tenfold up to this many times
_POLISH_QPS = 10          # QPs that polish an answer of the Newton method (FrictionalSolver._polish)
TOUCH_TOL = 1e-9          # m: a node within this of the ground touches it (contact begins/ends here)
_ANDERSON_DEPTH = 3       # previous iterates the fixed point's acceleration combines
_SLIP_FLOOR = 1e-12       # m/s: a tangential speed below this (plus relative round-off) is no slip
_TANGENTS = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
_UP = np.array([0.0, 0.0, 1.0])
_CYCLED = object()        # FrictionalSolver._modes_compiled: the modes cycled, every QP answered


def alart_curnier(r, mu, free_rates, delassus, rho, n_eq: int, n_rows: int, k: int):
    """``Phi(r)`` (n,) of :meth:`FrictionalSolver._newton`'s Alart–Curnier equation and its generalised Jacobian
    (n, n), with the friction coefficients ``mu`` (k,): the unknowns ``r = (y, f)`` (the ``n_rows`` method rows'
    multipliers, the first ``n_eq`` of them equalities, one normal row's per contact, then each contact's
    friction (k, 2)), the rates ``free_rates + delassus @ r`` less their targets, ``rho`` (n,) each row's
    effective mass. The plain reference of ``_newton_kernels.alart_curnier``."""
    n_qp = n_rows + k
    every = np.arange(k)
    ineq = np.arange(n_eq, n_qp)
    normal = np.arange(n_rows, n_qp)
    t_index = n_qp + 2 * every[:, None] + np.arange(2)  # (k, 2) positions of f in r
    res = free_rates + delassus @ r
    phi = np.empty_like(r)
    jac = np.zeros((len(r), len(r)))
    phi[:n_eq] = rho[:n_eq] * res[:n_eq]
    jac[:n_eq] = rho[:n_eq, None] * delassus[:n_eq]
    trial = r[ineq] + rho[ineq] * res[ineq]
    acting = trial > 0
    phi[ineq] = r[ineq] - np.maximum(trial, 0.0)
    jac[ineq[acting]] = -rho[ineq[acting], None] * delassus[ineq[acting]]
    jac[ineq[~acting], ineq[~acting]] = 1.0
    # the disc: f - proj(f - rho v_t) with radius mu s+, s the normal row's trial (as above)
    s = r[normal] + rho[normal] * res[normal]
    radius = mu * np.maximum(s, 0.0)
    ti = t_index.ravel()
    z = (r[ti] - rho[ti] * res[ti]).reshape(k, 2)
    dz = -rho[ti, None] * delassus[ti]
    dz[np.arange(2 * k), ti] += 1.0
    dz = dz.reshape(k, 2, -1)
    size = np.sqrt(np.einsum("ij,ij->i", z, z))
    out = size > radius
    direction = z / np.maximum(size, 1e-300)[:, None]
    projected = np.where(out[:, None], radius[:, None] * direction, z)
    phi[ti] = (r[ti].reshape(k, 2) - projected).ravel()
    scale = np.where(out, radius / np.maximum(size, 1e-300), 1.0)
    bend = np.eye(2) - np.where(out[:, None, None], direction[:, :, None] * direction[:, None, :], 0.0)
    d_proj = scale[:, None, None] * np.einsum("cij,cjn->cin", bend, dz)
    ds = rho[normal, None] * delassus[normal]
    ds[every, normal] += 1.0
    lifting = out & (s > 0)
    d_proj[lifting] += (mu[lifting, None, None] * direction[lifting, :, None]) * ds[lifting, None, :]
    d_phi = -d_proj
    d_phi[every[:, None], np.arange(2), t_index] += 1.0
    jac[ti] = d_phi.reshape(2 * k, -1)
    return phi, jac


def newton_descend(r, mu, iterations: int, free_rates, delassus, rho, n_eq: int, n_rows: int, k: int, tol: float,
                   impulse_scale: float, line_search: int, dampings: int):
    """Newton on :func:`alart_curnier` from ``r`` until ``|Phi|`` (friction coefficients ``mu``) is within a tenth
    of ``tol`` times the larger of ``impulse_scale`` and ``max |r|``, or stops falling, in at most ``iterations``:
    ``r``, its iterations. Each iteration takes the least-squares Newton step with an Armijo line search of
    ``line_search`` halvings on ``|Phi|^2 / 2``; where that does not descend (at a kink the chosen Jacobian can
    mislead, and a singular one leaves a direction free), Levenberg–Marquardt steps on the same model, damped
    tenfold more up to ``dampings`` times, which descend wherever the merit's gradient ``J^T Phi`` is not 0.
    The plain reference of ``_newton_kernels.newton_descend``."""
    def within(r, phi) -> bool:
        largest = float(np.max(np.abs(r), initial=0.0))
        return float(np.max(np.abs(phi), initial=0.0)) <= 0.1 * (tol * max(impulse_scale, largest))

    phi, jac = alart_curnier(r, mu, free_rates, delassus, rho, n_eq, n_rows, k)
    merit = 0.5 * float(phi @ phi)
    for it in range(1, iterations + 1):
        if within(r, phi):
            return r, it - 1
        found = None
        step = np.linalg.lstsq(jac, -phi, rcond=None)[0]
        # Armijo on |Phi|^2 / 2, along which the Newton step descends at rate -|Phi|^2 where Phi is smooth
        alpha = 1.0
        for _ in range(line_search):
            trial = r + alpha * step
            trial_phi, trial_jac = alart_curnier(trial, mu, free_rates, delassus, rho, n_eq, n_rows, k)
            trial_merit = 0.5 * float(trial_phi @ trial_phi)
            if trial_merit <= (1.0 - 2e-4 * alpha) * merit:
                found = trial, trial_phi, trial_jac, trial_merit
                break
            alpha *= 0.5
        if found is None:
            gradient, gram = jac.T @ phi, jac.T @ jac
            damping = 1e-10 * max(float(np.trace(gram)) / len(r), 1e-300)
            for _ in range(dampings):
                trial = r - np.linalg.solve(gram + damping * np.eye(len(r)), gradient)
                trial_phi, trial_jac = alart_curnier(trial, mu, free_rates, delassus, rho, n_eq, n_rows, k)
                trial_merit = 0.5 * float(trial_phi @ trial_phi)
                if trial_merit < merit:
                    found = trial, trial_phi, trial_jac, trial_merit
                    break
                damping *= 10.0
        if found is None:
            return r, it   # a stationary point of the merit that is no solution
        r, phi, jac, merit = found
    return r, iterations


def _polyhedral_start(delassus, free_rates, n_eq: int, n_rows: int, mu, scale: float, turn):
    """Impulses ``r`` (:meth:`FrictionalSolver._newton`'s: the rows' multipliers, then each contact's friction)
    solving the frictional problem with each Coulomb disc replaced by its inscribed polygon of
    :data:`_CONE_EDGES` edges: Stewart and Trinkle's linear complementarity problem (1996), which has a solution
    for any friction coefficient (Anitescu and Potra 1997), found exactly as a mixed-integer feasibility problem
    (one binary a complementarity pair, big-M bounds: HiGHS through ``scipy.optimize.milp``). The polygon's
    friction ``sum_j beta_j d_j`` and a contact's slip speed ``lam``::

        equality row i:     u_i = 0
        inequality row i:   0 <= y_i        complementary to  -u_i >= 0
        edge j, contact c:  0 <= beta_cj    complementary to  lam_c + d_j . u_t,c >= 0
        contact c:          0 <= lam_c      complementary to  mu_c y_n,c - sum_j beta_cj >= 0

    with ``u = free_rates + delassus r``. Impulses are in units of ``scale`` and bounded by :data:`_CONE_BOUND`
    of it, rates in those of the largest that such impulses make. None where HiGHS finds no point in
    :data:`_CONE_SECONDS` (or the bound is too tight), or where a number is not finite."""
    from scipy.optimize import Bounds, LinearConstraint, milp
    if not (np.isfinite(delassus).all() and np.isfinite(free_rates).all() and np.isfinite(scale) and scale > 0):
        return None
    k = len(mu)
    n_qp, m = n_rows + k, _CONE_EDGES
    n_in = n_qp - n_eq
    angles = turn[:, None] + 2.0 * np.pi * np.arange(m) / m                        # contact c's edge j's d_cj
    spread = np.zeros((2 * k, k * m))                                              # f (2k) = spread @ beta (km)
    for c in range(k):
        spread[2 * c, c * m:(c + 1) * m] = np.cos(angles[c])
        spread[2 * c + 1, c * m:(c + 1) * m] = np.sin(angles[c])
    rate = max(scale * float(np.max(np.abs(delassus), initial=0.0)), float(np.max(np.abs(free_rates))), 1e-300)
    big_r, big_u = _CONE_BOUND, _CONE_BOUND * (n_qp + k * m) + float(np.max(np.abs(free_rates))) / rate
    # scaled rates u / rate = base + gain @ (y, beta, lam) in units of scale, scale, rate
    gain = (scale / rate) * np.hstack([delassus[:, :n_qp], delassus[:, n_qp:] @ spread,
                                       np.zeros((len(free_rates), k))])
    base = free_rates / rate
    n_v = n_qp + k * m + k
    n_b = n_in + k * m + k
    rows, lo, hi = [], [], []

    def unit(i):
        row = np.zeros(n_v)
        row[i] = 1.0
        return row

    def add(coef, low, high, binary=None, weight=0.0):
        row = np.zeros(n_v + n_b)
        row[:len(coef)] = coef
        if binary is not None:
            row[n_v + binary] = weight
        rows.append(row)
        lo.append(low)
        hi.append(high)

    for i in range(n_eq):
        add(gain[i], -base[i], -base[i])
    for a, i in enumerate(range(n_eq, n_qp)):   # -u_i >= 0, -u_i <= big_u (1 - z), y_i <= big_r z
        add(-gain[i], base[i], np.inf)
        add(-gain[i], -np.inf, big_u + base[i], a, big_u)
        add(unit(i), -np.inf, 0.0, a, -big_r)
    for c in range(k):
        tangential = gain[n_qp + 2 * c:n_qp + 2 * c + 2]
        for j in range(m):   # lam + d_j . u_t >= 0, <= big_u (1 - z), beta <= big_r z
            edge = spread[2 * c:2 * c + 2, c * m + j]
            coef = edge @ tangential
            coef[n_qp + k * m + c] += 1.0
            shift = float(edge @ base[n_qp + 2 * c:n_qp + 2 * c + 2])
            z = n_in + c * m + j
            add(coef, -shift, np.inf)
            add(coef, -np.inf, big_u - shift, z, big_u)
            add(unit(n_qp + c * m + j), -np.inf, 0.0, z, -big_r)
        coef = np.zeros(n_v)   # mu y_n - sum beta >= 0, <= big_r (1 - z); lam <= big_u z
        coef[n_rows + c] = mu[c]
        coef[n_qp + c * m:n_qp + (c + 1) * m] = -1.0
        z = n_in + k * m + c
        add(coef, 0.0, np.inf)
        add(coef, -np.inf, big_r, z, big_r)
        add(unit(n_qp + k * m + c), -np.inf, 0.0, z, -big_u)
    lower = np.concatenate([np.full(n_eq, -big_r), np.zeros(n_v - n_eq + n_b)])
    upper = np.concatenate([np.full(n_qp + k * m, big_r), np.full(k, big_u), np.ones(n_b)])
    found = milp(np.zeros(n_v + n_b), constraints=LinearConstraint(np.array(rows), lo, hi),
                 bounds=Bounds(lower, upper), integrality=np.r_[np.zeros(n_v), np.ones(n_b)],
                 options={"time_limit": _CONE_SECONDS})
    if found.x is None:
        return None
    x = found.x
    return scale * np.concatenate([x[:n_qp], spread @ x[n_qp:n_qp + k * m]])


class FrictionError(QPError):
    """The friction modes found no fixed point, or the answer misses the Coulomb law."""


class ContactSet:
    """The contacts of a :class:`System` for one method: the ground's (a scene with a ``ground``) and the
    members' (``contact: response: true``, ``methods/contact/member.py``): which are armed, their targets,
    the impulses of the current step.

    ``inner``: the method's QP backend (``methods/qp/solvers.py``), used through :attr:`solver`.
    ``impulses``: (N, 3) N*s, the ground's impulses on each node summed over the current step (friction in
    x, y; normal along z); ``pair_impulses``: {(member i, member j): (normal N*s, friction (3,) N*s)} the
    member contacts' over the step, the impulse on member j (member i takes the opposite). Both are cleared
    by :meth:`take_impulses`.
    """

    def __init__(self, system: System, inner: QPSolver):
        ground = system.scene.ground
        self.height = 0.0 if ground is None else ground.height
        self.mu = 0.0 if ground is None else ground.friction
        self.restitution = 0.0 if ground is None else ground.restitution
        self.system = system
        self.radii = system.scene.node_radii
        self.free = np.flatnonzero(system.free)          # free node p <-> free index k
        self._free_index = np.full(system.n_nodes, -1)
        self._free_index[self.free] = np.arange(len(self.free))
        # the nodes that can touch the ground (none without one)
        self._grounded = self.free if ground is not None else np.zeros(0, dtype=int)
        self.members = MemberContacts(system) if system.scene.contact_response.response else None
        self._landing = (np.inf, self._grounded[:0])   # first_impact's: its fraction and the nodes landing then
        daqp = inner.inner if isinstance(inner, MassWrapper) else inner
        if isinstance(daqp, DaqpSolver):
            daqp.working_set = False   # DAQP alone: see DaqpSolver.working_set
        self.solver = FrictionalSolver(inner, self)
        self.impulses = np.zeros((system.n_nodes, 3))
        self.pair_impulses: dict[tuple[int, int], tuple[float, np.ndarray]] = {}

    # ------------------------------------------------------------------ geometry
    def gaps(self, x: np.ndarray) -> np.ndarray:
        """(N,) m: each node's height above the ground, minus its radius (negative: below)."""
        return x[:, 2] - self.radii - self.height

    def _gaps_of(self, x: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The gaps (len(p),) m of nodes ``p`` only (a scene may have fixed nodes, which never touch)."""
        return x[p, 2] - self.radii[p] - self.height

    def first_impact(self, x: np.ndarray, v: np.ndarray, v0: np.ndarray, tau: float) -> float:
        """Fraction of the sub-step (0, 1] at which the first free node above the ground reaches it on its
        free path ``g + t v_z + t^2 a_z / 2`` (``a_z = (v0_z - v_z) / tau``), or the first pair of members
        meets (:meth:`.member_contact.MemberContacts.first_impact`); 1.0 if none does."""
        first = 1.0 if self.members is None else self.members.first_impact(x, v, v0, tau, TOUCH_TOL)
        p = self._grounded
        g = self._gaps_of(x, p)
        vz, az = v[p, 2], (v0[p, 2] - v[p, 2]) / tau
        end = g + tau * vz + 0.5 * tau * tau * az
        hit = (g > TOUCH_TOL) & (end < 0.0)
        self._landing = (np.inf, p[:0])
        if not hit.any():
            return first
        g, vz, az = g[hit], vz[hit], az[hit]
        # the small root of g + vz t + az t^2/2 = 0, written to avoid cancellation (vz < 0 or az < 0)
        disc = np.sqrt(np.maximum(vz * vz - 2.0 * az * g, 0.0))
        t = 2.0 * g / (-vz + disc)
        fraction = float(np.clip(t.min() / tau, 0.0, 1.0))
        self._landing = (fraction, p[hit][t == t.min()])
        return min(first, fraction)

    def landed(self, theta: float) -> np.ndarray:
        """The nodes (system indices) whose impact the last :meth:`first_impact` located at the fraction
        ``theta`` of its sub-step (none if ``theta`` is another event's): a sub-step cut there ends with them
        at the ground, to the accuracy of their free path (:meth:`arm_impact`)."""
        fraction, nodes = self._landing
        return nodes if fraction == theta else nodes[:0]

    # ------------------------------------------------------------------ arming
    def arm_step(self, x_m: np.ndarray, v: np.ndarray, v0: np.ndarray, tau: float, half: float,
                 v_f: np.ndarray | None = None, floored: bool = False) -> bool:
        """Arm the contacts of a sub-step whose positions end at ``x_m + half * v_f`` (the inextensible
        midpoint: ``half = tau / 2``; the elastic drift: ``x_m = x_i``, ``half = h``): the nodes that may
        reach the ground by then, each with the target that lands it exactly on it, capped at the
        reversal of its normal velocity ``v`` (N, 3) at the start; and the member pairs likewise.
        Whether a node may reach the ground is judged on its free velocity ``v0`` (N, 3), and also on an
        answer ``v_f`` (N, 3) when given (a cable's impulse can carry a node the free motion kept clear
        of the ground into it). ``floored`` (the elastic method's): no target lets a node sink past
        ``TOUCH_TOL`` deep, nor deeper where it already is (a node leaving the ground upwards but kicked down
        by its members within the step was let down by as much as it rose). Returns whether any is armed."""
        p = self._grounded
        g = self._gaps_of(x_m, p)
        reach = g - half * np.abs(v0[p, 2])
        if v_f is not None:
            np.minimum(reach, g + half * v_f[p, 2], out=reach)
        armed = reach <= TOUCH_TOL
        w = -g[armed] / half
        np.minimum(w, -v[p[armed], 2], out=w)
        if floored:
            np.maximum(w, np.minimum(-(g[armed] + TOUCH_TOL) / half, 0.0), out=w)
        touching = g[armed] <= TOUCH_TOL
        pairs = None if self.members is None else self.members.arm_step(x_m, v, v0, half, TOUCH_TOL)
        self.solver.arm(p[armed], w, touching, pairs)
        return self.solver.armed

    def missed(self, x_m: np.ndarray, v_f: np.ndarray, half: float) -> bool:
        """Whether the answer ``v_f`` (N, 3) of a sub-step armed by :meth:`arm_step` carries a node that was
        not armed below the ground by the sub-step's end ``x_m + half * v_f``."""
        p = self._grounded
        below = self._gaps_of(x_m, p) + half * v_f[p, 2] < -TOUCH_TOL
        return bool(below.any()) and bool(np.any(below & ~np.isin(p, self.solver._nodes)))

    def arm_impact(self, x: np.ndarray, v: np.ndarray, dt: float, landed: np.ndarray | None = None) -> bool:
        """Arm the impacts at ``x``: nodes touching the ground and moving into it by more than
        ``TOUCH_TOL`` per step get Newton's law ``v_z+ >= -e v_z-``; the other touching nodes keep
        ``v_z+ >= 0`` (they are part of the same impact); member pairs likewise. Returns whether any node
        or pair impacts.

        ``landed`` (system indices, :meth:`landed`): nodes that the sub-step before was cut to bring to the
        ground, which touch it whatever their gap. The cut is where their free path meets the ground; the
        members' impulses move them off it, and one left a few nm above ``TOUCH_TOL`` (issue 47,
        ``bench_throws.py`` throw 1442: 6.2e-9 m, at 0.017 m/s) missed its impact and landed inside the
        step's last sub-step by its target, which reverses its normal velocity: a plastic ground bounced
        it, and its sticking friction, working on the mean of the velocities, made 4.4e-5 J."""
        p = self._grounded
        touching = self._gaps_of(x, p) <= TOUCH_TOL
        if landed is not None:
            touching |= np.isin(p, landed)
        vz = v[p[touching], 2]
        impacting = vz * dt < -TOUCH_TOL
        pairs, hit = (None, False) if self.members is None else self.members.arm_impact(x, v, dt, TOUCH_TOL)
        # every touching node takes part (a cable snapping at the same instant must not push one into
        # the ground); whether the impact happens at all is decided by the landing nodes and the snaps
        self.solver.arm(p[touching], np.where(impacting, -self.restitution * vz, 0.0), np.ones(len(vz), bool),
                        pairs)
        return bool(impacting.any()) or hit

    def arm_settle(self, x: np.ndarray, v: np.ndarray, landing_speed: np.ndarray) -> bool:
        """Arm the velocity-level contacts at the end of an elastic step: every node touching the ground at
        ``x`` gets ``v_z >= 0``, or ``v_z >= e * landing_speed`` (N,) m/s (its speed into the ground before
        this step's drift stopped it) when it landed in this step; touching member pairs likewise.
        Returns whether any is armed."""
        p = self._grounded
        touching = self._gaps_of(x, p) <= TOUCH_TOL
        nodes = p[touching]
        pairs = None if self.members is None else self.members.arm_settle(x, TOUCH_TOL)
        self.solver.arm(nodes, self.restitution * landing_speed[nodes], np.ones(len(nodes), bool), pairs)
        return self.solver.armed

    def velocity_step(self, x: np.ndarray, v: np.ndarray, rigid) -> np.ndarray:
        """The armed contacts' velocity problem for the elastic method: ``v`` (N, 3) m/s changed by the
        contact impulses and by impulses along the rigid struts (``rigid``: :class:`~.rigid.RigidStruts`)
        that keep their lengths at ``x`` (rate 0, as RATTLE does): otherwise SHAKE's position correction
        after the drift would push a node resting on the ground into it, a little every step.
        Returns the new velocities (N, 3); the ground's impulses go to ``impulses``. With rigid rods' mass blocks
        too (``BlockMassSolver``): the problem whose modes cycled and whose Newton starts missed the law (a
        ``three_bar`` reeling three cables to 40 % at once, a rod lying on both ends: its solution far along the
        rows' null space, :meth:`FrictionalSolver._newton`'s ``drift``) is answered with the blocks, never
        lumped."""
        free = self.free
        fi = self._free_index
        if rigid.count:
            n = self.system.geometry(x, rigid.ends)[2]
            rows = Rows(fi[rigid.ends], n, np.zeros(rigid.count), rigid.count)
        else:
            rows = Rows(np.zeros((0, 2), dtype=int), np.zeros((0, 3)), np.zeros(0), 0)
        out = v.copy()
        out[free] = self.solver.solve(v[free], rows)[0]
        self.solver.commit()
        return out

    def drift_step(self, x: np.ndarray, v: np.ndarray, v_half: np.ndarray, h: float, rigid,
                   v_f: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The drift's contact impulse of a velocity-Verlet step of ``h`` (s) (the elastic and massive methods):
        every node that would pass the ground by ``x + h v_half`` is landed exactly on it (:meth:`arm_step`,
        floored; ``v`` (N, 3) the step's start velocities, ``v_f`` an answer that may carry a node into the ground,
        or None). Begins the step's impulses. Returns the new ``v_half`` (N, 3) and each node's landing speed (N,)
        m/s (its speed into the ground where it was above it: :meth:`settle_step`'s restitution)."""
        self.begin_step()
        landing_speed = np.maximum(-v_half[:, 2], 0.0)
        if self.arm_step(x, v, v_half, h, h, v_f, floored=True):
            free = v_half
            v_half = self.velocity_step(x, free, rigid)
            # an answer that carries an unarmed node into the ground (its strut turned by its other end's
            # contact: 0.39 mm in one step, bench_throws --rods) is solved again with it armed
            while self.missed(x, v_half, h):
                v_f = free.copy() if v_f is None else v_f
                np.minimum(v_f[:, 2], v_half[:, 2], out=v_f[:, 2])
                self.begin_step()
                self.arm_step(x, v, free, h, h, v_f, floored=True)
                v_half = self.velocity_step(x, free, rigid)
        landing_speed *= self.gaps(x) > TOUCH_TOL
        return v_half, landing_speed

    def settle_step(self, x: np.ndarray, v: np.ndarray, landing_speed: np.ndarray, rigid) -> np.ndarray:
        """The closing kick's contact impulse (after :meth:`drift_step`): no node touching the ground at ``x``
        moves into it or slides against friction. Returns the new velocities ``v`` (N, 3)."""
        if self.arm_settle(x, v, landing_speed):
            v = self.velocity_step(x, v, rigid)
        return v

    def begin_step(self) -> None:
        """A new step: what a failed one left in ``impulses`` and ``pair_impulses`` is dropped."""
        self.impulses[:] = 0.0
        self.pair_impulses = {}

    def take_impulses(self) -> np.ndarray:
        """(N, 3) N*s: the ground's impulses on each node since the last call (normal along z); the member
        contacts' are taken with :meth:`take_pair_impulses`."""
        out, self.impulses = self.impulses, np.zeros_like(self.impulses)
        return out

    def take_pair_impulses(self) -> dict[tuple[int, int], tuple[float, np.ndarray]]:
        """The member contacts' impulses since the last call (``pair_impulses``)."""
        out, self.pair_impulses = self.pair_impulses, {}
        return out


def _velocity_level(rows: Rows) -> Rows:
    """``rows`` with the targets of the pure velocity level: equalities 0, inequalities at least 0 (no
    drift correction; ``v = 0`` meets them all)."""
    targets = rows.targets.copy()
    targets[: rows.n_eq] = 0.0
    np.maximum(targets[rows.n_eq:], 0.0, out=targets[rows.n_eq:])
    return Rows(rows.nodes, rows.directions, targets, rows.n_eq, rows.weights)


class FrictionalSolver:
    """A QP backend with the armed contacts added (module docstring: the mode fixed point).

    Same interface as :class:`~.qp.QPSolver`: ``solve(v0, rows, warm)`` returns ``v`` (n_free, 3) and the
    multipliers of ``rows`` only; the contacts' impulses go to ``ground.impulses`` and
    ``ground.pair_impulses`` when :meth:`commit` is called for the solve the method keeps.

    The armed contacts are the ground's (first, one node each: the member rows' 2-node fast path, with the
    tangents x and y) and the member pairs' (``methods/contact/member.py``; general rows of four nodes,
    tangents in the plane normal to each contact). Each has a normal ``n``, tangents ``T`` (2, 3), a
    Coulomb coefficient ``mu`` and an effective mass ``1 / sum_j w_j^2 / m_j`` (the node's mass on the
    ground), the scale of the Coulomb law's projection form.
    """

    last_hint = False   # QPSolver.last_hint: the last sub-step after an event keeps the sub-step before's hint

    def __init__(self, inner: QPSolver, ground: ContactSet):
        self.inner = inner
        self.ground = ground
        self.name = inner.name
        self._mass = inner.mass.reshape(-1, 3)[:, 0]          # (n_free,) kg
        self._nodes = np.zeros(0, dtype=int)                   # armed ground nodes (system index)
        n = ground.system.n_nodes
        self._stick = np.zeros(n, dtype=bool)                  # each node's mode in the last solve
        self._normal = np.zeros(n)                             # each node's y_n in the last solve
        self._slip = np.zeros((n, 2))                          # each node's slip direction in the last solve
        self._pair_memory: dict[int, tuple[bool, float, np.ndarray]] = {}   # a pair's mode, y_n, slip (3,)
        self.last = None                                       # impulses (k, 3) (tangents, normal) of the last solve
        self.iterations = 0                                    # QPs of the last solve (+ Newton iterations)
        self.relaxed = 0                                       # solves answered to ACCEPT_TOL (physical)
        self.resumed = 0                                       # Newton solves answered from the last answer
        self.cycled = 0                                        # solves whose modes cycled (Newton answered)
        self.resume = False                                    # a solve tries Newton from the last answer first
        self.answer = None                                     # the Newton method's last: (its problem, r)
        self._guess = None                                     # the modes' last iterate: multipliers, friction (k, 2)
        self.disarm()

    @property
    def compiled(self) -> bool:
        """Whether the backend builds its rows and checks its answers with numba kernels (it does the
        same for the contact rows, which are ordinary rows)."""
        return self.inner.compiled

    @compiled.setter
    def compiled(self, value: bool) -> None:
        self.inner.compiled = bool(value)

    def describe(self) -> dict:
        return {**self.inner.describe(), "friction": "Coulomb disc, mode fixed point, semismooth Newton fallback",
                "fixed_point_tol": FIXED_POINT_TOL}

    def arm(self, nodes: np.ndarray, targets: np.ndarray, touching: np.ndarray, pairs: Armed | None = None) -> None:
        """The contacts of the next solves: ground ``nodes`` (k,) system indices, normal targets
        ``v_z >= targets`` (k,) m/s; ``touching`` (k,) bool nodes start sticking unless they slide already;
        ``pairs``: the member contacts (or None)."""
        fi = self.ground._free_index[nodes]
        self._nodes, self._fi = nodes, fi
        if pairs is None or not len(pairs.keys):
            self._pairs, self._frames = None, None
            self._targets, self._touching = targets, touching
            self._meff, self._mu = self._mass[fi], np.full(len(nodes), self.ground.mu)
            return
        k, kp = len(nodes), len(pairs.keys)
        self._pairs = pairs
        self._targets = np.concatenate([targets, pairs.targets])
        self._touching = np.concatenate([touching, pairs.touching])
        # every contact as a general row: (k + kp, 4) free nodes (-1: none or fixed) and weights
        c_nodes = np.full((k + kp, 4), -1)
        c_nodes[:k, 0] = fi
        c_nodes[k:] = self.ground._free_index[pairs.nodes]
        weights = np.zeros((k + kp, 4))
        weights[:k, 0] = 1.0
        weights[k:] = np.where(c_nodes[k:] >= 0, pairs.weights, 0.0)
        normals = np.vstack([np.tile(_UP, (k, 1)), pairs.normals])
        tang = np.concatenate([np.tile(_TANGENTS, (k, 1, 1)), tangents(pairs.normals)])
        self._frames = (c_nodes, weights, normals, tang)
        inv = np.append(1.0 / self._mass, 0.0)[c_nodes]
        self._meff = np.concatenate([self._mass[fi], 1.0 / np.maximum((weights[k:] ** 2 * inv[k:]).sum(axis=1),
                                                                       1e-300)])
        self._mu = np.concatenate([np.full(k, self.ground.mu), np.full(kp, self.ground.members.mu)])

    def disarm(self) -> None:
        self.arm(np.zeros(0, dtype=int), np.zeros(0), np.zeros(0, dtype=bool))

    @property
    def armed(self) -> bool:
        return len(self._targets) > 0

    def _velocity(self, v: np.ndarray) -> np.ndarray:
        """(k, 3) m/s: each armed contact's relative velocity for free-node velocities ``v`` (n_free, 3)."""
        if self._frames is None:
            return v[self._fi]
        c_nodes, weights = self._frames[:2]
        return np.einsum("kj,kjd->kd", weights, np.vstack([v, np.zeros((1, 3))])[c_nodes])

    def _tangential(self, u: np.ndarray) -> np.ndarray:
        """(k, 2): the tangential components of contact vectors ``u`` (k, 3)."""
        if self._frames is None:
            return u[:, :2]
        return np.einsum("kid,kd->ki", self._frames[3], u)

    def _recall(self):
        """Each armed contact's mode (k,) bool, ``y_n`` (k,) N*s and slip direction (k, 2) in its tangents,
        from the last solve it took part in (``y_n = 0``: none)."""
        nodes = self._nodes
        stick, normal, slip = self._stick[nodes], self._normal[nodes], self._slip[nodes]
        if self._pairs is None:
            return stick, normal, slip
        memory = [self._pair_memory.get(key, (False, 0.0, np.zeros(3))) for key in self._pairs.keys.tolist()]
        world = np.array([m[2] for m in memory]).reshape(-1, 3)
        local = np.einsum("kid,kd->ki", self._frames[3][len(nodes):], world)
        local /= np.maximum(np.linalg.norm(local, axis=1), 1e-300)[:, None]   # the normal turned a little
        return (np.concatenate([stick, [m[0] for m in memory]]).astype(bool),
                np.concatenate([normal, [m[1] for m in memory]]), np.vstack([slip, local]))

    def _remember(self, stick: np.ndarray, normal: np.ndarray, slip: np.ndarray | None) -> None:
        """Keep each armed contact's mode, ``y_n`` and (unless None) slip direction (k, 2) for the next solves."""
        nodes, k = self._nodes, len(self._nodes)
        self._stick[nodes], self._normal[nodes] = stick[:k], normal[:k]
        if slip is not None:
            self._slip[nodes] = slip[:k]
        if self._pairs is None:
            return
        for c, key in enumerate(self._pairs.keys.tolist(), start=k):
            old = self._pair_memory.get(key, (False, 0.0, np.zeros(3)))[2]
            world = old if slip is None else slip[c] @ self._frames[3][c]
            self._pair_memory[key] = (bool(stick[c]), float(normal[c]), world)

    def commit(self) -> None:
        """Add the last solve's contact impulses to the step's (the method keeps that solve)."""
        if self.last is None:
            return
        impulses, nodes, k = self.last, self._nodes, len(self._nodes)
        self.ground.impulses[nodes] += impulses[:k]
        if self._pairs is not None:
            friction = np.einsum("ki,kid->kd", impulses[k:, :2], self._frames[3][k:])
            n_members = self.ground.system.n_members
            for c, key in enumerate(self._pairs.keys.tolist()):
                pair = (key // n_members, key % n_members)
                normal, tangential = self.ground.pair_impulses.get(pair, (0.0, np.zeros(3)))
                self.ground.pair_impulses[pair] = (normal + float(impulses[k + c, 2]), tangential + friction[c])
        self.last = None

    def solve(self, v0: np.ndarray, rows: Rows, warm: np.ndarray | None = None):
        """``v`` (n_free, 3) m/s and the multipliers (len(rows),) N*s of ``rows``, with the armed contacts.

        With :attr:`resume` set (the inextensible method sets it for a step after one whose modes cycled:
        ``InextensibleMethod._step_impl``), the Newton method from its last answer comes first, taken where it
        meets the law and the rows to the fixed point's own tolerance (``_newton(..., resume=True)``): the body
        still rocks on the same contacts, the solution moved little, and the modes would most likely cycle
        again. Measured (issue 47, ``bench/roll_cost.py``, the inextensible roll of ``examples/roll.yaml``): 55 of
        the 74 steps whose modes cycled followed one that did, each paying ~90 mode QPs before Newton."""
        self.last = None
        if not self.armed:
            return self.inner.solve(v0, rows, warm)
        if self.resume and self.answer is not None and self.answer[0] == self._structure(rows):
            found = self._newton(v0, rows, warm, resume=True)
            if found is not None:
                return found
        found = self._settle(v0, rows, warm)
        if found is None:
            found = self._jammed(v0, rows, warm)
        if found is None:
            # the modes cycled: once more with the method's targets at the pure velocity level (a drift
            # correction that only sliding could meet is what makes them cycle on a locked structure),
            # then the whole problem by the semismooth Newton method
            rows = _velocity_level(rows)
            found = self._settle(v0, rows, warm)
        if found is None:
            self.cycled += 1
            found = self._newton(v0, rows, warm)
        return found

    def _settle(self, v0, rows, warm):
        """The mode fixed point from the modes the contacts remember: the compiled kernel's answer
        (:meth:`_modes_compiled`), else the reference's (:meth:`_modes`: what the kernel answers, and what it
        leaves to it); None where the modes do not settle. Modes that the kernel found cycling (every QP
        answered) are not solved again by the reference, whose QPs are the same to the bit and cycle the same
        way: the kernel's last iterate is the Newton method's start (``_guess``), as the reference's would be.
        Measured (issue 47, the inextensible roll of ``examples/roll.yaml``, 3,000 steps): 134 of the
        friction solves of its Python path cycled, and their reference reruns took 2.2 of its 9.4 s."""
        if self.compiled and self._frames is None and isinstance(self.inner, DaqpSolver) and self.inner.verify:
            found = self._modes_compiled(v0, rows, warm)
            if found is not None:
                return None if found is _CYCLED else found
        return self._modes(v0, rows, warm)

    def _jammed(self, v0, rows, warm):
        """:meth:`_settle` again with every ground contact that carried load in its last solve starting to
        stick, where one of them started sliding; None if there is none, or the modes do not settle from there
        either, or a QP fails (the contacts' memory is then as it was). A sliding contact can have no fixed
        point: its friction may press its node into the ground harder than it lets it slide (the robot jams, as
        in Painlevé's paradox), and then only sticking answers. Measured (issue 47, ``bench_throws.py`` throw
        6046, superball at mu = 1.41, copy 3): a node sliding at 0.83 m/s, whose normal impulse grows by 1.1
        times the friction's (``mu y_n = 0.055 + 1.098 a`` N*s for a friction ``a``: no ``a >= 0`` meets it),
        the modes' 30 QPs wandered, the Newton method's answer missed a cable's row by 5.4e-4 m/s; sticking,
        its friction 3.78 N*s inside the disc's 4.37, it is answered by one QP."""
        nodes = self._nodes
        stick, loaded = self._stick[nodes].copy(), self._normal[nodes] > 0
        if not (loaded & ~stick & (self._mu[:len(nodes)] > 0)).any():
            return None
        self._stick[nodes] = stick | loaded
        try:
            found = self._settle(v0, rows, warm)
        except QPError:   # (a QP the sticking rows make fail: throw 5944's DAQP cycling on three of them)
            found = None
        if found is None:
            self._stick[nodes] = stick
        return found

    def _modes_compiled(self, v0, rows, warm):
        """:meth:`_modes` for ground contacts in one kernel call (``_friction_kernels.ground_modes``: the
        same QPs through DAQP's C function, the same mode changes and acceleration); None where the kernel
        leaves the solve to :meth:`_modes` (a QP refused, an answer off the Coulomb law), :data:`_CYCLED` where
        the modes do not settle in ``MAX_MODE_ITER`` QPs, every one answered (:meth:`_modes` would return None:
        its last iterate is kept in ``_guess`` as that method keeps it)."""
        old_stick, old_normal, old_slip = self._recall()
        given = warm is not None
        ok, v, y, impulses, remember, slip, its, guess_y, guess_f = kernels.ground_modes(
            *self.inner.c_call, v0, rows.nodes, rows.directions, rows.targets, rows.n_eq,
            warm if given else np.zeros(len(rows), dtype=bool), given, self._fi, self._targets,
            np.asarray(self._touching, dtype=bool), self._mu, old_stick, old_normal, old_slip, FIXED_POINT_TOL,
            _SLIP_FLOOR, MAX_MODE_ITER, _ANDERSON_DEPTH, _FEASIBILITY_TOL, _VELOCITY_FLOOR)
        if not ok:
            if its <= MAX_MODE_ITER:
                return None
            self._guess = (guess_y, guess_f)
            return _CYCLED
        self.iterations = its
        self._remember(remember, impulses[:, 2], slip)
        self.last = impulses
        return v, y

    def _modes(self, v0, rows, warm):
        """The mode fixed point (module docstring): ``(v, y)`` as :meth:`solve` returns them, or None if
        the modes do not settle in ``MAX_MODE_ITER`` QPs."""
        k = len(self._targets)
        mass, mu = self._meff, self._mu
        self._guess = None
        scale_v = max(float(np.max(np.abs(v0), initial=0.0)), float(np.max(np.abs(self._targets), initial=0.0)))
        # the initial modes: what each contact did in the last solve; a node arriving on the ground sticks if
        # it is not moving along it, else slides along its free tangential velocity with no friction yet
        u0 = self._velocity(v0)
        vt0 = self._tangential(u0)
        speed0 = np.sqrt(np.einsum("ij,ij->i", vt0, vt0))
        slip_tol = _SLIP_FLOOR + FIXED_POINT_TOL * scale_v
        old_stick, old_normal, old_slip = self._recall()
        known = old_normal > 0
        stick = np.where(known, old_stick, self._touching & (speed0 <= slip_tol))
        slip = np.where(known[:, None], old_slip, vt0 / np.maximum(speed0, 1e-300)[:, None])
        y_hat = np.where(known, old_normal, 0.0)
        stick &= mu > 0
        # a sliding contact's friction is -phi, phi = mu y_hat d (k, 2): the fixed point's unknown
        phi = (mu * y_hat)[:, None] * slip
        history: list[tuple[np.ndarray, np.ndarray]] = []   # Anderson: (phi, G(phi)) while no mode changes
        n_rows = len(rows)
        for it in range(1, MAX_MODE_ITER + 1):
            s = np.flatnonzero(stick)
            sliding = ~stick
            friction = np.zeros((k, 3))
            friction[sliding, :2] = -phi[sliding]
            try:
                v, y, yn, stick_f = self._qp(v0, rows, warm, friction, s, y_hat > 0)
            except QPError as exc:
                if exc.status != "infeasible" or not len(s):
                    raise
                # no velocity meets these sticking rows with the targets, even at the velocity level (an
                # impact lifting a body that three sticking contacts pin): the Newton method, which has no
                # sticking rows, takes the problem from the last iterate
                return None
            impulse_scale = max(float(np.max(mass * np.abs(u0).max(axis=1), initial=0.0)),
                                float(np.max(np.abs(y), initial=0.0)), 1e-300)
            tol = FIXED_POINT_TOL * impulse_scale
            friction[s, :2] = stick_f
            self._guess = (y[:n_rows + k], friction[:, :2].copy())
            vt = self._tangential(self._velocity(v))
            speed = np.sqrt(np.einsum("ij,ij->i", vt, vt))
            slip_tol = _SLIP_FLOOR + FIXED_POINT_TOL * max(scale_v, float(np.max(np.abs(v), initial=0.0)))
            y_hat = yn.copy()
            changed = False
            # sticking contacts outside the cone slide, opposite to their friction
            f_mag = np.sqrt(np.einsum("ij,ij->i", stick_f, stick_f))
            excess = f_mag - mu[s] * yn[s]
            # one mode change per solve, the worst first: releasing every overloaded contact at once can
            # cycle (they all slide, all turn back, all stick again)
            out = (excess > tol) & (excess == excess.max(initial=0.0))
            if out.any():
                changed = True
                slip[s[out]] = -stick_f[out] / f_mag[out, None]
                phi[s[out]] = (mu[s[out]] * yn[s[out]])[:, None] * slip[s[out]]
                stick[s[out]] = False
            # sliding contacts that carry load and turned back stick; one that stopped is consistent as it is
            # (at rest on the edge of the disc: with rows that depend on each other, such as a rigid strut's
            # and its two ends' sticking rows, the backend may share the friction unevenly between them)
            sl = np.flatnonzero(sliding)
            along = np.einsum("ij,ij->i", vt[sl], slip[sl])
            stops = (mu[sl] > 0) & (yn[sl] > tol) & (speed[sl] > slip_tol) & (along < 0)
            if changed:
                stops[:] = False
            elif stops.any():
                stops &= along == along[stops].min()
            if stops.any():
                changed = True
                stick[sl[stops]] = True
            moving = sl[~stops]
            new_slip = np.where((speed[moving] > slip_tol)[:, None],
                                vt[moving] / np.maximum(speed[moving], 1e-300)[:, None], slip[moving])
            target = (mu[moving] * yn[moving])[:, None] * new_slip      # G(phi) on the moving contacts
            drift = float(np.max(np.abs(target - phi[moving]), initial=0.0))
            if not changed and drift <= tol:
                self.iterations = it
                if not self._accepted(yn, friction, vt, tol, v0, y):
                    return None   # beyond the physical tolerance: the Newton method takes the problem
                # the next solve starts from these modes; a contact at rest starts sticking
                self._remember(stick | (speed <= slip_tol), yn, slip)
                impulses = friction.copy()
                impulses[:, 2] = yn
                self.last = impulses
                return v, y[:n_rows]
            slip[moving] = new_slip
            # Anderson acceleration of phi -> G(phi) while the modes stay (the coupled contacts of a locked
            # structure make the plain iteration converge linearly, at rate ~0.5 with alternating sign)
            if changed:
                history = []
                phi[moving] = target
                continue
            key = (moving.tobytes(), sl.tobytes())
            history = ([h for h in history if h[2] == key][-_ANDERSON_DEPTH:]
                       + [(phi[moving].ravel(), target.ravel(), key)])
            phi[moving] = target
            if len(history) > 1:
                x = np.array([h[0] for h in history])
                g = np.array([h[1] for h in history])
                f = g - x
                df, dg = np.diff(f, axis=0), np.diff(g, axis=0)
                gamma = np.linalg.lstsq(df.T, f[-1], rcond=None)[0]
                phi[moving] = (g[-1] - gamma @ dg).reshape(-1, 2)
        return None

    def _qp(self, v0, rows, warm, friction, s, loaded):
        """One QP: the method's ``rows``, a normal row per armed contact and four tangential rows per
        sticking contact ``s``, the known impulses ``friction`` (k, 3) (tangential components first) added
        to ``v0``. ``loaded``: (k,) contacts believed to carry load (a warm start). Returns ``v``, all
        multipliers, the normal impulses (k,) and the sticking rows' friction (len(s), 2), N*s."""
        k, n_rows = len(self._targets), len(rows)
        v0c, all_rows = self._with_contacts(v0, rows, friction, s)
        c_warm = np.concatenate([loaded, np.zeros(4 * len(s), dtype=bool)])
        all_warm = None if warm is None else np.concatenate([warm, c_warm])
        if all_warm is not None and len(s) and self._frames is None and isinstance(self.inner, DaqpSolver):
            # the contacts that stick held by their t and -t rows as sign-free pairs, the set of the last answer
            # (ground_modes tries it too): a resting body's QP without DAQP's factorisation of its ~45 rows
            guess, opposite = kernels.sticking_rows(all_warm, n_rows + k, len(s))
            found, v, y = daqp_kernels.solve_pairs(self.inner.c_call[1], self.inner.mass, all_rows.nodes,
                                                   all_rows.directions, v0c, all_rows.targets, all_rows.n_eq,
                                                   guess, opposite)
            if found:
                v = v.reshape(-1, 3)
                self.inner._check(v, y, v0c, all_rows)
                return self._split((v, y), n_rows, k)
        # with sticking contacts, DAQP alone first: its "infeasible" is answered below before any other backend
        alone = len(s) > 0 and isinstance(self.inner, DaqpSolver)
        try:
            v, y = (self.inner._solve_checked if alone else self.inner.solve)(v0c, all_rows, all_warm)
        except QPError as exc:
            if exc.status != "infeasible" or not len(s):
                if not alone:
                    raise
                return self._split(self.inner.solve(v0c, all_rows, all_warm), n_rows, k)   # restarts, fallbacks
            # sticking contacts hold a locked structure still (three of them fix a rigid body), and
            # v = 0 may then miss a cable's or strut's drift-correcting target: for this solve the
            # targets yield (pure velocity level, which v = 0 meets); the drift stays as it is. Measured
            # (issue 47): the inextensible icosahedron resting on the ground, from 8.7 s on every other
            # step's QP (targets of 1.3e-12 m/s, DAQP's primal_tol) was infeasible to DAQP, and NNLS, the
            # backend's fallback, answered it by the Python path: 3.4 ms a step where the step kernel takes 30 us
            all_rows.targets[:n_rows] = _velocity_level(rows).targets
            v, y = self.inner.solve(v0c, all_rows, all_warm)
        return self._split((v, y), n_rows, k)

    @staticmethod
    def _split(answer, n_rows: int, k: int):
        """A mode QP's answer ``(v, y)`` as :meth:`_qp` returns it: ``v``, all multipliers, the normal impulses
        (k,) and the sticking rows' friction (len(s), 2), N*s."""
        v, y = answer
        yt = y[n_rows + k:].reshape(-1, 4)
        return v, y, y[n_rows: n_rows + k], -(yt[:, :2] - yt[:, 2:])

    def _with_contacts(self, v0, rows, friction, s):
        """The QP of one mode iterate: ``v0`` with the known impulses ``friction`` (k, 3) added, and the
        method's ``rows`` followed by a normal row per armed contact (``-n . u <= -w``) and four
        tangential rows ``t1, t2, -t1, -t2`` per sticking contact ``s``. Returns ``(v0c, rows)``."""
        k, n_rows, n_eq = len(self._targets), len(rows), rows.n_eq
        c_targets = np.concatenate([-self._targets, np.zeros(4 * len(s))])
        if self._frames is None:   # ground contacts only: member rows, a fixed end and the node
            fi = self._fi
            if not self.inner.diagonal:   # M^-1 has cross entries (rods' blocks, cable plates)
                push = np.zeros_like(v0)
                np.add.at(push, fi, friction)
                v0c = v0 + self.inner.inverse(push.reshape(-1)).reshape(-1, 3)
            else:
                v0c = v0.copy()
                np.add.at(v0c, fi, friction / self._meff[:, None])
            tang_nodes = np.repeat(fi[s], 4)
            tang_dirs = np.tile(np.vstack([_TANGENTS, -_TANGENTS]), (len(s), 1))
            c_nodes = np.concatenate([fi, tang_nodes])
            c_dirs = np.vstack([np.tile(-_UP, (k, 1)), tang_dirs])
            all_rows = Rows(np.vstack([rows.nodes, np.stack([np.full(len(c_nodes), -1), c_nodes], axis=1)]),
                            np.vstack([rows.directions, c_dirs]), np.concatenate([rows.targets, c_targets]), n_eq)
        else:   # general rows: the method's as (-1, 1, 0, 0), each contact's on its four nodes
            c_nodes, weights, normals, tang = self._frames
            impulse = np.einsum("ki,kid->kd", friction[:, :2], tang)   # the friction in space, (k, 3)
            if not self.inner.diagonal:   # M^-1 has cross entries (rods' blocks, cable plates)
                push = np.zeros((len(v0) + 1, 3))
                np.add.at(push, c_nodes, weights[:, :, None] * impulse[:, None, :])
                v0c = v0 + self.inner.inverse(push[:-1].reshape(-1)).reshape(-1, 3)
            else:
                scaled = np.append(1.0 / self._mass, 0.0)[c_nodes] * weights
                change = np.zeros((len(v0) + 1, 3))
                np.add.at(change, c_nodes, scaled[:, :, None] * impulse[:, None, :])
                v0c = v0 + change[:-1]
            sides = np.concatenate([tang, -tang], axis=1)[s].reshape(-1, 3)   # t1, t2, -t1, -t2 per contact
            nodes4 = np.vstack([np.pad(rows.nodes, ((0, 0), (0, 2)), constant_values=-1), c_nodes,
                                np.repeat(c_nodes[s], 4, axis=0)])
            w4 = np.vstack([np.tile([-1.0, 1.0, 0.0, 0.0], (n_rows, 1)), weights, np.repeat(weights[s], 4, axis=0)])
            all_rows = Rows(nodes4, np.vstack([rows.directions, -normals, sides]),
                            np.concatenate([rows.targets, c_targets]), n_eq, w4)
        return v0c, all_rows

    def _structure(self, rows: Rows) -> tuple:
        """The structure of the Newton method's problem with ``rows``: the armed contacts and the method's rows
        (its members, equalities first). An answer to the same structure is a start of the same size and meaning
        (:attr:`answer`)."""
        return (self._nodes.tobytes(), b"" if self._pairs is None else self._pairs.keys.tobytes(),
                rows.nodes.tobytes(), rows.n_eq, len(rows))

    def _newton(self, v0, rows, warm, resume=False):
        """The frictional problem when the modes cycle: all of it at once (the method's ``rows``, the
        contacts' normal rows and the friction disc) as the Alart–Curnier equation ``Phi(r) = 0`` in the
        impulses ``r = (y, f)`` (``y``: the QP's multipliers, method rows then normal rows; ``f`` (k, 2)
        the friction), solved by a semismooth Newton method with an Armijo line search on ``|Phi|^2 / 2``
        (Alart & Curnier 1991; Siconos' ``fc3d_nonsmooth_Newton_AlartCurnier``)::

            equality row i:    rho_i (u_i - r_i)
            inequality row i:  y_i - max(0, y_i + rho_i (u_i - r_i))
            contact c:         f_c - proj_disc(mu_c s_c+)(f_c - rho_c v_t,c),  s_c = y_n,c + rho_n,c (u_n,c - r_n,c)

        with ``u = A v`` the rows' rates, ``v = v0 + M^-1 (-A^T y + T^T f)`` and ``rho`` each row's effective
        mass ``1 / (A M^-1 A^T)_ii`` (the scale that makes every entry an impulse, N*s). The equation is
        piecewise affine in ``r``: Newton stops once it has found the pieces, in a few iterations, where the
        modes' one change per QP can cycle between them. The Jacobian is singular where rows depend on each
        other (a locked structure's self-stress, a rigid strut lying on the ground): its least-squares
        step is taken, the impulses along the dependent directions being whatever the last iterate had.
        The answer is checked as the QPs' are: by the backend's optimality check of the QP with the
        friction as a known impulse, and by the Coulomb law's projection form (:meth:`_verify`).
        Newton is globalised by its line search, Levenberg–Marquardt steps where the Newton step does not
        descend, and further starts where it stops at a local minimum of the merit: from its last answer to a
        problem of the same structure (:attr:`answer`), from zero, from NSGS sweeps of the same fixed point, along
        the friction coefficients from the frictionless problem's solution (``continued``), from the solution of
        the problem with polygons for discs (:func:`_polyhedral_start`), then from seeded random impulses (see
        below). Returns ``(v, y)`` as
        :meth:`solve` does; raises :class:`FrictionError` naming the contacts whose law is unmet if no
        start reaches an answer that meets it. ``resume``: from the last answer (to a problem of the same
        :meth:`_structure`) alone, None where that is no answer (:meth:`solve`'s :attr:`resume`)."""
        k, n_rows, mass, mu = len(self._targets), len(rows), self._meff, self._mu
        n_qp = n_rows + k                                   # method rows, then one normal row per contact
        every = np.arange(k)
        v0_free, all_rows = self._with_contacts(v0, rows, np.zeros((k, 3)), every)
        dense = all_rows.dense(self.inner.n_free)
        qp_rows = dense[:n_qp]
        tang = dense[n_qp:].reshape(k, 4, -1)[:, :2].reshape(2 * k, -1)   # t1, t2 of each contact
        rates = np.vstack([qp_rows, tang])                  # u = rates @ v
        push = np.vstack([-qp_rows, tang])                  # v = v0 + M^-1 push^T r
        delassus = rates @ self.inner.inverse(push.T)
        rho = 1.0 / np.maximum(np.abs(np.diag(delassus)), 1e-300)
        targets = np.concatenate([all_rows.targets[:n_qp], np.zeros(2 * k)])
        free_rates = rates @ v0_free.ravel() - targets      # u - r at r = 0
        n_eq = all_rows.n_eq
        problem = self._structure(rows)
        ineq = np.arange(n_eq, n_qp)
        t_index = n_qp + 2 * every[:, None] + np.arange(2)  # (k, 2) positions of f in r
        u0 = self._velocity(v0)
        impulse_scale = max(float(np.max(mass * np.abs(u0).max(axis=1), initial=0.0)), 1e-300)

        compiled = self.compiled and all(np.isfinite(a).all() for a in (delassus, free_rates, rho))
        ac, nd = (newton_kernels.alart_curnier, newton_kernels.newton_descend) if compiled else (alart_curnier,
                                                                                               newton_descend)

        def equation(r, mu=mu):
            """Phi(r) (n,) and its generalised Jacobian (n, n), with the friction coefficients ``mu`` (k,)."""
            return ac(r, mu, free_rates, delassus, rho, n_eq, n_rows, k)

        def descend(r, mu=mu, iterations=MAX_NEWTON_ITER):
            """Newton from ``r`` until ``|Phi|`` (friction coefficients ``mu``) is within tolerance or stops
            falling, in at most ``iterations``: ``r``, its iterations."""
            return nd(r, mu, iterations, free_rates, delassus, rho, n_eq, n_rows, k, FIXED_POINT_TOL, impulse_scale,
                      _LINE_SEARCH, _LM_DAMPINGS)

        def tolerance(r) -> float:
            """N*s: the law's tolerance at impulses ``r``, relative to the larger of them and the contacts' scale."""
            return FIXED_POINT_TOL * max(impulse_scale, float(np.max(np.abs(r), initial=0.0)))

        def within(r, phi) -> bool:
            """Whether ``Phi(r)``, ``phi``, is within Newton's tolerance."""
            return float(np.max(np.abs(phi), initial=0.0)) <= 0.1 * tolerance(r)

        best = [np.inf, None]   # the start whose answer came nearest the law: its miss, its impulses

        def solved(r):
            miss = float(np.max(np.abs(equation(r)[0]), initial=0.0)) / (0.1 * tolerance(r))
            if miss < best[0]:
                best[:] = miss, r.copy()
            return miss <= 1.0

        def continued():
            """Newton along the friction coefficients ``t mu``, t from 0 to 1: from no impulse at ``t = 0`` (no
            friction: the rows' and normals' convex problem), each solution the next ``t``'s start, the step in
            ``t`` grown by half where Newton answered in :data:`_CONTINUATION_ITER` iterations, halved where
            not. Returns the solution at ``t = 1``, or the last iterate where the step falls below
            :data:`_CONTINUATION_MIN` (the caller checks it); and the Newton iterations taken."""
            r, its = descend(np.zeros(n_qp + 2 * k), 0.0 * mu)
            if not within(r, equation(r, 0.0 * mu)[0]):
                return r, its
            t, step = 0.0, _CONTINUATION_STEP
            while t < 1.0 and step >= _CONTINUATION_MIN:
                nearer = min(1.0, t + step)
                trial, taken = descend(r.copy(), nearer * mu, _CONTINUATION_ITER)
                its += taken
                if within(trial, equation(trial, nearer * mu)[0]):
                    r, t, step = trial, nearer, 1.5 * step
                else:
                    step *= 0.5
            return r, its

        def sweep(r):
            """One projected Gauss–Seidel sweep (NSGS) of the same fixed point, row by row and contact by
            contact (its normal, then its friction in the disc): ``r`` updated in place."""
            for i in range(n_qp):
                new = r[i] + rho[i] * (free_rates[i] + delassus[i] @ r)
                r[i] = new if i < n_eq else max(new, 0.0)
            for c in range(k):
                t = t_index[c]
                trial = r[t] - rho[t] * (free_rates[t] + delassus[t] @ r)
                size, bound = float(np.hypot(*trial)), mu[c] * r[n_rows + c]
                r[t] = trial * (bound / size) if size > bound else trial

        def drift(r):
            """NSGS with steps along the Delassus matrix's null space, from ``r`` (an NSGS iterate: its friction
            in the discs, its inequality rows' impulses >= 0): where the rows depend on each other (a rod lying on
            the ground on both ends: its length row and its ends' friction along it), a direction of impulses
            changes no velocity, and the solution may lie far along it, where one end's friction reaches its
            disc's edge (at rest on it). NSGS drifts there at a constant rate per sweep (measured on such a rod of
            ``three_bar``: 1e5 sweeps); after each round of :data:`_DRIFT_SWEEPS` sweeps the last sweep's change,
            projected on the null space, is taken as far as the first disc edge or impulse sign it meets. Returns
            the last iterate (solved or not: the caller checks)."""
            if not np.isfinite(delassus).all():   # (the check after names what is not finite)
                return r
            _, size, vh = np.linalg.svd(delassus)
            null = vh[size <= 1e-12 * size.max(initial=0.0)].T
            for _ in range(_DRIFT_ROUNDS):
                for _ in range(_DRIFT_SWEEPS):
                    previous = r.copy()
                    sweep(r)
                if solved(r) or not null.shape[1] or not np.isfinite(r).all():
                    return r
                d = null @ (null.T @ (r - previous))
                step = np.inf
                shrinking = d[ineq] < 0.0   # inequality rows' impulses stay >= 0
                if shrinking.any():
                    step = float(np.min(-r[ineq][shrinking] / d[ineq][shrinking]))
                for c in range(k):   # |f + t df|^2 <= mu^2 (y + t dy)^2: the first root past 0 of the quadratic
                    y, dy, f, df = r[n_rows + c], d[n_rows + c], r[t_index[c]], d[t_index[c]]
                    roots = np.roots([df @ df - (mu[c] * dy) ** 2, 2.0 * (f @ df - mu[c] ** 2 * y * dy),
                                      f @ f - (mu[c] * y) ** 2])
                    ahead = roots[(np.abs(roots.imag) <= 1e-12 * np.abs(roots)) & (roots.real > 0.0)].real
                    step = min(step, float(ahead.min(initial=np.inf)))
                if np.isfinite(step):
                    r += step * d
            return r

        def answer(r):
            """The impulses ``r``'s answer: ``y``, ``f`` (k, 2), the contacts' impulses (k, 3) without the normal,
            ``v`` and the contacts' tangential velocities."""
            y = r[:n_qp].copy()
            y[n_eq:] = np.maximum(y[n_eq:], 0.0)                 # the clipped round-off of released rows
            f = r[n_qp:].reshape(k, 2)
            applied = np.zeros((k, 3))
            applied[:, :2] = f
            v = (v0_free.ravel() + self.inner.inverse(push.T @ np.concatenate([y, f.ravel()]))).reshape(-1, 3)
            return y, f, applied, v, self._tangential(self._velocity(v))

        def acceptable(r) -> bool:
            """Whether ``r`` (None: no start yet) would be accepted at the end (the Coulomb law and the rows to
            the physical tolerance): the further starts, which can only find a closer answer, are skipped.
            Measured (issue 47, prism3 set down, ``bench_throws.py`` throw 3): 16 Newton solves of 60 steps took
            400 s through every start, their answers accepted to the physical tolerance in the end."""
            if r is None:
                return False
            y, _, applied, v, vt = answer(r)
            try:
                self._verify(y[n_rows:], applied, vt, mass, self._physical_tol(v0, r))
            except FrictionError:
                return False
            v0c, _ = self._with_contacts(v0, rows, applied, every[:0])
            return self._rows_within(v, y, v0c, all_rows.subset(np.arange(n_qp), all_rows.targets[:n_qp], n_eq),
                                     v0, r)

        def from_last_answer():
            """Newton from the last answer alone (``resume``: one to a problem of this structure, :meth:`solve`
            checks): its answer where it meets the law and the rows to the fixed point's own tolerance, else None
            (the caller solves the problem from its modes)."""
            r, it = descend(self.answer[1].copy())
            if not solved(r):
                return None
            y, _, applied, v, vt = answer(r)   # (accepted as the modes' answers are: no physical tolerance)
            tol = tolerance(r)
            try:
                self._verify(y[n_rows:], applied, vt, mass, tol)
                v0c, _ = self._with_contacts(v0, rows, applied, every[:0])
                self.inner._check(v, y, v0c, all_rows.subset(np.arange(n_qp), all_rows.targets[:n_qp], n_eq))
            except QPError:
                return None
            self.iterations = it
            self._keep(v0, v, vt, applied, y[n_rows:], tol)
            self.answer = (problem, r.copy())
            self.resumed += 1
            return v, y[:n_rows]

        def polish(r):
            """:meth:`_polish` of the answer of ``r``."""
            y, _, applied, _, _ = answer(r)
            return self._polish(v0, rows, warm, applied, y[n_rows:] > 0, tolerance(r))

        # from the modes' last iterate (its multipliers and friction). Where that ends at a local minimum of
        # the merit that is no solution (Alart–Curnier's has some), Newton again from NSGS sweeps, which
        # approach the solution of a well-conditioned problem (measured: a locked icosahedron on one node at
        # mu = 1.7, where 33 Newton starts failed, was solved by Newton after 100 sweeps, one on a face at
        # mu = 1.6, whose Delassus matrix has condition 240, after 1000, NSGS alone after 5000); where they stall
        # too (with mu > 1 a cable pulling harder on a node can press it harder on the ground, so the nearest
        # solution may be far along a branch neither sees), from seeded random impulses of the problem's
        # scale: measured on such a problem (prism3 thrown at mu = 1.6), 37 of 200 starts reach a solution
        if resume:
            return from_last_answer()
        r = np.zeros(n_qp + 2 * k)
        if self._guess is not None:
            r[:n_qp], r[n_qp:] = self._guess[0], self._guess[1].ravel()
        scale = max(impulse_scale, float(np.max(np.abs(r), initial=0.0)))
        r, it = descend(r)
        chains = [r]   # the Newton iterates the NSGS sweeps go on from, the nearer first
        if self.answer is not None and self.answer[0] == problem and not (solved(r) or acceptable(best[1])):
            # from the impulses of the last answer to a problem of the same structure (a body resting on the same
            # contacts a step earlier): the solution moved little, and it lies along the same directions of the
            # rows' (near) null space, which Newton from the other starts crawls along. Measured (issue 47,
            # bench_throws.py throw 15991: three_bar set down at mu = 1.53 on three nodes, rows of rank 18 of 20
            # and a singular value 6.1e-5 of 65, one node at rest on its disc's edge): at step 88 Newton's damped
            # steps (1/64 of the Newton step) crawled from the modes' iterate to |Phi| 3e-6 N*s in 100 iterations
            # and from zero's to the law in 94 of its 100 (in main's benchmark run, its round-off a little
            # otherwise, in none: the step stopped); from step 87's answer it is solved in 1 iteration. Tried before
            # zero's: it is the nearer start
            again, its = descend(self.answer[1].copy())
            it += its
            if solved(again):
                r = again
                self.resumed += 1
        if self._guess is not None and not (solved(r) or acceptable(best[1])):
            # from no impulse: the modes' iterate can lie in another piece of the equation, and there Newton
            # stops at a local minimum. Measured (issue 47, bench_throws.py throw 5944: three_bar set down at
            # mu = 1.35 on three nodes, its struts' blocks): from the cycled modes' iterate every start missed the
            # law by 2.1e-7 N*s (after 6900 iterations, 11 s); from zero it is solved in 49 iterations, and 6
            # steps later, from zero and its NSGS sweeps
            zero, its = descend(np.zeros_like(r))
            it += its
            chains = [zero, r] if np.max(np.abs(equation(zero)[0])) < np.max(np.abs(equation(r)[0])) else [r, zero]
            r = chains[0]
        # NSGS sweeps, then Newton, from both iterates in turn: which of the two stalled nearer the solution says
        # little of which piece it lies in. Measured (issue 47, bench_throws.py throw 12549: three_bar set down at
        # mu = 1.58, its rows of rank 18 of 20 and a singular value 7.6e-5 of 65): Newton stalled with |Phi| at
        # 1.1e-5 N*s from the modes' iterate, 2.4e-5 from zero, and every further start went on from the first
        # (7000 iterations, 20 s, the best answer 3.5e-7 N*s off the law: the step stopped); from zero's iterate
        # 100 sweeps and Newton solve it (0.4 s)
        swept = [c.copy() for c in chains[:_CHAINS]]
        for sweeps in _NSGS_SWEEPS:
            for chain in swept:
                if solved(r) or acceptable(best[1]):
                    break
                for _ in range(sweeps):
                    sweep(chain)
                r, its = descend(chain.copy())
                it += its
        if not (solved(r) or acceptable(best[1])):
            # continued from the frictionless problem (``continued``): with mu > 1 the solution can move far from
            # every start above as the friction grows (a cable pulling a node sideways presses it into the ground
            # through its friction), and Newton from them stops at a local minimum of the merit; along t mu each
            # start is near its solution. Measured (issue 47, bench_throws.py throw 22448: superball resting on
            # three nodes at mu = 1.46 as cables are let out, 36 unknowns, a singular value 8.1e-4 of 6.3): every
            # other start missed the law by 1.4e-5 N*s after 8100 iterations; along t mu the normal impulses
            # grow from 0.017 to 0.065 N*s, all three nodes sliding, and ~10 steps of t reach it in 0.2 s
            r, its = continued()
            it += its
        if not (solved(r) or acceptable(best[1])):
            # from the polyhedral cone's solution (:func:`_polyhedral_start`), which exists for any mu: where the
            # rows depend on each other nearly (a singular value 1e-6 of the Delassus matrix's largest), the
            # solution can lie where neither Newton nor the sweeps go. Measured (issue 47, bench_throws.py throw
            # 20455: three_bar resting on three nodes at mu = 1.45 as a cable is let out, 20 rows on 18 degrees
            # of freedom, a singular value 6.1e-5 of 65): 7400 iterations from every other start missed the law
            # by 4.3e-7 N*s; the polygon's solution has one node sliding at 1.3e-4 m/s. A polygon's friction
            # meets the disc's law exactly where a sliding contact's edge points against its slip: each try turns
            # the polygons so (the problem's solutions are many: the next may slide another contact)
            turn = np.zeros(k)   # each polygon's first edge's angle to t1
            slip_tol = _SLIP_FLOOR + FIXED_POINT_TOL * float(np.max(np.abs(free_rates)))
            for _ in range(_CONE_TURNS):
                start = _polyhedral_start(delassus, free_rates, n_eq, n_rows, mu, scale, turn)
                if start is None:
                    break
                r, its = descend(start)
                it += its
                if solved(r) or acceptable(best[1]):
                    break
                slip = (free_rates + delassus @ start)[n_qp:].reshape(k, 2)
                turn = np.where(np.hypot(slip[:, 0], slip[:, 1]) > slip_tol, np.arctan2(-slip[:, 1], -slip[:, 0]),
                                turn)
        for seed in range(_RESTARTS):
            if solved(r) or acceptable(best[1]):
                break
            rng = np.random.default_rng(seed)
            start = np.abs(rng.normal(0.0, scale, len(r)))
            start[n_qp:] = rng.normal(0.0, scale, 2 * k)
            r, its = descend(start)
            it += its
        if not (solved(r) or acceptable(best[1])):   # from the nearer chain's last NSGS iterate: friction in discs
            r = drift(swept[0])
        if not solved(r) and best[1] is not None:   # (None: every miss NaN; the check below names it)
            r = best[1]
        y, _, applied, v, vt = answer(r)
        tol = tolerance(r)
        yn = y[n_rows:]
        self.iterations = MAX_MODE_ITER + it
        try:
            try:
                self._verify(yn, applied, vt, mass, tol)
            except FrictionError as exc:
                try:
                    self._verify(yn, applied, vt, mass, self._physical_tol(v0, r))
                except FrictionError:
                    raise FrictionError(self.name, "no solution",
                                        f"{exc.detail} after {MAX_MODE_ITER} mode QPs and {it} semismooth Newton "
                                        "iterations") from None
                self.relaxed += 1
            v0c, _ = self._with_contacts(v0, rows, applied, every[:0])
            self._check_rows(v, y, v0c, all_rows.subset(np.arange(n_qp), all_rows.targets[:n_qp], n_eq), v0, r)
        except QPError:
            polished = polish(r)
            if polished is None:
                raise
            return polished
        self._keep(v0, v, vt, applied, yn, tol)
        self.answer = (problem, r.copy())
        return v, y[:n_rows]

    def _keep(self, v0, v, vt, impulses, yn, tol) -> None:
        """An accepted answer of the Newton method or its polish: the contacts remember sticking where its
        friction ``impulses[:, :2]`` lies inside the disc by ``tol`` or its slip ``vt`` is round-off, and
        ``impulses`` with the normal impulses ``yn`` are :attr:`last`."""
        speed = np.sqrt(np.einsum("ij,ij->i", vt, vt))
        slip_tol = _SLIP_FLOOR + FIXED_POINT_TOL * max(float(np.max(np.abs(v0), initial=0.0)),
                                                       float(np.max(np.abs(v), initial=0.0)))
        size = np.sqrt(np.einsum("ij,ij->i", impulses[:, :2], impulses[:, :2]))
        self._remember((size < self._mu * yn - tol) | (speed <= slip_tol), yn, None)
        impulses[:, 2] = yn
        self.last = impulses

    def _polish(self, v0, rows, warm, friction, loaded, tol):
        """The Newton method's answer polished where it misses the law or the QP rows: its friction ``friction``
        (k, 3) (normal 0) a known impulse on the QP of the method's ``rows`` and the normal rows (its answer
        checked by the backend, so the rows are met), then the friction projected on its disc at that answer's
        slip, ``f <- proj_disc(mu y_n)(f - m v_t)``, and so on for up to :data:`_POLISH_QPS` QPs. Returns the
        first answer that meets the Coulomb law (:meth:`_accepted`, to ``2 tol`` or the physical tolerance) as
        :meth:`solve` does, else None. Measured (issue 47, ``bench_throws.py`` throw 5467: the locked superball
        set down at mu = 0.49, three nodes on the ground, whose Newton answer stays 1.7e-6 m/s off a cable's
        row, 1.9e-6 N*s in the heaviest node's mass against a tolerance of 1.3e-6): the first QP's answer
        misses the law by 1.8e-6 N*s, the second's by 1.2e-6, accepted."""
        n_rows = len(rows)
        friction = friction.copy()
        for _ in range(_POLISH_QPS):
            try:
                v, y, yn, _ = self._qp(v0, rows, warm, friction, np.zeros(0, dtype=int), loaded)
            except QPError:
                return None
            vt = self._tangential(self._velocity(v))
            if self._accepted(yn, friction, vt, tol, v0, y):
                self._keep(v0, v, vt, friction.copy(), yn, tol)
                return v, y[:n_rows]
            trial = friction[:, :2] - self._meff[:, None] * vt
            size = np.sqrt(np.einsum("ij,ij->i", trial, trial))
            friction[:, :2] = trial * np.minimum(1.0, self._mu * yn / np.maximum(size, 1e-300))[:, None]
        return None

    def _contact_names(self, contacts: np.ndarray) -> str:
        """The armed contacts ``contacts`` (indices) by name: a ground contact by its node, a member
        contact by its two members."""
        scene, k = self.ground.system.scene, len(self._nodes)
        members = [s.name for s in scene.struts] + list(scene.cable_names)
        names = []
        for c in np.asarray(contacts).tolist():
            if c < k:
                names.append(f"{scene.node_names[self._nodes[c]]!r} on the ground")
            else:
                key = int(self._pairs.keys[c - k])
                n_members = self.ground.system.n_members
                names.append(f"{members[key // n_members]!r} on {members[key % n_members]!r}")
        return ", ".join(names)

    def _physical_tol(self, v0, impulses) -> float:
        """Half the Coulomb residual (N*s) an answer may keep, :data:`ACCEPT_TOL` of the momentum in play:
        the free nodes' ``sum m_i |v0_i|`` (at rest, the structure's weight times the step), or the largest
        impulse ``impulses`` if larger. The contacts' own impulse scale, which the fixed point is held to,
        can be round-off small (a node touching down carries a sliver of the load: 1e-15 N*s tolerances)."""
        momentum = float(np.sum(self._mass * np.sqrt(np.einsum("ij,ij->i", v0, v0))))
        return 0.5 * ACCEPT_TOL * max(momentum, float(np.max(np.abs(impulses), initial=0.0)), 1e-300)

    def _check_rows(self, v, y, v0c, rows, v0, impulses) -> None:
        """The backend's optimality check of the Newton method's answer on the QP rows (the method's and
        the normal rows, the friction ``v0c`` added), else the same residuals to the physical tolerance:
        the impulses' balance and signs to :meth:`_physical_tol`, and a violated or not-landed acting row
        (m/s) times the heaviest node's mass (N*s) too; counted in :attr:`relaxed`. Measured (issue 47,
        ``bench/bench_throws.py --seed 1``, throw 16): an icosahedron set down at restitution 0.94, its
        answer's acting row 1.1e-8 m/s short of its target, refused at 1e-7 of its 0.019 m/s."""
        try:
            self.inner._check(v, y, v0c, rows)
            return
        except QPError as exc:
            if exc.status != "inaccurate output" and exc.status != "infeasible output":
                raise
            if not self._rows_within(v, y, v0c, rows, v0, impulses):
                raise
        self.relaxed += 1

    def _rows_within(self, v, y, v0c, rows, v0, impulses) -> bool:
        """Whether the answer meets the QP rows to the physical tolerance (:meth:`_check_rows`). A row whose
        impulse is within that tolerance of zero does not count as acting: within the tolerance it is a row
        without an impulse, which may then be anywhere short of its target. Measured (issue 47,
        ``bench_throws.py`` throw 19541): a superball set down, its answer's impulses at most 6.9e-6 N*s
        against a tolerance of 8.2e-6, one of them on a row 3.5e-5 m/s short of its target, stopped the run."""
        tol = 2.0 * self._physical_tol(v0, impulses)
        _, viol, _, stationarity, smallest, slack = self.inner._residuals_reference(v, y, v0c, rows, tol)
        heaviest = float(self._mass.max(initial=0.0))
        return not (stationarity > tol or smallest < -tol or heaviest * max(viol, slack) > tol)

    def _accepted(self, yn, friction, vt, tol, v0, y) -> bool:
        """Whether the modes' answer meets the Coulomb law: to ``2 tol`` (the fixed point's own scale), or
        else to the physical tolerance (:meth:`_physical_tol`, counted in :attr:`relaxed`)."""
        try:
            self._verify(yn, friction, vt, self._meff, tol)
            return True
        except FrictionError:
            pass
        try:
            self._verify(yn, friction, vt, self._meff, self._physical_tol(v0, y))
        except FrictionError:
            return False
        self.relaxed += 1
        return True

    def _verify(self, yn, friction, vt, mass, tol) -> None:
        """The Coulomb law at the answer, as the natural residual of its projection form (Alart–Curnier):
        ``f = proj_disc(mu y_n)(f - m v_t)`` holds exactly for a sticking contact (``v_t = 0``, ``f`` in
        the disc), a sliding one (``f = -mu y_n v_t/|v_t|``) and one at rest on the disc's edge, and
        for nothing else; each contact's residual must be within ``2 tol`` (N*s)."""
        f = friction[:, :2]
        trial = f - mass[:, None] * vt
        size = np.sqrt(np.einsum("ij,ij->i", trial, trial))
        projected = trial * np.minimum(1.0, self._mu * yn / np.maximum(size, 1e-300))[:, None]
        residual = np.sqrt(np.einsum("ij,ij->i", f - projected, f - projected))
        inside = np.sqrt(np.einsum("ij,ij->i", f, f)) <= self._mu * yn + 2.0 * tol
        bad = (residual > 2.0 * tol) | ~inside
        if bad.any():
            raise FrictionError(self.name, "inaccurate output",
                                f"contacts {self._contact_names(np.flatnonzero(bad))} miss the Coulomb law by up "
                                f"to {float(residual.max()):.3g} N*s (tolerance {2.0 * tol:.3g} N*s)")
