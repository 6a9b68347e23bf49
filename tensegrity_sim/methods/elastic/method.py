"""Method 2 of physics.md §4: massless elastic cables (tension ``k max(0, e)``), elastic or rigid struts.

Integrator: velocity Verlet (with RATTLE for rigid struts), chosen by measurement
(``bench/energy_drift.py``, ``test/test_elastic.py``):

* It is symplectic and time-reversible, so an undamped structure's energy error stays bounded (it
  oscillates at O(h^2) and does not drift) over long runs; an explicit Runge-Kutta of the same cost
  drifts. With constant slack/taut switching the cable force's kink leaves the theory's smooth case:
  each switch adds an energy error of either sign and the error random-walks (grows like sqrt(t), its
  trend changing sign with the seed and with round-off): prism3 with random velocities (0.5 m/s), 1e6
  steps at 1 ms (``omega_max dt = 0.30``), seven seeds: max |dE|/E 5.9e-4..5.3e-3; at 0.5 ms (2e6 steps)
  5.1e-4 where 1 ms gave 3.4e-3; at order 4, 1 ms, 4.9e-5 (``bench/hard_cases.py``, ``DRIFT_RATIO``).
* Every force is an equal-and-opposite pair along a member, and Verlet applies it at one configuration,
  so linear and angular momentum are conserved to round-off (it is a variational integrator).
* The cable force ``k max(0, e)`` is continuous in the positions and only its derivative jumps at a
  slack/taut switch. A step containing the kink has an O(h^2) local error whose constant depends on
  where in the step the switch falls, so by default the step is split at the switch
  (``locate_switches``, ``methods/elastic/composition.py``): each part sees a smooth force and every halving
  of dt divides the error by 4 (bungee and dead band, 4 ms to 0.25 ms: ratios 3.7 to 4.1, measured by
  ``test_composition.py``). Unlocated, the global error is still O(h^2) but the ratios scatter (1.5 to
  44 on the bungee).
* ``order=4`` composes five Verlet steps (Suzuki) for an O(h^4) error, through switches too.
* A split step is not symplectic as a whole (its parts' sizes depend on the state). With the fastest
  vibration resolved that costs nothing measurable, but with it under-resolved the energy random-walks:
  prism3 (elastic struts, ``omega_max = 302 rad/s``), 1e6 steps at 1 ms (``omega_max dt = 0.30``):
  located, max |dE|/E 2.1e-2, the tenths' mean rising from 7.5e-3 J to 4.1e-2 J, five times plain
  Verlet's drift above. So locate at order 2 only where ``omega_max dt <= 0.2`` (prism3 at 0.5 ms, 0.15: max |dE|/E 6.3e-4 over 2e5 steps with no trend, plain Verlet 4.1e-4;
  the tumbling icosahedron at 1 ms, 0.035: 4.2e-6, flat over 1e5 steps).
* It is explicit: stable only for ``dt < 2 / omega_max`` of the elastic members. The limit is computed
  at start-up and a larger step is refused with the limit in the message; stiff struts can be made
  ``"rigid"`` instead, which removes their frequency from the limit.

Cable damping ``c de/dt`` acts only while a cable is taut, and the total cable tension is clipped at
zero: a damped cable that is being released goes slack at once instead of pushing. The damping force
at the end of a step uses the half-step velocity (first order in the damping term, still exactly
momentum-conserving since it is along the cable).

Impulses: the velocity update applies each cable's tension as ``h/2 (t_start + t_end)``; that is the
cable's impulse over the step (summed over the parts and stages of a split or composed step), and
``impulses / h`` the step's mean tension.

Two implementations of the same arithmetic: the numba kernels (used unless ``compiled`` is False) of
``elastic/_kernels.py`` for plain Verlet (order 2, switches not located) and of
``_composition_kernels.py`` for the located and order-4 options, and the numpy code below (the primitive
:meth:`ElasticMethod.verlet` composed by ``methods/elastic/composition.py``), the plain reference they must
match to 1e-12 in tests. Rigid struts that share a node (class-k: coupled SHAKE/RATTLE, a Newton solve)
are stepped by the reference only; a scene with a ground or a member contact response by
``elastic/_ground_kernels.py`` (below).

**Ground contact** (a scene with a ``ground``; ``methods/contact/friction.py``): an impulse step for the contact
set at each half-kick while the cables stay explicit. After the first half-kick, the nodes that would
pass the ground during the drift get the impulse that lands them exactly on it, with exact Coulomb
friction, the rigid struts keeping their lengths (the QP of ``methods/qp/solvers.py`` with the contact rows);
after the closing half-kick, the nodes on the ground get the impulse that stops them moving into it
(Newton's restitution for those that landed in this step) and applies friction again. What it costs:
the impact is not located inside the step, so a step with an impact or a stick/slip switch is first
order (a bounce's height is off by O(h v): measured 3e-5..7e-5 m for 1 m at 1 ms), and the scheme is no
longer symplectic while a contact is closed — contact and friction impulses only remove energy
(plastic impacts, dissipative friction), but Verlet's own O(h²) energy wobble remains (measured 4e-6
relative per step on the dropped icosahedron). Away from the ground nothing changes. A scene with a
ground steps plain Verlet (order 2, switches not located): the options are refused there.

Compiled, the ground's velocity problems are solved block by block (with elastic cables only a rigid
strut couples nodes: ``_friction_block_kernels.py``, a damped semismooth Newton on the Alart–Curnier form
with the exact disc, against the Coulomb law's projection form; a rod's block couples its ends' rows through
``M^-1``'s cross entry too, and the reference's QPs take the full block mass matrix in ``BlockMassSolver``'s
coordinates, its last resort NSGS with steps along the rows' null space), the same answers as the QP fixed point to
its tolerance (``test/test_friction_blocks.py``) and every closed form of ``test/test_ground.py`` on both
paths. A block the Newton leaves unsolved (measured: 1 % of random blocks with arbitrary strut directions,
masses and mu up to 1; none on the test scenes) has its step taken by the reference (``fallbacks`` counts
them), and the compiled loop goes on after it. A member contact
response (``contact: response: true``, ``methods/contact/member.py``) is the same impulse step with the
member pairs' rows beside the ground's, at the same cost to the order and energy behaviour. Compiled, an
armed member pair (one that may touch by the drift's end, or touches at the step's end) joins the blocks of
the bodies it touches into one coupled block (``solve_coupled``: the same Newton on general rows; the pairs'
impulses of :meth:`ElasticMethod.advance` are kept in ``advanced_pairs``); a step the kernel does not take
(a coupled block beyond ``MAX_COUPLED`` rows, segments that meet) goes to the reference in the same way
(``member_steps`` counts them).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...system import System
from . import _composition_kernels as composed
from . import _ground_kernels as ground_kernels
from ..contact import _detection_kernels as detection_kernels
from . import _kernels as kernels
from ..base import MethodStep, State, StepMethod
from .composition import MIN_SPLIT, STABILITY, WEIGHTS, Stepper, check_stable
from ..contact.friction import TOUCH_TOL, ContactSet
from ..qp.solvers import make_solver
from ..rigid import RigidStruts

__all__ = ["ElasticMethod"]

_GROUND_CHUNK = 1024   # steps per compiled call of :meth:`ElasticMethod.advance` with a ground
_PAIR_RECORDS = 4096   # member-pair impulse records a compiled call keeps at most (it stops where they run out)
_HELD = (np.empty((0, 0, 1)), np.empty((0, 0, 3, 1)))   # no per-step inputs: the state's held


class _Warm(NamedTuple):
    """A carry of :meth:`ElasticMethod.carry` that is only the contact solver's warm start (2, N + P, 3, 1):
    what an input left for the next step."""

    warm: np.ndarray


class _Forces(NamedTuple):
    """What the step needs at one configuration: accelerations (N, 3) m/s^2, cable tensions
    (n_cables,) N, member unit vectors (m, 3), slack cables (n_cables,) bool, cable elongations
    ``length - rest`` (n_cables,) m (negative when slack)."""

    acc: np.ndarray
    cable_tensions: np.ndarray
    directions: np.ndarray
    slack: np.ndarray
    elongations: np.ndarray


class ElasticMethod(StepMethod):
    """Options: ``order`` 2 (velocity Verlet, one force evaluation per step) or 4 (Suzuki's symmetric
    composition of five Verlet steps, five evaluations); ``locate_switches`` splits a step at each
    slack/taut switch (``methods/elastic/composition.py``); default (None): at order 4 only (at order 2 it
    costs a located part per switching step and, with the fastest vibration under-resolved, lets the
    energy random-walk: see the module docstring). ``compiled``: step with the numba kernels (True; not
    for coupled rigid struts; with a member contact response a step with an armed pair by the reference) or
    the numpy reference (False)."""

    name = "elastic"
    options = ("order", "locate_switches")

    def __init__(self, system: System, dt: float, *, order: int = 2, locate_switches: bool | None = None,
                 compiled: bool = True):
        super().__init__(system, dt)
        missing = [c.name for c in system.scene.cables if c.stiffness is None]
        if missing:
            raise ValueError(f"method 'elastic' needs a stiffness for every cable; missing for {missing}")
        if isinstance(order, bool) or order not in STABILITY:
            raise ValueError(f"order must be one of {sorted(STABILITY)}, got {order!r}")
        if not (locate_switches is None or isinstance(locate_switches, (bool, np.bool_))):
            raise ValueError(f"locate_switches must be True, False or None (automatic), got {locate_switches!r}")
        self.order = int(order)
        self.rigid = RigidStruts(system)
        self.omega_max = system.max_frequency(system.scene.positions, include_cables=True)
        if locate_switches is None:
            locate_switches = self.order == 4
        self.locate_switches = bool(locate_switches)
        if self.locate_switches and len(system.attached):
            raise ValueError(f"method 'elastic' locates slack/taut switches only for cables between two nodes; "
                             f"cable {system.scene.cable_names[system.attached[0]]!r} is attached along a strut: "
                             f"use locate_switches=False")
        check_stable("elastic", self.order, self.dt, self.omega_max, "use a smaller dt or rigid struts")
        self.stepper = Stepper(self.verlet, self.order, system, self.dt, self.locate_switches)
        self._damped = bool(np.any(system.cable_damping > 0))
        self._rest = np.empty(system.n_members)
        self._rest[: system.n_struts] = system.strut_rest
        self._cache: _Forces | None = None
        # a ground: the contact set's velocity problem solved by the QP backends (methods/contact/friction.py),
        # in the reference step, which is then plain Verlet (one primitive step per step)
        self.ground = None
        if system.scene.ground is not None or system.scene.contact_response.response:
            if self.order != 2 or self.locate_switches:
                raise ValueError("a scene with a ground or a contact response is stepped by plain Verlet: order 4 "
                                 "and located switches are not available with contacts")
            self.ground = ContactSet(system, make_solver(None, system.masses[system.free], system.mass))
        self._contact = None   # the ground's impulses of the last step (N, 3) N*s, or None
        self._pairs = None     # the member contacts' of the last step (ContactSet.pair_impulses), or None
        # the compiled kernels: plain Verlet (elastic/_kernels.py), the options (_composition_kernels.py) and
        # the contacts (elastic/_ground_kernels.py); coupled rigid struts run the numpy primitive
        self.compiled = compiled and not self.rigid.coupled
        self._ground_model = (None if self.ground is None
                              else ground_kernels.ground_arrays(system, self.rigid, TOUCH_TOL, self.ground.members))
        self.fallbacks = 0     # compiled steps with contacts retaken by the reference (a block unsolved) ...
        self.member_steps = 0  # ... and taken by it (a member pair the kernel does not take)
        # the member pairs the kernel examines, (P, 2) system member indices: its impulse records' keys
        self._pair_keys = (None if self.ground is None
                           else ground_kernels.eligible_pairs(system, self.ground.members).tolist())
        self._records = {}    # the member pairs' impulses of the last compiled call, {step: pair_impulses}
        # the compiled call's flags (failed, reason, n_records: (1,) int64 each) and, without member pairs, its
        # empty record buffer, made once: a call of one step (a command every step) is where they cost
        self._flags = tuple(np.empty(1, dtype=np.int64) for _ in range(3))
        self._no_records = np.empty((1, 0, 6))
        # the kernel's summary of its steps (peak impulses, snaps, slack), which a batch that keeps no step reads;
        # Simulator reads its kept steps instead: none asked for (no column)
        nc = system.n_cables
        self._summary = (np.empty((nc, 0)), np.empty((nc, 0), dtype=np.int64), np.empty((nc, 0), dtype=bool))
        self._plain = self.order == 2 and not self.locate_switches
        self._weights = np.array(WEIGHTS[self.order])
        self._model = kernels.model_arrays(system, self.rigid)
        # the compiled path's carry from one step to the next (batch of one): accelerations (N, 3, 1),
        # cable tensions (n_cables, 1), rigid strut directions (nr, 3, 1), slack cables (n_cables, 1) at
        # the last step's end; with a ground, each node's last contact impulses (2, N, 3, 1) too
        self._carry = None
        self._warm = None   # the contact solver's warm starts (2, N, 3, 1) kept when an input drops the carry
        # member-contact detection inside the compiled loop (loop_detects): the detector whose state
        # advance moves on (a contact.CompiledDetector, set by the simulator for a run), and the events
        # of the last advance (_detection_kernels.new_events)
        self.detection = None
        self.found = None
        self._no_detection = detection_kernels.no_detection()
        if self.compiled:
            self._load_kernels()

    def _load_kernels(self) -> None:
        """Compile the kernels, or load them from numba's cache, now rather than in the first step: a
        simulator that exists steps at full speed (a node's first steps, a timed loop)."""
        scene = self.system.scene
        x, v = scene.positions.reshape(-1, 3, 1).copy(), scene.velocities.reshape(-1, 3, 1).copy()
        rest = scene.cable_rest_lengths.reshape(-1, 1).copy()
        out = (x[None].copy(), v[None].copy(), np.empty((0,) + rest.shape), np.empty((0,) + rest.shape, dtype=bool))
        self._advance(State(x, v, rest, np.zeros_like(x)), x, v, 0, 1, *out, np.empty((0,) + x.shape))
        self._carry = None

    @property
    def carry_outlives_inputs(self) -> bool:
        """With contacts: the contact solver's warm starts outlive an input (:meth:`invalidate` keeps them), so
        the simulator puts the loop back at the state before an input changes (``base.py``'s rule 10): the warm
        start an input leaves is the state's, not that of steps computed ahead and dropped, whenever they were
        computed (a live node computes them in its idle time, its replay in the step)."""
        return self.ground is not None

    def invalidate(self) -> None:
        self._cache = None
        if self._carry is not None:   # the contact solver's warm starts outlive an input (a hint, not state)
            self._warm = self._carry[4]
        self._carry = None

    def prepare(self, state: State) -> None:
        """Initial velocities that would stretch a rigid strut lose that component (a rigid body cannot
        have it); the change is internal, so momentum is unchanged. A reset forgets the contact solver's
        warm starts, so that a reset simulator steps as a fresh one does, to the bit (a warm start from
        the steps computed ahead before the reset gave a rolling pair's run 1e-16 m apart)."""
        self._carry = self._warm = None
        if self.rigid.count:
            state.velocities = state.velocities + self.rigid.project_velocities(state.positions, state.velocities)

    def tensions(self, x: np.ndarray, v: np.ndarray, rest_lengths: np.ndarray):
        """Member tensions (m,) N (struts first; rigid struts 0), lengths (m,) m and unit vectors (m, 3)
        at ``x``."""
        sys = self.system
        rest = self._rest
        rest[sys.n_struts:] = rest_lengths
        _, length, n = sys.geometry(x)
        t = sys.stiffness * np.maximum(length - rest, sys.floor)
        if self._damped:
            cables = t[sys.n_struts:]
            rate = sys.cable_rates(v, n[sys.n_struts:])
            taut = cables > 0
            cables += np.where(taut, sys.cable_damping * rate, 0.0)
            np.maximum(cables, 0.0, out=cables)  # a damped cable never pushes
        return t, length, n

    def accelerations(self, x, v, state: State) -> _Forces:
        t, length, n = self.tensions(x, v, state.rest_lengths)
        sys = self.system
        f = sys.assemble(t[:, None] * n) + sys.gravity_force + state.external_forces
        e = length[sys.n_struts:] - state.rest_lengths
        return _Forces(sys.mass.solve(f), t[sys.n_struts:], n, e < 0, e)

    def _advance(self, state: State, x: np.ndarray, v: np.ndarray, steps: int, every: int, positions, velocities,
                 impulses, slack, contact=None, inputs=_HELD) -> int:
        """The compiled loop (batch of one) from ``state`` but at ``x``, ``v`` (N, 3, 1), which it
        advances in place; the outputs are those of :meth:`advance` with a trailing batch axis, and with a
        ground ``contact`` (K, N, 3, 1) N*s its impulses, and ``_records`` the member pairs' of the steps that had
        any, {step: ``MethodStep.pair_impulses``}. ``inputs`` (a ground): each step's rest lengths (steps, nc, 1)
        and forces (steps, N, 3, 1), ``state``'s being those in effect before them. Returns ``(-1, 0)``, or
        (contacts) a step and why the loop stopped there (``_ground_kernels``' reasons): ``x``, ``v`` are then
        at its start; one left to the reference (a contact block not solved, a member pair the kernel does not
        take) has the carry dropped, its inputs (with ``inputs``) in ``state`` and ``fallbacks`` or
        ``member_steps`` counting it; at ``FULL`` (no room for its pairs' impulses) the carry holds and
        ``state`` has the inputs before it, for a call that goes on from there."""
        rest = state.rest_lengths.reshape(-1, 1)
        ext = state.external_forces.reshape(-1, 3, 1)
        if self._carry is None:   # the start forces: the last step's end, or computed here
            forces = (np.empty_like(x), np.empty((self.system.n_cables, 1)), np.empty((self.rigid.count, 3, 1)))
            # with a ground: each node's last contact impulses (drift and closing solves), kept over an input
            warm = (np.zeros((2, x.shape[0] + len(self._pair_keys or ()), 3, 1)) if self._warm is None
                    else self._warm)
            self._warm = None
            self._carry = forces + (kernels.elastic_forces(x, v, rest, ext, *self._model[:10], *forces), warm)
        if self._ground_model is not None:
            failed, reason, count = self._flags
            n_pairs = len(self._pair_keys)
            records = (self._no_records if not n_pairs
                       else np.empty((1, max(n_pairs, min(steps * n_pairs, _PAIR_RECORDS)), 6)))
            ground_kernels.ground_steps_serial(x, v, rest, ext, self.dt, steps, every, *self._model, *self._carry[:3],
                                               *self._ground_model, self._carry[4], *inputs, positions, velocities,
                                               impulses, slack, contact, records, count, failed, reason,
                                               *self._summary, 1)
            self._records = self._pair_records(records[0, :count[0]])
            at, why = int(failed[0]), int(reason[0])
            if at >= 0 and why != ground_kernels.FULL:
                self._carry = None
                if why == ground_kernels.MEMBERS:
                    self.member_steps += 1
                else:
                    self.fallbacks += 1
            if inputs[0].shape[0]:   # the inputs of the last step taken (or of the one not taken)
                last = steps - 1 if at < 0 else at - (why == ground_kernels.FULL)
                if last >= 0:
                    state.rest_lengths = inputs[0][last, :, 0].copy()
                    state.external_forces = inputs[1][last, ..., 0].copy()
            return at, why
        if self._plain:
            self.found = kernels.elastic_steps(x, v, rest, ext, self.dt, steps, every, *self._model, *self._carry[:3],
                                               positions, velocities, impulses, slack,
                                               self._no_detection if self.detection is None else self.detection.state)
        else:
            composed.composed_steps(x, v, rest, ext, self.dt, steps, every, self._weights, self.locate_switches,
                                    MIN_SPLIT * self.dt, *self._model, *self._carry[:4], positions, velocities,
                                    impulses, slack)
        return -1, 0

    def _pair_records(self, records: np.ndarray) -> dict:
        """The kernel's member-pair records (k, 6) (step, pair, normal, friction in space) as
        {step: ``MethodStep.pair_impulses``}."""
        out = {}
        for step, pair, normal, *friction in records.tolist():
            out.setdefault(int(step), {})[tuple(self._pair_keys[int(pair)])] = (normal, np.array(friction))
        return out

    def _step_impl(self, state: State) -> MethodStep:
        if not self.compiled:
            return self._step_reference(state)
        n = self.system.n_nodes
        x, v = state.positions.copy(), state.velocities.copy()
        impulses = np.empty((1, self.system.n_cables, 1))
        slack = np.empty((1, self.system.n_cables, 1), dtype=bool)
        contact = np.empty((1, n, 3, 1))
        x3, v3 = x.reshape(-1, 3, 1), v.reshape(-1, 3, 1)
        # the step writes in place (a record buffer has room for one step's pairs: never FULL)
        if self._advance(state, x3, v3, 1, 1, x3[None], v3[None], impulses, slack, contact)[0] >= 0:
            # a contact block the compiled solver left unsolved or an armed member pair: the step in the
            # reference (friction.py's QP fixed point and its fallbacks)
            self._cache = None
            return self._step_reference(state)
        return MethodStep(x, v, impulses.reshape(-1), slack.reshape(-1),
                          None if self._ground_model is None else contact.reshape(n, 3), self._records.get(0))

    def has_loop(self) -> bool:
        return self.compiled

    def has_ground_loop(self) -> bool:
        return self.compiled and self._ground_model is not None

    def loop_detects(self) -> bool:
        return self.compiled and self._plain and self._ground_model is None

    def carry(self):
        """The compiled loop's carry (a copy), or, where no step ran since an input dropped it, the contact
        solver's warm start kept for the next step (:class:`_Warm`; None: none): a rewind to it computes the
        same steps again."""
        if self._carry is not None:
            return tuple(a.copy() for a in self._carry)
        return None if self._warm is None else _Warm(self._warm.copy())

    def restore(self, carry) -> None:
        if isinstance(carry, _Warm):
            self._carry, self._warm = None, carry.warm.copy()
        else:
            self._carry, self._warm = (None if carry is None else tuple(a.copy() for a in carry)), None

    def retrace(self, state: State) -> MethodStep | None:
        if not self.compiled:
            return None
        self._cache = None
        return self._step_reference(state)

    def runs_commands(self) -> bool:
        return self.compiled and self._ground_model is not None

    def advance(self, state: State, steps: int, every: int, positions: np.ndarray, velocities: np.ndarray,
                impulses: np.ndarray, slack: np.ndarray, contact: np.ndarray | None = None, inputs=None
                ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`StepMethod.advance`; with a ground, ``contact`` (K, N, 3) N*s gets its impulses, summed
        like the cables' (None: not kept), and ``inputs`` may give each step's rest lengths (steps, nc) and
        external forces (steps, N, 3) (:meth:`runs_commands`; ``state``'s are those in effect before them, and
        are not changed). The member contacts' impulses of the steps that had any go to ``advanced_pairs``."""
        x, v = state.positions.copy(), state.velocities.copy()
        x3, v3 = x.reshape(-1, 3, 1), v.reshape(-1, 3, 1)
        self.advanced_pairs = {}
        if self._ground_model is None:
            self._advance(state, x3, v3, steps, every, positions[..., None], velocities[..., None],
                          impulses[..., None], slack[..., None])
            return x, v
        # contacts: chunks of single steps, summed into the kept ones here; a step whose contact block the
        # compiled solver leaves unsolved, or with a member pair it does not take, is taken by the reference,
        # and the compiled loop goes on after it
        now = State(x, v, state.rest_lengths, state.external_forces, state.step_count)
        seq = None if inputs is None else (inputs[0][..., None], inputs[1][..., None])

        def run(first, m, *outs):
            """Steps ``first`` .. ``first + m - 1`` compiled: the steps the kernel took and, where it left the
            next one to the reference, that step by the reference (else None)."""
            at, why = self._advance(now, x3, v3, m, 1, *outs, _HELD if seq is None else
                                    (seq[0][first:first + m], seq[1][first:first + m]))
            self.advanced_pairs.update({first + k: pairs for k, pairs in self._records.items()})
            if at < 0 or why == ground_kernels.FULL:
                return (m if at < 0 else at), None
            out = self._retake(now, x, v)
            if out.pair_impulses:
                self.advanced_pairs[first + at] = out.pair_impulses
            return at, out

        n, nc = x.shape[0], self.system.n_cables
        if every == 1 and contact is not None:   # every step kept: straight into the outputs
            done = 0
            while done < steps:
                got, out = run(done, steps - done, positions[done:, ..., None], velocities[done:, ..., None],
                               impulses[done:, :, None], slack[done:, :, None], contact[done:, ..., None])
                done += got
                if out is not None:
                    positions[done], velocities[done], contact[done] = x, v, out.contact_impulses
                    impulses[done], slack[done] = out.impulses, out.slack
                    done += 1
            return x, v
        chunk = min(steps, _GROUND_CHUNK)
        c_x, c_v, c_contact = np.empty((chunk, n, 3, 1)), np.empty((chunk, n, 3, 1)), np.empty((chunk, n, 3, 1))
        c_imp, c_slack = np.empty((chunk, nc, 1)), np.empty((chunk, nc, 1), dtype=bool)
        impulses[...] = 0.0
        if contact is not None:
            contact[...] = 0.0
        done = 0
        while done < steps:
            m = min(chunk, steps - done)
            got, out = run(done, m, c_x[:m], c_v[:m], c_imp[:m], c_slack[:m], c_contact[:m])
            if out is not None:
                c_x[got, ..., 0], c_v[got, ..., 0], c_contact[got, ..., 0] = x, v, out.contact_impulses
                c_imp[got, :, 0], c_slack[got, :, 0] = out.impulses, out.slack
                got += 1
            g = done + np.arange(got)          # the steps in the run, from 0, and their kept rows
            j = g // every
            np.add.at(impulses, j, c_imp[:got, :, 0])
            if contact is not None:
                np.add.at(contact, j, c_contact[:got, ..., 0])
            last = ((g + 1) % every == 0) | (g == steps - 1)
            positions[j[last]], velocities[j[last]] = c_x[:got][last, ..., 0], c_v[:got][last, ..., 0]
            slack[j[last]] = c_slack[:got][last, :, 0]
            done += got
        return x, v

    def _retake(self, state: State, x: np.ndarray, v: np.ndarray) -> MethodStep:
        """The step from ``x``, ``v`` (N, 3; updated in place) that the compiled loop left to the reference
        (friction.py's QP fixed point and its fallbacks)."""
        self._cache = None
        out = self._step_reference(State(x.copy(), v.copy(), state.rest_lengths, state.external_forces))
        x[...], v[...] = out.positions, out.velocities
        return out

    def _step_reference(self, state: State) -> MethodStep:
        x, v = state.positions, state.velocities
        # the forces at the step's start are the previous step's end forces, unless an input changed
        start = self._cache if self._cache is not None else self.accelerations(x, v, state)
        x_new, v_new, end, impulses = self.stepper.step(x, v, start, self.dt, state)
        self._cache = end
        return MethodStep(x_new, v_new, impulses, end.slack, self._contact, self._pairs)

    def verlet(self, x: np.ndarray, v: np.ndarray, start: _Forces, h: float, state: State):
        """The primitive: one velocity-Verlet/RATTLE step of any size ``h`` (s, may be negative) from
        ``x``, ``v`` (N, 3) with the forces ``start`` at ``x``. Returns the end positions and velocities
        (N, 3) and the forces there. ``methods/elastic/composition.py`` builds every option from it. With a ground
        (then one primitive step per step) it applies the contact impulses and keeps them in ``_contact``."""
        v_half = v + (0.5 * h) * start.acc
        if self.ground is not None:
            # armed also where zeroing its rigid strut's length rate (the velocity problem's rows, SHAKE's after
            # the drift) carries a node into the ground: a strut's axial rate, large under a rod's mass block, took
            # an unarmed end 0.13 mm under it in one step (bench_throws --rods)
            v_f = v_half + self.rigid.project_velocities(x, v_half, start.directions[self.rigid.members]) \
                if self.rigid.count else None
            v_half, landing_speed = self.ground.drift_step(x, v, v_half, h, self.rigid, v_f)
        x_new = x + h * v_half
        if self.rigid.count:
            dx = self.rigid.project_positions(x, x_new, start.directions[self.rigid.members])
            x_new += dx
            v_half += dx / h
        end = self.accelerations(x_new, v_half, state)
        v_new = v_half + (0.5 * h) * end.acc
        if self.rigid.count:
            v_new += self.rigid.project_velocities(x_new, v_new, end.directions[self.rigid.members])
        if self.ground is not None:
            v_new = self.ground.settle_step(x_new, v_new, landing_speed, self.rigid)
            self._contact, self._pairs = self.ground.take_impulses(), self.ground.take_pair_impulses()
        return x_new, v_new, end

    def strain_energy(self, positions: np.ndarray, rest_lengths: np.ndarray) -> float:
        sys = self.system
        rest = np.concatenate([sys.strut_rest, rest_lengths])
        _, length, _ = sys.geometry(positions)
        e = np.maximum(length - rest, sys.floor)
        return float(0.5 * np.sum(sys.stiffness * e * e))

    def describe(self) -> dict:
        return {"method": self.name, "dt": self.dt, "order": self.order, "locate_switches": self.locate_switches}
