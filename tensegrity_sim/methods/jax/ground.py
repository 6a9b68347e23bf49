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
(``f <- proj_disc(mu y_n)(f - m v_t)``). Its fixed points are exactly the solutions of the Coulomb problem
(the numpy reference's mode fixed point finds the same velocities); every update is a ``max`` or a projection
(``jnp.where``), so the work is the same for every block and every copy. The sweeps converge linearly, at a
rate set by the angle between the strut and the ground (fastest lying flat; a standing strut's length and
normal rows share a node: rate about ``m_a / (m_a + m_b)``): ``SWEEPS`` = 60 brings an end's velocity to
round-off at rates up to about 0.55 (``test/test_jax_ground.py`` measures the agreement with the reference).

**Stopping at a tolerance** (``GroundModel.tolerance`` > 0, what ``fit`` uses): the sweeps start from the
previous step's impulses of the same solve (a warm start: a contact that persists changes its impulse little from
one step to the next) and stop once no velocity of any block and copy moved by more than ``tolerance`` (m/s) in a
sweep, ``SWEEPS`` at most. A warm start alone does not shorten them much (the rolling icosahedron's persistent
contacts still took about 32 sweeps at the rate above), so these sweeps also solve each end on the problem with
the strut's length row eliminated (its inverse mass ``1/m (I - c n n^T)``, ``c = (1/m) / w_rigid``): the length
row after each end, not once a sweep; the normal row's step that diagonal's inverse; friction's one scalar step
that contracts both its directions best; and where the end's exact sticking answer (the 3x3 solve, closed form by
Sherman-Morrison) lies in the disc, that answer. Every update is still a ``max``, a projection on the disc with a
positive scalar step, or an exact solve, so the fixed points are the same Coulomb solutions. A ``lax.while_loop``
differentiates in forward mode only (``jax.jvp``, ``jax.jacfwd``: the tangents follow the same sweeps), so the
default stays the fixed count, which ``jax.grad`` also differentiates.
"""
from __future__ import annotations

from dataclasses import field

import jax
import jax.numpy as jnp
import numpy as np

from ..contact.friction import TOUCH_TOL
from .elastic import _dot3, _index, _pytree

__all__ = ["GroundModel", "ground_model", "gaps", "velocity_step", "drift_contacts", "contact_step", "SWEEPS",
           "TOLERANCE", "TOUCH_TOL"]

SWEEPS = 60
TOLERANCE = 1e-13   # m/s: a sweep that moves no velocity by more than this ends the sweeps (tolerance mode)


@_pytree("lone", "tolerance")
class GroundModel:
    """The ground of a scene, as arrays: height (m), friction (Coulomb mu), restitution (Newton's e), radii (N,) m
    (a node touches at its position minus its largest member radius); static: lone, the free nodes on no
    moving rigid strut; tolerance (m/s): 0, ``SWEEPS`` sweeps; > 0, warm-started sweeps stopping at it (module
    docstring)."""

    height: jax.Array
    friction: jax.Array
    restitution: jax.Array
    radii: jax.Array
    lone: tuple = field(default=())
    tolerance: float = 0.0


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
                       _index(lone), float(tolerance))


def gaps(ground: GroundModel, x):
    """(N, B) m: each node's height above the ground minus its radius (negative: below), at ``x`` (N, 3, B)."""
    return x[:, 2] - ground.radii[:, None] - ground.height


def _disc(f, radius):
    """``f`` (k, 2, B) projected on the discs of ``radius`` (k, B)."""
    norm = jnp.sqrt(f[:, 0] * f[:, 0] + f[:, 1] * f[:, 1])
    scale = jnp.where(norm > radius, radius / jnp.where(norm > 0.0, norm, 1.0), 1.0)
    return f * scale[:, None]


def _contact(ground, mass, armed, w, v, y, f, steps=None):
    """One normal row and its friction for nodes with velocities ``v`` (k, 3, B), masses (k,), targets ``w``
    (k, B), current normal impulses ``y`` (k, B) and friction (k, 2, B); unarmed rows keep no impulse; ``steps``:
    the normal and friction rows' step sizes ((k, B) kg each; None: the masses). Returns the velocity change
    (k, 3, B) and the new ``y``, ``f``."""
    m = mass[:, None]
    step_n, step_t = (m, m) if steps is None else steps
    y_new = jnp.where(armed, jnp.maximum(0.0, y + step_n * (w - v[:, 2])), 0.0)
    f_new = jnp.where(armed[:, None], _disc(f - step_t[:, None] * v[:, :2], ground.friction * y_new), 0.0)
    return _kick(mass, f_new - f, y_new - y), y_new, f_new


def _kick(mass, df, dy):
    """The velocity change (k, 3, B) of friction impulses ``df`` (k, 2, B) and normal impulses ``dy`` (k, B) on
    nodes of masses (k,)."""
    m = mass[:, None]
    return jnp.concatenate([df / m[:, None], (dy / m)[:, None]], axis=1)


def _sweeps(sweep, state, tolerance):
    """``sweep`` applied to ``state`` (the ends' velocities first) ``SWEEPS`` times, or (``tolerance`` > 0) until
    no velocity moves by more than it, ``SWEEPS`` at most."""
    if not tolerance > 0:
        return jax.lax.scan(lambda s, _: (sweep(s), None), state, None, length=SWEEPS)[0]

    def more(loop):
        k, moved, _ = loop
        return (k < SWEEPS) & (moved > tolerance)

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
    inv_mass = jnp.where(free, 1.0 / jnp.where(free, model.masses, 1.0), 0.0)
    mass = jnp.where(free, model.masses, jnp.inf)
    impulses = jnp.zeros_like(v)
    out = v
    if model.rigid_members:
        ends = np.asarray(model.rigid_ends, dtype=int)
        a, b = ends[:, 0], ends[:, 1]
        d = x[b] - x[a]
        n = d / jnp.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])[:, None]
        ia, ib = inv_mass[a][:, None, None], inv_mass[b][:, None, None]
        w_rigid = (inv_mass[a] + inv_mass[b])[:, None]

        def length_row(va, vb):   # exactly, the contacts held
            rate = (jnp.sum((vb - va) * n, axis=1) / w_rigid)[:, None]
            return va + ia * rate * n, vb - ib * rate * n

        def sweep(state):
            va, vb, ya, fa, yb, fb = state
            va, vb = length_row(va, vb)
            dv, ya, fa = _contact(ground, mass[a], armed[a], w[a], va, ya, fa)
            va = va + dv
            dv, yb, fb = _contact(ground, mass[b], armed[b], w[b], vb, yb, fb)
            return va, vb + dv, ya, fa, yb, fb

        # tolerance mode: each end on the problem with the length row eliminated, its inverse mass
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

        def stuck(mass, share, armed, w, v, y, f, dv, y_new, f_new):
            """The end's exact sticking answer (its velocity to ``(0, 0, w)``: the impulse ``W^-1 (u - v)``,
            ``W^-1 = m (I + share / (1 - share) n n^T)``) where it lies in the disc and the other end is free to
            move (``share`` < 0.9); elsewhere the projected step's ``dv``, ``y_new``, ``f_new``."""
            du = jnp.concatenate([-v[:, :2], (w - v[:, 2])[:, None]], axis=1)
            k = share / jnp.maximum(1.0 - share, 0.1)
            dp = mass[:, None, None] * (du + (k * _dot3(n, du))[:, None] * n)
            ys, fs = y + dp[:, 2], f + dp[:, :2]
            keep = armed & (share < 0.9) & (ys >= 0.0) & \
                (fs[:, 0] * fs[:, 0] + fs[:, 1] * fs[:, 1] <= (ground.friction * ys) ** 2)
            y_new, f_new = jnp.where(keep, ys, y_new), jnp.where(keep[:, None], fs, f_new)
            return _kick(mass, f_new - f, y_new - y), y_new, f_new

        def reduced_sweep(state):   # tolerance mode: the length row after each end, each end's rows its steps
            va, vb, ya, fa, yb, fb = state
            va, vb = length_row(va, vb)
            dv, ya2, fa2 = _contact(ground, mass[a], armed[a], w[a], va, ya, fa, steps_a)
            dv, ya, fa = stuck(mass[a], share_a, armed[a], w[a], va, ya, fa, dv, ya2, fa2)
            va, vb = length_row(va + dv, vb)
            dv, yb2, fb2 = _contact(ground, mass[b], armed[b], w[b], vb, yb, fb, steps_b)
            dv, yb, fb = stuck(mass[b], share_b, armed[b], w[b], vb, yb, fb, dv, yb2, fb2)
            return va, vb + dv, ya, fa, yb, fb

        if start is None:
            zero = jnp.zeros((len(a),) + v.shape[2:], v.dtype)
            zero2 = jnp.zeros((len(a), 2) + v.shape[2:], v.dtype)
            state = (v[a], v[b], zero, zero2, zero, zero2)
        else:   # the start impulses of the armed ends, applied
            ya, yb = jnp.where(armed[a], start[a, 2], 0.0), jnp.where(armed[b], start[b, 2], 0.0)
            fa = jnp.where(armed[a][:, None], start[a, :2], 0.0)
            fb = jnp.where(armed[b][:, None], start[b, :2], 0.0)
            state = (v[a] + _kick(mass[a], fa, ya), v[b] + _kick(mass[b], fb, yb), ya, fa, yb, fb)
        va, vb, ya, fa, yb, fb = _sweeps(reduced_sweep if ground.tolerance > 0 else sweep, state, ground.tolerance)
        out = out.at[a].set(va).at[b].set(vb)
        impulses = impulses.at[a].set(jnp.concatenate([fa, ya[:, None]], axis=1))
        impulses = impulses.at[b].set(jnp.concatenate([fb, yb[:, None]], axis=1))
    if ground.lone:
        p = np.asarray(ground.lone, dtype=int)
        zero = jnp.zeros((len(p),) + v.shape[2:], v.dtype)
        zero2 = jnp.zeros((len(p), 2) + v.shape[2:], v.dtype)
        dv, y, f = _contact(ground, mass[p], armed[p], w[p], v[p], zero, zero2)
        out = out.at[p].add(dv)
        impulses = impulses.at[p].set(jnp.concatenate([f, y[:, None]], axis=1))
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
