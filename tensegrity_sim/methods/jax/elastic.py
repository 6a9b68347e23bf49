"""The elastic method's step in JAX: the arithmetic of ``methods/elastic/_kernels.py`` (velocity Verlet,
SHAKE/RATTLE of independent rigid struts in closed form, tension-only cables ``k max(floor, l - rest)``,
damping only while taut and the total clipped at zero, impulses ``h/2 (t_start + t_end)``), with the same
function names. Tests require the two to agree to 1e-12 in float64 (``test/test_jax.py``).

Layout: the numba kernels' (style rule 8): every array carries the batch of ``B`` copies LAST, so that the
member vectors and the force assembly are each one matrix product with the incidence over ``(N, 3 B)`` and every
other operation runs over contiguous rows of copies (``bench/bench_jax.py``'s free case on this project's 2-core
machine, 1,024 thrown icosahedra, load ~5-6: a batch-first ``vmap`` of one copy's step ran 128,000
scene-steps/s; batch last with gathers ``x[ends]`` for the member vectors 185,000-218,000, 0.40-0.55 of the numba
batch; with the incidence products 325,000-419,000, 0.74-0.79 of it, taking turns in one session):

    x, v (N, 3, B) m, m/s           positions, velocities
    rest (nc, B) m                  cable rest lengths held (the base of a schedule)
    ext (N, 3, B) N                 external forces held
    acc (N, 3, B) m/s^2, tension (nc, B) N, dirs (nr, 3, B)   the forces at the step's start (the carry)

A run (:func:`elastic_steps`) is one ``lax.scan`` over the steps; a command schedule (:class:`Inputs`:
rest-length ramps, force steps, per copy) is evaluated inside it at each step's start time, and where an
input changed at a step the start forces are recomputed there, as ``BatchSimulator.set_rest_lengths``
makes the numba batch do (``invalidate``).

Gradients: everything here is differentiable with ``jax.grad``/``jax.jacfwd`` (:func:`rollout`). The flow is
piecewise smooth: a cable's tension ``k max(0, e)`` has a kink where it goes slack or taut, and the damping
term switches on and off there. Away from a switch the derivative of a run is the derivative of the smooth
flow (tested against central differences to 1e-6). A step where a cable crosses ``e = 0`` contributes the
one-sided derivative of the branch the step evaluated (JAX differentiates ``max(e, 0)`` as 1 for ``e > 0`` and
0 for ``e < 0``); the time of the switch inside the step is not differentiated (the switch is not located, as
in the numba default), so the derivative of a run through a switch is that of the discrete map, which differs
from the continuous flow's by O(h) per switch, and it jumps where a parameter change moves a switch from one
step to the next. Finite differences across such a jump do not converge; a step that lands exactly on
``e = 0`` takes the mean of the two branches (JAX's convention for ``maximum`` at a tie).
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax import lax

__all__ = ["ElasticModel", "Carry", "Inputs", "model_arrays", "held_inputs", "schedule_inputs", "elastic_forces",
           "verlet_step", "elastic_steps", "rollout"]


def _pytree(*meta: str):
    """A frozen dataclass as a JAX pytree whose ``meta`` fields (the topology: tuples of node and member indices,
    hashable) are static, so that a gradient may be taken with respect to the whole object (its float arrays)."""

    def register(cls):
        cls = dataclass(frozen=True)(cls)
        cls._replace = replace   # NamedTuple's spelling of a copy with some fields changed
        data = [f.name for f in fields(cls) if f.name not in meta]
        return jax.tree_util.register_dataclass(cls, data_fields=data, meta_fields=list(meta))

    return register


def _index(values) -> tuple:
    """An index array as a hashable (static) tuple of ints, or of pairs of ints."""
    return tuple(tuple(int(i) for i in row) if np.ndim(row) else int(row) for row in np.asarray(values))


@_pytree("rigid_members", "rigid_ends", "mass_partner")
class ElasticModel:
    """What does not change during a run (a pytree: a gradient may be taken with respect to any array, the
    topology's index tuples being static). ``m`` members (struts first), ``N`` nodes, ``nr`` moving rigid
    struts.

    stiffness (m,) N/m (0 for rigid struts), floor (m,) (-inf for struts, 0 for cables), strut_rest (n_struts,) m,
    damping (nc,) N*s/m, masses (N,) kg (lumped: ``M``'s row sums), mass_block (N,) kg (the off-diagonal entry
    ``B`` of the 2x2 mass block of a node's rigid strut, 0 without one: ``M``'s diagonal is ``masses -
    mass_block``), free (N,) 1.0 for a free node and 0.0 for a fixed one, gravity (3,) m/s^2, incidence (N, m)
    (+1 at a member's first node, -1 at its second; a cable end along a strut shared by its weights),
    rigid_incidence (N, nr), rigid_length_sq (nr,) m^2; static: rigid_members (nr rows in the member arrays),
    rigid_ends (nr pairs of node indices), mass_partner (N: the other end of a node's block where both move, else
    the node itself); ground: the scene's ground (``ground.GroundModel``) or None."""

    stiffness: jax.Array
    floor: jax.Array
    strut_rest: jax.Array
    damping: jax.Array
    masses: jax.Array
    free: jax.Array
    gravity: jax.Array
    incidence: jax.Array
    rigid_incidence: jax.Array
    rigid_length_sq: jax.Array
    rigid_members: tuple
    rigid_ends: tuple
    mass_block: jax.Array = None
    mass_partner: tuple = ()
    ground: object = None   # a ground.GroundModel, or None without a ground


class Carry(NamedTuple):
    """What one step hands the next, batch last: x, v (N, 3, B), acc (N, 3, B) m/s^2, tension (nc, B) N and the
    rigid struts' unit vectors dirs (nr, 3, B) at the step's end; contact (2, N, 3, B) N*s: the ground's impulses
    of the step's drift and closing solves, where the next step's sweeps start (a ground with a tolerance:
    ``ground.py``; else (0, N, 3, B))."""

    x: jax.Array
    v: jax.Array
    acc: jax.Array
    tension: jax.Array
    dirs: jax.Array
    contact: jax.Array


@_pytree("rest_cables")
class Inputs:
    """The inputs of a run, per copy. rest (nc, B) m and ext (N, 3, B) N: held, and the base of a schedule.
    A schedule (:func:`schedule_inputs`; ``S = 0`` and ``F = 0`` without one): rest_cables (static: S cable
    indices), the scheduled cables; rest_times, rest_values (B, S, P) s, m: each one's points, linear between
    them and held outside (padded past the last point with its value); force_times (B, F) s (padded with +inf)
    and force_values (B, F, N, 3) N: the external forces from each point on."""

    rest: jax.Array
    ext: jax.Array
    rest_times: jax.Array
    rest_values: jax.Array
    force_times: jax.Array
    force_values: jax.Array
    rest_cables: tuple


def model_arrays(system, rigid, dtype=jnp.float64) -> ElasticModel:
    """The model of a ``System`` and its ``RigidStruts`` (independent struts only: the closed-form SHAKE), in
    ``dtype``."""
    if rigid.coupled:
        raise ValueError("the JAX backend steps independent rigid struts only (at most one rigid strut per node); "
                         "this scene's share a node (class-k): use the numba backend")
    f = partial(jnp.asarray, dtype=dtype)
    from .ground import ground_model

    rigid_ends = rigid.ends.reshape(-1, 2)
    mass = system.mass
    partner = np.where(mass.partner >= 0, mass.partner, np.arange(system.n_nodes))
    return ElasticModel(
        f(system.stiffness), f(system.floor), f(system.strut_rest), f(system.cable_damping), f(system.masses),
        f(system.free.astype(float)), f(np.asarray(system.scene.gravity, dtype=float)),
        f(_dense(system.incidence_matrix())), f(_dense(system.incidence_matrix(rigid_ends))),
        f(rigid.length_sq), _index(rigid.members), _index(rigid_ends), f(mass.lumped - mass.diagonal),
        _index(partner), ground_model(system, rigid, dtype))


def _dense(incidence) -> np.ndarray:
    """``System.incidence_matrix``'s (N, k) as a dense array (it is sparse for a large structure): +1 at each
    member's first node, -1 at its second (a tension t along the unit vector first -> second pulls the first
    node by +t n); a cable end along a strut shared ``(1 - w, w)`` between the strut's nodes."""
    return incidence.toarray() if sp.issparse(incidence) else np.asarray(incidence)


def held_inputs(rest, ext, dtype=jnp.float64) -> Inputs:
    """Inputs held for the whole run: rest (nc, B) m, ext (N, 3, B) N."""
    rest, ext = jnp.asarray(rest, dtype=dtype), jnp.asarray(ext, dtype=dtype)
    b = rest.shape[1]
    return Inputs(rest, ext, jnp.zeros((b, 0, 1), dtype), jnp.zeros((b, 0, 1), dtype), jnp.zeros((b, 0), dtype),
                  jnp.zeros((b, 0, ext.shape[0], 3), dtype), ())


def schedule_inputs(schedules, rest, ext, dtype=jnp.float64) -> Inputs:
    """Inputs from ``commands.CommandSchedule``s: one for every copy or a sequence of B (one per copy), on top of
    rest (nc, B) m and ext (N, 3, B) N (what a cable or a node the schedule does not name keeps)."""
    rest, ext = np.asarray(rest, dtype=float), np.asarray(ext, dtype=float)
    b = rest.shape[1]
    schedules = [schedules] * b if not isinstance(schedules, (list, tuple)) else list(schedules)
    if len(schedules) != b:
        raise ValueError(f"commands: expected one schedule or {b} (one per copy), got {len(schedules)}")
    cables = sorted({int(c) for s in schedules for c in s.rest_cables})
    points = max([len(t) for s in schedules for t in s.rest_times] + [1])
    forces = max(len(s.force_times) for s in schedules)
    shared = all(s is schedules[0] for s in schedules)   # one schedule for all: its arrays once, broadcast
    copies = 1 if shared else b
    rest_times = np.zeros((copies, len(cables), points))
    rest_values = np.zeros((copies, len(cables), points))
    force_times = np.full((copies, forces), np.inf)
    force_values = np.zeros((copies, forces, ext.shape[0], 3))
    for k, s in enumerate(schedules[:copies]):
        named = {int(c): (t, v) for c, t, v in zip(s.rest_cables, s.rest_times, s.rest_values)}
        for j, c in enumerate(cables):
            # a cable this copy does not schedule keeps its rest length: one point, held
            t, v = named.get(c, (np.zeros(1), rest[c, k:k + 1]))
            # past the last point: the last value at later times (interpolating between equal values holds it)
            rest_times[k, j] = np.concatenate([t, t[-1] + np.arange(1, points - len(t) + 1)])
            rest_values[k, j] = np.concatenate([v, np.full(points - len(v), v[-1])])
        force_times[k, :len(s.force_times)] = s.force_times
        force_values[k, :len(s.force_times)] = s.force_values
    f = partial(jnp.asarray, dtype=dtype)
    rest_times, rest_values, force_times, force_values = (
        jnp.broadcast_to(f(a), (b,) + a.shape[1:]) for a in (rest_times, rest_values, force_times, force_values))
    return Inputs(f(rest), f(ext), rest_times, rest_values, force_times, force_values, tuple(cables))


def _derived(model: ElasticModel):
    """``M^-1`` as its diagonal and its blocks' cross entries (N,) 1/kg (0 for fixed nodes; ``mass.MassOperator``),
    gravity forces (N, 3) N and the rigid struts' ``W_kk`` (nr,) 1/kg (an equal-and-opposite push's: ``1/m_a +
    1/m_b`` lumped), from the masses (so that a gradient with respect to them sees all of them)."""
    free = model.free > 0
    partner = np.asarray(model.mass_partner, dtype=int)
    blocked = partner != np.arange(len(partner))
    diagonal = model.masses - model.mass_block
    cross = jnp.where(blocked, model.mass_block, 0.0)
    det = jnp.where(blocked, diagonal * diagonal[partner] - cross * cross, diagonal)
    inv_mass = jnp.where(free, jnp.where(blocked, diagonal[partner], 1.0) / jnp.where(free, det, 1.0), 0.0)
    inv_cross = jnp.where(free & blocked, -cross / jnp.where(blocked, det, 1.0), 0.0)
    gravity_force = (model.masses * model.free)[:, None] * model.gravity[None, :]
    rigid_ends = np.asarray(model.rigid_ends, dtype=int).reshape(-1, 2)
    axial = inv_mass - inv_cross
    w = axial[rigid_ends[:, 0]] + axial[rigid_ends[:, 1]]
    return (inv_mass, inv_cross), gravity_force, w


def _solve_mass(model: ElasticModel, inverse, f):
    """``M^-1 f`` for forces ``f`` (N, 3, B) N: ``inverse`` is :func:`_derived`'s first item."""
    inv_mass, inv_cross = inverse
    out = inv_mass[:, None, None] * f
    if any(p != i for i, p in enumerate(model.mass_partner)):   # static: only where the scene has blocks
        out = out + inv_cross[:, None, None] * f[np.asarray(model.mass_partner, dtype=int)]
    return out


def _dot3(a, b):
    """Row-wise dot products (k, B) of (k, 3, B) arrays, summed in the kernels' order."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _through(spec: str, incidence, a):
    """A product with an incidence matrix (``jnp.einsum(spec, ...)``) at full precision: a GPU multiplies
    float32 matrices in TF32 (10-bit mantissas) by default, which would round every coordinate to 1e-3."""
    return jnp.einsum(spec, incidence, a, precision=jax.lax.Precision.HIGHEST)


def _differences(incidence, x):
    """Each member's second end minus its first, (m, 3, B), from nodes ``x`` (N, 3, B): a product with the
    incidence (exact for a member between two nodes: one +1 and one -1; a cable end along a strut interpolates
    its nodes by its weights), which XLA runs faster than two gathers."""
    return -_through("nm,njb->mjb", incidence, x)


def _forces(model: ElasticModel, x, v, rest, ext):
    """Accelerations (N, 3, B), cable tensions (nc, B), member unit vectors (m, 3, B) and slack cables (nc, B) at
    ``x`` (damping from ``v``) with rest lengths ``rest`` (nc, B) and external forces ``ext`` (N, 3, B)."""
    inverse, gravity_force, _ = _derived(model)
    d = _differences(model.incidence, x)
    length = jnp.sqrt(_dot3(d, d))
    n = d / length[:, None]
    ns = model.strut_rest.shape[0]
    r = jnp.concatenate([jnp.broadcast_to(model.strut_rest[:, None], (ns, rest.shape[1])), rest])
    t = model.stiffness[:, None] * jnp.maximum(length - r, model.floor[:, None])
    cables = t[ns:]
    rate = _dot3(_differences(model.incidence[:, ns:], v), n[ns:])
    cables = jnp.where(cables > 0.0, cables + model.damping[:, None] * rate, cables)
    cables = jnp.maximum(cables, 0.0)   # a damped cable never pushes
    t = jnp.concatenate([t[:ns], cables])
    assembled = _through("nm,mjb->njb", model.incidence, t[:, None] * n)
    acc = _solve_mass(model, inverse, gravity_force[:, :, None] + ext + assembled)
    return acc, cables, n, length[ns:] < rest


def elastic_forces(model: ElasticModel, x, v, rest, ext):
    """Accelerations (N, 3, B) m/s^2, cable tensions (nc, B) N, the rigid struts' unit vectors (nr, 3, B) and the
    slack cables (nc, B) bool at ``x`` (N, 3, B) (damping from ``v``)."""
    acc, tension, n, slack = _forces(model, x, v, rest, ext)
    return acc, tension, n[np.asarray(model.rigid_members, dtype=int)], slack


def _push(model, inverse, strengths, dirs):
    """Node displacements (or velocity changes) (N, 3, B) of equal-and-opposite pushes ``strengths`` (nr, B)
    along the rigid struts' ``dirs`` (nr, 3, B): ``M^-1`` of them (``inverse`` is :func:`_derived`'s first item)."""
    axial = inverse[0] - inverse[1]
    return axial[:, None, None] * _through("nk,kjb->njb", model.rigid_incidence, strengths[:, None] * dirs)


def verlet_step(model: ElasticModel, carry: Carry, rest, ext, h):
    """One velocity Verlet + SHAKE/RATTLE step of ``h`` (s) of every copy (``_elastic_kernels._step``) from
    ``carry``, rest lengths ``rest`` (nc, B) and forces ``ext`` (N, 3, B); with a ground, the contact impulses of
    ``ElasticMethod.verlet`` (after the first half-kick: the drift's, landing every node that would pass the
    ground exactly on it; after the closing half-kick: the touching nodes', Newton's restitution for those that
    landed in this step). Returns the new :class:`Carry`, the cable impulses (nc, B) N*s and the slack cables
    (nc, B) at the step's end."""
    from .ground import TOUCH_TOL, contact_step, drift_contacts, gaps

    x, v, acc, tension, dirs, contact = carry
    inverse, _, w = _derived(model)
    half = 0.5 * h
    v_half = v + half * acc
    ground = model.ground
    if ground is not None:
        landing_speed = jnp.maximum(-v_half[:, 2], 0.0)
        free_z = v_half[:, 2]
        if len(model.rigid_members):   # armed on the velocity with each rigid strut's length rate zeroed too
            rate = _dot3(_differences(model.rigid_incidence, v_half), dirs)
            free_z = (v_half + _push(model, inverse, rate / w[:, None], dirs))[:, 2]
        warm = carry.contact if len(carry.contact) else (None, None)
        armed, target = drift_contacts(model, ground, x, v, v_half, h, free_z)
        out, drift = contact_step(model, ground, x, v_half, armed, target, warm[0])
        # ContactSet.missed: a copy whose answer carries an unarmed node into the ground is solved again with the
        # nodes it carries within TOUCH_TOL of it armed too
        end_gap = gaps(ground, x) + h * out[:, 2]
        free = (model.free > 0)[:, None]
        missed = jnp.any(free & ~armed & (end_gap < -TOUCH_TOL), axis=0)
        again = armed | (free & missed[None] & (end_gap <= TOUCH_TOL))

        def solve_again():
            out_again, drift_again = contact_step(model, ground, x, v_half, again, target, warm[0])
            return jnp.where(missed[None, None], out_again, out), jnp.where(missed[None, None], drift_again, drift)

        v_half, drift = jax.lax.cond(jnp.any(missed), solve_again, lambda: (out, drift))
        landing_speed = jnp.where(gaps(ground, x) > TOUCH_TOL, landing_speed, 0.0)
    x_new = x + h * v_half
    nr = len(model.rigid_members)
    if nr:
        r = _differences(model.rigid_incidence, x_new)
        p = _dot3(r, dirs)
        q = _dot3(r, r) - model.rigid_length_sq[:, None]
        # SHAKE: the small root of w^2 g^2 - 2 w p g + q = 0, written to avoid cancellation
        gamma = q / (w[:, None] * (p + jnp.sqrt(jnp.maximum(p * p - q, 0.0))))
        dx = _push(model, inverse, gamma, dirs)
        x_new = x_new + dx
        v_half = v_half + dx / h
    acc_end, tension_end, n, slack = _forces(model, x_new, v_half, rest, ext)
    impulses = half * (tension + tension_end)
    v_new = v_half + half * acc_end
    if nr:
        dirs = n[np.asarray(model.rigid_members, dtype=int)]
        # RATTLE: zero every rigid strut's length rate along its end-of-step direction
        rate = _dot3(_differences(model.rigid_incidence, v_new), dirs)
        v_new = v_new + _push(model, inverse, rate / w[:, None], dirs)
    if ground is not None:
        touching = (model.free > 0)[:, None] & (gaps(ground, x_new) <= TOUCH_TOL)
        v_new, closing = contact_step(model, ground, x_new, v_new, touching, ground.restitution * landing_speed,
                                      warm[1])
        if len(carry.contact):
            contact = jnp.stack([drift, closing])
    return Carry(x_new, v_new, acc_end, tension_end, dirs, contact), impulses, slack


@jax.jit
def start_carry(model: ElasticModel, x, v, rest, ext, contact=None) -> Carry:
    """The carry at the start of a run from positions ``x`` and velocities ``v`` (N, 3, B); ``contact``: the
    ground's impulses the sweeps start from (:class:`Carry`; None: zero)."""
    acc, tension, dirs, _ = elastic_forces(model, x, v, rest, ext)
    if contact is None:
        warm = model.ground is not None and model.ground.tolerance > 0
        contact = jnp.zeros((2 if warm else 0,) + x.shape, x.dtype)
    return Carry(x, v, acc, tension, dirs, contact)


def _inputs_at(inputs: Inputs, t):
    """Every copy's rest lengths (nc, B) and external forces (N, 3, B) in effect at time ``t`` (s)."""
    rest, ext = inputs.rest, inputs.ext
    if inputs.rest_cables:
        ramp = jax.vmap(jax.vmap(jnp.interp, in_axes=(None, 0, 0)), in_axes=(None, 0, 0))
        rest = rest.at[np.asarray(inputs.rest_cables)].set(ramp(t, inputs.rest_times, inputs.rest_values).T)
    if inputs.force_times.shape[1]:
        k = jax.vmap(partial(jnp.searchsorted, side="right"), in_axes=(0, None))(inputs.force_times, t) - 1
        step_force = jnp.take_along_axis(inputs.force_values, jnp.maximum(k, 0)[:, None, None, None], axis=1)[:, 0]
        ext = jnp.where(k >= 0, jnp.moveaxis(step_force, 0, -1), ext)
    return rest, ext


class Outputs(NamedTuple):
    """A run's kept steps and its totals, batch last (the numba kernels' outputs):
    x, v (K, N, 3, B); impulses (K, nc, B) N*s summed since the previous kept step; slack (K, nc, B) bool;
    peak_impulses (nc, B) N*s, each cable's largest step impulse; snaps (nc, B) int, slack-to-taut switches
    between consecutive step ends (the run's start counts as the first); rest (nc, B), ext (N, 3, B): the
    inputs in effect at the last step."""

    x: jax.Array
    v: jax.Array
    impulses: jax.Array
    slack: jax.Array
    peak_impulses: jax.Array
    snaps: jax.Array
    rest: jax.Array
    ext: jax.Array


# A reverse-mode gradient of a run keeps, of each step, only what enters it (the carry and the inputs) and
# recomputes the step's inside on the way back: memory per copy-step of the carry (~2 kB in float64 for the
# icosahedron), not of every intermediate; a run that is not differentiated is unchanged.
_remat_step = jax.checkpoint(verlet_step)


def _scan_steps(model, h, inputs, scheduled, n_steps, first, loop, every):
    """``every`` steps of every copy from ``loop`` = (carry, step index k in the run, rest and ext in effect,
    was_slack, peak, snaps); a step at ``k >= n_steps`` (the last kept step's padding) changes nothing. Returns
    the loop after them and the impulses summed over them."""

    def body(state, _):
        loop, total = state
        carry, k, rest_prev, ext_prev, was_slack, peak, snaps = loop
        if scheduled:
            rest, ext = _inputs_at(inputs, (first + k).astype(h.dtype) * h)
            changed = jnp.any(rest != rest_prev) | jnp.any(ext != ext_prev)
            # a new input: the start forces at the step's start state with it (the numba batch's invalidate)
            carry = lax.cond(changed, lambda: start_carry(model, carry.x, carry.v, rest, ext, carry.contact),
                             lambda: carry)
        else:
            rest, ext = rest_prev, ext_prev
        carry, impulses, slack = _remat_step(model, carry, rest, ext, h)
        new = (carry, k + 1, rest, ext, slack, jnp.maximum(peak, impulses), snaps + (was_slack & ~slack))
        if n_steps % every == 0:   # no padding: nothing to mask (a select of the whole state costs a copy of it)
            return (new, total + impulses), None
        active = k < n_steps
        loop = jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), new, loop)
        return (loop, total + jnp.where(active, impulses, 0.0)), None

    zero = jnp.zeros_like(loop[0].tension)
    (loop, total), _ = lax.scan(body, (loop, zero), None, length=every)
    return loop, total


@partial(jax.jit, static_argnames=("n_steps", "every", "scheduled"))
def elastic_steps(model: ElasticModel, carry: Carry, inputs: Inputs, h, n_steps: int, every: int = 1,
                  first_step=0, was_slack=None, scheduled: bool = False):
    """``n_steps`` steps of ``h`` (s) of every copy from ``carry`` (:func:`start_carry`), keeping steps
    ``every``, ``2 every``, ... and the last (``K = ceil(n_steps / every)``). ``inputs`` are held, or, with
    ``scheduled``, a schedule evaluated at each step's start time ``(first_step + k) h``. ``was_slack`` (nc, B):
    the cables slack before the run (for the snaps; default: none). Returns the final :class:`Carry` and the
    :class:`Outputs`.

    One loop of K kept steps of ``every`` steps each, the steps past ``n_steps`` in the last masked out (so the
    step is compiled once: the compile time, not the masked steps, is what a short run pays)."""
    h = jnp.asarray(h, dtype=carry.x.dtype)
    if was_slack is None:
        was_slack = jnp.zeros(carry.tension.shape, dtype=bool)
    loop = (carry, jnp.asarray(0, dtype=jnp.int64), inputs.rest, inputs.ext, was_slack,
            jnp.zeros_like(carry.tension), jnp.zeros(carry.tension.shape, dtype=jnp.int32))

    def kept(loop, _):
        loop, total = _scan_steps(model, h, inputs, scheduled, n_steps, first_step, loop, every)
        return loop, (loop[0].x, loop[0].v, total, loop[4])

    loop, (xs, vs, imps, slacks) = lax.scan(kept, loop, None, length=-(-n_steps // every))
    carry, _, rest, ext, _, peak, snaps = loop
    return carry, Outputs(xs, vs, imps, slacks, peak, snaps, rest, ext)


def rollout(model: ElasticModel, x0, v0, inputs: Inputs, h, n_steps: int, every: int = 1, scheduled: bool = False):
    """The differentiable run: :func:`elastic_steps` from positions ``x0`` and velocities ``v0`` (N, 3, B)
    (their start forces computed here). Returns the :class:`Outputs`; ``jax.grad`` of any function of them with
    respect to the model's fields (stiffness, damping, masses, ...), ``x0``, ``v0`` or the inputs (rest lengths,
    external forces, a schedule's values) is the derivative of the discrete run (module docstring)."""
    rest, ext = (inputs.rest, inputs.ext) if not scheduled else _inputs_at(inputs, jnp.zeros((), x0.dtype))
    carry = start_carry(model, x0, v0, rest, ext)
    return elastic_steps(model, carry, inputs._replace(rest=rest, ext=ext), h, n_steps, every,
                         scheduled=scheduled)[1]
