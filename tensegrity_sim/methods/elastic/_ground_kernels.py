"""The elastic method's step with contacts, compiled: ``elastic/_kernels.py``'s velocity Verlet with the
contact impulse steps of :meth:`.elastic.ElasticMethod.verlet` (``methods/contact/friction.py``'s model: after the
first half-kick the nodes that would pass the ground during the drift get the impulse that lands them on
it; after the closing half-kick the touching nodes get the impulse that stops them moving into it, with
Newton's restitution for those that landed), each velocity problem solved block by block
(``_friction_block_kernels.py``: a moving rigid strut with its ends' contacts, a lone node's closed form;
with elastic cables nothing else couples the nodes). As in the reference, a solve also zeroes every
other rigid strut's length rate (RATTLE's projection, the QP's rows of the struts without contacts).

**Member pairs** (``contact: response: true``; a scene without a ground has its plane at ``-inf``) are armed as
``MemberContacts`` arms them (:func:`_arm_pairs`): before the drift, ``arm_step``'s test (gap minus ``h`` times
the pair's closing rate on the free velocities within ``touch_tol``; the target that closes the gap, capped at
the reversal of the rate at the step's start, floored at ``touch_tol`` deep), at the step's end
``arm_settle``'s (gap within ``touch_tol``; Newton's restitution for those that landed), on the eligible pairs
whose boxes, grown as ``MemberContacts.candidates`` grows them, overlap, with ``_detection_kernels._closest``'s
closest points and ``member.tangents``' frames. An armed pair joins the bodies of its moving nodes (union-find
over the struts and the lone nodes) into one coupled block, solved by ``solve_coupled`` (the same Newton on
the general rows); its impulse (normal, and friction in space, on the second member) is recorded by step
(``out_pairs``). A step whose pair's segments meet (no normal: the reference's ``contact_geometry`` has its
fallback) or whose coupled block has more than ``MAX_COUPLED`` rows is left to the reference (``MEMBERS``).

Batch axis last, as the other kernels; :func:`ground_steps` steps the copies on every core (``prange``).
The ground's model (:func:`ground_arrays`):

    height, mu, restitution      the plane z = height, its Coulomb coefficient and restitution
    radii (N,) m                 each node's contact radius
    node_strut (N,) int64        the moving rigid strut a node ends (its row in rigid_members), or -1
    touch_tol m                  a node within this of the ground touches it (friction.TOUCH_TOL), and a
                                 member pair within this of contact
    pair_nodes (P, 4) int64      the eligible member pairs' nodes (a0, a1, b0, b1) (none without a response;
                                 :func:`eligible_pairs`)
    pair_radii (P, 2) m          their members' radii
    pair_mu, pair_restitution    the member contacts' Coulomb coefficient and restitution

What a step carries beside ``_elastic_kernels``' carry: ``warm`` (2, N + P, 3, B) N*s, each node's contact
impulse (friction x, y, normal) and each pair's (in space) in the last drift (0) and closing (1) solve, the
block solver's warm start for the same solve of the next step (the two differ: a resting node's drift
impulse holds its weight over the drift, the closing one cancels the closing half-kick).
"""
from __future__ import annotations

import types
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ._kernels import (_close, _close_copies, _drift, _drift_copies, _forces, _forces_copies, gather_copies,
                       scatter_copies)
from .._mass_kernels import axial_inverse
from ..contact._detection_kernels import _closest
from ..contact._friction_block_kernels import MAX_COUPLED, MAX_ROWS, lone_contact, solve_block, solve_coupled

__all__ = ["GroundModel", "ground_arrays", "ground_steps", "ground_steps_serial", "pair_scratch", "UNSOLVED", "MEMBERS",
           "FULL"]

UNSOLVED = 1   # the reasons a step is left to the reference (``failed``): a contact block the Newton left unsolved,
MEMBERS = 2    # or a member pair's the kernel does not take (segments that meet, a coupled block beyond its scratch);
FULL = 3       # and where the loop stops before a step, not left to the reference: no room for its pairs' impulses


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
    pair_mu: float
    pair_restitution: float


def eligible_pairs(system, members=None) -> np.ndarray:
    """(P, 2) int64: the member pairs ``(i, j)``, ``i < j`` (system order), that the kernels examine (the
    rows of ``pair_nodes``): the eligible pairs of ``MemberContacts`` ``members`` (None: none) with a free
    node (two fixed members never move against each other)."""
    if members is None:
        return np.zeros((0, 2), dtype=np.int64)
    i, j = members.detector.eligible_pairs()
    moving = system.free[system.ends[i]].any(axis=1) | system.free[system.ends[j]].any(axis=1)
    return np.stack([i[moving], j[moving]], axis=1).astype(np.int64)


def ground_arrays(system, rigid, touch_tol: float, members=None) -> GroundModel:
    """The kernels' contact arrays for a ``System`` with a ground or a member contact response, its
    ``RigidStruts`` and its ``MemberContacts`` (None without a response)."""
    ground = system.scene.ground
    node_strut = np.full(system.n_nodes, -1, dtype=np.int64)
    for k, (a, c) in enumerate(rigid.ends):
        node_strut[a] = node_strut[c] = k
    pairs = eligible_pairs(system, members)
    pair_nodes = np.ascontiguousarray(system.ends[pairs].reshape(-1, 4), dtype=np.int64)
    pair_radii = (np.zeros((0, 2)) if members is None
                  else np.ascontiguousarray(members.detector.radius[pairs], dtype=float))
    pair_mu, pair_restitution = (0.0, 0.0) if members is None else (float(members.mu), float(members.restitution))
    height, mu, restitution = ((-np.inf, 0.0, 0.0) if ground is None
                               else (float(ground.height), float(ground.friction), float(ground.restitution)))
    return GroundModel(height, mu, restitution, np.ascontiguousarray(system.scene.node_radii, dtype=float),
                       node_strut, float(touch_tol), pair_nodes, pair_radii, pair_mu, pair_restitution)


@njit(cache=True, error_model="numpy", _nrt=False)
def _arm_pairs(x, v, v0, h, pair_nodes, pair_radii, touch_tol, restitution, armed_pairs, frames, weights, targets,
               landing, ends4, out, s5, t5, b):
    """The member pairs of copy ``b`` that ``MemberContacts`` arms (module docstring). With ``h`` > 0,
    ``arm_step``'s before the drift of ``h`` s from ``x`` (N, 3, B) at the free velocities ``v`` (N, 3, B), the
    step starting at ``v0`` (N, 3): within ``touch_tol`` of contact by the drift's end on the free closing
    rate, each targeting the rate that closes its gap (capped at the reversal of its rate at ``v0``, floored
    at ``touch_tol`` deep), and ``landing`` (P,) gets the closing speed of those not yet touching (0 for the
    others). With ``h`` = 0, ``arm_settle``'s at ``x``: those touching, each targeting ``restitution`` times
    its ``landing`` speed. Writes the armed pairs' indices into ``armed_pairs`` and, by pair index,
    ``frames`` (P, 3, 3) (the tangents, then the unit normal from a to b), ``weights`` (P, 4) and ``targets``
    (P,) m/s. Returns how many, or -1 where a pair's segments meet (no normal between their closest points:
    the reference's ``contact_geometry`` takes it). The pairs examined are those whose boxes, grown as
    ``MemberContacts.candidates`` grows them, overlap; the rest is scratch."""
    pad = touch_tol
    if h > 0.0:   # the candidates' reach: h times the largest velocity components, free and at the start
        fast = 0.0
        start = 0.0
        for p in range(x.shape[0]):
            for j in range(3):
                fast = max(fast, abs(v[p, j, b]))
                start = max(start, abs(v0[p, j]))
        pad = h * (fast + start) + touch_tol
    count = 0
    for k in range(pair_nodes.shape[0]):
        a0 = pair_nodes[k, 0]
        a1 = pair_nodes[k, 1]
        b0 = pair_nodes[k, 2]
        b1 = pair_nodes[k, 3]
        grow_a = pair_radii[k, 0] + pad
        grow_b = pair_radii[k, 1] + pad
        apart = False
        for j in range(3):   # the members' boxes, grown by their radii and the reach
            if (min(x[b0, j, b], x[b1, j, b]) - grow_b > max(x[a0, j, b], x[a1, j, b]) + grow_a
                    or min(x[a0, j, b], x[a1, j, b]) - grow_a > max(x[b0, j, b], x[b1, j, b]) + grow_b):
                apart = True
                break
        if h > 0.0:
            landing[k] = 0.0
        if apart:
            continue
        size = 0.0
        for i in range(4):
            for j in range(3):
                ends4[i, j] = x[pair_nodes[k, i], j, b]
                size = max(size, abs(ends4[i, j]))
        _closest(ends4, out, s5, t5)
        gap = out[0] - (pair_radii[k, 0] + pair_radii[k, 1])
        if gap > touch_tol and h == 0.0:
            continue
        s = out[1]
        t = out[2]
        w0 = s - 1.0
        w1 = -s
        w2 = 1.0 - t
        w3 = t
        rate = 0.0    # the closing rate on the free velocities (h > 0)
        rate0 = 0.0   # ... and at the step's start
        if out[0] <= 1e-12 * (1.0 + size):
            return -1
        for j in range(3):
            n = out[3 + j] / out[0]
            rate += n * (w0 * v[a0, j, b] + w1 * v[a1, j, b] + w2 * v[b0, j, b] + w3 * v[b1, j, b])
            rate0 += n * (w0 * v0[a0, j] + w1 * v0[a1, j] + w2 * v0[b0, j] + w3 * v0[b1, j])
        if h > 0.0:
            if gap - h * abs(rate) > touch_tol:
                continue
            target = max(min(-gap / h, -rate0), -(gap + touch_tol) / h)
            if gap > touch_tol:
                landing[k] = max(-rate, 0.0)
        else:
            target = restitution * landing[k]
        armed_pairs[count] = k
        count += 1
        targets[k] = target
        weights[k, 0] = w0
        weights[k, 1] = w1
        weights[k, 2] = w2
        weights[k, 3] = w3
        least = 0   # the tangents (member.tangents): the normal crossed with the axis it is least aligned with
        for j in range(3):
            frames[k, 2, j] = out[3 + j] / out[0]
        for j in range(1, 3):
            if abs(frames[k, 2, j]) < abs(frames[k, 2, least]):
                least = j
        n0 = frames[k, 2, 0]
        n1 = frames[k, 2, 1]
        n2 = frames[k, 2, 2]
        c0 = n1 * (least == 2) - n2 * (least == 1)
        c1 = n2 * (least == 0) - n0 * (least == 2)
        c2 = n0 * (least == 1) - n1 * (least == 0)
        norm = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        frames[k, 0, 0] = c0 / norm
        frames[k, 0, 1] = c1 / norm
        frames[k, 0, 2] = c2 / norm
        frames[k, 1, 0] = n1 * frames[k, 0, 2] - n2 * frames[k, 0, 1]
        frames[k, 1, 1] = n2 * frames[k, 0, 0] - n0 * frames[k, 0, 2]
        frames[k, 1, 2] = n0 * frames[k, 0, 1] - n1 * frames[k, 0, 0]
    return count


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _root(parent, i):
    """The root of ``i`` in the union-find forest ``parent``, halving the path on the way."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _pair_root(parent, pair_nodes, k, inv_mass, node_strut, nr):
    """The union-find root of pair ``k``'s block: that of its first moving node's body (its rigid strut, or
    the node alone: ``nr`` + the node)."""
    p = pair_nodes[k, 0]
    for e in range(1, 4):
        if inv_mass[p, 0] > 0.0:
            break
        p = pair_nodes[k, e]
    return _root(parent, nr + p if node_strut[p] < 0 else node_strut[p])


@njit(cache=True, error_model="numpy", _nrt=False)
def _solve_coupled(v, b, root, armed, target, inv_mass, ends, rigid_members, dirs, node_strut, mu, warm, contact,
                   n_armed, pair_nodes, pair_mu, pairs):
    """The coupled block of the bodies whose union-find root is ``root`` (:func:`_solve`): its rigid struts'
    rows, its nodes' ground contacts and its member pairs' contacts by ``solve_coupled``, in place on ``v``;
    the ground's impulses added to ``contact`` and kept in ``warm`` as :func:`_solve`'s, each pair's in
    ``pair_impulse`` (P, 4) (normal, then the friction in space) and in ``warm``'s row ``N + k`` (its impulse in
    space, the next solve's warm start in that solve's frame). Returns 0, ``UNSOLVED``, or ``MEMBERS`` (a
    block beyond the scratch's ``MAX_COUPLED`` rows). ``pairs``: :func:`pair_scratch`'s."""
    (armed_pairs, frames, weights, targets, _, pair_impulse, _, parent, _, local, nodes, g, inv_b, vel_b, z_b, target_b,
     mu_b, cwork) = pairs
    n_nodes = v.shape[0]
    nr = rigid_members.shape[0]
    max_nodes = inv_b.shape[0]
    nb = 0
    s = 0
    for k in range(nr):   # the struts' ends, then the lone nodes
        if _root(parent, k) == root:
            for e in range(2):
                if nb == max_nodes:
                    return MEMBERS
                p = ends[rigid_members[k], e]
                local[p] = nb
                nodes[nb] = p
                nb += 1
            s += 1
    for p in range(n_nodes):
        if node_strut[p] < 0 and inv_mass[p, 0] > 0.0 and _root(parent, nr + p) == root:
            if nb == max_nodes:
                return MEMBERS
            local[p] = nb
            nodes[nb] = p
            nb += 1
    k_ground = 0
    for i in range(nb):
        k_ground += armed[nodes[i]]
    k_pairs = 0
    for c in range(n_armed):
        k_pairs += _pair_root(parent, pair_nodes, armed_pairs[c], inv_mass, node_strut, nr) == root
    q = s + 3 * (k_ground + k_pairs)
    if q > g.shape[0]:
        return MEMBERS
    for i in range(q):
        for col in range(3 * nb):
            g[i, col] = 0.0
    row = 0
    for k in range(nr):
        if _root(parent, k) == root:
            la = local[ends[rigid_members[k], 0]]
            lc = local[ends[rigid_members[k], 1]]
            for j in range(3):
                g[row, 3 * la + j] = -dirs[k, j, b]
                g[row, 3 * lc + j] = dirs[k, j, b]
            row += 1
    c = 0
    for i in range(nb):
        p = nodes[i]
        inv_b[i, 0] = inv_mass[p, 0]
        inv_b[i, 1] = inv_mass[p, 1] if i < 2 * s else 0.0   # the struts' ends first, in pairs
        for j in range(3):
            vel_b[i, j] = v[p, j, b]
        if armed[p]:
            for j in range(3):
                g[row + j, 3 * i + j] = 1.0
                z_b[row + j] = warm[p, j, b]
            target_b[c] = target[p]
            mu_b[c] = mu
            row += 3
            c += 1
    for a in range(n_armed):
        k = armed_pairs[a]
        if _pair_root(parent, pair_nodes, k, inv_mass, node_strut, nr) != root:
            continue
        for r in range(3):
            for e in range(4):
                p = pair_nodes[k, e]
                if inv_mass[p, 0] > 0.0:
                    for j in range(3):
                        g[row + r, 3 * local[p] + j] = weights[k, e] * frames[k, r, j]
            acc = 0.0
            for j in range(3):
                acc += warm[n_nodes + k, j, b] * frames[k, r, j]
            z_b[row + r] = acc
        target_b[c] = targets[k]
        mu_b[c] = pair_mu
        row += 3
        c += 1
    if solve_coupled(inv_b, g, nb, s, k_ground + k_pairs, target_b, mu_b, vel_b, z_b, cwork) < 0:
        return UNSOLVED
    for i in range(nb):
        for j in range(3):
            v[nodes[i], j, b] = vel_b[i, j]
    row = s
    for i in range(nb):
        p = nodes[i]
        if armed[p]:
            for j in range(3):
                contact[p, j] += z_b[row + j]
                warm[p, j, b] = z_b[row + j]
            row += 3
    for a in range(n_armed):
        k = armed_pairs[a]
        if _pair_root(parent, pair_nodes, k, inv_mass, node_strut, nr) != root:
            continue
        pair_impulse[k, 0] += z_b[row + 2]
        for j in range(3):
            friction = z_b[row] * frames[k, 0, j] + z_b[row + 1] * frames[k, 1, j]
            pair_impulse[k, 1 + j] += friction
            warm[n_nodes + k, j, b] = friction + z_b[row + 2] * frames[k, 2, j]
        row += 3
    return 0


@njit(cache=True, error_model="numpy", _nrt=False)
def _join(n_armed, pair_nodes, inv_mass, node_strut, n_rigid, pairs):
    """The bodies (union-find over the rigid struts, then the nodes) that the ``n_armed`` member pairs armed in
    ``pairs`` (:func:`pair_scratch`) join: each pair joins the bodies of its moving nodes, and each joined
    set's root is marked in the scratch's ``joined``."""
    armed_pairs, parent, joined = pairs[0], pairs[7], pairs[8]
    for i in range(parent.shape[0]):
        parent[i] = i
        joined[i] = False
    for a in range(n_armed):
        k = armed_pairs[a]
        first = -1
        for e in range(4):
            p = pair_nodes[k, e]
            if inv_mass[p, 0] > 0.0:
                body = _root(parent, n_rigid + p if node_strut[p] < 0 else node_strut[p])
                if first < 0:
                    first = body
                elif body != first:
                    parent[body] = first
    for a in range(n_armed):
        joined[_pair_root(parent, pair_nodes, armed_pairs[a], inv_mass, node_strut, n_rigid)] = True


@njit(cache=True, error_model="numpy", _nrt=False)
def _solve(v, b, armed, target, inv_mass, ends, rigid_members, rigid_w, dirs, node_strut, mu, warm, contact,
           work, inv2, vel, z, ends_k, target_k, vel3, z3, n_armed, parent, joined):
    """The armed ground contacts' velocity problem of copy ``b``, block by block, in place on ``v``; adds their
    impulses to ``contact`` (N, 3) and keeps them in ``warm`` (N + P, 3, B), this solve's warm starts. ``dirs``
    (nr, 3, B): the rigid struts' unit vectors at the configuration. A rigid strut with its ends' ground
    contacts is a block (``solve_block``), a lone node's contact one more (its closed form). With ``n_armed``
    member pairs, the bodies they join (:func:`_join`'s ``parent`` and ``joined``) are skipped: their coupled
    blocks are :func:`_solve_pairs`' (after this, in the same solve). The rest is scratch. Returns 0, or
    ``UNSOLVED`` if a block was not solved (the caller starts the step again in the reference)."""
    n_nodes = v.shape[0]
    nr = rigid_members.shape[0]
    for p in range(n_nodes):
        if not armed[p]:
            for j in range(3):
                warm[p, j, b] = 0.0
    for k in range(nr):
        if n_armed and joined[_root(parent, k)]:
            continue
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
            wa = axial_inverse(inv_mass, a)
            wc = axial_inverse(inv_mass, c)
            v[a, 0, b] += wa * (s * n0)
            v[a, 1, b] += wa * (s * n1)
            v[a, 2, b] += wa * (s * n2)
            v[c, 0, b] -= wc * (s * n0)
            v[c, 1, b] -= wc * (s * n1)
            v[c, 2, b] -= wc * (s * n2)
            continue
        inv2[0] = inv_mass[a, 0]
        inv2[1] = inv_mass[c, 0]
        inv2[2] = inv_mass[a, 1]   # M^-1's cross entry of the rod's block (0 lumped or with a fixed end)
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
            return UNSOLVED
        for j in range(3):
            v[a, j, b] = vel[0, j]
            v[c, j, b] = vel[1, j]
        for i in range(count):
            p = a if ends_k[i] == 0 else c
            for j in range(3):
                contact[p, j] += z[1 + 3 * i + j]
                warm[p, j, b] = z[1 + 3 * i + j]
    for p in range(n_nodes):
        if armed[p] and node_strut[p] < 0 and not (n_armed and joined[_root(parent, nr + p)]):
            for j in range(3):
                vel3[j] = v[p, j, b]
            lone_contact(inv_mass[p, 0], vel3, target[p], mu, z3)
            for j in range(3):
                v[p, j, b] = vel3[j]
                contact[p, j] += z3[j]
                warm[p, j, b] = z3[j]
    return 0


@njit(cache=True, error_model="numpy", _nrt=False)
def _solve_pairs(v, b, armed, target, inv_mass, ends, rigid_members, dirs, node_strut, mu, warm, contact, n_armed,
                 pair_nodes, pair_mu, pairs):
    """The coupled blocks of :func:`_solve` (its arguments; ``pairs``: :func:`pair_scratch`, joined by
    :func:`_join`), each once, from its first pair (:func:`_solve_coupled`). Returns 0, ``UNSOLVED``, or
    ``MEMBERS`` for a coupled block beyond the scratch (``v`` is then partly changed: the caller starts the step
    again in the reference)."""
    armed_pairs, parent, joined = pairs[0], pairs[7], pairs[8]
    nr = rigid_members.shape[0]
    for a in range(n_armed):
        root = _pair_root(parent, pair_nodes, armed_pairs[a], inv_mass, node_strut, nr)
        if not joined[root]:
            continue
        joined[root] = False
        why = _solve_coupled(v, b, root, armed, target, inv_mass, ends, rigid_members, dirs, node_strut, mu, warm,
                             contact, n_armed, pair_nodes, pair_mu, pairs)
        if why:
            return why
    return 0


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _solve_all(v, b, armed, target, inv_mass, ends, rigid_members, rigid_w, dirs, node_strut, mu, warm, contact,
               work, inv2, vel, z, ends_k, target_k, vel3, z3, n_armed, pair_nodes, pair_mu, pairs):
    """A solve of the step: the bodies the ``n_armed`` member pairs join (:func:`_join`), the strut and node
    blocks (:func:`_solve`), then the coupled ones (:func:`_solve_pairs`); returns as those. Compiled into its
    caller: :func:`_solve` is handed the pairs' scratch only where pairs are armed (a call costs ~4 ns an array)."""
    if n_armed:
        _join(n_armed, pair_nodes, inv_mass, node_strut, rigid_members.shape[0], pairs)
    why = _solve(v, b, armed, target, inv_mass, ends, rigid_members, rigid_w, dirs, node_strut, mu, warm, contact,
                 work, inv2, vel, z, ends_k, target_k, vel3, z3, n_armed, pairs[7], pairs[8])
    if why or not n_armed:
        return why
    return _solve_pairs(v, b, armed, target, inv_mass, ends, rigid_members, dirs, node_strut, mu, warm, contact,
                        n_armed, pair_nodes, pair_mu, pairs)


@njit(cache=True, error_model="numpy", _nrt=False)
def _arm_pairs_for(x, v, v0, h, pair_nodes, pair_radii, touch_tol, restitution, warm, ends4, out6, s5, t5, pairs, b):
    """:func:`_arm_pairs` with the scratch ``pairs`` (:func:`pair_scratch`); the pairs it arms are marked in
    ``touched`` (the step's pairs with impulses to report) and those it does not lose their warm starts in
    ``warm`` (N + P, 3, B), the solve's. Returns as :func:`_arm_pairs`."""
    armed_pairs, frames, weights, targets, landing, touched = pairs[0], pairs[1], pairs[2], pairs[3], pairs[4], pairs[6]
    count = _arm_pairs(x, v, v0, h, pair_nodes, pair_radii, touch_tol, restitution, armed_pairs, frames, weights,
                       targets, landing, ends4, out6, s5, t5, b)
    n_nodes = x.shape[0]
    c = 0
    for k in range(pair_nodes.shape[0]):
        if c < count and armed_pairs[c] == k:
            touched[k] = True
            c += 1
        else:
            for j in range(3):
                warm[n_nodes + k, j, b] = 0.0
    return count


@njit(cache=True)
def pair_scratch(n_nodes, n_rigid, n_pairs):
    """The member pairs' scratch of the kernels (a tuple): by pair, the armed pairs' indices, their frames,
    weights, targets, landing speeds, the step's impulses (normal, friction in space) and whether the step
    armed them; the union-find of the bodies (struts, then nodes) and the coupled block's arrays (none without
    pairs: only an armed pair makes a coupled block, and its 110 kB were zeroed at every call, one a step where a
    controller commands every step)."""
    rows = MAX_COUPLED if n_pairs else 0
    width = rows // 3 + 1   # nodes a coupled block may hold
    return (np.empty(n_pairs, dtype=np.int64), np.empty((n_pairs, 3, 3)), np.empty((n_pairs, 4)), np.empty(n_pairs),
            np.zeros(n_pairs), np.zeros((n_pairs, 4)), np.zeros(n_pairs, dtype=np.bool_),
            np.empty(n_rigid + n_nodes, dtype=np.int64), np.empty(n_rigid + n_nodes, dtype=np.bool_),
            np.empty(n_nodes, dtype=np.int64), np.empty(width, dtype=np.int64), np.empty((rows, 3 * width)),
            np.empty((width, 2)), np.empty((width, 3)), np.empty(rows), np.empty(rows // 3), np.empty(rows // 3),
            np.zeros((6, rows, rows)))


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _landing_target(gap, vz0, h, touch_tol):
    """m/s: the drift's normal target of a node armed ``gap`` m above the ground that started the step at
    ``vz0``: the rate that lands it on the ground, capped at the reversal of its start velocity but never
    letting it sink past ``touch_tol`` deep (ContactSet.arm_step's floored). Computed only for the armed
    nodes (two divisions a node)."""
    return max(min(-gap / h, -vz0), min(-(gap + touch_tol) / h, 0.0))


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _drift_contacts(x, v, v0, h, rigid_dirs, bodies, ground, members, warm, dx, v0b, contact, contacts, armed,
                    target, landing, solver, pairs, done, why, width):
    """Each of the ``width`` copies (not ``done``) of a chunk's ``x``, ``v`` (N, 3, W) after the opening half-kick,
    one after the other (inlined in the step loop: a call handing over these ~50 arrays cost a copy alone a tenth
    of its step; the model and the scratch come in the tuples ``bodies``, ``ground``, ``members`` and ``solver``,
    since Python passes a call of more than 30 arguments as ``*args``, which numba does not inline): the nodes (and
    member pairs) that the drift would carry into contact armed (``ContactSet.arm_step``, module docstring) and
    their velocity problem solved, in place on ``v``; ``v0`` (N, 3, W): the velocities at the step's start.
    ``contacts`` (N, 3, W) gets each copy's impulses, ``landing`` (N, W) the closing speeds of its nodes not yet
    touching (:func:`_settle_contacts`' restitution), ``pairs`` (:func:`pair_scratch`) the member pairs' (of the
    last copy: a chunk with pairs holds one), ``work`` (W, ...) and ``z`` (W, ...) each copy's solver scratch;
    ``dx``, ``v0b``, ``contact`` (N, 3) and the rest are scratch. ``why`` (W,) int64: 0, or why the copy's step
    is left to the reference (``UNSOLVED``, ``MEMBERS``: its ``v`` is then not a step's)."""
    ends, inv_mass, rigid_members, rigid_w, node_strut = bodies
    height, mu, restitution, radii, touch_tol = ground
    pair_nodes, pair_radii, pair_mu, pair_restitution = members
    work, inv2, vel, z, ends_k, target_k, vel3, z3, ends4, out6, s5, t5 = solver
    n_nodes = x.shape[0]
    n_pairs = pair_nodes.shape[0]
    for w in range(width):
        why[w] = 0
        if done[w]:
            continue
        found = False
        for p in range(n_nodes):
            for j in range(3):
                contact[p, j] = 0.0
                v0b[p, j] = v0[p, j, w]
            gap = x[p, 2, w] - radii[p] - height
            landing[p, w] = max(-v[p, 2, w], 0.0) if gap > touch_tol else 0.0
            # armed where within touch_tol by the drift's end at its vertical velocity, or at that velocity once
            # its rigid strut's length rate is zeroed (ContactSet.arm_step's v_f, measured only where the first
            # misses)
            armed[p] = inv_mass[p, 0] > 0.0 and gap - h * abs(v[p, 2, w]) <= touch_tol
            r = node_strut[p]
            if not armed[p] and inv_mass[p, 0] > 0.0:
                vz = v[p, 2, w]
                if r >= 0:
                    a = ends[rigid_members[r], 0]
                    c = ends[rigid_members[r], 1]
                    rate = ((v[c, 0, w] - v[a, 0, w]) * rigid_dirs[r, 0, w]
                            + (v[c, 1, w] - v[a, 1, w]) * rigid_dirs[r, 1, w]
                            + (v[c, 2, w] - v[a, 2, w]) * rigid_dirs[r, 2, w])
                    s = rate / rigid_w[r, r]
                    vz += ((axial_inverse(inv_mass, a) if p == a else -axial_inverse(inv_mass, c))
                           * (s * rigid_dirs[r, 2, w]))
                armed[p] = gap + h * vz <= touch_tol
            if armed[p]:
                target[p] = _landing_target(gap, v0b[p, 2], h, touch_tol)
                found = True
        n_armed = 0
        if n_pairs:
            pair_impulse, touched = pairs[5], pairs[6]
            for k in range(n_pairs):
                touched[k] = False
                for j in range(4):
                    pair_impulse[k, j] = 0.0
            n_armed = _arm_pairs_for(x, v, v0b, h, pair_nodes, pair_radii, touch_tol, pair_restitution, warm[0],
                                     ends4, out6, s5, t5, pairs, w)
            if n_armed < 0:
                why[w] = MEMBERS
                continue
        if found or n_armed:
            for p in range(n_nodes):   # the free velocities, for a solve again
                for j in range(3):
                    dx[p, j] = v[p, j, w]
            while True:
                why[w] = _solve_all(v, w, armed, target, inv_mass, ends, rigid_members, rigid_w, rigid_dirs,
                                    node_strut, mu, warm[0], contact, work[w], inv2, vel, z[w], ends_k, target_k,
                                    vel3, z3, n_armed, pair_nodes, pair_mu, pairs)
                if why[w]:
                    break
                # ContactSet.missed: the answer carries an unarmed node into the ground (its strut turned by its
                # other end's contact): those within touch_tol of it by the drift's end are armed too, and solved
                # again
                missed = False
                for p in range(n_nodes):
                    end_gap = x[p, 2, w] - radii[p] - height + h * v[p, 2, w]
                    missed = missed or (not armed[p] and inv_mass[p, 0] > 0.0 and end_gap < -touch_tol)
                if not missed:
                    break
                if n_armed:   # the member pairs' impulses are summed in the solve: the reference solves again
                    why[w] = MEMBERS
                    break
                for p in range(n_nodes):
                    gap = x[p, 2, w] - radii[p] - height
                    if not armed[p] and inv_mass[p, 0] > 0.0 and gap + h * v[p, 2, w] <= touch_tol:
                        armed[p] = True
                        target[p] = _landing_target(gap, v0b[p, 2], h, touch_tol)
                    for j in range(3):
                        v[p, j, w] = dx[p, j]
                        contact[p, j] = 0.0
        for p in range(n_nodes):
            for j in range(3):
                contacts[p, j, w] = contact[p, j]


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _settle_contacts(x, v, v0, rigid_dirs, bodies, ground, members, warm, v0b, contact, contacts, armed, target,
                     landing, solver, pairs, done, why, width):
    """Each copy (not ``done``) of a chunk after the closing half-kick and RATTLE, as :func:`_drift_contacts`
    (its arguments): the touching nodes (and member pairs) armed (``ContactSet.arm_settle``: Newton's
    restitution of its ``landing``) and their velocity problem solved, in place on ``v``; ``contacts`` adds the
    impulses."""
    ends, inv_mass, rigid_members, rigid_w, node_strut = bodies
    height, mu, restitution, radii, touch_tol = ground
    pair_nodes, pair_radii, pair_mu, pair_restitution = members
    work, inv2, vel, z, ends_k, target_k, vel3, z3, ends4, out6, s5, t5 = solver
    n_nodes = x.shape[0]
    for w in range(width):
        why[w] = 0
        if done[w]:
            continue
        for p in range(n_nodes):
            for j in range(3):
                contact[p, j] = contacts[p, j, w]
                v0b[p, j] = v0[p, j, w]
        n_armed = 0
        if pair_nodes.shape[0]:
            n_armed = _arm_pairs_for(x, v, v0b, 0.0, pair_nodes, pair_radii, touch_tol, pair_restitution, warm[1],
                                     ends4, out6, s5, t5, pairs, w)
            if n_armed < 0:
                why[w] = MEMBERS
                continue
        found = False
        for p in range(n_nodes):
            armed[p] = inv_mass[p, 0] > 0.0 and x[p, 2, w] - radii[p] - height <= touch_tol
            target[p] = restitution * landing[p, w]
            found = found or armed[p]
        if found or n_armed:
            why[w] = _solve_all(v, w, armed, target, inv_mass, ends, rigid_members, rigid_w, rigid_dirs, node_strut,
                                mu, warm[1], contact, work[w], inv2, vel, z[w], ends_k, target_k, vel3, z3, n_armed,
                                pair_nodes, pair_mu, pairs)
            for p in range(n_nodes):
                for j in range(3):
                    contacts[p, j, w] = contact[p, j]


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _take_inputs(rest_seq, ext_seq, ext_held, s, first, done, rest, ext, moved, width) -> bool:
    """Step ``s``'s inputs into a chunk's ``rest`` (nc, W) and ``ext`` (N, 3, W) from columns ``first`` ... of
    ``rest_seq`` and ``ext_seq`` (or their one column of every copy), for the copies not ``done``; ``moved``
    (W,) gets whether a copy's changed, and the return whether any did. ``ext_held`` (T,):
    :func:`_held_external`'s (where it holds step ``s``, ``ext`` already has step ``s - 1``'s, the same numbers:
    not compared again). Each number's copies are walked innermost (consecutive columns of the inputs)."""
    by_copy_rest = rest_seq.shape[2] > 1   # each copy's own column of the inputs (else one of every copy's)
    by_copy_ext = ext_seq.shape[3] > 1
    for w in range(width):
        moved[w] = False
    for ci in range(rest.shape[0]):
        for w in range(width):
            value = rest_seq[s, ci, first + w if by_copy_rest else 0]
            if not done[w] and rest[ci, w] != value:
                rest[ci, w] = value
                moved[w] = True
    if not ext_held[s]:
        for i in range(ext.shape[0]):
            for j in range(3):
                for w in range(width):
                    value = ext_seq[s, i, j, first + w if by_copy_ext else 0]
                    if not done[w] and ext[i, j, w] != value:
                        ext[i, j, w] = value
                        moved[w] = True
    any_moved = False
    for w in range(width):
        any_moved = any_moved or moved[w]
    return any_moved


@njit(cache=True, error_model="numpy", _nrt=False)
def _held_external(ext_seq, held):
    """``held`` (T,) bool: whether step ``s`` >= 1 of ``ext_seq`` (T, N, 3, Be) repeats step ``s - 1``'s external
    forces for every copy (``==``: a NaN never does), found once a call for a schedule of every copy (Be = 1: an
    environment's copies under the same forces, where comparing them again at every copy's step took 2 % of its
    run); False at step 0 and for a schedule per copy."""
    for s in range(ext_seq.shape[0]):
        same = s > 0 and ext_seq.shape[3] == 1
        for i in range(ext_seq.shape[1]):
            for j in range(3):
                same = same and ext_seq[s, i, j, 0] == ext_seq[s - 1, i, j, 0]
        held[s] = same


def _ground_steps(x, v, rest, ext, h, n_steps, every, ends, attach, attach_at, stiffness, floor, strut_rest, damping,
                  inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, acc, tension, rigid_dirs,
                  height,
                  mu, restitution, radii, node_strut, touch_tol, pair_nodes, pair_radii, pair_mu,
                  pair_restitution, warm, rest_seq, ext_seq, out_x, out_v, out_impulses, out_slack, out_contact,
                  out_pairs, n_records, failed, reason, peak, snaps, was_slack, blocks):
    """``n_steps`` steps of ``h`` (s) of every copy (in ``blocks`` contiguous blocks of copies spread over the
    cores), in place on ``x``, ``v`` and the carry (``acc``, ``tension``, ``rigid_dirs``, ``warm``); the kept steps as
    ``_elastic_kernels.elastic_steps`` keeps them, and ``out_contact`` (K, N, 3, B) the ground's impulses
    summed like the cables'. ``out_pairs`` (B, R, 6): each copy's member contacts of each step, one record a
    pair armed in the step (the step, the pair's index, its normal impulse, its friction in space, N*s),
    ``n_records`` (B,) int64 of them. ``failed`` (B,) int64: -1, or the step of the copy left to the reference
    (the copy stops there: its ``x``, ``v`` are those at that step's start, its carry is not), and ``reason``
    (B,) int64 why (``UNSOLVED``, ``MEMBERS``), or the step before which a copy stopped for want of room for
    its records (``FULL``: fewer than P left; its carry is that step's start's, for a call that goes on).
    Over the steps taken, ``BatchSimulator.run``'s summary of them: ``peak`` (nc, B) N*s, each cable's largest
    impulse of a step (raised from what it holds; a NaN is none, as ``np.fmax``), and ``snaps`` (nc, B) int64,
    each cable's steps that ended taut after a step that ended slack (added to), from ``was_slack`` (nc, B) bool
    at the first step's start, which gets the slack cables at the last step's end (what a run keeping no step
    reads instead of every step's impulses and slack flags); with no column (nc, 0), none is computed.
    A block's copies are stepped in chunks of ``CHUNK`` (:func:`_chunk_steps`), each copy with the very arithmetic
    of ``Simulator``'s loop (a batch of one), bit for bit.

    ``rest_seq`` (T, nc, Bs), ``ext_seq`` (T, N, 3, Be): with T = ``n_steps``, each step's rest lengths and external
    forces (a command schedule evaluated at the steps' start times; Bs, Be = B, or 1 for every copy: an environment's
    copies reel each its own cables under the same forces), with T = 0
    ``rest`` and ``ext`` held. A step whose inputs differ from the last step's starts from forces computed anew
    at its start (as ``Simulator`` does after a new input: the carry dropped, ``elastic_forces`` at the state;
    the contact warm starts kept): a run with a schedule here is the very arithmetic of commanding each step."""
    for blk in prange(blocks):
        _block(blk, blocks, x, v, rest, ext, h, n_steps, every, ends, attach, attach_at, stiffness, floor, strut_rest,
               damping, inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w, acc, tension, rigid_dirs,
               height, mu,
               restitution, radii, node_strut, touch_tol, pair_nodes, pair_radii, pair_mu, pair_restitution, warm,
               rest_seq, ext_seq, out_x, out_v, out_impulses, out_slack, out_contact, out_pairs, n_records, failed,
               reason, peak, snaps, was_slack)


@njit(cache=True, error_model="numpy", _nrt=False)
def _leave(w, b, x, v, x0, v0, acc, tension, dirs, warm, gx, gv, gacc, gtension, gdirs, gwarm):
    """Copy ``w`` of a chunk stops (a step left to the reference, or no room for its records): its ``x``, ``v``
    back at the step's start (``x0``, ``v0``), written with its carry as the step left it into copy ``b`` of
    the batch's arrays (``g*``)."""
    for i in range(x.shape[0]):
        for j in range(3):
            x[i, j, w] = x0[i, j, w]
            v[i, j, w] = v0[i, j, w]
    scatter_copies(x, v, acc, tension, dirs, w, b, 1, gx, gv, gacc, gtension, gdirs)
    for i in range(warm.shape[1]):
        for j in range(3):
            gwarm[0, i, j, b] = warm[0, i, j, w]
            gwarm[1, i, j, b] = warm[1, i, j, w]


@njit(cache=True, error_model="numpy", _nrt=False)
def _chunk_steps(first, h, n_steps, every, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                 gravity_force, rigid_members, rigid_length_sq, rigid_w, height, mu, restitution, radii, node_strut,
                 touch_tol, pair_nodes, pair_radii, pair_mu, pair_restitution, x, v, rest, ext, acc, tension, dirs,
                 warm, rest_seq, ext_seq, ext_held, x0, v0, dxw, strength, imp, sl, total, contacts, total_contact,
                 landing, kept, kept_one, imp_one, sl_one, done, moved, why, acc_new, tension_new, dirs_new, v0b, dx,
                 contact, armed, target, work, inv2, vel, z, ends_k, target_k, vel3, z3, ends4, out6, s5, t5, pairs, gx,
                 gv, gacc, gtension, gdirs, gwarm, out_x, out_v, out_impulses, out_slack, out_contact, out_pairs,
                 n_records, failed, reason, peak, snaps, was_slack, many):
    """``n_steps`` steps of a chunk of W copies, batch ``first`` to ``first + W - 1``, in the chunk's own arrays
    (``x`` ... ``warm``, batch last; the scratch beside them, :func:`_block` allocates): each phase of a step
    that treats every copy alike (the half-kicks, the drift and SHAKE, the forces and RATTLE) walks the W
    copies innermost, as ``_kernels.elastic_steps_copies`` does, and the contacts' arming and solves go copy by
    copy (``work``, ``z``: one solver scratch a copy, so that each sees only its own last solve's, as a copy
    stepped alone does). A copy's numbers are those of stepping it alone (``Simulator``'s loop), bit for bit:
    the same operations in the same order. A copy whose step is left to the reference (or that has no room
    for its pairs' records) stops there (:func:`_leave`, ``done``); the others go on. ``many`` None: a chunk of
    one copy (``Simulator``'s, a scene with member pairs, a block's last), compiled apart (W = 1 a constant:
    no loop over the copies, the copy's index 0), which drifts and closes with the per-copy kernels (``_drift``,
    ``_close``, ``_forces``; ``kept_one``, ``imp_one``, ``sl_one`` theirs); an int: W copies (the copies'
    loops of one trip had cost a copy alone a third more). Outputs as
    :func:`_ground_steps`', but the summary's ``peak``, ``snaps`` and ``was_slack`` (nc, W) are the chunk's."""
    n_nodes, _, width = x.shape
    if many is None:   # a chunk of one copy, compiled apart: its loops over the copies of one trip, its index constant
        width = 1
    nc = rest.shape[0]
    n_pairs = pair_nodes.shape[0]
    half = 0.5 * h
    # the contact phases' arguments in a few tuples (a call of more than 30 arguments is not inlined)
    bodies = (ends, inv_mass, rigid_members, rigid_w, node_strut)
    ground = (height, mu, restitution, radii, touch_tol)
    members = (pair_nodes, pair_radii, pair_mu, pair_restitution)
    solver = (work, inv2, vel, z, ends_k, target_k, vel3, z3, ends4, out6, s5, t5)
    for s in range(n_steps):
        for i in range(n_nodes):
            for j in range(3):
                for w in range(width):
                    x0[i, j, w] = x[i, j, w]
                    v0[i, j, w] = v[i, j, w]
        if n_pairs:
            for w in range(width):
                b = first + w
                if not done[w] and n_records[b] + n_pairs > out_pairs.shape[1]:   # no room for this step's pairs
                    _leave(w, b, x, v, x0, v0, acc, tension, dirs, warm, gx, gv, gacc, gtension, gdirs, gwarm)
                    failed[b] = s
                    reason[b] = FULL
                    done[w] = True
        if rest_seq.shape[0] > 0:
            any_moved = _take_inputs(rest_seq, ext_seq, ext_held, s, first, done, rest, ext, moved, width)
            if any_moved:
                # a copy's new inputs: forces computed anew at its state (after the first step from the members'
                # geometry that the last step's end kept: a reel's every step); a copy without keeps its carry
                if many is None:
                    _forces(x, v, rest, ext, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                            gravity_force, rigid_members, acc_new, tension_new, dirs_new, sl_one, 0, kept_one, s == 0)
                else:
                    _forces_copies(x, v, rest, ext, ends, attach, attach_at, stiffness, floor, strut_rest, damping,
                                   inv_mass, gravity_force, rigid_members, acc_new, tension_new, dirs_new, sl, kept,
                                   s == 0)
                for w in range(width):
                    if moved[w]:
                        for i in range(n_nodes):
                            for j in range(3):
                                acc[i, j, w] = acc_new[i, j, w]
                        for ci in range(nc):
                            tension[ci, w] = tension_new[ci, w]
                        for k in range(dirs.shape[0]):
                            for j in range(3):
                                dirs[k, j, w] = dirs_new[k, j, w]
        for i in range(n_nodes):
            for j in range(3):
                for w in range(width):
                    v[i, j, w] += half * acc[i, j, w]
        _drift_contacts(x, v, v0, h, dirs, bodies, ground, members, warm, dx, v0b, contact, contacts, armed, target,
                        landing, solver, pairs, done, why, width)
        for w in range(width):
            if why[w]:
                b = first + w
                _leave(w, b, x, v, x0, v0, acc, tension, dirs, warm, gx, gv, gacc, gtension, gdirs, gwarm)
                failed[b] = s
                reason[b] = why[w]
                done[w] = True
        if many is None:   # a copy alone: the copies' loops of one trip would cost it a third more
            _drift(x, v, h, ends, inv_mass, rigid_members, rigid_length_sq, rigid_w, dirs, dx, 0)
            _close(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                   gravity_force, rigid_members, rigid_w, acc, tension, dirs, dx, imp_one, sl_one, 0, kept_one)
            for ci in range(nc):
                imp[ci, 0] = imp_one[ci]
                sl[ci, 0] = sl_one[ci]
        else:
            _drift_copies(x, v, h, ends, inv_mass, rigid_members, rigid_length_sq, rigid_w, dirs, dxw, strength)
            _close_copies(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping,
                          inv_mass, gravity_force, rigid_members, rigid_w, acc, tension, dirs, dxw, strength, imp, sl,
                          kept)
        last = (s + 1) % every == 0 or s == n_steps - 1
        _settle_contacts(x, v, v0, dirs, bodies, ground, members, warm, v0b, contact, contacts, armed, target,
                         landing, solver, pairs, done, why, width)
        for w in range(width):
            if done[w]:
                continue
            b = first + w
            if why[w]:
                _leave(w, b, x, v, x0, v0, acc, tension, dirs, warm, gx, gv, gacc, gtension, gdirs, gwarm)
                failed[b] = s
                reason[b] = why[w]
                done[w] = True
                continue
            if n_pairs:   # the step's member contacts: (step, pair, normal, friction in space)
                pair_impulse, touched = pairs[5], pairs[6]
                for k in range(n_pairs):
                    if touched[k]:
                        r = n_records[b]
                        out_pairs[b, r, 0] = s
                        out_pairs[b, r, 1] = k
                        for j in range(4):
                            out_pairs[b, r, 2 + j] = pair_impulse[k, j]
                        n_records[b] = r + 1
            for ci in range(nc):
                total[ci, w] += imp[ci, w]
            if peak.shape[1]:   # the summary asked for
                for ci in range(nc):
                    if imp[ci, w] > peak[ci, w]:   # (a NaN is no peak)
                        peak[ci, w] = imp[ci, w]
                    snaps[ci, w] += was_slack[ci, w] and not sl[ci, w]
                    was_slack[ci, w] = sl[ci, w]
            for i in range(n_nodes):
                for j in range(3):
                    total_contact[i, j, w] += contacts[i, j, w]
            if last:
                k = s // every
                for i in range(n_nodes):
                    for j in range(3):
                        out_x[k, i, j, b] = x[i, j, w]
                        out_v[k, i, j, b] = v[i, j, w]
                        out_contact[k, i, j, b] = total_contact[i, j, w]
                        total_contact[i, j, w] = 0.0
                for ci in range(nc):
                    out_impulses[k, ci, b] = total[ci, w]
                    out_slack[k, ci, b] = sl[ci, w]
                    total[ci, w] = 0.0


# copies stepped together (measured on Roll-v0's vector environment: 8, 16, 32, 64 took 0.80, 0.74, 0.71, 0.75 of
# the time a copy at a time took)
CHUNK = 32


@njit(cache=True, error_model="numpy")
def _block(blk, blocks, x, v, rest, ext, h, n_steps, every, ends, attach, attach_at, stiffness, floor, strut_rest,
           damping, inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w, acc, tension, rigid_dirs, height,
           mu, restitution,
           radii, node_strut, touch_tol, pair_nodes, pair_radii, pair_mu, pair_restitution, warm, rest_seq, ext_seq,
           out_x, out_v, out_impulses, out_slack, out_contact, out_pairs, n_records, failed, reason, peak, snaps,
           was_slack):
    """Block ``blk`` of ``blocks`` of :func:`_ground_steps`' copies (its arguments): one function that the
    parallel loop calls once a block and the serial loop once, so both step the copies with the same code.
    The block's copies go in chunks of ``CHUNK`` (:func:`_chunk_steps`), one at a time where the scene has
    member pairs (their scratch, :func:`pair_scratch`, holds one copy's step)."""
    n_nodes = x.shape[0]
    nc, n_copies = rest.shape
    nr = rigid_members.shape[0]
    m = ends.shape[0]
    # the model's arrays copied for each block, measured when the step loop still counted references per call
    # (threads sharing one array's count took turns at it: 178-204k scene-steps/s sharing them, 233-243k with
    # copies); since _chunk_steps counts none per step, only the counts of this function's calls remain
    ends_b, stiffness_b, strut_rest_b, damping_b = ends.copy(), stiffness.copy(), strut_rest.copy(), damping.copy()
    attach_b, attach_at_b = attach, attach_at   # read only where the scene has them (None otherwise)
    inv_mass_b, gravity_b, rigid_members_b = inv_mass.copy(), gravity_force.copy(), rigid_members.copy()
    rigid_length_sq_b, rigid_w_b, radii_b, node_strut_b = (rigid_length_sq.copy(), rigid_w.copy(), radii.copy(),
                                                           node_strut.copy())
    floor_b, pair_nodes_b, pair_radii_b = floor.copy(), pair_nodes.copy(), pair_radii.copy()
    n_pairs = pair_nodes.shape[0]
    pairs = pair_scratch(n_nodes, nr, n_pairs)
    v0b = np.empty((n_nodes, 3))
    dx = np.empty((n_nodes, 3))
    contact = np.empty((n_nodes, 3))
    armed = np.empty(n_nodes, dtype=np.bool_)
    target = np.empty(n_nodes)
    inv2 = np.empty(3)
    vel = np.empty((2, 3))
    ends_k = np.empty(2, dtype=np.int64)
    target_k = np.empty(2)
    vel3 = np.empty(3)
    z3 = np.empty(3)
    ends4 = np.empty((4, 3))
    out6 = np.empty(6)
    s5 = np.empty(5)
    t5 = np.empty(5)
    ext_held = np.empty(ext_seq.shape[0], dtype=np.bool_)
    _held_external(ext_seq, ext_held)
    first = np.int64(blk)   # prange's index is unsigned: with a signed number it would make a float
    lo = n_copies * first // blocks
    hi = n_copies * (first + 1) // blocks
    chunk = 1 if n_pairs else CHUNK
    for start in range(lo, hi, chunk):
        width = min(chunk, hi - start)
        xw = np.empty((n_nodes, 3, width))
        vw = np.empty((n_nodes, 3, width))
        accw = np.empty((n_nodes, 3, width))
        extw = np.empty((n_nodes, 3, width))
        restw = np.empty((nc, width))
        tensionw = np.empty((nc, width))
        dirsw = np.empty((nr, 3, width))
        warmw = np.empty((2, n_nodes + n_pairs, 3, width))
        # (each number's copies innermost, consecutive in the batch's arrays and the chunk's)
        gather_copies(x, v, acc, ext, rest, tension, rigid_dirs, start, xw, vw, accw, extw, restw, tensionw, dirsw, 0,
                      width)
        for i in range(n_nodes + n_pairs):
            for j in range(3):
                for w in range(width):
                    warmw[0, i, j, w] = warm[0, i, j, start + w]
                    warmw[1, i, j, w] = warm[1, i, j, start + w]
        for w in range(width):
            failed[start + w] = -1
            reason[start + w] = 0
            n_records[start + w] = 0
        summed = width if peak.shape[1] else 0   # the summary's columns of the chunk, where asked for
        peak_w = np.empty((nc, summed))
        snaps_w = np.empty((nc, summed), dtype=np.int64)
        slack_w = np.empty((nc, summed), dtype=np.bool_)
        for ci in range(nc):
            for w in range(summed):
                peak_w[ci, w] = peak[ci, start + w]
                snaps_w[ci, w] = snaps[ci, start + w]
                slack_w[ci, w] = was_slack[ci, start + w]
        done = np.zeros(width, dtype=np.bool_)
        # each copy starts from the scratch a call of its own would have
        work = np.zeros((width, 6, MAX_ROWS, MAX_ROWS))
        z = np.zeros((width, MAX_ROWS))
        def chunk_steps(many):   # (a closure: one call written out for the two compilations)
            _chunk_steps(start, h, n_steps, every, ends_b, attach_b, attach_at_b, stiffness_b, floor_b, strut_rest_b,
                         damping_b, inv_mass_b, gravity_b, rigid_members_b, rigid_length_sq_b, rigid_w_b, height, mu,
                         restitution, radii_b, node_strut_b, touch_tol, pair_nodes_b, pair_radii_b, pair_mu,
                         pair_restitution, xw, vw, restw, extw, accw, tensionw, dirsw, warmw, rest_seq, ext_seq,
                         ext_held,
                         np.empty((n_nodes, 3, width)), np.empty((n_nodes, 3, width)), np.empty((n_nodes, 3, width)),
                         np.empty((nr, width)), np.empty((nc, width)), np.empty((nc, width), dtype=np.bool_),
                         np.zeros((nc, width)), np.empty((n_nodes, 3, width)), np.zeros((n_nodes, 3, width)),
                         np.empty((n_nodes, width)), np.empty((m, 4, width)), np.empty((m, 4)), np.empty(nc),
                         np.empty(nc, dtype=np.bool_), done, np.empty(width, dtype=np.bool_),
                         np.empty(width, dtype=np.int64),
                         np.empty((n_nodes, 3, width)), np.empty((nc, width)), np.empty((nr, 3, width)), v0b, dx,
                         contact, armed, target, work, inv2, vel, z, ends_k, target_k, vel3, z3, ends4, out6, s5, t5,
                         pairs, x, v, acc, tension, rigid_dirs, warm, out_x, out_v, out_impulses, out_slack,
                         out_contact, out_pairs, n_records, failed, reason, peak_w, snaps_w, slack_w, many)
        if width == 1:
            chunk_steps(None)
        else:
            chunk_steps(width)
        for ci in range(nc):
            for w in range(summed):
                peak[ci, start + w] = peak_w[ci, w]
                snaps[ci, start + w] = snaps_w[ci, w]
                was_slack[ci, start + w] = slack_w[ci, w]
        w = 0
        while w < width:   # each run of copies that did not stop (a stopped one's _leave wrote it)
            if done[w]:
                w += 1
                continue
            end = w + 1
            while end < width and not done[end]:
                end += 1
            scatter_copies(xw, vw, accw, tensionw, dirsw, w, start + w, end - w, x, v, acc, tension, rigid_dirs)
            for i in range(n_nodes + n_pairs):
                for j in range(3):
                    for k in range(w, end):
                        warm[0, i, j, start + k] = warmw[0, i, j, k]
                        warm[1, i, j, start + k] = warmw[1, i, j, k]
            w = end


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
