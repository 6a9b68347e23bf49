"""The elastic step of :mod:`.elastic` for B copies of one structure at once.

Two implementations of the same arithmetic: the compiled kernels of ``elastic/_kernels.py`` (``Simulator``
drives them with B = 1; a batch runs ``elastic_steps_copies``, the same step with the copies innermost;
used unless ``compiled`` is False) and the numpy code here, their plain
batched reference (tests require the two to agree to 1e-12).

Same physics and the same arithmetic as :class:`~.elastic.ElasticMethod` (velocity Verlet, SHAKE/RATTLE
for rigid struts, the tension law ``k max(floor, e)``, damping only while taut and never pushing), with
every state array carrying the batch as its **last** axis, as mujoco's rollout and brax's vmap lay a
batch out: positions and velocities ``(N, 3, B)``, rest lengths ``(n_cables, B)``, external forces
``(N, 3, B)``. A member gather ``x[ends]`` then moves whole contiguous rows of ``3 B`` numbers and the
force assembly is one matrix product ``A @ (m, 3 B)``, so one step costs a few dozen numpy calls
whatever B is. Each copy agrees with a single :class:`~tensegrity_sim.simulator.Simulator` run to
round-off (``test/test_batch.py``).
"""
from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

from ...system import System
from . import _ground_kernels as ground_kernels
from . import _kernels as kernels
from .._copy_blocks import copy_blocks, on_blocks
from ..base import State, StepError
from .method import _HELD, ElasticMethod

_PAIR_RECORDS = 512   # member-pair impulse records a copy keeps at most in a compiled call (beyond: its advance)

__all__ = ["ElasticBatch"]


class ElasticBatch:
    """Steps B copies of ``system`` with the elastic method; checks ``dt`` as :class:`ElasticMethod` does.

    The state is held by the caller and passed in; this object caches only the forces at the last
    step's end (the next step's start), which :meth:`invalidate` drops (contract rule 4).
    ``compiled``: step with the numba kernels (True; not for coupled rigid struts) or the numpy reference.

    A scene with a ground or a member contact response is stepped by ``_elastic_ground_kernels.ground_steps``,
    the copies spread over every core, each copy the very arithmetic of a ``Simulator``'s loop (the
    reference: an :class:`ElasticMethod` reference per copy); a copy at a step the kernel leaves to the
    reference (a member pair it does not take, an unsolved block) goes on as ``ElasticMethod.advance`` does, to the end
    of the call. :attr:`contact` then holds the ground's impulses of the last :meth:`advance`, (steps, N, 3, B)
    N*s, and :attr:`pairs` the member contacts' impulses of its steps that had any, {(step, copy): impulses}
    (``ElasticMethod.advanced_pairs``).
    """

    name = "elastic"

    def __init__(self, system: System, dt: float, *, compiled: bool = True):
        self.single = ElasticMethod(system, dt)   # checks the scene and dt, and does the rigid algebra
        self.ground = self.single._ground_model   # None without a ground or a member response
        self.contact = None
        self.pairs: dict = {}
        self._copies = None   # with a ground, the reference's ElasticMethod per copy
        self._kept = None     # the compiled path's output arrays of the last advance, and their key
        # coupled rigid struts (class-k) only have the reference, as in ElasticMethod
        self.compiled = compiled and not self.single.rigid.coupled
        self.system = system
        self.dt = self.single.dt
        self.rigid = self.single.rigid
        self._damped = self.single._damped
        self._rest_struts = system.strut_rest[:, None]
        self._k = system.stiffness[:, None]
        self._floor = system.floor[:, None]
        # sparse incidences whatever the size: a dense (N, m) @ (m, 3 B) product multiplies mostly zeros
        # (and hands a tiny product to a multi-threaded BLAS); the sparse one does 2 m 3 B multiplications
        self._incidence = sp.csr_matrix(system.incidence_matrix())
        self._rigid_incidence = sp.csr_matrix(system.incidence_matrix(self.rigid.ends))
        self._model = kernels.model_arrays(system, self.rigid)
        # the forces at the last step's end: the numpy path's (acc, tensions, directions, slack), or the
        # compiled path's carry (acc (N, 3, B), tensions (nc, B), rigid strut directions (nr, 3, B))
        self._cache = None
        self._warm = None   # the warm starts of the contact solves, kept over an input (invalidate)

    def invalidate(self) -> None:
        if self._cache is not None and len(self._cache) > 3:   # the contact warm starts outlive an input, as
            self._warm = self._cache[3]                         # ElasticMethod's
        self._cache = None
        if self._copies is not None:
            for method in self._copies:
                method.invalidate()

    def forget(self, copies: np.ndarray) -> None:
        """:meth:`invalidate`, and the contact warm starts of ``copies`` zeroed: they start again (a new batch's
        copies start from zero warm starts)."""
        self.invalidate()
        if self._warm is not None:
            self._warm[..., copies] = 0.0

    def prepare(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Initial velocities (N, 3, B) without the components that would stretch a rigid strut."""
        if not self.rigid.count:
            return v
        return v + self._rattle(x, v, self._directions(x, self.rigid.ends))

    # ------------------------------------------------------------------ algebra, batch last
    def _directions(self, x, ends):
        d = x[ends[:, 1]] - x[ends[:, 0]]
        return d / np.sqrt(np.einsum("ijb,ijb->ib", d, d))[:, None, :]

    def _assemble(self, incidence, member_forces):
        """Node forces (N, 3, B) from member force vectors (k, 3, B)."""
        k, _, b = member_forces.shape
        return (incidence @ member_forces.reshape(k, 3 * b)).reshape(-1, 3, b)

    def _forces(self, x, v, rest_lengths, f_ext):
        """Accelerations (N, 3, B), cable tensions (n_cables, B), unit vectors (m, 3, B), slack (n_cables, B)."""
        sys = self.system
        d = sys.member_vectors(x)
        length = np.sqrt(np.einsum("ijb,ijb->ib", d, d))
        n = d / length[:, None, :]
        rest = np.concatenate([np.broadcast_to(self._rest_struts, (sys.n_struts, x.shape[2])), rest_lengths])
        t = self._k * np.maximum(length - rest, self._floor)
        if self._damped:
            cables = t[sys.n_struts:]
            rate = np.einsum("ijb,ijb->ib", sys.cable_vectors(v), n[sys.n_struts:])
            cables += np.where(cables > 0, sys.cable_damping[:, None] * rate, 0.0)
            np.maximum(cables, 0.0, out=cables)   # a damped cable never pushes
        f = self._assemble(self._incidence, t[:, None, :] * n) + sys.gravity_force[:, :, None] + f_ext
        return sys.mass.solve(f), t[sys.n_struts:], n, length[sys.n_struts:] < rest_lengths

    def _push(self, strengths, directions):
        """Node displacements (N, 3, B) of equal-and-opposite pushes ``strengths`` (nr, B) along the struts."""
        return self.system.mass.axial_inverse[:, None, None] * self._assemble(self._rigid_incidence,
                                                                              strengths[:, None, :] * directions)

    def _shake(self, x_start, x_pred, n0):
        """SHAKE (see :mod:`.rigid`) for every copy: the displacement (N, 3, B) back onto the strut lengths."""
        rig = self.rigid
        if rig.coupled:   # a class-k structure: Newton's method on the coupled struts, copy by copy
            return np.stack([rig.project_positions(x_start[..., b], x_pred[..., b], n0[..., b])
                             for b in range(x_pred.shape[2])], axis=-1)
        e = rig.ends
        r = x_pred[e[:, 1]] - x_pred[e[:, 0]]
        p = np.einsum("ijb,ijb->ib", r, n0)
        c = np.einsum("ijb,ijb->ib", r, r) - rig.length_sq[:, None]
        gamma = c / (rig._w[:, None] * (p + np.sqrt(np.maximum(p * p - c, 0.0))))
        return self._push(gamma, n0)

    def _rattle(self, x, v, n):
        """RATTLE for every copy: the velocity change (N, 3, B) that zeroes every strut's length rate."""
        rig = self.rigid
        if rig.coupled:
            return np.stack([rig.project_velocities(x[..., b], v[..., b], n[..., b])
                             for b in range(v.shape[2])], axis=-1)
        e = rig.ends
        rate = np.einsum("ijb,ijb->ib", v[e[:, 1]] - v[e[:, 0]], n)
        return self._push(rate / rig._w[:, None], n)

    # ------------------------------------------------------------------ step
    def _step_reference(self, x, v, rest_lengths, f_ext):
        """The numpy reference: one step of ``dt`` for every copy from positions ``x`` and velocities ``v``
        (N, 3, B), rest lengths (n_cables, B) m and external forces ``f_ext`` (N, 3, B) N. Returns the new
        positions and velocities (N, 3, B), the cable impulses over the step (n_cables, B) N*s and the
        slack cables (n_cables, B) at its end. The inputs are not modified."""
        h = self.dt
        start = self._cache if self._cache is not None else self._forces(x, v, rest_lengths, f_ext)
        v_half = v + (0.5 * h) * start[0]
        x_new = x + h * v_half
        if self.rigid.count:
            dx = self._shake(x, x_new, start[2][self.rigid.members])
            x_new += dx
            v_half += dx / h
        end = self._forces(x_new, v_half, rest_lengths, f_ext)
        v_new = v_half + (0.5 * h) * end[0]
        if self.rigid.count:
            v_new += self._rattle(x_new, v_new, end[2][self.rigid.members])
        self._cache = end
        return x_new, v_new, (0.5 * h) * (start[1] + end[1]), end[3]

    def _outputs(self, key, make) -> tuple:
        """The output arrays of an advance: those of the last one where its ``key`` (path, steps, copies) was the
        same, else ``make()``'s. Memory new to the process costs its first touch (page faults): a third of
        the time of 1,024 rolling copies' compiled steps on 2 cores, against arrays used again (3.5 against
        2.6 us a copy-step, timed in turns in one process). The caller reads them before its next advance."""
        if self._kept is None or self._kept[0] != key:
            self._kept = (key, make())
        return self._kept[1]

    def runs_commands(self) -> bool:
        """Whether :meth:`advance` evaluates a command schedule inside its compiled loop (a ground)."""
        return self.compiled and self.ground is not None

    def advance(self, x, v, rest_lengths, f_ext, steps: int, commands=None, first_step: int = 0):
        """``steps`` steps of every copy from ``x``, ``v`` (N, 3, B) with rest lengths (n_cables, B) and
        external forces (N, 3, B) held, or (:meth:`runs_commands`) with ``commands`` (a ``CommandSchedule``,
        or one per copy) evaluated at each step's start time ``(first_step + k) dt`` on top of them
        (``inputs_in_effect`` then has the inputs of the last step). Returns every step's positions and
        velocities (steps, N, 3, B), impulses (steps, n_cables, B) N*s and slack cables (steps, n_cables, B),
        compiled in arrays the next advance of as many steps writes again (:meth:`_outputs`). Inputs are not
        modified. With a ground, compiled: a copy whose step the reference cannot take either (a ``StepError``:
        a QP without a solution, a non-finite result) has NaN from that step on, as a non-finite step has."""
        n, nc, b = x.shape[0], rest_lengths.shape[0], x.shape[2]
        if self.ground is not None:
            return self._advance_ground(x, v, rest_lengths, f_ext, steps, commands, first_step)
        if not self.compiled:
            out_x, out_v = np.empty((steps, n, 3, b)), np.empty((steps, n, 3, b))
            out_imp, out_slack = np.empty((steps, nc, b)), np.empty((steps, nc, b), dtype=bool)
            for k in range(steps):
                x, v, out_imp[k], out_slack[k] = self._step_reference(x, v, rest_lengths, f_ext)
                out_x[k], out_v[k] = x, v
            return out_x, out_v, out_imp, out_slack
        # the kernel with the copies innermost: each loop walks contiguous numbers (stepping one copy at a
        # time walks numbers B apart: 5.6x slower at B = 1024, measured by bench/bench_batch.py's case)
        x, v, rest, ext = (np.array(a, dtype=float, order="C") for a in (x, v, rest_lengths, f_ext))
        out_x, out_v, out_imp, out_slack = self._outputs(
            ("free", steps, b), lambda: (np.empty((steps, n, 3, b)), np.empty((steps, n, 3, b)),
                                         np.empty((steps, nc, b)), np.empty((steps, nc, b), dtype=bool)))
        if self._cache is None:
            self._cache = (np.empty_like(x), np.empty((nc, b)), np.empty((self.rigid.count, 3, b)))
            kernels.elastic_forces(x, v, rest, ext, *self._model[:10], *self._cache)
        blocks = copy_blocks(b)
        if len(blocks) == 1:
            kernels.elastic_steps_copies(x, v, rest, ext, self.dt, steps, 1, *self._model, *self._cache,
                                         out_x, out_v, out_imp, out_slack)
            return out_x, out_v, out_imp, out_slack

        def run(block):   # a block of copies in arrays of its own (methods/_copy_blocks.py), written back
            state = [np.ascontiguousarray(a[..., block]) for a in (x, v, *self._cache)]
            outs = [np.empty(a.shape[:-1] + (block.stop - block.start,), dtype=a.dtype)
                    for a in (out_x, out_v, out_imp, out_slack)]
            kernels.elastic_steps_copies(state[0], state[1], np.ascontiguousarray(rest[..., block]),
                                         np.ascontiguousarray(ext[..., block]), self.dt, steps, 1, *self._model,
                                         *state[2:], *outs)
            for whole, part in zip((x, v, *self._cache, out_x, out_v, out_imp, out_slack), state + outs):
                whole[..., block] = part

        on_blocks(run, blocks)
        return out_x, out_v, out_imp, out_slack

    def _inputs(self, commands, rest, ext, steps: int, first_step: int):
        """Each step's rest lengths (steps, nc, Bs) and forces (steps, N, 3, Be) from ``commands`` on top of
        ``rest`` (nc, B) and ``ext`` (N, 3, B): Bs = 1 where one schedule meets copies with the same rest lengths,
        Be = 1 where it meets them with the same forces (an environment's copies: its actions reel each copy's
        cables, its forces are every copy's none; one column each step instead of B, 1.5 MB a control period
        of 256 copies)."""
        times = (first_step + np.arange(steps)) * self.dt
        if isinstance(commands, (list, tuple)):
            per_copy = [c.inputs_at(times, rest[:, b], ext[..., b]) for b, c in enumerate(commands)]
            return tuple(np.ascontiguousarray(np.stack([p[i] for p in per_copy], axis=-1)) for i in range(2))
        if (rest == rest[:, :1]).all():
            rest = rest[:, :1]
        if (ext == ext[..., :1]).all():
            ext = ext[..., :1]
        return tuple(np.ascontiguousarray(a) for a in commands.inputs_at(times, rest, ext))

    def _advance_ground(self, x, v, rest_lengths, f_ext, steps: int, commands=None, first_step: int = 0):
        """:meth:`advance` with a ground; its impulses go to :attr:`contact`."""
        n, nc, b = x.shape[0], rest_lengths.shape[0], x.shape[2]
        n_pairs = len(self.single._pair_keys)
        self.pairs = {}

        def copy_major(*shape, dtype=float):
            # (steps, ..., B) over memory laid out copy by copy: the loop steps one copy at a time, and its
            # writes then fall on consecutive numbers, not numbers B apart (1,024 rolling copies on 2 threads:
            # 3.1-3.3 us a copy-step against 4.0-4.3, timed in turns in one process)
            return np.moveaxis(np.empty((b, steps) + shape, dtype=dtype), 0, -1)

        if not self.compiled:
            out_x, out_v, out_imp = copy_major(n, 3), copy_major(n, 3), copy_major(nc)
            out_slack, self.contact = copy_major(nc, dtype=bool), copy_major(n, 3)
            out_contact = self.contact
            if self._copies is None:
                self._copies = [ElasticMethod(self.system, self.dt, compiled=False) for _ in range(b)]
            for c, method in enumerate(self._copies):
                state = State(x[..., c].copy(), v[..., c].copy(), rest_lengths[:, c].copy(), f_ext[..., c].copy())
                for k in range(steps):
                    out = method.step(state)
                    state.positions, state.velocities = out.positions, out.velocities
                    out_x[k, ..., c], out_v[k, ..., c], out_contact[k, ..., c] = out.positions, out.velocities, \
                        out.contact_impulses
                    out_imp[k, :, c], out_slack[k, :, c] = out.impulses, out.slack
                    if out.pair_impulses:
                        self.pairs[(k, c)] = out.pair_impulses
            return out_x, out_v, out_imp, out_slack
        out_x, out_v, out_imp, out_slack, out_contact = self._outputs(
            ("ground", steps, b), lambda: (copy_major(n, 3), copy_major(n, 3), copy_major(nc),
                                           copy_major(nc, dtype=bool), copy_major(n, 3)))
        self.contact = out_contact
        x, v, rest, ext = self._ground_start(x, v, rest_lengths, f_ext)
        failed, reason, count = (np.empty(b, dtype=np.int64) for _ in range(3))
        records = np.empty((b, n_pairs and max(n_pairs, min(steps * n_pairs, _PAIR_RECORDS)), 6))
        seq = _HELD if commands is None else self._inputs(commands, rest, ext, steps, first_step)
        # no summary asked of the kernel (no column): every step is kept, and the run sums them up
        summary = tuple(np.empty((nc, 0), dtype=t) for t in (float, np.int64, bool))
        ground_kernels.ground_steps(x, v, rest, ext, self.dt, steps, 1, *self._model, *self._cache[:3], *self.ground,
                                    self._cache[3], *seq, out_x, out_v, out_imp, out_slack, out_contact, records,
                                    count, failed, reason, *summary, min(b, numba.get_num_threads()))
        self._inputs_in_effect(seq, rest, ext, commands)
        for c in np.flatnonzero(count > 0):
            self.pairs.update({(k, c): pairs for k, pairs in self.single._pair_records(records[c, :count[c]]).items()})
        for c in np.flatnonzero(failed >= 0):
            # a contact block the compiled solver left unsolved, or a member pair it does not take: this copy goes
            # on from that step's start as a Simulator's loop does (ElasticMethod.advance: that step by the
            # reference, then compiled); where the kernel ran out of room for the pairs' impulses, from its carry
            done = int(failed[c])
            full = reason[c] == ground_kernels.FULL
            method = ElasticMethod(self.system, self.dt)
            bs, be = (c if seq[0].shape[2] > 1 else 0), (c if seq[1].shape[3] > 1 else 0)
            inputs = None if commands is None else (seq[0][done:, :, bs], seq[1][done:, ..., be])
            state = State(x[..., c].copy(), v[..., c].copy(), rest[:, c].copy(), ext[..., c].copy())
            if inputs is not None and (done or not full):   # the inputs in effect (at FULL: the step's before)
                state.rest_lengths = seq[0][done - full, :, bs].copy()
                state.external_forces = seq[1][done - full, ..., be].copy()
            if full:
                method.restore(tuple(a[..., c:c + 1] for a in self._cache[:3]) + (np.zeros((nc, 1), dtype=bool),
                                                                                  self._cache[3][..., c:c + 1]))
            rows = steps - done
            pos, vel, contact = (np.full((rows, n, 3), np.nan) for _ in range(3))
            imp, slack = np.full((rows, nc), np.nan), np.zeros((rows, nc), dtype=bool)
            stopped = False
            try:
                # (overflow is not warned of: a copy whose numbers run off is reported by BatchSimulator's guard)
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    x[..., c], v[..., c] = method.advance(state, rows, 1, pos, vel, imp, slack, contact, inputs)
            except StepError:
                stopped = True
                # the copy fails alone, its steps from the one the reference could not take NaN (the rows before
                # it are written): BatchSimulator's guard reports it (a copy refused before, stepped from its
                # absurd state, is known there already), where the exception would stop every copy
                x[..., c] = v[..., c] = np.nan
            self.pairs.update({(done + k, c): impulses for k, impulses in method.advanced_pairs.items()})
            out_x[done:, ..., c], out_v[done:, ..., c], out_contact[done:, ..., c] = pos, vel, contact
            out_imp[done:, :, c], out_slack[done:, :, c] = imp, slack
            if stopped:   # no carry: the guard keeps the copy's state before the failure
                continue
            carry = method.carry()
            if carry is None:   # its last step was the reference's: the next starts from forces computed anew there
                xc, vc = np.ascontiguousarray(x[..., c:c + 1]), np.ascontiguousarray(v[..., c:c + 1])
                last = (rest[:, c:c + 1], ext[..., c:c + 1]) if inputs is None else (inputs[0][-1][:, None],
                                                                                     inputs[1][-1][..., None])
                forces = (np.empty_like(xc), np.empty((nc, 1)), np.empty((self.rigid.count, 3, 1)))
                kernels.elastic_forces(xc, vc, *(np.ascontiguousarray(a) for a in last), *self._model[:10], *forces)
                carry = forces + (None, np.zeros((2, n + n_pairs, 3, 1)))   # and no warm start, as ElasticMethod's
            for mine, its in zip(self._cache, carry[:3] + carry[4:]):
                mine[..., c] = its[..., 0]
        return out_x, out_v, out_imp, out_slack

    def _ground_start(self, x, v, rest_lengths, f_ext) -> tuple:
        """The ground kernel's inputs, contiguous copies of ``x``, ``v``, the rest lengths and forces (it steps
        ``x`` and ``v`` in place), the carry computed first where there is none."""
        x, v, rest, ext = (np.array(a, dtype=float, order="C") for a in (x, v, rest_lengths, f_ext))
        if self._cache is None:
            n, nc, b = x.shape[0], rest.shape[0], x.shape[2]
            self._cache = (np.empty_like(x), np.empty((nc, b)), np.empty((self.rigid.count, 3, b)))
            kernels.elastic_forces(x, v, rest, ext, *self._model[:10], *self._cache)
            # each node's and member pair's last contact impulses (drift, closing)
            self._cache += (np.zeros((2, n + len(self.single._pair_keys), 3, b)) if self._warm is None
                            else self._warm,)
            self._warm = None
        return x, v, rest, ext

    def _inputs_in_effect(self, seq, rest, ext, commands) -> None:
        """After a run of ``commands`` (each step's inputs ``seq``): the last step's, as (n_cables, B), (N, 3, B)."""
        if commands is not None:
            self.inputs_in_effect = (np.ascontiguousarray(np.broadcast_to(seq[0][-1], rest.shape)),
                                     np.ascontiguousarray(np.broadcast_to(seq[1][-1], ext.shape)))

    def summarises(self) -> bool:
        """Whether :meth:`advance_summary` takes runs that keep no step (compiled, on a ground, no member pairs)."""
        return self.compiled and self.ground is not None and not self.single._pair_keys

    def advance_summary(self, x, v, rest_lengths, f_ext, steps: int, commands, first_step: int, was_slack):
        """:meth:`advance` of a run that keeps no step (:meth:`summarises`): the kernel keeps only the last step
        and sums up the others itself (``_ground_kernels.ground_steps``' summary), where every step's numbers
        cost a fifth of a ``Roll-v0`` control period (the kernel's writes of 20 steps of 256 copies and the run's
        reductions of them). ``was_slack`` (n_cables, B) bool: the slack cables at the start. Returns the
        positions and velocities (N, 3, B) after the steps, each cable's largest impulse of a step (n_cables, B)
        N*s, its snaps (n_cables, B) int and the slack cables (n_cables, B) at the end; or None, changing
        nothing, where a copy's step was left to the reference or a number is not finite (the caller then takes
        :meth:`advance`, whose every step it needs for those)."""
        nc, b = rest_lengths.shape
        n = x.shape[0]
        x, v, rest, ext = self._ground_start(x, v, rest_lengths, f_ext)
        carry = tuple(a.copy() for a in self._cache)
        out = self._outputs(("summary", b), lambda: (np.empty((1, n, 3, b)), np.empty((1, n, 3, b)),
                                                     np.empty((1, nc, b)), np.empty((1, nc, b), dtype=bool),
                                                     np.empty((1, n, 3, b))))
        failed, reason, count = (np.empty(b, dtype=np.int64) for _ in range(3))
        seq = _HELD if commands is None else self._inputs(commands, rest, ext, steps, first_step)
        peak, snaps, slack = np.zeros((nc, b)), np.zeros((nc, b), dtype=np.int64), np.array(was_slack, order="C")
        ground_kernels.ground_steps(x, v, rest, ext, self.dt, steps, steps, *self._model, *self._cache[:3],
                                    *self.ground, self._cache[3], *seq, *out, np.empty((b, 0, 6)), count, failed,
                                    reason, peak, snaps, slack, min(b, numba.get_num_threads()))
        with np.errstate(invalid="ignore", over="ignore"):
            finite = np.isfinite(np.add.reduce(x, axis=None) + np.add.reduce(v, axis=None)
                                 + np.add.reduce(out[2], axis=None))
        if not finite or (failed >= 0).any():
            self._cache = carry
            return None
        self._inputs_in_effect(seq, rest, ext, commands)
        return x, v, peak, snaps, slack

    def slack(self, x, rest_lengths) -> np.ndarray:
        """(n_cables, B) bool: the cables shorter than their rest lengths at ``x`` (N, 3, B)."""
        d = self.system.cable_vectors(x)
        return np.sqrt(np.einsum("ijb,ijb->ib", d, d)) < rest_lengths

    def strain_energy(self, x, rest_lengths) -> np.ndarray:
        """Elastic energy (B,) J of every copy at positions ``x`` (N, 3, B) and rest lengths (n_cables, B)."""
        sys = self.system
        d = sys.member_vectors(x)
        length = np.sqrt(np.einsum("ijb,ijb->ib", d, d))
        rest = np.concatenate([np.broadcast_to(self._rest_struts, (sys.n_struts, x.shape[2])), rest_lengths])
        e = np.maximum(length - rest, self._floor)
        return 0.5 * np.sum(self._k * e * e, axis=0)
