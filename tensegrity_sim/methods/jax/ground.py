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
"""
from __future__ import annotations

from dataclasses import field

import jax
import jax.numpy as jnp
import numpy as np

from ..contact.friction import TOUCH_TOL
from .elastic import _index, _pytree

__all__ = ["GroundModel", "ground_model", "gaps", "velocity_step", "drift_contacts", "contact_step", "SWEEPS",
           "TOUCH_TOL"]

SWEEPS = 60


@_pytree("lone")
class GroundModel:
    """The ground of a scene, as arrays: height (m), friction (Coulomb mu), restitution (Newton's e), radii (N,) m
    (a node touches at its position minus its largest member radius); static: lone, the free nodes on no
    moving rigid strut."""

    height: jax.Array
    friction: jax.Array
    restitution: jax.Array
    radii: jax.Array
    lone: tuple = field(default=())


def ground_model(system, rigid, dtype=jnp.float64) -> GroundModel | None:
    """The ground of ``system`` (None without one)."""
    ground = system.scene.ground
    if ground is None:
        return None
    on_strut = np.zeros(system.n_nodes, dtype=bool)
    on_strut[rigid.ends.reshape(-1)] = True
    lone = np.flatnonzero(system.free & ~on_strut)
    return GroundModel(jnp.asarray(ground.height, dtype), jnp.asarray(ground.friction, dtype),
                       jnp.asarray(ground.restitution, dtype), jnp.asarray(system.scene.node_radii, dtype),
                       _index(lone))


def gaps(ground: GroundModel, x):
    """(N, B) m: each node's height above the ground minus its radius (negative: below), at ``x`` (N, 3, B)."""
    return x[:, 2] - ground.radii[:, None] - ground.height


def _disc(f, radius):
    """``f`` (k, 2, B) projected on the discs of ``radius`` (k, B)."""
    norm = jnp.sqrt(f[:, 0] * f[:, 0] + f[:, 1] * f[:, 1])
    scale = jnp.where(norm > radius, radius / jnp.where(norm > 0.0, norm, 1.0), 1.0)
    return f * scale[:, None]


def _contact(ground, mass, armed, w, v, y, f):
    """One normal row and its friction for nodes with velocities ``v`` (k, 3, B), masses (k,), targets ``w``
    (k, B), current normal impulses ``y`` (k, B) and friction (k, 2, B); unarmed rows keep no impulse. Returns the
    velocity change (k, 3, B) and the new ``y``, ``f``."""
    m = mass[:, None]
    y_new = jnp.where(armed, jnp.maximum(0.0, y + m * (w - v[:, 2])), 0.0)
    f_new = jnp.where(armed[:, None], _disc(f - m[:, None] * v[:, :2], ground.friction * y_new), 0.0)
    dv = jnp.concatenate([(f_new - f) / m[:, None], ((y_new - y) / m)[:, None]], axis=1)
    return dv, y_new, f_new


def velocity_step(model, ground: GroundModel, x, v, armed, w):
    """The velocities (N, 3, B) m/s after the contact impulses of the ``armed`` (N, B) nodes (targets
    ``v_z >= w`` (N, B) m/s, exact Coulomb friction) and the rigid struts' length rows at ``x`` (N, 3, B) (rate 0),
    from ``v`` (N, 3, B); and the ground's impulses (N, 3, B) N*s (friction x, y; normal z)."""
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

        def sweep(state, _):
            va, vb, ya, fa, yb, fb = state
            # the length row exactly, the contacts held
            rate = (jnp.sum((vb - va) * n, axis=1) / w_rigid)[:, None]
            va, vb = va + ia * rate * n, vb - ib * rate * n
            dv, ya, fa = _contact(ground, mass[a], armed[a], w[a], va, ya, fa)
            va = va + dv
            dv, yb, fb = _contact(ground, mass[b], armed[b], w[b], vb, yb, fb)
            return (va, vb + dv, ya, fa, yb, fb), None

        zero = jnp.zeros((len(a),) + v.shape[2:], v.dtype)
        zero2 = jnp.zeros((len(a), 2) + v.shape[2:], v.dtype)
        state = (v[a], v[b], zero, zero2, zero, zero2)
        (va, vb, ya, fa, yb, fb), _ = jax.lax.scan(sweep, state, None, length=SWEEPS)
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


def contact_step(model, ground, x, v, armed, w):
    """:func:`velocity_step` in the copies where any node is armed (as the reference, which then also holds
    every rigid strut at rate 0), ``v`` unchanged in the others; and the ground's impulses."""
    out, impulses = velocity_step(model, ground, x, v, armed, w)
    any_armed = jnp.any(armed, axis=0)
    return jnp.where(any_armed, out, v), jnp.where(any_armed, impulses, 0.0)
