"""The ground contact of the elastic method in JAX: the velocity problem of ``methods/contact/friction.py``
(``ContactSet.velocity_step``: contact rows ``v_z >= w`` with exact Coulomb friction on the disc
``|f| <= mu y_n``, every rigid strut keeping its length) solved branch-free, so that it vectorises over
copies.

**Blocks.** The elastic method's cables are explicit, so the velocity problem couples nodes only through the
rigid struts, and a tensegrity's rigid struts share no node (the closed-form SHAKE needs that too): the problem
splits into one block per rigid strut (its length row, and for each of its two ends a normal row and two
friction unknowns: at most 7 unknowns) and one per free node on no rigid strut (a normal row and its
friction: closed form, ``y_n = m max(0, w - v_z)``, ``f = proj_disc(mu y_n)(-m v_t)``).

**The solve.** Nonsmooth block Gauss-Seidel (the ``NSGS`` of Moreau and Jean) with a fixed number of sweeps:
each sweep solves the length row exactly for the others fixed, then each end's normal row
(``y_n <- max(0, y_n + m (w - v_z))``) and its friction on the exact disc
(``f <- proj_disc(mu y_n)(f - m v_t)``), ``m`` the end's effective mass ``1 / d`` and its impulse moving it by
``d`` and the strut's other end by ``M^-1``'s cross entry (a rod's 2x2 mass block, physics.md section 4c: the
arithmetic of the numba kernels' ``solve_block``; lumped, ``d = 1 / m`` and no cross entry). Its fixed points are
exactly the solutions of the Coulomb problem (the numpy reference's mode fixed point finds the same velocities);
every update is a ``max`` or a projection (``jnp.where``), so the work is the same for every block and every copy.
The sweeps converge linearly, at a rate set by the angle between the strut and the ground (fastest lying flat;
a standing strut's length and normal rows share a node: rate ``a_e^2 / ((a_a + a_c) d_e)`` with the axial entries
``a = d - cross``, lumped ``m_a / (m_a + m_b)``): ``SWEEPS`` = 60 brings an end's velocity to round-off at rates up
to about 0.55, and a scene whose rods' blocks converge slower takes more (:func:`block_sweeps`: a uniform rod's
0.75, 125 sweeps; three_bar's 149). ``test/test_jax_ground.py`` measures the agreement with the reference and
the numba batch.

**Stopping at a tolerance** (``GroundModel.tolerance`` > 0, what ``fit`` uses): the sweeps start from the
previous step's impulses of the same solve (a warm start: a contact that persists changes its impulse little from
one step to the next) and stop once no velocity of any block and copy moved by more than ``tolerance`` (m/s) in a
sweep, ``GroundModel.sweeps`` at most. A warm start alone does not shorten them much (the rolling icosahedron's persistent
contacts still took about 32 sweeps at the rate above), so these sweeps also solve each end on the problem with
the strut's length row eliminated (its inverse mass ``1/m (I - c n n^T)``, ``c = (1/m) / w_rigid``): the length
row after each end, not once a sweep; the normal row's step that diagonal's inverse; friction's one scalar step
that contracts both its directions best; and where the end's exact sticking answer (the 3x3 solve, closed form by
Sherman-Morrison) lies in the disc, that answer. Every update is still a ``max``, a projection on the disc with a
positive scalar step, or an exact solve, so the fixed points are the same Coulomb solutions. A ``lax.while_loop``
differentiates in forward mode only (``jax.jvp``, ``jax.jacfwd``: the tangents follow the same sweeps), so the
default stays the fixed count, which ``jax.grad`` also differentiates.
A scene whose rods carry their 2x2 mass blocks takes the plain sweeps above in this mode (warm-started,
stopping at the tolerance): the eliminated problem's steps and sticking answer are derived for lumped ends.
"""
from __future__ import annotations

from dataclasses import field

import jax
import jax.numpy as jnp
import numpy as np

from ..contact.friction import TOUCH_TOL
from .elastic import _derived, _dot3, _index, _pytree

__all__ = ["GroundModel", "ground_model", "block_sweeps", "gaps", "velocity_step", "drift_contacts", "contact_step",
           "SWEEPS", "MAX_SWEEPS", "TOLERANCE", "TOUCH_TOL"]

SWEEPS = 60          # the fewest sweeps (lumped ends of equal mass: rate 0.5) ...
MAX_SWEEPS = 400     # ... and the most (a rate near 1: a rod pinned at one end standing on the other)
_ROUND_OFF = 0.55 ** SWEEPS   # the contraction SWEEPS sweeps at rate 0.55 reach (2.7e-16)
TOLERANCE = 1e-13   # m/s: a sweep that moves no velocity by more than this ends the sweeps (tolerance mode)


@_pytree("lone", "sweeps", "tolerance")
class GroundModel:
    """The ground of a scene, as arrays: height (m), friction (Coulomb mu), restitution (Newton's e), radii (N,) m
    (a node touches at its position minus its largest member radius); static: lone, the free nodes on no
    moving rigid strut; sweeps, the block Gauss-Seidel's (:func:`block_sweeps`); tolerance (m/s): 0, ``sweeps``
    sweeps; > 0, warm-started sweeps stopping at it, ``sweeps`` at most (module docstring)."""

    height: jax.Array
    friction: jax.Array
    restitution: jax.Array
    radii: jax.Array
    lone: tuple = field(default=())
    sweeps: int = SWEEPS
    tolerance: float = 0.0


def block_sweeps(mass, rigid_ends) -> int:
    """The sweeps that bring every rigid strut's block to round-off (:data:`_ROUND_OFF`) at its slowest rate, that
    of the strut standing on one end (its length row and that end's normal row both vertical): ``W_ln^2 / (W_ll
    W_nn)`` with ``M^-1``'s entries, ``a_e^2 / ((a_a + a_c) d_e)`` (``d`` the diagonal, ``a = d - cross`` the axial
    entry; lumped ``m_c / (m_a + m_c)``, 0.5 for equal ends: :data:`SWEEPS`; a uniform rod's block 0.75, the
    built-in three_bar's 0.79: 149 sweeps). At least :data:`SWEEPS`, at most :data:`MAX_SWEEPS`. ``mass``: a
    ``MassOperator``; ``rigid_ends`` (nr, 2) the moving rigid struts' end nodes."""
    rate = 0.0
    axial = mass.axial_inverse
    for a, c in np.asarray(rigid_ends, dtype=int).reshape(-1, 2):
        for e in (a, c):
            if mass.inv_diagonal[e] > 0.0:
                rate = max(rate, axial[e] ** 2 / ((axial[a] + axial[c]) * mass.inv_diagonal[e]))
    if rate <= 0.0:
        return SWEEPS
    if rate >= 1.0:
        return MAX_SWEEPS
    return int(np.clip(np.ceil(np.log(_ROUND_OFF) / np.log(rate)), SWEEPS, MAX_SWEEPS))


def ground_model(system, rigid, dtype=jnp.float64, tolerance: float = 0.0) -> GroundModel | None:
    """The ground of ``system`` (None without one); ``tolerance``: :attr:`GroundModel.tolerance`."""
    ground = system.scene.ground
    if ground is None:
        return None
    on_strut = np.zeros(system.n_nodes, dtype=bool)
    on_strut[rigid.ends.reshape(-1)] = True
    lone = np.flatnonzero(system.free & ~on_strut)
    return GroundModel(jnp.asarray(ground.height, dtype), jnp.asarray(ground.friction, dtype),
                       jnp.asarray(ground.restitution, dtype), jnp.asarray(system.scene.node_radii, dtype),
                       _index(lone), block_sweeps(system.mass, rigid.ends), float(tolerance))


def gaps(ground: GroundModel, x):
    """(N, B) m: each node's height above the ground minus its radius (negative: below), at ``x`` (N, 3, B)."""
    return x[:, 2] - ground.radii[:, None] - ground.height


def _disc(f, radius):
    """``f`` (k, 2, B) projected on the discs of ``radius`` (k, B)."""
    norm = jnp.sqrt(f[:, 0] * f[:, 0] + f[:, 1] * f[:, 1])
    scale = jnp.where(norm > radius, radius / jnp.where(norm > 0.0, norm, 1.0), 1.0)
    return f * scale[:, None]


def _contact(ground, mass, armed, w, v, y, f, steps=None):
    """One normal row and its friction for nodes with velocities ``v`` (k, 3, B), effective masses ``mass`` (k,)
    (``1 / M^-1``'s diagonal entry: the node's mass lumped, its rod's block's otherwise), targets ``w`` (k, B),
    current normal impulses ``y`` (k, B) and friction (k, 2, B); unarmed rows keep no impulse; ``steps``: the normal
    and friction rows' step sizes ((k, B) kg each; None: the masses). Returns the impulse change (k, 3, B) N*s
    (``M^-1`` of it is the velocity change: the node's, and its block's partner's) and the new ``y``, ``f``."""
    m = mass[:, None]
    step_n, step_t = (m, m) if steps is None else steps
    y_new = jnp.where(armed, jnp.maximum(0.0, y + step_n * (w - v[:, 2])), 0.0)
    f_new = jnp.where(armed[:, None], _disc(f - step_t[:, None] * v[:, :2], ground.friction * y_new), 0.0)
    return _impulse(f_new - f, y_new - y), y_new, f_new


def _impulse(f, y):
    """The impulses (k, 3, B) N*s of friction ``f`` (k, 2, B) and normal ``y`` (k, B)."""
    return jnp.concatenate([f, y[:, None]], axis=1)


def _sweeps(sweep, state, count, tolerance):
    """``sweep`` applied to ``state`` (the ends' velocities first) ``count`` times, or (``tolerance`` > 0) until no
    velocity moves by more than it, ``count`` at most."""
    if not tolerance > 0:
        return jax.lax.scan(lambda s, _: (sweep(s), None), state, None, length=count)[0]

    def more(loop):
        k, moved, _ = loop
        return (k < count) & (moved > tolerance)

    def body(loop):
        k, _, old = loop
        new = sweep(old)
        moved = jnp.maximum(jnp.max(jnp.abs(new[0] - old[0])), jnp.max(jnp.abs(new[1] - old[1])))
        return k + 1, jax.lax.stop_gradient(moved), new

    start = (jnp.asarray(0), jnp.asarray(jnp.inf, state[0].dtype), state)
    return jax.lax.while_loop(more, body, start)[2]


def velocity_step(model, ground: GroundModel, x, v, armed, w, start=None):
    """The velocities (N, 3, B) m/s after the contact impulses of the ``armed`` (N, B) nodes (targets
    ``v_z >= w`` (N, B) m/s, exact Coulomb friction) and the rigid struts' length rows at ``x`` (N, 3, B) (rate 0),
    from ``v`` (N, 3, B); and the ground's impulses (N, 3, B) N*s (friction x, y; normal z). ``start`` (N, 3, B):
    the impulses the sweeps start from (the armed nodes'; None: zero)."""
    free = model.free > 0
    (inv_mass, inv_cross), _, _ = _derived(model)   # M^-1: its diagonal, its rods' blocks' cross entries
    mass = jnp.where(free, 1.0 / jnp.where(free, inv_mass, 1.0), jnp.inf)
    impulses = jnp.zeros_like(v)
    out = v
    if model.rigid_members:
        ends = np.asarray(model.rigid_ends, dtype=int)
        a, b = ends[:, 0], ends[:, 1]
        d = x[b] - x[a]
        n = d / jnp.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])[:, None]
        # a push along the strut moves its ends by M^-1's axial entries; an impulse on one end moves it by the
        # diagonal entry and the other end by the cross entry (0 lumped or with a fixed end)
        axial = inv_mass - inv_cross
        ia, ib = axial[a][:, None, None], axial[b][:, None, None]
        w_rigid = (axial[a] + axial[b])[:, None]
        da, db, cross = inv_mass[a][:, None, None], inv_mass[b][:, None, None], inv_cross[a][:, None, None]
        blocked = any(p != i for i, p in enumerate(model.mass_partner))

        def length_row(va, vb):   # exactly, the contacts held
            rate = (jnp.sum((vb - va) * n, axis=1) / w_rigid)[:, None]
            return va + ia * rate * n, vb - ib * rate * n

        def kick(va, vb, pa, pb):   # impulses pa on the ends a, pb on the ends b
            va, vb = va + da * pa, vb + db * pb
            if blocked:   # static: only where the scene has rods' blocks
                va, vb = va + cross * pb, vb + cross * pa
            return va, vb

        zero = jnp.zeros_like(v[a])

        def sweep(state):
            va, vb, ya, fa, yb, fb = state
            va, vb = length_row(va, vb)
            dp, ya, fa = _contact(ground, mass[a], armed[a], w[a], va, ya, fa)
            va, vb = kick(va, vb, dp, zero)
            dp, yb, fb = _contact(ground, mass[b], armed[b], w[b], vb, yb, fb)
            va, vb = kick(va, vb, zero, dp)
            return va, vb, ya, fa, yb, fb

        # tolerance mode, rods lumped: each end on the problem with the length row eliminated, its inverse mass
        # 1/m (I - share n n^T), share its part of w_rigid (module docstring)
        share_a, share_b = ia[:, 0] / w_rigid, ib[:, 0] / w_rigid

        def reduced_steps(inv, share):
            """An end's normal and friction steps (nr, B) kg: the inverse of the normal row's diagonal, and the
            one scalar step (the disc needs one for both directions) that contracts both friction directions
            best; at most 10 times the end's mass (a strut standing on an end whose other end is fixed)."""
            nz, nt = n[:, 2] * n[:, 2], n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1]
            inv = inv[:, 0]
            return (1.0 / (inv * jnp.maximum(1.0 - share * nz, 0.1)),
                    2.0 / (inv * jnp.maximum(2.0 - share * nt, 0.2)))

        steps_a, steps_b = reduced_steps(ia, share_a), reduced_steps(ib, share_b)

        def stuck(mass, share, armed, w, v, y, f, dp, y_new, f_new):
            """The end's exact sticking answer (its velocity to ``(0, 0, w)``: the impulse ``W^-1 (u - v)``,
            ``W^-1 = m (I + share / (1 - share) n n^T)``) where it lies in the disc and the other end is free to
            move (``share`` < 0.9); elsewhere the projected step's impulse change ``dp``, ``y_new``, ``f_new``."""
            du = jnp.concatenate([-v[:, :2], (w - v[:, 2])[:, None]], axis=1)
            k = share / jnp.maximum(1.0 - share, 0.1)
            stick = mass[:, None, None] * (du + (k * _dot3(n, du))[:, None] * n)
            ys, fs = y + stick[:, 2], f + stick[:, :2]
            keep = armed & (share < 0.9) & (ys >= 0.0) & \
                (fs[:, 0] * fs[:, 0] + fs[:, 1] * fs[:, 1] <= (ground.friction * ys) ** 2)
            y_new, f_new = jnp.where(keep, ys, y_new), jnp.where(keep[:, None], fs, f_new)
            return _impulse(f_new - f, y_new - y), y_new, f_new

        def reduced_sweep(state):   # tolerance mode: the length row after each end, each end's rows its steps
            va, vb, ya, fa, yb, fb = state
            va, vb = length_row(va, vb)
            dp, ya2, fa2 = _contact(ground, mass[a], armed[a], w[a], va, ya, fa, steps_a)
            dp, ya, fa = stuck(mass[a], share_a, armed[a], w[a], va, ya, fa, dp, ya2, fa2)
            va, vb = length_row(*kick(va, vb, dp, zero))
            dp, yb2, fb2 = _contact(ground, mass[b], armed[b], w[b], vb, yb, fb, steps_b)
            dp, yb, fb = stuck(mass[b], share_b, armed[b], w[b], vb, yb, fb, dp, yb2, fb2)
            va, vb = kick(va, vb, zero, dp)
            return va, vb, ya, fa, yb, fb

        zero1, zero2 = zero[:, 2], zero[:, :2]
        if start is None:
            state = (v[a], v[b], zero1, zero2, zero1, zero2)
        else:   # the start impulses of the armed ends, applied
            ya, yb = jnp.where(armed[a], start[a, 2], 0.0), jnp.where(armed[b], start[b, 2], 0.0)
            fa = jnp.where(armed[a][:, None], start[a, :2], 0.0)
            fb = jnp.where(armed[b][:, None], start[b, :2], 0.0)
            state = kick(v[a], v[b], _impulse(fa, ya), _impulse(fb, yb)) + (ya, fa, yb, fb)
        reduced = ground.tolerance > 0 and not blocked
        va, vb, ya, fa, yb, fb = _sweeps(reduced_sweep if reduced else sweep, state, ground.sweeps,
                                         ground.tolerance)
        out = out.at[a].set(va).at[b].set(vb)
        impulses = impulses.at[a].set(_impulse(fa, ya))
        impulses = impulses.at[b].set(_impulse(fb, yb))
    if ground.lone:
        p = np.asarray(ground.lone, dtype=int)
        zero = jnp.zeros((len(p),) + v.shape[2:], v.dtype)
        zero2 = jnp.zeros((len(p), 2) + v.shape[2:], v.dtype)
        dp, y, f = _contact(ground, mass[p], armed[p], w[p], v[p], zero, zero2)
        out = out.at[p].add(inv_mass[p][:, None, None] * dp)
        impulses = impulses.at[p].set(_impulse(f, y))
    return out, impulses


def drift_contacts(model, ground: GroundModel, x, v, v_half, h, v_f_z):
    """The drift's contacts (``ContactSet.arm_step`` with the elastic drift's ``half = h``): the free nodes that
    may reach the ground by the step's end on the free velocities ``v_half`` or at the vertical velocities
    ``v_f_z`` (N, B) (the method's: its rigid struts' length rates zeroed), each with the target that lands it
    exactly on it, capped at the reversal of its normal velocity at the step's start ``v`` but never letting it
    sink past ``TOUCH_TOL`` deep. Returns armed (N, B) bool and the targets (N, B)."""
    g = gaps(ground, x)
    armed = (model.free > 0)[:, None] & (jnp.minimum(g - h * jnp.abs(v_half[:, 2]), g + h * v_f_z) <= TOUCH_TOL)
    return armed, jnp.maximum(jnp.minimum(-g / h, -v[:, 2]), jnp.minimum(-(g + TOUCH_TOL) / h, 0.0))


def contact_step(model, ground, x, v, armed, w, start=None):
    """:func:`velocity_step` in the copies where any node is armed (as the reference, which then also holds
    every rigid strut at rate 0), ``v`` unchanged in the others; and the ground's impulses (zero there)."""
    out, impulses = velocity_step(model, ground, x, v, armed, w, start)
    any_armed = jnp.any(armed, axis=0)
    return jnp.where(any_armed, out, v), jnp.where(any_armed, impulses, 0.0)
