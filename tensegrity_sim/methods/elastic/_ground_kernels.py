"""The elastic method's step with contacts, compiled: ``elastic/_kernels.py``'s velocity Verlet with the
contact impulse steps of :meth:`.elastic.ElasticMethod.verlet` (``methods/contact/friction.py``'s model: after the
first half-kick the nodes that would pass the ground during the drift get the impulse that lands them on
it; after the closing half-kick the touching nodes get the impulse that stops them moving into it, with
Newton's restitution for those that landed), each velocity problem solved block by block
(``_friction_block_kernels.py``: a moving rigid strut with its ends' contacts, a lone node's closed form;
with elastic cables nothing else couples the nodes). As in the reference, a solve also zeroes every
other rigid strut's length rate (RATTLE's projection, the QP's rows of the struts without contacts).

**Member pairs** (``contact: response: true``; a scene without a ground has its plane at ``-inf``). A step
in which ``MemberContacts`` would arm a member pair is not taken here: the kernel stops at it as at a block
it leaves unsolved (``failed``, with the reason ``MEMBERS``) and the caller takes it by the reference, whose
QP fixed point holds the pair rows beside the ground's. The test is ``MemberContacts.arm_step``'s before the
drift (gap minus ``h`` times the pair's closing rate on the free velocities within ``touch_tol``) and
``arm_settle``'s at the step's end (gap within ``touch_tol``), on every eligible pair
(``_detection_kernels._closest``'s closest points) less those whose boxes are farther apart than any rate
could close (``|n . u| <= 2 max_j |v_j|``, the weights' magnitudes summing to 2): a superset of the pairs the
reference arms (it also leaves out pairs its own boxes keep apart), so a step taken here is one where the
reference arms no pair, the same velocity problems.

Batch axis last, as the other kernels; :func:`ground_steps` steps the copies on every core (``prange``).
The ground's model (:func:`ground_arrays`):

    height, mu, restitution      the plane z = height, its Coulomb coefficient and restitution
    radii (N,) m                 each node's contact radius
    node_strut (N,) int64        the moving rigid strut a node ends (its row in rigid_members), or -1
    touch_tol m                  a node within this of the ground touches it (friction.TOUCH_TOL), and a
                                 member pair within this of contact
    pair_nodes (P, 4) int64      the eligible member pairs' nodes (a0, a1, b0, b1) (none without a response)
    pair_radii (P,) m            their radii's sums

What a step carries beside ``_elastic_kernels``' carry: ``warm`` (2, N, 3, B) N*s, each node's contact
impulse (friction x, y, normal) in the last drift (0) and closing (1) solve, the block solver's warm start
for the same solve of the next step (the two differ: a resting node's drift impulse holds its weight over
the drift, the closing one cancels the closing half-kick).
"""
from __future__ import annotations

import types
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ._kernels import _close, _drift, elastic_forces, gather_copy, keep, scatter_copy
from ..contact._detection_kernels import _closest
from ..contact._friction_block_kernels import MAX_ROWS, lone_contact, solve_block

__all__ = ["GroundModel", "ground_arrays", "ground_steps", "ground_steps_serial", "UNSOLVED", "MEMBERS"]

UNSOLVED = 1   # the reasons a step is left to the reference (``failed``): a contact block the Newton left unsolved,
MEMBERS = 2    # or a member pair armed


class GroundModel(NamedTuple):
    """The contacts' arrays of the kernels (module docstring), in their argument order."""

    height: float
    mu: float
    restitution: float
    radii: np.ndarray
    node_strut: np.ndarray
    touch_tol: float
    pair_nodes: np.ndarray
    pair_radii: np.ndarray


def ground_arrays(system, rigid, touch_tol: float, members=None) -> GroundModel:
    """The kernels' contact arrays for a ``System`` with a ground or a member contact response, its
    ``RigidStruts`` and its ``MemberContacts`` (None without a response)."""
    ground = system.scene.ground
    node_strut = np.full(system.n_nodes, -1, dtype=np.int64)
    for k, (a, c) in enumerate(rigid.ends):
        node_strut[a] = node_strut[c] = k
    if members is None:
        pair_nodes, pair_radii = np.zeros((0, 4), dtype=np.int64), np.zeros(0)
    else:
        i, j = members.detector.eligible_pairs()
        pair_nodes = np.ascontiguousarray(np.concatenate([system.ends[i], system.ends[j]], axis=1), dtype=np.int64)
        pair_radii = members.detector.radius[i] + members.detector.radius[j]
    height, mu, restitution = ((-np.inf, 0.0, 0.0) if ground is None
                               else (float(ground.height), float(ground.friction), float(ground.restitution)))
    return GroundModel(height, mu, restitution, np.ascontiguousarray(system.scene.node_radii, dtype=float),
                       node_strut, float(touch_tol), pair_nodes, pair_radii)


@njit(cache=True, error_model="numpy", _nrt=False)
def _pair_armed(x, v, h, speed, pair_nodes, pair_radii, touch_tol, ends4, out, s5, t5, b):
    """Whether copy ``b`` has a member pair that ``MemberContacts`` would arm (module docstring): with
    ``h`` > 0 before the drift of ``h`` s from ``x`` at the free velocities ``v`` (N, 3, B), whose largest
    node speed is ``speed`` m/s; with ``h`` = 0 touching at ``x``. The rest is scratch."""
    reach = touch_tol + 2.0 * h * speed
    for k in range(pair_nodes.shape[0]):
        a0 = pair_nodes[k, 0]
        a1 = pair_nodes[k, 1]
        b0 = pair_nodes[k, 2]
        b1 = pair_nodes[k, 3]
        far = reach + pair_radii[k]
        apart = False
        for j in range(3):   # the segments' boxes: their distance along an axis is at most the capsules'
            if (min(x[b0, j, b], x[b1, j, b]) - max(x[a0, j, b], x[a1, j, b]) > far
                    or min(x[a0, j, b], x[a1, j, b]) - max(x[b0, j, b], x[b1, j, b]) > far):
                apart = True
                break
        if apart:
            continue
        for i in range(4):
            for j in range(3):
                ends4[i, j] = x[pair_nodes[k, i], j, b]
        _closest(ends4, out, s5, t5)
        gap = out[0] - pair_radii[k]
        if gap <= touch_tol:
            return True
        if h > 0.0:   # apart: the normal is along the closest points' vector, out[3:6]
            s = out[1]
            t = out[2]
            rate = 0.0
            for j in range(3):
                u = (s - 1.0) * v[a0, j, b] - s * v[a1, j, b] + (1.0 - t) * v[b0, j, b] + t * v[b1, j, b]
                rate += u * out[3 + j]
            if gap - h * abs(rate / out[0]) <= touch_tol:
                return True
    return False


@njit(cache=True, error_model="numpy", _nrt=False)
def _solve(v, b, armed, target, inv_mass, ends, rigid_members, rigid_w, dirs, node_strut, mu, warm, contact,
           work, inv2, vel, z, ends_k, target_k, vel3, z3):
    """The armed contacts' velocity problem of copy ``b``, block by block, in place on ``v``; adds the
    contact impulses to ``contact`` (N, 3) and keeps them in ``warm`` (N, 3, B), this solve's warm starts. ``dirs`` (nr, 3, B): the rigid
    struts' unit vectors at the configuration. The rest is scratch. Returns False if a block was not
    solved (``v`` is then partly changed: the caller starts the step again in the reference)."""
    for p in range(v.shape[0]):
        if not armed[p]:
            for j in range(3):
                warm[p, j, b] = 0.0
    for k in range(rigid_members.shape[0]):
        m = rigid_members[k]
        a = ends[m, 0]
        c = ends[m, 1]
        n0 = dirs[k, 0, b]
        n1 = dirs[k, 1, b]
        n2 = dirs[k, 2, b]
        count = 0
        if armed[a]:
            ends_k[count] = 0
            target_k[count] = target[a]
            count += 1
        if armed[c]:
            ends_k[count] = 1
            target_k[count] = target[c]
            count += 1
        if count == 0:   # RATTLE's projection (_rattle) of this strut alone
            rate = ((v[c, 0, b] - v[a, 0, b]) * n0 + (v[c, 1, b] - v[a, 1, b]) * n1 + (v[c, 2, b] - v[a, 2, b]) * n2)
            s = rate / rigid_w[k, k]
            v[a, 0, b] += inv_mass[a] * (s * n0)
            v[a, 1, b] += inv_mass[a] * (s * n1)
            v[a, 2, b] += inv_mass[a] * (s * n2)
            v[c, 0, b] -= inv_mass[c] * (s * n0)
            v[c, 1, b] -= inv_mass[c] * (s * n1)
            v[c, 2, b] -= inv_mass[c] * (s * n2)
            continue
        inv2[0] = inv_mass[a]
        inv2[1] = inv_mass[c]
        vel3[0] = n0
        vel3[1] = n1
        vel3[2] = n2
        for j in range(3):
            vel[0, j] = v[a, j, b]
            vel[1, j] = v[c, j, b]
        z[0] = 0.0
        for i in range(count):
            p = a if ends_k[i] == 0 else c
            for j in range(3):
                z[1 + 3 * i + j] = warm[p, j, b]
        if solve_block(inv2, True, vel3, ends_k, target_k, count, mu, vel, z, work) < 0:
            return False
        for j in range(3):
            v[a, j, b] = vel[0, j]
            v[c, j, b] = vel[1, j]
        for i in range(count):
            p = a if ends_k[i] == 0 else c
            for j in range(3):
                contact[p, j] += z[1 + 3 * i + j]
                warm[p, j, b] = z[1 + 3 * i + j]
    for p in range(v.shape[0]):
        if armed[p] and node_strut[p] < 0:
            for j in range(3):
                vel3[j] = v[p, j, b]
            lone_contact(inv_mass[p], vel3, target[p], mu, z3)
            for j in range(3):
                v[p, j, b] = vel3[j]
                contact[p, j] += z3[j]
                warm[p, j, b] = z3[j]
    return True


@njit(cache=True, error_model="numpy", _nrt=False)
def _ground_step(x, v, rest, ext, h, ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
                 rigid_members, rigid_length_sq, rigid_w, acc, tension, rigid_dirs, height, mu, restitution, radii,
                 node_strut, touch_tol, pair_nodes, pair_radii, warm, dx, impulses, slack, contact, armed, target,
                 landing, work, inv2, vel, z, ends_k, target_k, vel3, z3, ends4, out6, s5, t5, b):
    """One step of copy ``b`` with the contacts (module docstring), in place as ``_elastic_kernels._step``;
    ``contact`` (N, 3) gets the ground's impulses of the step. Returns 0, or the reason the step is left to
    the reference (``UNSOLVED``, ``MEMBERS``: the copy's ``x``, ``v`` and carry are then not those of a step,
    the caller restarts it)."""
    n_nodes = x.shape[0]
    half = 0.5 * h
    found = False
    speed = 0.0
    for p in range(n_nodes):
        for j in range(3):
            contact[p, j] = 0.0
        vz0 = v[p, 2, b]
        for j in range(3):
            v[p, j, b] += half * acc[p, j, b]
        speed = max(speed, np.sqrt(v[p, 0, b] * v[p, 0, b] + v[p, 1, b] * v[p, 1, b] + v[p, 2, b] * v[p, 2, b]))
        gap = x[p, 2, b] - radii[p] - height
        armed[p] = inv_mass[p] > 0.0 and gap - h * abs(v[p, 2, b]) <= touch_tol
        # the drift's target lands the node on the ground, capped at the reversal of its start velocity
        # but never letting it sink past touch_tol deep (ContactSet.arm_step's floored)
        target[p] = max(min(-gap / h, -vz0), min(-(gap + touch_tol) / h, 0.0))
        landing[p] = max(-v[p, 2, b], 0.0) if gap > touch_tol else 0.0
        found = found or armed[p]
    if pair_nodes.shape[0] and _pair_armed(x, v, h, speed, pair_nodes, pair_radii, touch_tol, ends4, out6, s5, t5, b):
        return MEMBERS
    if found and not _solve(v, b, armed, target, inv_mass, ends, rigid_members, rigid_w, rigid_dirs, node_strut,
                            mu, warm[0], contact, work, inv2, vel, z, ends_k, target_k, vel3, z3):
        return UNSOLVED
    _drift(x, v, h, ends, inv_mass, rigid_members, rigid_length_sq, rigid_w, rigid_dirs, dx, b)
    _close(x, v, rest, ext, h, ends, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
           rigid_members, rigid_w, acc, tension, rigid_dirs, dx, impulses, slack, b)
    if pair_nodes.shape[0] and _pair_armed(x, v, 0.0, 0.0, pair_nodes, pair_radii, touch_tol, ends4, out6, s5, t5,
                                           b):
        return MEMBERS
    found = False
    for p in range(n_nodes):
        armed[p] = inv_mass[p] > 0.0 and x[p, 2, b] - radii[p] - height <= touch_tol
        target[p] = restitution * landing[p]
        found = found or armed[p]
    if found and not _solve(v, b, armed, target, inv_mass, ends, rigid_members, rigid_w, rigid_dirs, node_strut, mu,
                            warm[1], contact, work, inv2, vel, z, ends_k, target_k, vel3, z3):
        return UNSOLVED
    return 0


@njit(cache=True, error_model="numpy", _nrt=False)
def _take_inputs(rest_seq, ext_seq, s, bs, rest, ext) -> bool:
    """Step ``s``'s inputs of copy ``bs`` into ``rest`` (nc, 1) and ``ext`` (N, 3, 1); whether they changed."""
    changed = False
    for ci in range(rest.shape[0]):
        if rest[ci, 0] != rest_seq[s, ci, bs]:
            rest[ci, 0] = rest_seq[s, ci, bs]
            changed = True
    for i in range(ext.shape[0]):
        for j in range(3):
            if ext[i, j, 0] != ext_seq[s, i, j, bs]:
                ext[i, j, 0] = ext_seq[s, i, j, bs]
                changed = True
    return changed


def _ground_steps(x, v, rest, ext, h, n_steps, every, ends, stiffness, floor, strut_rest, damping, inv_mass,
                  gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, acc, tension, rigid_dirs, height,
                  mu, restitution, radii, node_strut, touch_tol, pair_nodes, pair_radii, warm, rest_seq, ext_seq, out_x,
                  out_v, out_impulses, out_slack, out_contact, failed, reason, blocks):
    """``n_steps`` steps of ``h`` (s) of every copy (in ``blocks`` contiguous blocks of copies spread over the
    cores), in place on ``x``, ``v`` and the carry (``acc``, ``tension``, ``rigid_dirs``, ``warm``); the kept steps as
    ``_elastic_kernels.elastic_steps`` keeps them, and ``out_contact`` (K, N, 3, B) the ground's impulses
    summed like the cables'. ``failed`` (B,) int64: -1, or the step of the copy left to the reference (the copy
    stops there: its ``x``, ``v`` are those at that step's start, its carry is not), and ``reason`` (B,) int64
    why (``UNSOLVED``, ``MEMBERS``).
    Each copy is stepped in contiguous arrays of its own (a batch of one: the very arithmetic of
    ``Simulator``'s loop, and no stride of B between a copy's numbers).

    ``rest_seq`` (T, nc, Bs), ``ext_seq`` (T, N, 3, Bs): with T = ``n_steps``, each step's rest lengths and external
    forces (a command schedule evaluated at the steps' start times; Bs = B, or 1 for every copy), with T = 0
    ``rest`` and ``ext`` held. A step whose inputs differ from the last step's starts from forces computed anew
    at its start (as ``Simulator`` does after a new input: the carry dropped, ``elastic_forces`` at the state;
    the contact warm starts kept): a run with a schedule here is the very arithmetic of commanding each step."""
    n_nodes = x.shape[0]
    nc, n_copies = rest.shape
    nr = rigid_members.shape[0]
    for blk in prange(blocks):
        # a block of copies a thread (the scratch allocated once for its copies: allocated for each copy, it
        # cost 7 ms a call of 1,024 copies); the model's arrays copied for each block: numba counts references
        # to an array passed between its functions, atomically, and threads sharing one array's count take turns
        # at it (1,024 rolling copies through BatchSimulator.run on 2 threads, best of 6: 178-204k scene-steps/s
        # sharing them, 233-243k with copies)
        ends_b, stiffness_b, strut_rest_b, damping_b = ends.copy(), stiffness.copy(), strut_rest.copy(), damping.copy()
        inv_mass_b, gravity_b, rigid_members_b = inv_mass.copy(), gravity_force.copy(), rigid_members.copy()
        rigid_length_sq_b, rigid_w_b, radii_b, node_strut_b = (rigid_length_sq.copy(), rigid_w.copy(), radii.copy(),
                                                               node_strut.copy())
        floor_b, pair_nodes_b, pair_radii_b = floor.copy(), pair_nodes.copy(), pair_radii.copy()
        xb = np.empty((n_nodes, 3, 1))
        vb = np.empty((n_nodes, 3, 1))
        accb = np.empty((n_nodes, 3, 1))
        extb = np.empty((n_nodes, 3, 1))
        warmb = np.empty((2, n_nodes, 3, 1))
        restb = np.empty((nc, 1))
        tensionb = np.empty((nc, 1))
        dirsb = np.empty((nr, 3, 1))
        dx = np.empty((n_nodes, 3))
        imp = np.empty(nc)
        total = np.empty(nc)
        sl = np.empty(nc, dtype=np.bool_)
        contact = np.empty((n_nodes, 3))
        total_contact = np.empty((n_nodes, 3))
        armed = np.empty(n_nodes, dtype=np.bool_)
        target = np.empty(n_nodes)
        landing = np.empty(n_nodes)
        x0 = np.empty((n_nodes, 3))
        v0 = np.empty((n_nodes, 3))
        work = np.empty((6, MAX_ROWS, MAX_ROWS))
        inv2 = np.empty(2)
        vel = np.empty((2, 3))
        z = np.empty(MAX_ROWS)
        ends_k = np.empty(2, dtype=np.int64)
        target_k = np.empty(2)
        vel3 = np.empty(3)
        z3 = np.empty(3)
        ends4 = np.empty((4, 3))
        out6 = np.empty(6)
        s5 = np.empty(5)
        t5 = np.empty(5)
        first = np.int64(blk)   # prange's index is unsigned: with a signed number it would make a float
        for b in range(n_copies * first // blocks, n_copies * (first + 1) // blocks):
            gather_copy(x, v, acc, ext, rest, tension, rigid_dirs, b, xb, vb, accb, extb, restb, tensionb, dirsb)
            for i in range(n_nodes):
                for j in range(3):
                    warmb[0, i, j, 0] = warm[0, i, j, b]
                    warmb[1, i, j, 0] = warm[1, i, j, b]
            total[:] = 0.0   # each copy starts from the scratch a call of its own would have
            total_contact[:] = 0.0
            work[:] = 0.0
            z[:] = 0.0
            failed[b] = -1
            reason[b] = 0
            bs = b if rest_seq.shape[2] > 1 else 0   # the copy's column of the inputs (or the one of every copy's)
            for s in range(n_steps):
                for i in range(n_nodes):
                    for j in range(3):
                        x0[i, j] = xb[i, j, 0]
                        v0[i, j] = vb[i, j, 0]
                if rest_seq.shape[0] > 0 and _take_inputs(rest_seq, ext_seq, s, bs, restb, extb):
                    elastic_forces(xb, vb, restb, extb, ends_b, stiffness_b, floor_b, strut_rest_b, damping_b,
                                   inv_mass_b, gravity_b, rigid_members_b, accb, tensionb, dirsb)
                why = _ground_step(xb, vb, restb, extb, h, ends_b, stiffness_b, floor_b, strut_rest_b, damping_b,
                                   inv_mass_b, gravity_b, rigid_members_b, rigid_length_sq_b, rigid_w_b, accb,
                                   tensionb, dirsb, height, mu, restitution, radii_b, node_strut_b, touch_tol,
                                   pair_nodes_b, pair_radii_b, warmb, dx, imp, sl, contact, armed, target, landing,
                                   work, inv2, vel, z, ends_k, target_k, vel3, z3, ends4, out6, s5, t5, 0)
                if why:
                    for i in range(n_nodes):
                        for j in range(3):
                            xb[i, j, 0] = x0[i, j]
                            vb[i, j, 0] = v0[i, j]
                    failed[b] = s
                    reason[b] = why
                    break
                for ci in range(nc):
                    total[ci] += imp[ci]
                for i in range(n_nodes):
                    for j in range(3):
                        total_contact[i, j] += contact[i, j]
                if (s + 1) % every == 0 or s == n_steps - 1:
                    k = s // every
                    keep(xb, vb, 0, total, sl, k, b, out_x, out_v, out_impulses, out_slack)
                    for i in range(n_nodes):
                        for j in range(3):
                            out_contact[k, i, j, b] = total_contact[i, j]
                            total_contact[i, j] = 0.0
            scatter_copy(xb, vb, accb, tensionb, dirsb, b, x, v, acc, tension, rigid_dirs)
            for i in range(n_nodes):
                for j in range(3):
                    warm[0, i, j, b] = warmb[0, i, j, 0]
                    warm[1, i, j, b] = warmb[1, i, j, 0]


def _named(function, name: str):
    """``function`` under another name: numba names a kernel's cache files after the function (not its
    options), so two compilations of one function would load each other's code from the cache."""
    twin = types.FunctionType(function.__code__, function.__globals__, name, function.__defaults__,
                              function.__closure__)
    twin.__qualname__ = name
    return twin


# one loop, two compilations: a batch spreads its copies over the cores; one copy (Simulator) runs without
# the thread pool's start-up
ground_steps = njit(cache=True, parallel=True, error_model="numpy")(_named(_ground_steps, "_ground_steps_parallel"))
ground_steps_serial = njit(cache=True, error_model="numpy")(_ground_steps)
