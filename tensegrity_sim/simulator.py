"""The simulator: one scene, one method, a state, and the public stepping API (contract §2).

Inputs are checked here, once, at the boundary (with :mod:`tensegrity_sim.checks`); a bad argument
raises ``ValueError`` naming it and leaves the simulator exactly as it was. The methods behind it never
check anything. A step whose result is not finite (an absurd but finite force, speed or distance)
raises :class:`NonFiniteError` and leaves the state as it was: one cheap test per step, the diagnosis
only when it fails.
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Mapping

import numpy as np

from .commands import CommandSchedule
from .checks import check_memory, describe, float_array, real, time_step, whole
from .methods.contact.detection import ActiveContact, CompiledDetector, make_detector
from .methods.contact.ground import GroundDetector
from .methods import State, StepError, make_method
from .methods.contact.friction import TOUCH_TOL
from .results import StepResult, Trajectory, step_result
from .scene import Scene, contact_kinds
from .system import System

__all__ = ["Simulator", "NonFiniteError", "SpeedError", "absurd_speed"]

_CHUNK = 1024   # steps per compiled chunk when contact detection walks through a run's steps
AHEAD = 64      # most steps Simulator.step computes ahead in a compiled loop by default (Simulator.max_steps_ahead)
MAX_AHEAD = 1 << 16   # ... at most (the steps' arrays: 48 bytes a node each)


class NonFiniteError(StepError):
    """A step whose result is not finite; the message names the node or cable and the inputs in effect."""


class SpeedError(StepError):
    """A step from a state whose speeds no step can resolve (:func:`absurd_speed`); the message names the
    node and its speed."""


# A node may move in one step at most this many times the shortest member's length. Beyond it the
# positions after the step are so large that their round-off (machine epsilon times the coordinate)
# exceeds 1e-9 of that member's length, the relative tolerance to which the methods hold rigid struts and
# compare lengths: the step would return a structure whose shape is lost in rounding (a scene at 1e100 m/s
# ran for 20 s of meaningless steps). At dt = 1 ms and a 0.1 m member the limit is 4.5e8 m/s, above the
# speed of light: no physical scene is refused.
SPEED_LIMIT_LENGTHS = 1e-9 / float(np.finfo(float).eps)


def absurd_speed(scene: Scene, velocities: np.ndarray, dt: float, shortest: float) -> str | None:
    """Why no step of ``dt`` s can resolve ``velocities`` (N, 3) m/s of ``scene``'s free nodes, whose
    shortest member is ``shortest`` m long (:data:`SPEED_LIMIT_LENGTHS`), or None when it can. A speed
    that is not finite is left to the non-finite check."""
    speed = np.sqrt(np.einsum("ij,ij->i", velocities, velocities)) * ~scene.fixed
    limit = SPEED_LIMIT_LENGTHS * shortest / dt
    over = np.flatnonzero(speed > limit)
    if not over.size:
        return None
    i = int(over[np.argmax(speed[over])])
    return (f"node {scene.node_names[i]!r} moves at {speed[i]:.6g} m/s: in one step of {dt:g} s it would "
            f"move {speed[i] * dt:.3g} m, over {SPEED_LIMIT_LENGTHS:.3g} times the shortest member "
            f"({shortest:.6g} m), where the positions' round-off exceeds 1e-9 of a member's length "
            f"(at most {limit:.6g} m/s at this dt)")


def finite_step(out) -> bool:
    """Whether a step's positions, velocities and impulses (a ``MethodStep``) are all finite: one sum of
    each, since a sum is finite only if every term is (or the terms overflow together, which is no
    better). The one check the step loop has (bench/bench_guard.py measures it)."""
    add = np.add.reduce  # the ufunc itself: no method dispatch, no ufunc call for the test (math's)
    return math.isfinite(add(out.positions, None) + add(out.velocities, None) + add(out.impulses, None))


def non_finite_report(scene: Scene, state: State, dt: float, positions: np.ndarray, velocities: np.ndarray,
                      impulses: np.ndarray) -> str:
    """Why a step from ``state`` gave non-finite ``positions``/``velocities`` (N, 3) or ``impulses``
    (n_cables,): the first node or cable affected, and the largest of each input (force, speed, coordinate,
    rest length), the one that was absurd among them. Only called once a step has failed."""
    bad = ~np.all(np.isfinite(positions) & np.isfinite(velocities), axis=1)
    # free nodes first: a fixed node's values turn NaN only through 0 * inf, the free one's did first
    bad_nodes = np.concatenate([np.flatnonzero(bad & ~scene.fixed), np.flatnonzero(bad & scene.fixed)])
    bad_cables = np.flatnonzero(~np.isfinite(impulses))
    where = []
    if bad_nodes.size:
        where.append(f"node {scene.node_names[bad_nodes[0]]!r}" + (f" (and {bad_nodes.size - 1} more)"
                                                                    if bad_nodes.size > 1 else ""))
    if bad_cables.size:
        where.append(f"cable {scene.cable_names[bad_cables[0]]!r}" + (f" (and {bad_cables.size - 1} more)"
                                                                       if bad_cables.size > 1 else ""))
    inputs = []
    for what, unit, values in (("external force", "N", state.external_forces), ("speed", "m/s", state.velocities),
                               ("coordinate", "m", state.positions)):
        size = np.max(np.abs(values), axis=1) if values.size else values
        if size.size and size.max() > 0:
            k = int(np.argmax(size))
            inputs.append(f"largest {what} {float(size[k]):.3g} {unit} at node {scene.node_names[k]!r}")
    if state.rest_lengths.size:
        k = int(np.argmax(state.rest_lengths))
        inputs.append(f"longest rest length {float(state.rest_lengths[k]):.3g} m of cable {scene.cable_names[k]!r}")
    return (f"the step from t = {state.step_count * dt:.6f} s gave non-finite values at "
            f"{' and '.join(where) or 'a sum'} (inputs: {'; '.join(inputs) or 'none'}; dt {dt:g} s); the state is as before the step")


def run_plan(duration, steps, every, dt: float, bytes_per_kept: int):
    """``run``'s arguments checked: the step count (``steps``, or ``round(duration / dt)``), ``every``,
    the kept steps (counted from 1: ``every``, ``2 every``, ... and the last; refused if keeping them at
    ``bytes_per_kept`` each would exceed the memory) and how many steps each kept one sums."""
    if (duration is None) == (steps is None):
        raise ValueError("run: give exactly one of duration (s) or steps")
    if steps is None:
        d = real(duration, "duration")
        if d < 0:
            raise ValueError(f"duration must be a finite number of seconds >= 0, got {duration!r}")
        ratio = d / dt
        if not math.isfinite(ratio):  # round() would raise OverflowError
            raise ValueError(f"duration / dt = {duration!r} / {dt!r} s is beyond the float range")
        steps = whole(round(ratio), "duration / dt")
    steps = whole(steps, "steps")
    if isinstance(every, (bool, np.bool_)) or not isinstance(every, (int, np.integer)) or every < 1:
        raise ValueError(f"every must be a whole number >= 1, got {describe(every)}")
    every = int(every)
    n_kept = -(-steps // every)
    check_memory(n_kept * bytes_per_kept, f"run: the trajectory of {describe(n_kept)} steps")
    kept = np.minimum(np.arange(1, n_kept + 1) * every, steps)                # kept steps, counted from 1
    return steps, every, kept, np.diff(kept, prepend=0)                       # and the steps each one sums


class _Ahead:
    """Steps that :meth:`Simulator.step` computed ahead in the method's compiled loop, the inputs held,
    from step ``start_count`` (positions and velocities ``start``, the method's ``carry`` then: what a
    rewind starts from). ``rows`` hands them out in order up to ``stop``, the first that is not finite
    (or their ``count``): (index, the state's positions and velocities, then the result's fields but
    time and contacts). ``pairs``: the member contacts' impulses of the steps that have any (the method's
    ``advanced_pairs``). ``events``: {index: member-contact events} of the steps up to ``stop``, walked by
    the compiled detector in one call, and ``detector`` its state before them (what it is put back to when
    the steps are dropped before all are taken); None where the detector is stepped with each step."""

    __slots__ = ("stop", "count", "start", "start_count", "carry", "positions", "rows", "pairs", "events", "detector")

    def __init__(self, start, start_count: int, carry, pos, vel, imp, slack, stop: int, dt: float, ground=None,
                 pairs=None, events=None, detector=None):
        self.stop, self.count, self.pairs = stop, len(pos), pairs or {}
        self.events, self.detector = events, detector
        self.start, self.start_count, self.carry, self.positions = start, start_count, carry, pos
        # the state takes one copy of the positions and velocities, the results another (a user may
        # write into theirs); every other field belongs to one result only
        self.rows = zip(range(stop), pos, vel, pos.copy(), vel.copy(), imp, imp / dt, slack,
                        np.zeros_like(pos) if ground is None else ground)


_NO_ROWS = iter(())


def _walk(detector, xs: np.ndarray, step_start, dt: float, pairs: dict) -> dict:
    """``detector.walk`` through the steps of ``xs`` (K + 1, N, 3, 1) at once, each step's events carrying its
    member contacts' impulses ``pairs`` ({step: impulses}, a method's ``advanced_pairs``; none for a step it
    lacks), the detector's active contacts then reporting the last step's. (Walked apart at each step with
    impulses, a strut resting on another cost 0.5 ms a step; walked as the steps before the last, then the last,
    a live node's chunk of steps paid a second walk, 30 us.)"""
    steps = len(xs) - 1
    if steps < 1:
        return {}
    return detector.walk(xs, step_start, dt, impulses=pairs.get(steps - 1),
                         per_step={(k, 0): impulses for k, impulses in pairs.items() if k < steps})


class Simulator:
    """Steps a :class:`Scene` with a method picked by name.

    ``method``: "elastic", "inextensible", "massive" (cables with mass, physics.md §4b) or "auto" (then
    ``method_reason`` says why).
    ``dt``: the fixed step, s.
    ``contacts``: member kinds to check for contact (see ``scene.CONTACT_KINDS``), overriding the
    scene's ``contact: kinds`` (``self.scene`` is then the scene with that override); ``()`` switches
    detection off. ``contact_kinds`` is what is in use.
    ``solver``: the QP backend of the inextensible method (``methods.qp.SOLVERS``; default: chosen by
    size, ``methods.qp.choose_solver``); ``method_settings`` reports the one in use and why.
    ``order``: 2 (default) or 4, the elastic and massive methods' order (docs/methods.md: which for which error);
    ``locate_switches``: the elastic method splits a step at each slack/taut switch (default: at order 4
    only; ``method_settings`` says which); the massive method locates its snaps and releases (default: on).
    ``reel_speed``: the inextensible method's motor top speed, m/s (default 1 m/s; ``math.inf``: none):
    a faster rest-length command is followed at that speed (``applied_rest_lengths``).
    ``reel_force``: the inextensible method's motor pull limit, N (default 2 kN; ``math.inf``: none): a motor
    that would pull harder stalls at that force, behind its command (``motor_stalls`` counts those steps).
    ``backend``: where the elastic method's step runs: "numba" (default: the compiled kernels) or "jax" (the
    JAX backend, ``methods/jax/``, a batch of one; needs the ``jax`` extra) in ``dtype`` "float64" (default)
    or "float32".
    """

    def __init__(self, scene: Scene, method: str = "auto", dt: float = 1e-3, *, contacts=None,
                 solver: str | None = None, order: int | None = None, locate_switches: bool | None = None,
                 reel_speed: float | None = None, reel_force: float | None = None, backend: str = "numba",
                 dtype: str | None = None):
        if not isinstance(scene, Scene):
            raise ValueError(f"scene must be a Scene (see load_scene), got {type(scene).__name__}")
        if contacts is not None:
            # the scene as run: a log embedding it (and a replay of that log) checks the same pairs
            scene = replace(scene, contact_kinds=contact_kinds(contacts, "contacts"))
            if scene.contact_response.response and not scene.contact_kinds:
                raise ValueError("contacts: the scene's contact response (contact: response: true) needs member "
                                 "kinds to check (without them members would pass through each other)")
        self.scene = scene
        self.dt = time_step(dt)
        self.system = System(scene)
        self._method, self.method_reason = make_method(self.system, method, self.dt, backend=backend, dtype=dtype,
                                                       solver=solver, order=order, locate_switches=locate_switches,
                                                       reel_speed=reel_speed, reel_force=reel_force)
        # None when nothing can be in contact: then detection costs nothing at all
        # with a contact response, members rest in contact at a gap of ~0: a contact ends beyond TOUCH_TOL
        self._contacts = make_detector(self.system, scene.contact_kinds,
                                       TOUCH_TOL if scene.contact_response.response else 0.0)
        self._ground = None if scene.ground is None else GroundDetector(self.system)
        self._cable_index = {name: i for i, name in enumerate(scene.cable_names)}
        self._node_index = {name: i for i, name in enumerate(scene.node_names)}
        self._ahead: _Ahead | None = None
        self._rows = _NO_ROWS     # the steps computed ahead still to hand out
        self._ahead_size = 1
        self._max_ahead = AHEAD
        self._inputs_since = 0    # the step count when the inputs last changed
        self._ground_busy = None  # (k,) bool: the steps ahead at which a ground contact begins or ends
        _, length, _ = self.system.geometry(scene.positions)
        self._shortest = float(length[length > 0].min(initial=math.inf))   # m, what absurd_speed compares with
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the scene's initial state (time 0, initial rest lengths, no external force)."""
        self._settle()
        s = self.scene
        self._state = State(s.positions, s.velocities, s.cable_rest_lengths, np.zeros((len(s.nodes), 3)))
        self._method.prepare(self._state)
        self._inputs_changed()
        self._speeds_unchecked = True   # the scene's velocities: checked at the first step (absurd_speed)
        if self._contacts is not None:
            self._contacts.reset(self._state.positions)
        if self._ground is not None:
            self._ground.reset(self._state.positions)

    @property
    def method(self) -> str:
        return self._method.name

    @property
    def method_settings(self) -> dict:
        """The method's settings worth logging."""
        return self._method.describe()

    @property
    def motor_stalls(self) -> int:
        """Motor steps at the force limit since the simulator was made (the inextensible method's ``reel_force``:
        a motor that would pull harder pulls at that force, behind its command); 0 in the other methods."""
        return getattr(self._method, "stalls", 0)

    @property
    def time(self) -> float:
        """Simulation time, s (``step_count * dt``, so it does not accumulate round-off)."""
        return self._state.step_count * self.dt

    @property
    def step_count(self) -> int:
        return self._state.step_count

    @property
    def steps_ahead(self) -> int:
        """How many steps computed ahead wait for :meth:`step` to hand them out (see :meth:`look_ahead`)."""
        a = self._ahead
        return 0 if a is None else max(0, a.stop - (self._state.step_count - a.start_count))

    @property
    def positions(self) -> np.ndarray:
        return self._state.positions.copy()

    @property
    def velocities(self) -> np.ndarray:
        return self._state.velocities.copy()

    @property
    def rest_lengths(self) -> np.ndarray:
        return self._state.rest_lengths.copy()

    @property
    def applied_rest_lengths(self) -> np.ndarray:
        """The rest lengths in effect (n_cables,) m: ``rest_lengths`` once the motors have reached them
        (the inextensible method follows a command at ``reel_speed``)."""
        self._settle()
        return self._method.applied_rest_lengths(self._state)

    @property
    def external_forces(self) -> np.ndarray:
        return self._state.external_forces.copy()

    # ------------------------------------------------------------------ inputs
    def _by_name_or_array(self, values, argument: str, index: Mapping[str, int], width: int | None,
                          current: np.ndarray) -> np.ndarray:
        """A full new array from a partial {name: value} mapping or a complete array; checks shape,
        names and finiteness. ``width`` is None for scalars per entry, 3 for vectors."""
        if not isinstance(values, Mapping):
            return float_array(values, argument, current.shape)   # a new array
        out = current.copy()
        for name, value in values.items():
            if not isinstance(name, str) or name not in index:
                raise ValueError(f"{argument}: unknown name {describe(name)} (known: {', '.join(index)})")
            out[index[name]] = float_array(value, f"{argument}[{name!r}]", () if width is None else (width,))
        return out

    def set_rest_lengths(self, values) -> None:
        """New cable rest lengths, m: ``{cable name: length}`` (partial) or an array in cable order. The very
        lengths in effect change nothing (a controller that sends its command every step keeps the steps
        computed ahead, as a command schedule's unchanged step does in ``run``)."""
        current = self._state.rest_lengths
        if type(values) is np.ndarray and values.dtype == current.dtype and values.shape == current.shape:
            # a controller's array each step: the lengths in effect are valid already, new ones are checked
            # here only as far as accepting them (every length finite and > 0); anything else takes the full
            # checks below, which name what is wrong (they cost 7 us a call, more than a held step)
            if values.tobytes() == current.tobytes():
                return
            if np.minimum.reduce(values) > 0.0 and np.maximum.reduce(values) < math.inf:   # NaN fails both
                self._settle()
                self._state.rest_lengths = values.copy()
                self._inputs_changed()
                return
        new = self._by_name_or_array(values, "rest_lengths", self._cable_index, None, current)
        bad = np.flatnonzero(new <= 0)
        if bad.size:
            name = self.scene.cable_names[bad[0]]
            raise ValueError(f"rest_lengths[{name!r}]: must be > 0, got {float(new[bad[0]])!r}")
        if np.array_equal(new, self._state.rest_lengths):
            return
        self._settle()
        self._state.rest_lengths = new
        self._inputs_changed()

    def set_external_forces(self, values) -> None:
        """External node forces, N: ``{node name: [fx, fy, fz]}`` (partial) or an (N, 3) array.
        Held until replaced; a force on a fixed node has no effect. The very forces in effect change nothing."""
        new = self._by_name_or_array(values, "external_forces", self._node_index, 3, self._state.external_forces)
        if np.array_equal(new, self._state.external_forces):
            return
        self._settle()
        self._state.external_forces = new
        self._inputs_changed()

    def _settle(self) -> None:
        """Before an input changes or the method is asked about the present: a method whose loop carries
        what a command does not rebuild from the state (``carry_outlives_inputs``) is put back at the
        state, the steps computed ahead dropped (the others are dropped by :meth:`_inputs_changed`), so
        that what follows an input does not depend on how far ahead the steps were computed
        (:meth:`look_ahead`)."""
        if self._ahead is not None and self._method.carry_outlives_inputs:
            self._rewind()

    def _inputs_changed(self) -> None:
        """The state changed from outside: the method recomputes what it cached, and the steps computed
        ahead with the old inputs are dropped. The next look ahead computes as many steps as the old inputs
        held (1 to :attr:`max_steps_ahead`): a controller that commands every ``n`` steps gets its ``n`` steps
        in one compiled call, none wasted (from 1 doubling, a command every 10 steps cost four calls and five
        steps dropped)."""
        self._method.invalidate()
        self._detector_at_state()
        self._ahead, self._rows = None, _NO_ROWS
        count = self._state.step_count
        self._ahead_size = max(1, count - self._inputs_since)   # (capped where it is used)
        self._inputs_since = count

    # ------------------------------------------------------------------ stepping
    def step(self) -> StepResult:
        """Advance one step of ``dt``. A :class:`~tensegrity_sim.methods.StepError` (a QP without a solution,
        a non-finite result) leaves the state as it was.

        A method with a compiled loop computes steps ahead in it, the inputs held (as many as the last
        inputs held, then twice as many each time up to :attr:`max_steps_ahead`, while no input changes):
        one compiled call for many steps, each handed out here as the very result of stepping it alone
        (rule 10 of ``methods/base.py``). A new input drops them; ``run`` rewinds the loop to the state."""
        if self._speeds_unchecked:
            self._check_speeds()
        row = next(self._rows, None)
        if row is None:
            if self._ahead is None and self._ahead_size == 1 and self._ground is not None and self._contacts is None:
                # the inputs changed at the last step too (a controller commanding every step): this step alone,
                # without the bookkeeping of steps ahead for a single one (the same step: rule 10 of
                # methods/base.py), and the next look ahead twice as far, as after a look ahead of one step
                self._ahead_size = 2
                return self._step_once()
            if not self._look_ahead():
                return self._step_once()
            row = next(self._rows)
        i, x, v, result_x, result_v, impulses, tensions, slack, ground = row
        st, a = self._state, self._ahead
        if a.events is not None:
            contacts = a.events.get(i, ())
        else:
            contacts = () if self._contacts is None else self._contacts.step(st.positions, x, st.step_count * self.dt,
                                                                              self.dt, a.pairs.get(i))
        if self._ground is not None:
            if self._ground_busy[i]:
                landed = self._ground.step(st.positions, x, st.velocities, st.step_count * self.dt, self.dt, ground)
                if landed:
                    contacts = tuple(sorted(contacts + landed, key=lambda e: e.time))
            else:   # no contact begins or ends: the detector only keeps the impulses (GroundDetector.changes)
                self._ground.impulses = ground
        st.positions, st.velocities = x, v
        st.step_count += 1
        return step_result(st.step_count * self.dt, result_x, result_v, impulses, tensions, slack, contacts, ground)

    def look_ahead(self) -> bool:
        """Compute now the steps that the next :meth:`step` would compute ahead, if none are left to hand out:
        a caller with time to spare between two steps (a live node's idle time) takes that work out of the
        step. The same steps either way (a new input drops them as it drops any). Whether steps computed ahead
        are waiting now; nothing is computed for a method that steps one at a time, before the first step
        (which checks the speeds first), or where the steps ahead stopped at one that is not finite (the next
        step raises there)."""
        a = self._ahead
        if self.steps_ahead:
            return True
        if self._speeds_unchecked or (a is not None and a.stop < a.count):
            return False
        return self._look_ahead()

    def _check_speeds(self) -> None:
        """Refuse (:class:`SpeedError`) a start from speeds no step can resolve: the scene's, once."""
        reason = absurd_speed(self.scene, self._state.velocities, self.dt, self._shortest)
        if reason is not None:
            raise SpeedError(f"the step from t = {self.time:.6f} s is refused: {reason}")
        self._speeds_unchecked = False

    def _look_ahead(self) -> bool:
        """Compute the next steps in the method's compiled loop; False where :meth:`step` takes one at a
        time: no loop, a ground (its detector needs each step's contact impulses), or the step after the
        last handed out is not finite (the loop is then rewound to it, and the one-step path raises at
        that very step)."""
        a = self._ahead
        if a is not None and a.stop < a.count:
            self._rewind()
            return False
        method = self._method
        if not method.has_loop() or (self._ground is not None and not method.has_ground_loop()):
            return False
        if a is not None:   # the last steps ahead were all taken, the inputs held: look further
            self._ahead_size = min(2 * self._ahead_size, self._max_ahead)
        k, st = min(self._ahead_size, self._max_ahead), self._state
        n, nc = st.positions.shape[0], st.rest_lengths.shape[0]
        pos, vel = np.empty((k, n, 3)), np.empty((k, n, 3))
        imp, slack = np.empty((k, nc)), np.empty((k, nc), dtype=bool)
        carry = method.carry()
        ground = None
        if self._ground is None:
            method.advance(st, k, 1, pos, vel, imp, slack)
        else:
            ground = np.empty((k, n, 3))
            method.advance(st, k, 1, pos, vel, imp, slack, ground)
            self._ground_busy = self._ground.changes(pos, ground)
        # finite_step's test of each step: the same sums (of a row, in the same order)
        add = np.add.reduce
        finite = np.isfinite(add(pos.reshape(k, -1), 1) + add(vel.reshape(k, -1), 1) + add(imp, 1))
        stop = k if finite.all() else int(np.argmin(finite))
        events = saved = None
        detector = self._contacts
        if isinstance(detector, CompiledDetector) and stop:   # the steps' events in one walk
            # (one step is handed out at once, never dropped: nothing to put the detector back to)
            saved = detector.snapshot() if stop > 1 else None
            events = self._walk_ahead(st.positions, pos[:stop], st.step_count, method.advanced_pairs)
        self._ahead = a = _Ahead((st.positions, st.velocities), st.step_count, carry, pos, vel, imp, slack, stop,
                                 self.dt, ground, method.advanced_pairs, events, saved)
        self._rows = a.rows
        return self._look_ahead() if stop == 0 else True

    def _walk_ahead(self, start: np.ndarray, positions: np.ndarray, count: int, pairs: dict) -> dict:
        """The compiled detector walked from ``start`` (N, 3) m through steps ``count``, ``count + 1``, ...
        ending at ``positions`` (k, N, 3), with the member contacts' impulses ``pairs`` ({index: impulses}):
        {index: events} of the steps that have any."""
        xs = np.empty((len(positions) + 1,) + start.shape)
        xs[0], xs[1:] = start, positions
        found = _walk(self._contacts, xs[..., None], lambda j: (count + j) * self.dt, self.dt, pairs)
        return {step: events for (step, _), events in found.items()}

    def _detector_at_state(self) -> bool:
        """Put the compiled detector at the state if it walked the steps computed ahead further: its state
        before them, walked again over those handed out (the same arithmetic, the same state; their events
        were handed out already). Whether it did (not after a reset: a new state, the detector starts over)."""
        a = self._ahead
        taken = 0 if a is None else self._state.step_count - a.start_count
        if a is None or a.detector is None or not 0 <= taken < a.stop:
            return False
        self._contacts.restore(a.detector)
        if taken:
            self._walk_ahead(a.start[0], a.positions[:taken], a.start_count,
                             {i: impulses for i, impulses in a.pairs.items() if i < taken})
        return True

    def _rewind(self) -> None:
        """Drop the steps computed ahead and not handed out, putting the method's loop back at the state:
        its carry from before them, advanced again over those handed out (the same arithmetic, so the
        same carry), and the detector at the state (:meth:`_detector_at_state`)."""
        self._detector_at_state()
        a, self._ahead, self._rows = self._ahead, None, _NO_ROWS
        st = self._state
        taken = 0 if a is None else st.step_count - a.start_count
        if a is None or taken == a.count:
            return
        method = self._method
        method.restore(a.carry)
        if taken:
            start = State(a.start[0], a.start[1], st.rest_lengths, st.external_forces, a.start_count)
            n, nc = st.positions.shape[0], st.rest_lengths.shape[0]
            method.advance(start, taken, taken, np.empty((1, n, 3)), np.empty((1, n, 3)), np.empty((1, nc)),
                           np.empty((1, nc), dtype=bool))

    def _step_once(self) -> StepResult:
        """One step through the method's ``step``: checked, detected and committed."""
        out = self._method.step(self._state)
        if not finite_step(out):
            # the plain reference's take of the step: numpy's warnings say what overflowed, and the report
            # names what it made non-finite, whichever implementation stepped
            out = self._method.retrace(self._state) or out
            self._method.invalidate()  # drop what the method cached from the failed step
            raise NonFiniteError(non_finite_report(self.scene, self._state, self.dt, out.positions,
                                                   out.velocities, out.impulses))
        st = self._state
        contacts = () if self._contacts is None else self._contacts.step(st.positions, out.positions,
                                                                          self.time, self.dt, out.pair_impulses)
        ground = out.contact_impulses
        if self._ground is not None:
            if ground is not None and not self._ground.changes(out.positions[None], ground[None])[0]:
                self._ground.impulses = ground   # no contact begins or ends (as in a step computed ahead)
            else:
                landed = self._ground.step(st.positions, out.positions, st.velocities, self.time, self.dt, ground)
                if landed:
                    contacts = tuple(sorted(contacts + landed, key=lambda e: e.time))
        st.positions, st.velocities = out.positions, out.velocities
        st.step_count += 1
        return step_result(self.time, out.positions.copy(), out.velocities.copy(), out.impulses,
                           out.impulses / self.dt, self.slack() if out.slack is None else out.slack, contacts,
                           np.zeros_like(out.positions) if ground is None else ground)

    @property
    def max_steps_ahead(self) -> int:
        """The most steps :meth:`step` computes ahead in one call of the method's compiled loop (default
        :data:`AHEAD`): fewer spread the work more evenly over the steps (a live node's ticks), more
        amortise the call over more steps."""
        return self._max_ahead

    @max_steps_ahead.setter
    def max_steps_ahead(self, value: int) -> None:
        try:
            count = whole(value, "max_steps_ahead")
        except ValueError:
            count = 0
        if not 1 <= count <= MAX_AHEAD:
            raise ValueError(f"max_steps_ahead must be a whole number from 1 to {MAX_AHEAD}, got {describe(value)}")
        self._max_ahead = count

    @property
    def contact_kinds(self) -> tuple[str, ...]:
        """The member kinds contact detection checks (the scene's, or the ``contacts`` override)."""
        return self.scene.contact_kinds

    def active_contacts(self) -> tuple[ActiveContact, ...]:
        """Every contact going on now (begun, not yet ended), with its current gap (negative while the
        members overlap) and closest points: the events only mark begins and ends. Ground contacts
        (``(node name, "ground")``) carry the normal and friction impulses of the last step."""
        detector, members = self._contacts, ()
        if detector is not None:
            # a detector that walked ahead of the state answers at the state, then goes on from where it was
            ahead = detector.snapshot() if self._ahead is not None and self._ahead.detector is not None else None
            back = ahead is not None and self._detector_at_state()
            members = detector.active(self._state.positions)
            if back:
                detector.restore(ahead)
        ground = () if self._ground is None else self._ground.active(self._state.positions)
        return members + ground

    def slack(self) -> np.ndarray:
        """(n_cables,) bool: the cables slack now, in the method's model."""
        self._settle()
        return self._method.slack(self._state.positions, self._state.rest_lengths)

    def run(self, duration: float | None = None, *, steps: int | None = None, every: int = 1,
            callback=None, commands: CommandSchedule | None = None) -> Trajectory:
        """Run ``steps`` steps, or ``round(duration / dt)``; returns them stacked, the inputs held, or set by
        ``commands``.

        ``every``: keep steps ``every``, ``2 every``, ... and the last one only (memory); a kept step's
        impulses are summed over the steps since the previous kept one and its tensions are their mean
        over that time, so no impulse is lost. Contact events are all kept.
        ``callback(k, result)`` is called after each step ``k`` (a progress bar, a command schedule).
        Without a callback a method with a compiled loop runs the steps in it.
        ``commands``: a :class:`~tensegrity_sim.commands.CommandSchedule` applied before each step at its
        start time, as ``tensegrity-sim run --commands`` does (a cable it does not name keeps its rest length
        at the run's start; an input is set only where it changed). A method that evaluates a schedule in
        its compiled loop (``runs_commands``: the elastic and inextensible methods on a ground) runs it there,
        each step the very arithmetic of setting its inputs and stepping it; the others step one at a time.
        """
        if callback is not None and not callable(callback):
            raise ValueError(f"callback must be callable, got {describe(callback)}")
        n, nc = len(self.scene.nodes), len(self.scene.cables)
        if commands is not None:
            if not isinstance(commands, CommandSchedule):
                raise ValueError(f"commands must be a CommandSchedule (see load_commands), got {describe(commands)}")
            commands.fits(n)
            held = (self._state.rest_lengths.copy(), self._state.external_forces.copy())
        steps, every, kept, span = run_plan(duration, steps, every, self.dt, 8 + 48 * n + 17 * nc)
        if self._speeds_unchecked and steps:
            self._check_speeds()
        time = (self._state.step_count + kept) * self.dt
        pos = np.empty((len(kept), n, 3))
        vel = np.empty((len(kept), n, 3))
        imp = np.zeros((len(kept), nc))
        slack = np.empty((len(kept), nc), dtype=bool)
        ground = np.zeros((len(kept), n, 3))   # the ground's impulses, summed like the cables'
        contacts = []
        done = 0
        method = self._method
        if (callback is None and method.has_loop() and (self._ground is None or method.has_ground_loop())
                and (commands is None or (self._ground is not None and method.runs_commands()))):
            self._rewind()
            done = self._run_compiled(steps, every, pos, vel, imp, slack, contacts, ground,
                                      None if commands is None else (commands,) + held)
        for k in range(done, steps):   # step by step (all of them, or from a compiled part that failed)
            if commands is not None:
                commands.apply(self, self.time, *held)
            r = self.step()
            j = k // every
            imp[j] += r.impulses
            ground[j] += r.contact_impulses
            if k + 1 == kept[j]:
                pos[j], vel[j], slack[j] = r.positions, r.velocities, r.slack
            contacts.extend(r.contacts)
            if callback is not None:
                callback(k, r)
        return Trajectory(time, pos, vel, imp, imp / (span[:, None] * self.dt), slack, contacts, ground)

    def _run_compiled(self, steps, every, pos, vel, imp, slack, contacts, ground, commands=None) -> int:
        """:meth:`run` in the method's compiled loop: straight into the trajectory's arrays, or, with
        contact detection, in chunks of every step that the detector then walks through. Returns the
        steps done: a part whose result is not finite is not committed (the method's carry is put back,
        its cache dropped) and is left to :meth:`step`, which raises :class:`NonFiniteError` at the very step, as a run
        step by step does. ``commands``: (schedule, base rest lengths, forces at the run's start), evaluated
        chunk by chunk into each step's inputs (a method that ``runs_commands``, a ground)."""
        st, method = self._state, self._method
        add = np.add.reduce
        detector = self._contacts
        if self._ground is None and (detector is None
                                     or (method.loop_detects() and isinstance(detector, CompiledDetector))):
            # straight into the trajectory's arrays
            carry = method.carry()
            saved = None if detector is None else detector.snapshot()
            if detector is not None:
                method.detection = detector
            try:
                x, v = method.advance(st, steps, every, pos, vel, imp, slack)
            finally:
                if detector is not None:
                    method.detection = None
            if not math.isfinite(add(x, None) + add(v, None) + add(imp, None)):
                method.restore(carry)
                method.invalidate()
                if detector is not None:
                    detector.restore(saved)
                imp[...] = 0.0
                return 0
            if detector is not None:
                count = st.step_count
                found = detector.record(*method.found, lambda k: (count + k) * self.dt, self.dt)
                contacts.extend(e for key in sorted(found) for e in found[key])
            st.positions, st.velocities = x, v
            st.step_count += steps
            return steps
        chunk = min(steps, _CHUNK)
        n, nc = pos.shape[1], imp.shape[1]
        xs = np.empty((chunk + 1, n, 3))   # the positions before the chunk's steps, then after each
        c_pos, c_vel = xs[1:], np.empty((chunk, n, 3))
        c_imp, c_slack = np.empty((chunk, nc)), np.empty((chunk, nc), dtype=bool)
        c_ground = None if self._ground is None else np.empty((chunk, n, 3))
        done = 0
        while done < steps:
            m = min(chunk, steps - done)
            carry = method.carry()
            inputs = None
            if self._ground is None:
                x, v = method.advance(st, m, 1, c_pos[:m], c_vel[:m], c_imp[:m], c_slack[:m])
            else:
                if commands is not None:
                    inputs = commands[0].inputs_at((st.step_count + np.arange(m)) * self.dt, *commands[1:])
                x, v = method.advance(st, m, 1, c_pos[:m], c_vel[:m], c_imp[:m], c_slack[:m], c_ground[:m],
                                      **({} if inputs is None else {"inputs": inputs}))
            if not math.isfinite(add(x, None) + add(v, None) + add(c_imp[:m], None)):
                method.restore(carry)
                method.invalidate()
                return done
            if detector is not None:
                xs[0] = st.positions
                count = st.step_count
                found = _walk(detector, xs[:m + 1, ..., None], lambda k: (count + k) * self.dt, self.dt,
                              method.advanced_pairs)
                contacts.extend(e for key in sorted(found) for e in found[key])
            g = done + np.arange(m)              # the chunk's steps in the run, from 0
            j = g // every
            if self._ground is not None:
                landed = self._ground.walk(st.positions, st.velocities, c_pos[:m], c_vel[:m], c_ground[:m],
                                           st.step_count * self.dt, self.dt)
                if landed:
                    contacts.extend(landed)
                    contacts.sort(key=lambda e: e.time)
                if every == 1:   # each step its own row: add.at's sums are the steps themselves
                    ground[done:done + m] += c_ground[:m]
                else:
                    np.add.at(ground, j, c_ground[:m])
            if every == 1:
                imp[done:done + m] += c_imp[:m]
            else:
                np.add.at(imp, j, c_imp[:m])
            last = (g + 1) % every == 0
            last[-1] |= done + m == steps
            pos[j[last]], vel[j[last]], slack[j[last]] = c_pos[:m][last], c_vel[:m][last], c_slack[:m][last]
            st.positions, st.velocities = x, v
            if inputs is not None:   # the last step's inputs, those the method's carry was computed with
                st.rest_lengths, st.external_forces = inputs[0][m - 1].copy(), inputs[1][m - 1].copy()
            st.step_count += m
            done += m
        return done

    # ------------------------------------------------------------------ invariants
    def energy(self) -> dict[str, float]:
        """Energies, J: kinetic (the nodes' and, in the massive method, the moving cable plates'), strain (what
        the method's model stores), gravity (``-sum m g.x``), total."""
        st, sys = self._state, self.system
        kinetic = sys.mass.kinetic_energy(st.velocities)
        kinetic += self._method.plate_energy(st.positions, st.velocities, st.rest_lengths)   # cables' plates
        strain = self._method.strain_energy(st.positions, st.rest_lengths)
        gravity = -float(np.sum(sys.gravity_force * st.positions))
        return {"kinetic": kinetic, "strain": strain, "gravity": gravity,
                "total": kinetic + strain + gravity}

    @property
    def energy_lost(self) -> float:
        """J: the energy the method's model removed at its events since the reset, apart from any drift (the
        massive method's cable plates at snaps and releases, physics.md §4b; 0 in the other methods)."""
        self._settle()   # the steps computed ahead put back: the losses up to the present
        return self._method.losses

    def momentum(self) -> tuple[np.ndarray, np.ndarray]:
        """Total linear momentum (3,) kg*m/s and angular momentum about the origin (3,) kg*m^2/s,
        of the free nodes (``sum M v`` and ``sum x cross M v``: a rigid strut's its whole mass's)."""
        st = self._state
        return self.system.mass.momentum(st.positions, st.velocities)
