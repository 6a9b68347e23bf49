"""Compiled kernels of the elastic method: the same arithmetic as :class:`.elastic.ElasticMethod` (the
plain numpy reference, which tests require these to match to 1e-12), with numba.

One kernel, two drivers (style.md rule 8): every array carries a batch axis LAST, so the kernel steps
``B >= 1`` independent copies of one system. :class:`.elastic.ElasticMethod` (and so ``Simulator``)
drives it with ``B = 1``; a batch simulator drives it with ``B`` copies. Shapes below use ``N`` nodes,
``m = n_struts + n_cables`` members (struts first), ``nc`` cables, ``nr`` moving rigid struts.

The system (never changes during a run; :func:`model_arrays` builds it from a ``System``):

    ends (m, 2) int64           node indices of each member (a, b)
    attach (k, 5) int64         the cables with an end along a strut (physics.md section 4c), in member order:
                                their member row, then the node pairs (a0, a1, b0, b1) of their two ends
    attach_at (k, 2)            the weights (wa, wb) of a1 and b1: end a at (1 - wa) x_a0 + wa x_a1, and so b
                                (a node end is (node, node) with weight 0); the main loop skips these rows.
                                Both None for a scene without such cables: the kernels then compile without
                                them (two more array arguments through the step cost its run() ~10 %)
    stiffness (m,) N/m          zero for rigid struts
    floor (m,)                  -inf for struts, 0 for cables: tension ``k max(floor, l - rest)``
    strut_rest (n_struts,) m
    damping (nc,) N*s/m         cable damping (acts while taut, total tension clipped at 0)
    inv_mass (N, 2) 1/kg        M^-1 (methods/_mass_kernels.py): its diagonal (zero for fixed nodes) and the
                                cross entry of a rigid strut's 2x2 block where its mass is spread along it
    gravity_force (N, 3) N
    rigid_members (nr,) int64   rows of the moving rigid struts in the member arrays
    rigid_length_sq (nr,) m^2
    rigid_w (nr, nr)            W = S M^-1 S^T of the moving rigid struts
    coupled (bool)              W is not diagonal (class-k); must be False: the kernels do the closed-form
                                SHAKE/RATTLE of independent rigid struts, and ElasticMethod steps a scene
                                with coupled ones with its numpy reference (its Newton solve would make
                                every first run compile LAPACK bindings: 18 s of CPU instead of ~3)

The state and what one step carries to the next (all float64, batch last):

    x, v (N, 3, B) m, m/s       positions, velocities at the step's start
    rest (nc, B) m              cable rest lengths
    ext (N, 3, B) N             external forces
    acc (N, 3, B) m/s^2         accelerations at the step's start    (in: start, out: end)
    tension (nc, B) N           cable tensions at the step's start   (in: start, out: end)
    rigid_dirs (nr, 3, B)       rigid strut unit vectors at the start (in: start, out: end)

:func:`elastic_forces` fills the last three at a configuration (after a reset or a new input);
:func:`elastic_steps` advances ``n_steps`` steps of ``h`` and keeps every ``every``-th, one copy after
the other (the fastest for a few copies); :func:`elastic_steps_copies` does the same with the copies
innermost (5.6x faster at B = 1024), the same numbers bit for bit.
:func:`verlet_step` is one step of any size ``h`` (velocity Verlet + RATTLE) for a caller that
composes steps (located switches, higher-order splitting).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .._mass_kernels import axial_inverse, solve_forces, solve_forces_copies
from ..contact._detection_kernels import event_arrays, examine, measure, moved_on, new_events, new_work

__all__ = ["ElasticModel", "model_arrays", "elastic_forces", "elastic_steps", "elastic_steps_copies", "keep", "verlet_step"]


class ElasticModel(NamedTuple):
    """The system arrays of the kernels (module docstring), in the kernels' argument order."""

    ends: np.ndarray
    attach: np.ndarray | None
    attach_at: np.ndarray | None
    stiffness: np.ndarray
    floor: np.ndarray
    strut_rest: np.ndarray
    damping: np.ndarray
    inv_mass: np.ndarray
    gravity_force: np.ndarray
    rigid_members: np.ndarray
    rigid_length_sq: np.ndarray
    rigid_w: np.ndarray
    coupled: bool


def model_arrays(system, rigid) -> ElasticModel:
    """The kernels' system arrays for a ``System`` and its ``RigidStruts``."""
    c = system.attached
    attach = attach_at = None
    if len(c):
        attach = np.concatenate([(system.n_struts + c)[:, None], system.cable_nodes[c].reshape(-1, 4)], axis=1)
        attach, attach_at = np.ascontiguousarray(attach, dtype=np.int64), np.ascontiguousarray(system.cable_weights[c])
    return ElasticModel(
        np.ascontiguousarray(system.ends, dtype=np.int64), attach, attach_at,
        np.ascontiguousarray(system.stiffness, dtype=float),
        np.ascontiguousarray(system.floor, dtype=float), np.ascontiguousarray(system.strut_rest, dtype=float),
        np.ascontiguousarray(system.cable_damping, dtype=float), system.mass.kernel_array,
        np.ascontiguousarray(system.gravity_force, dtype=float),
        np.ascontiguousarray(rigid.members, dtype=np.int64), np.ascontiguousarray(rigid.length_sq, dtype=float),
        np.ascontiguousarray(rigid.w_matrix, dtype=float), bool(rigid.coupled))


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _member_geometry(x, a, c, b):
    """The length (m) and unit vector (from node ``a`` to node ``c``) of a member of copy ``b`` at ``x``."""
    d0 = x[c, 0, b] - x[a, 0, b]
    d1 = x[c, 1, b] - x[a, 1, b]
    d2 = x[c, 2, b] - x[a, 2, b]
    length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    return length, d0 / length, d1 / length, d2 / length


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _damped(t, cd, v, a, c, b, n0, n1, n2):
    """A cable's tension ``t`` (N) with its damping ``cd`` (N s/m) along the rate of its length (its ends ``a``,
    ``c`` of copy ``b`` at ``v``, along the unit vector ``n``): a damped cable never pushes."""
    if cd > 0.0:
        rate = ((v[c, 0, b] - v[a, 0, b]) * n0 + (v[c, 1, b] - v[a, 1, b]) * n1 + (v[c, 2, b] - v[a, 2, b]) * n2)
        if t > 0.0:
            t += cd * rate
        t = max(t, 0.0)
    return t


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _push_ends(acc, a, c, b, t, n0, n1, n2):
    """A member's tension ``t`` along the unit vector ``n`` from node ``a`` to ``c`` added to copy ``b``'s
    forces ``acc``: toward ``c`` on ``a``, the opposite on ``c``."""
    acc[a, 0, b] += t * n0
    acc[a, 1, b] += t * n1
    acc[a, 2, b] += t * n2
    acc[c, 0, b] -= t * n0
    acc[c, 1, b] -= t * n1
    acc[c, 2, b] -= t * n2


@njit(cache=True, error_model="numpy", _nrt=False)
def _forces(x, v, rest, ext, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
            rigid_members, acc, tension, rigid_dirs, slack, b, kept=None, fresh=True):
    """Copy ``b``: accelerations, cable tensions, rigid strut directions and slack cables at ``x``
    (damping from ``v``), written into ``acc``, ``tension``, ``rigid_dirs`` and ``slack``. ``kept`` (m, 4): each
    member's length (m) and unit vector at ``x``, written here where ``fresh``, else read from the last call at
    this very ``x`` (forces again after new inputs: the same numbers without a square root and three divisions
    a member; the cables along a strut are measured anew). None (compiled without it): measured, not kept."""
    n_nodes = x.shape[0]
    n_struts = strut_rest.shape[0]
    for i in range(n_nodes):
        for j in range(3):
            acc[i, j, b] = gravity_force[i, j] + ext[i, j, b]
    rigid_k = 0
    n_rigid = rigid_members.shape[0]
    attach_k = 0
    next_attach = _attached_row(attach, 0)   # the next cable along a strut: _attached_force takes it
    for i in range(ends.shape[0]):
        if i == next_attach:
            attach_k += 1
            next_attach = _attached_row(attach, attach_k)
            continue
        a = ends[i, 0]
        c = ends[i, 1]
        if kept is not None and not fresh:
            length = kept[i, 0]
            n0 = kept[i, 1]
            n1 = kept[i, 2]
            n2 = kept[i, 3]
        else:
            length, n0, n1, n2 = _member_geometry(x, a, c, b)
            if kept is not None:
                kept[i, 0] = length
                kept[i, 1] = n0
                kept[i, 2] = n1
                kept[i, 3] = n2
        if rigid_k < n_rigid and rigid_members[rigid_k] == i:
            rigid_dirs[rigid_k, 0, b] = n0
            rigid_dirs[rigid_k, 1, b] = n1
            rigid_dirs[rigid_k, 2, b] = n2
            rigid_k += 1
        if i < n_struts:
            r = strut_rest[i]
        else:
            r = rest[i - n_struts, b]
        t = stiffness[i] * max(length - r, floor[i])
        if i >= n_struts:
            ci = i - n_struts
            t = _damped(t, damping[ci], v, a, c, b, n0, n1, n2)
            tension[ci, b] = t
            slack[ci] = length < r
        _push_ends(acc, a, c, b, t, n0, n1, n2)
    if attach is not None:   # a scene without cables along a strut compiles without this (attach None)
        for k in range(attach.shape[0]):
            slack[attach[k, 0] - n_struts] = _attached_force(x, v, rest, attach, attach_at, stiffness, floor,
                                                             damping, n_struts, acc, tension, k, b)
    solve_forces(acc, inv_mass, ends, rigid_members, b)


@njit(cache=True, error_model="numpy", _nrt=False)
def _attached_row(attach, k):
    """The member row of the ``k``-th cable along a strut, or -1 past the last (or with none: ``attach`` None)."""
    if attach is None:
        return -1
    return attach[k, 0] if k < attach.shape[0] else -1


@njit(cache=True, error_model="numpy", inline="always", _nrt=False)
def _attached_force(x, v, rest, attach, attach_at, stiffness, floor, damping, n_struts, acc, tension, k, b):
    """Copy ``b``'s force of cable ``attach[k]``, whose end lies along a strut (module docstring): each end at
    its weighted point, the force there shared by the same weights, added to ``acc``; its tension written
    into ``tension``; returns whether it is slack."""
    i = attach[k, 0]
    a0 = attach[k, 1]
    a1 = attach[k, 2]
    c0 = attach[k, 3]
    c1 = attach[k, 4]
    wa = attach_at[k, 0]
    wc = attach_at[k, 1]
    ua = 1.0 - wa
    uc = 1.0 - wc
    d0 = (uc * x[c0, 0, b] + wc * x[c1, 0, b]) - (ua * x[a0, 0, b] + wa * x[a1, 0, b])
    d1 = (uc * x[c0, 1, b] + wc * x[c1, 1, b]) - (ua * x[a0, 1, b] + wa * x[a1, 1, b])
    d2 = (uc * x[c0, 2, b] + wc * x[c1, 2, b]) - (ua * x[a0, 2, b] + wa * x[a1, 2, b])
    length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    n0 = d0 / length
    n1 = d1 / length
    n2 = d2 / length
    ci = i - n_struts
    r = rest[ci, b]
    t = stiffness[i] * max(length - r, floor[i])
    cd = damping[ci]
    if cd > 0.0:
        rate = (((uc * v[c0, 0, b] + wc * v[c1, 0, b]) - (ua * v[a0, 0, b] + wa * v[a1, 0, b])) * n0
                + ((uc * v[c0, 1, b] + wc * v[c1, 1, b]) - (ua * v[a0, 1, b] + wa * v[a1, 1, b])) * n1
                + ((uc * v[c0, 2, b] + wc * v[c1, 2, b]) - (ua * v[a0, 2, b] + wa * v[a1, 2, b])) * n2)
        if t > 0.0:
            t += cd * rate
        t = max(t, 0.0)   # a damped cable never pushes
    tension[ci, b] = t
    acc[a0, 0, b] += ua * (t * n0)
    acc[a0, 1, b] += ua * (t * n1)
    acc[a0, 2, b] += ua * (t * n2)
    acc[a1, 0, b] += wa * (t * n0)
    acc[a1, 1, b] += wa * (t * n1)
    acc[a1, 2, b] += wa * (t * n2)
    acc[c0, 0, b] -= uc * (t * n0)
    acc[c0, 1, b] -= uc * (t * n1)
    acc[c0, 2, b] -= uc * (t * n2)
    acc[c1, 0, b] -= wc * (t * n0)
    acc[c1, 1, b] -= wc * (t * n1)
    acc[c1, 2, b] -= wc * (t * n2)
    return length < r


@njit(cache=True, error_model="numpy")
def elastic_forces(x, v, rest, ext, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                   gravity_force, rigid_members, acc, tension, rigid_dirs):
    """Fill ``acc`` (N, 3, B), ``tension`` (nc, B) and ``rigid_dirs`` (nr, 3, B) at ``x`` for every copy;
    returns the slack cables (nc, B) bool."""
    slack = np.empty((rest.shape[0], x.shape[2]), dtype=np.bool_)
    row = np.empty(rest.shape[0], dtype=np.bool_)
    for b in range(x.shape[2]):
        _forces(x, v, rest, ext, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                gravity_force, rigid_members, acc, tension, rigid_dirs, row, b)
        for ci in range(row.shape[0]):   # element loops: a slice assignment costs seconds of compile time
            slack[ci, b] = row[ci]
    return slack


@njit(cache=True, error_model="numpy", _nrt=False)
def _push(node_a, node_b, inv_mass, s, n0, n1, n2, out):
    """Equal-and-opposite push ``s`` along ``n`` on a rigid strut's ends, ``M^-1`` of it, added to ``out`` (N, 3)."""
    wa = axial_inverse(inv_mass, node_a)
    wb = axial_inverse(inv_mass, node_b)
    out[node_a, 0] += wa * (s * n0)
    out[node_a, 1] += wa * (s * n1)
    out[node_a, 2] += wa * (s * n2)
    out[node_b, 0] -= wb * (s * n0)
    out[node_b, 1] -= wb * (s * n1)
    out[node_b, 2] -= wb * (s * n2)


@njit(cache=True, error_model="numpy", _nrt=False)
def _shake(x_pred, dirs, ends, inv_mass, rigid_members, length_sq, w, dx, b):
    """SHAKE for copy ``b`` (rigid.RigidStruts.project_positions): the displacement, written into
    ``dx`` (N, 3) (zeroed here), that puts ``x_pred`` back on every rigid strut length along ``dirs``."""
    for i in range(dx.shape[0]):
        for j in range(3):
            dx[i, j] = 0.0
    for k in range(rigid_members.shape[0]):
        i = rigid_members[k]
        a = ends[i, 0]
        c = ends[i, 1]
        r0 = x_pred[c, 0, b] - x_pred[a, 0, b]
        r1 = x_pred[c, 1, b] - x_pred[a, 1, b]
        r2 = x_pred[c, 2, b] - x_pred[a, 2, b]
        p = r0 * dirs[k, 0, b] + r1 * dirs[k, 1, b] + r2 * dirs[k, 2, b]
        q = r0 * r0 + r1 * r1 + r2 * r2 - length_sq[k]
        # small root of w^2 g^2 - 2 w p g + q = 0, written to avoid cancellation
        gamma = q / (w[k, k] * (p + np.sqrt(max(p * p - q, 0.0))))
        _push(a, c, inv_mass, gamma, dirs[k, 0, b], dirs[k, 1, b], dirs[k, 2, b], dx)


@njit(cache=True, error_model="numpy", _nrt=False)
def _rattle(v, dirs, ends, inv_mass, rigid_members, w, dv, b):
    """RATTLE for copy ``b`` (rigid.RigidStruts.project_velocities): zero every rigid strut's length
    rate along ``dirs``, in place on ``v``; ``dv`` (N, 3) is scratch."""
    for i in range(dv.shape[0]):
        for j in range(3):
            dv[i, j] = 0.0
    for k in range(rigid_members.shape[0]):
        i = rigid_members[k]
        a = ends[i, 0]
        c = ends[i, 1]
        rate = ((v[c, 0, b] - v[a, 0, b]) * dirs[k, 0, b] + (v[c, 1, b] - v[a, 1, b]) * dirs[k, 1, b]
                + (v[c, 2, b] - v[a, 2, b]) * dirs[k, 2, b])
        _push(a, c, inv_mass, rate / w[k, k], dirs[k, 0, b], dirs[k, 1, b], dirs[k, 2, b], dv)
    # the pushes are summed before being added, as in the reference (v + project_velocities(...))
    for i in range(v.shape[0]):
        for j in range(3):
            v[i, j, b] += dv[i, j]


@njit(cache=True, error_model="numpy", _nrt=False)
def _drift(x, v, h, ends, inv_mass, rigid_members, rigid_length_sq, rigid_w, rigid_dirs, dx, b):
    """Copy ``b``'s drift ``x += h v`` and SHAKE's correction (added to ``v`` as ``dx / h``)."""
    n_nodes = x.shape[0]
    for i in range(n_nodes):
        for j in range(3):
            x[i, j, b] += h * v[i, j, b]
    if rigid_members.shape[0]:
        _shake(x, rigid_dirs, ends, inv_mass, rigid_members, rigid_length_sq, rigid_w, dx, b)
        for i in range(n_nodes):
            for j in range(3):
                x[i, j, b] += dx[i, j]
                v[i, j, b] += dx[i, j] / h


@njit(cache=True, error_model="numpy", _nrt=False)
def _close(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
           rigid_members, rigid_w, acc, tension, rigid_dirs, dx, impulses, slack, b, kept=None):
    """Copy ``b``'s end of a step: the forces at the drifted ``x`` (its members' geometry written into ``kept``,
    :func:`_forces`'), the cables' impulses, the closing half-kick and RATTLE."""
    n_nodes = x.shape[0]
    nc = tension.shape[0]
    half = 0.5 * h
    for ci in range(nc):
        impulses[ci] = tension[ci, b]
    _forces(x, v, rest, ext, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
            rigid_members, acc, tension, rigid_dirs, slack, b, kept)
    for ci in range(nc):
        impulses[ci] = half * (impulses[ci] + tension[ci, b])
    for i in range(n_nodes):
        for j in range(3):
            v[i, j, b] += half * acc[i, j, b]
    if rigid_members.shape[0]:
        _rattle(v, rigid_dirs, ends, inv_mass, rigid_members, rigid_w, dx, b)


@njit(cache=True, error_model="numpy", _nrt=False)
def _step(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
          rigid_members, rigid_length_sq, rigid_w, coupled, acc, tension, rigid_dirs, dx, impulses, slack, b):
    """One velocity Verlet (+ SHAKE/RATTLE) step of ``h`` of copy ``b``, in place on ``x``, ``v`` and the
    carried ``acc``, ``tension``, ``rigid_dirs``; ``impulses`` (nc,) and ``slack`` (nc,) of the step;
    ``dx`` (N, 3) is scratch."""
    half = 0.5 * h
    for i in range(x.shape[0]):
        for j in range(3):
            v[i, j, b] += half * acc[i, j, b]
    _drift(x, v, h, ends, inv_mass, rigid_members, rigid_length_sq, rigid_w, rigid_dirs, dx, b)
    _close(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass, gravity_force,
           rigid_members, rigid_w, acc, tension, rigid_dirs, dx, impulses, slack, b)


@njit(cache=True, error_model="numpy")
def verlet_step(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, acc, tension, rigid_dirs):
    """One step of any size ``h`` (s) of every copy, in place on ``x``, ``v``, ``acc``, ``tension`` and
    ``rigid_dirs`` (module docstring). Returns the cable impulses (nc, B) N*s and the slack cables
    (nc, B) bool at the step's end."""
    nc, n_copies = rest.shape
    impulses = np.empty((nc, n_copies))
    slack = np.empty((nc, n_copies), dtype=np.bool_)
    dx = np.empty((x.shape[0], 3))
    imp = np.empty(nc)
    sl = np.empty(nc, dtype=np.bool_)
    for b in range(n_copies):
        _step(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
              gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, acc, tension, rigid_dirs, dx, imp, sl, b)
        for ci in range(nc):
            impulses[ci, b] = imp[ci]
            slack[ci, b] = sl[ci]
    return impulses, slack


@njit(cache=True, error_model="numpy", _nrt=False)
def gather_copies(x, v, acc, ext, rest, tension, rigid_dirs, b, wx, wv, wacc, wext, wrest, wten, wdirs, w, count):
    """Copies ``b`` ... ``b + count - 1`` of the batch-last state and carry into columns ``w`` ... of the ``w*``
    arrays (a chunk of copies stepped in arrays of its own), each number's copies innermost: consecutive in both
    (a copy at a time, every number of it in another cache line, took most of a 256-copy call's fixed cost)."""
    for i in range(x.shape[0]):
        for j in range(3):
            for k in range(count):
                wx[i, j, w + k] = x[i, j, b + k]
                wv[i, j, w + k] = v[i, j, b + k]
                wacc[i, j, w + k] = acc[i, j, b + k]
                wext[i, j, w + k] = ext[i, j, b + k]
    for ci in range(rest.shape[0]):
        for k in range(count):
            wten[ci, w + k] = tension[ci, b + k]
            wrest[ci, w + k] = rest[ci, b + k]
    for r in range(rigid_dirs.shape[0]):
        for j in range(3):
            for k in range(count):
                wdirs[r, j, w + k] = rigid_dirs[r, j, b + k]


@njit(cache=True, error_model="numpy", _nrt=False)
def scatter_copies(wx, wv, wacc, wten, wdirs, w, b, count, x, v, acc, tension, rigid_dirs):
    """Columns ``w`` ... ``w + count - 1`` of the chunk's state and carry written back as copies ``b`` ...
    (:func:`gather_copies`' inverse)."""
    for i in range(x.shape[0]):
        for j in range(3):
            for k in range(count):
                x[i, j, b + k] = wx[i, j, w + k]
                v[i, j, b + k] = wv[i, j, w + k]
                acc[i, j, b + k] = wacc[i, j, w + k]
    for ci in range(tension.shape[0]):
        for k in range(count):
            tension[ci, b + k] = wten[ci, w + k]
    for r in range(rigid_dirs.shape[0]):
        for j in range(3):
            for k in range(count):
                rigid_dirs[r, j, b + k] = wdirs[r, j, w + k]


@njit(cache=True, error_model="numpy", _nrt=False)
def keep(x, v, c, total, slack, k, b, out_x, out_v, out_impulses, out_slack):
    """Write copy ``c`` of ``x``, ``v`` (N, 3, .) and the step's ``total`` impulses (nc,) N*s and ``slack``
    (nc,) as kept step ``k`` of copy ``b`` of the outputs (see :func:`elastic_steps`); ``total`` restarts
    at 0."""
    for i in range(x.shape[0]):
        for j in range(3):
            out_x[k, i, j, b] = x[i, j, c]
            out_v[k, i, j, b] = v[i, j, c]
    for ci in range(total.shape[0]):
        out_impulses[k, ci, b] = total[ci]
        out_slack[k, ci, b] = slack[ci]
        total[ci] = 0.0


@njit(cache=True, error_model="numpy")
def elastic_steps(x, v, rest, ext, h, n_steps, every, ends, attach, attach_at, stiffness, floor, strut_rest, damping,
                  inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, acc, tension, rigid_dirs,
                  out_x, out_v, out_impulses, out_slack, detection):
    """``n_steps`` steps of ``h`` (s) of every copy, in place on ``x``, ``v``, ``acc``, ``tension``,
    ``rigid_dirs``; keeps steps ``every``, ``2 every``, ... and the last one in the outputs:

        out_x, out_v (K, N, 3, B)       positions, velocities after each kept step
        out_impulses (K, nc, B) N*s     each cable's impulse summed over the steps since the last kept one
        out_slack (K, nc, B) bool       slack cables after each kept step

    with ``K = ceil(n_steps / every)``. ``detection``: member-contact detection over every step
    (``_detection_kernels.detection_state``, or ``no_detection()``); returns its events
    (``_detection_kernels.event_arrays``)."""
    n_nodes = x.shape[0]
    nc, n_copies = rest.shape
    dx = np.empty((n_nodes, 3))
    imp = np.empty(nc)
    total = np.empty(nc)
    sl = np.empty(nc, dtype=np.bool_)
    detecting = detection[0].shape[0] > 0
    events, points = new_events()
    work = new_work()
    before = np.empty((n_nodes, 3, 1))   # the positions at the step's start, for detection
    for b in range(n_copies):
        for ci in range(nc):
            total[ci] = 0.0
        for s in range(n_steps):
            if detecting:
                for i in range(n_nodes):
                    for j in range(3):
                        before[i, j, 0] = x[i, j, b]
            _step(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                  gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, acc, tension, rigid_dirs, dx, imp,
                  sl, b)
            if detecting and moved_on(before, 0, x, b, b, detection):
                p = measure(x, b, b, detection, work, 0)
                if p >= 0:
                    examine(before, 0, x, b, b, s, detection, work, events, points, p, b)
            for ci in range(nc):
                total[ci] += imp[ci]
            if (s + 1) % every == 0 or s == n_steps - 1:
                keep(x, v, b, total, sl, s // every, b, out_x, out_v, out_impulses, out_slack)
    return event_arrays(events, points)


# ---------------------------------------------------------------------------------------------------------
# The same step with the copies innermost (what a large batch runs): every loop over nodes, members and
# rigid struts walks all copies at once, so consecutive operations touch consecutive numbers (the batch
# is the last, contiguous axis) instead of numbers B apart. Each copy sees the very operations of
# ``_step``, in the same order, so its numbers are the same bit for bit (test_batch.py checks it).


@njit(cache=True, error_model="numpy", _nrt=False)
def _forces_copies(x, v, rest, ext, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                   gravity_force, rigid_members, acc, tension, rigid_dirs, slack, kept=None, fresh=True):
    """:func:`_forces` of every copy: ``slack`` (nc, B). ``kept`` (m, 4, B): each member's length (m) and unit
    vector at ``x``, written here where ``fresh``, else read from the last call at this very ``x`` (forces again
    after new inputs: the same numbers without a square root and three divisions a member; the cables along a
    strut are measured anew). None (compiled without it): measured, not kept."""
    n_nodes, _, n_copies = x.shape
    n_struts = strut_rest.shape[0]
    for i in range(n_nodes):
        for j in range(3):
            for b in range(n_copies):
                acc[i, j, b] = gravity_force[i, j] + ext[i, j, b]
    rigid_k = 0
    n_rigid = rigid_members.shape[0]
    attach_k = 0
    next_attach = _attached_row(attach, 0)   # the next cable along a strut: _attached_force takes it
    for i in range(ends.shape[0]):
        if i == next_attach:
            attach_k += 1
            next_attach = _attached_row(attach, attach_k)
            continue
        a = ends[i, 0]
        c = ends[i, 1]
        is_rigid = rigid_k < n_rigid and rigid_members[rigid_k] == i
        k_i = stiffness[i]
        floor_i = floor[i]
        ci = i - n_struts
        cd = damping[ci] if ci >= 0 else 0.0
        if kept is not None and fresh:
            # the geometry in a loop of its own, without branches: vectorised over the copies (its square root
            # and three divisions a member were, one copy at a time, two thirds of this function's time)
            for b in range(n_copies):
                kept[i, 0, b], kept[i, 1, b], kept[i, 2, b], kept[i, 3, b] = _member_geometry(x, a, c, b)
        if kept is not None and ci >= 0:
            # a cable's tension, then its pushes on its ends, each in a loop of its own (vectorised over the
            # copies; the same numbers)
            for b in range(n_copies):
                length = kept[i, 0, b]
                r = rest[ci, b]
                t = _damped(k_i * max(length - r, floor_i), cd, v, a, c, b, kept[i, 1, b], kept[i, 2, b],
                            kept[i, 3, b])
                tension[ci, b] = t
                slack[ci, b] = length < r
            for b in range(n_copies):
                _push_ends(acc, a, c, b, tension[ci, b], kept[i, 1, b], kept[i, 2, b], kept[i, 3, b])
        else:
            for b in range(n_copies):
                if kept is not None:
                    length = kept[i, 0, b]
                    n0 = kept[i, 1, b]
                    n1 = kept[i, 2, b]
                    n2 = kept[i, 3, b]
                else:
                    length, n0, n1, n2 = _member_geometry(x, a, c, b)
                if is_rigid:
                    rigid_dirs[rigid_k, 0, b] = n0
                    rigid_dirs[rigid_k, 1, b] = n1
                    rigid_dirs[rigid_k, 2, b] = n2
                if ci < 0:
                    r = strut_rest[i]
                else:
                    r = rest[ci, b]
                t = k_i * max(length - r, floor_i)
                if ci >= 0:
                    t = _damped(t, cd, v, a, c, b, n0, n1, n2)
                    tension[ci, b] = t
                    slack[ci, b] = length < r
                _push_ends(acc, a, c, b, t, n0, n1, n2)
        if is_rigid:
            rigid_k += 1
    if attach is not None:   # the same arithmetic as _forces' (the copies' numbers bit for bit)
        for k in range(attach.shape[0]):
            for b in range(n_copies):
                slack[attach[k, 0] - n_struts, b] = _attached_force(x, v, rest, attach, attach_at, stiffness, floor,
                                                                    damping, n_struts, acc, tension, k, b)
    solve_forces_copies(acc, inv_mass, ends, rigid_members)


@njit(cache=True, error_model="numpy", _nrt=False)
def _pushes_copies(ends, inv_mass, rigid_members, strengths, dirs, out):
    """``out`` (N, 3, B) = the node displacements (or velocity changes) of equal-and-opposite pushes of
    ``strengths`` (nr, B) along the rigid struts' ``dirs`` of every copy (:func:`_push`, strut by strut)."""
    n_copies = out.shape[2]
    for i in range(out.shape[0]):
        for j in range(3):
            for b in range(n_copies):
                out[i, j, b] = 0.0
    for k in range(rigid_members.shape[0]):
        m = rigid_members[k]
        node_a = ends[m, 0]
        node_b = ends[m, 1]
        wa = axial_inverse(inv_mass, node_a)
        wb = axial_inverse(inv_mass, node_b)
        for j in range(3):
            for b in range(n_copies):
                push = strengths[k, b] * dirs[k, j, b]
                out[node_a, j, b] += wa * push
                out[node_b, j, b] -= wb * push


@njit(cache=True, error_model="numpy", _nrt=False)
def _drift_copies(x, v, h, ends, inv_mass, rigid_members, rigid_length_sq, rigid_w, rigid_dirs, dx, strength):
    """:func:`_drift` of every copy; ``dx`` (N, 3, B) and ``strength`` (nr, B) are scratch."""
    n_nodes, _, n_copies = x.shape
    nr = rigid_members.shape[0]
    for i in range(n_nodes):
        for j in range(3):
            for b in range(n_copies):
                x[i, j, b] += h * v[i, j, b]
    if nr:
        for k in range(nr):   # SHAKE (_shake)
            m = rigid_members[k]
            a = ends[m, 0]
            c = ends[m, 1]
            wkk = rigid_w[k, k]
            for b in range(n_copies):
                r0 = x[c, 0, b] - x[a, 0, b]
                r1 = x[c, 1, b] - x[a, 1, b]
                r2 = x[c, 2, b] - x[a, 2, b]
                p = r0 * rigid_dirs[k, 0, b] + r1 * rigid_dirs[k, 1, b] + r2 * rigid_dirs[k, 2, b]
                q = r0 * r0 + r1 * r1 + r2 * r2 - rigid_length_sq[k]
                strength[k, b] = q / (wkk * (p + np.sqrt(max(p * p - q, 0.0))))
        _pushes_copies(ends, inv_mass, rigid_members, strength, rigid_dirs, dx)
        for i in range(n_nodes):
            for j in range(3):
                for b in range(n_copies):
                    x[i, j, b] += dx[i, j, b]
                    v[i, j, b] += dx[i, j, b] / h


@njit(cache=True, error_model="numpy", _nrt=False)
def _close_copies(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                  gravity_force, rigid_members, rigid_w, acc, tension, rigid_dirs, dx, strength, impulses, slack,
                  kept=None):
    """:func:`_close` of every copy: ``impulses`` and ``slack`` (nc, B) the step's, ``kept`` (m, 4, B)
    :func:`_forces_copies`'; ``dx`` (N, 3, B) and ``strength`` (nr, B) are scratch."""
    n_nodes, _, n_copies = x.shape
    nc = tension.shape[0]
    nr = rigid_members.shape[0]
    half = 0.5 * h
    for ci in range(nc):
        for b in range(n_copies):
            impulses[ci, b] = tension[ci, b]
    _forces_copies(x, v, rest, ext, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                   gravity_force, rigid_members, acc, tension, rigid_dirs, slack, kept)
    for ci in range(nc):
        for b in range(n_copies):
            impulses[ci, b] = half * (impulses[ci, b] + tension[ci, b])
    for i in range(n_nodes):
        for j in range(3):
            for b in range(n_copies):
                v[i, j, b] += half * acc[i, j, b]
    if nr:
        for k in range(nr):   # RATTLE (_rattle)
            m = rigid_members[k]
            a = ends[m, 0]
            c = ends[m, 1]
            wkk = rigid_w[k, k]
            for b in range(n_copies):
                rate = ((v[c, 0, b] - v[a, 0, b]) * rigid_dirs[k, 0, b]
                        + (v[c, 1, b] - v[a, 1, b]) * rigid_dirs[k, 1, b]
                        + (v[c, 2, b] - v[a, 2, b]) * rigid_dirs[k, 2, b])
                strength[k, b] = rate / wkk
        _pushes_copies(ends, inv_mass, rigid_members, strength, rigid_dirs, dx)
        for i in range(n_nodes):
            for j in range(3):
                for b in range(n_copies):
                    v[i, j, b] += dx[i, j, b]


@njit(cache=True, error_model="numpy", _nrt=False)
def _step_copies(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                 gravity_force, rigid_members, rigid_length_sq, rigid_w, acc, tension, rigid_dirs, dx, strength,
                 impulses, slack):
    """:func:`_step` of every copy; ``dx`` (N, 3, B) and ``strength`` (nr, B) are scratch, ``impulses``
    and ``slack`` (nc, B) the step's."""
    n_nodes, _, n_copies = x.shape
    half = 0.5 * h
    for i in range(n_nodes):
        for j in range(3):
            for b in range(n_copies):
                v[i, j, b] += half * acc[i, j, b]
    _drift_copies(x, v, h, ends, inv_mass, rigid_members, rigid_length_sq, rigid_w, rigid_dirs, dx, strength)
    _close_copies(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                  gravity_force, rigid_members, rigid_w, acc, tension, rigid_dirs, dx, strength, impulses, slack)


@njit(cache=True, error_model="numpy", nogil=True)   # nogil: blocks of copies on threads (methods/_copy_blocks.py)
def elastic_steps_copies(x, v, rest, ext, h, n_steps, every, ends, attach, attach_at, stiffness, floor, strut_rest,
                         damping, inv_mass, gravity_force, rigid_members, rigid_length_sq, rigid_w, coupled, acc,
                         tension, rigid_dirs,
                         out_x, out_v, out_impulses, out_slack):
    """:func:`elastic_steps` (same arguments, same numbers) with the copies innermost: faster for a
    large batch, where stepping one copy at a time walks numbers ``B`` apart."""
    n_nodes, _, n_copies = x.shape
    nc = rest.shape[0]
    dx = np.empty((n_nodes, 3, n_copies))
    strength = np.empty((rigid_members.shape[0], n_copies))
    imp = np.empty((nc, n_copies))
    sl = np.empty((nc, n_copies), dtype=np.bool_)
    total = np.zeros((nc, n_copies))
    for s in range(n_steps):
        _step_copies(x, v, rest, ext, h, ends, attach, attach_at, stiffness, floor, strut_rest, damping, inv_mass,
                     gravity_force, rigid_members, rigid_length_sq, rigid_w, acc, tension, rigid_dirs, dx, strength,
                     imp, sl)
        for ci in range(nc):
            for b in range(n_copies):
                total[ci, b] += imp[ci, b]
        if (s + 1) % every == 0 or s == n_steps - 1:
            k = s // every
            for i in range(n_nodes):
                for j in range(3):
                    for b in range(n_copies):
                        out_x[k, i, j, b] = x[i, j, b]
                        out_v[k, i, j, b] = v[i, j, b]
            for ci in range(nc):
                for b in range(n_copies):
                    out_impulses[k, ci, b] = total[ci, b]
                    out_slack[k, ci, b] = sl[ci, b]
                    total[ci, b] = 0.0
