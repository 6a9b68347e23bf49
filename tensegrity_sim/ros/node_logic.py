"""The whole behaviour of the ``tensegrity_sim`` node (contract §4, ``msg_docs/``), without rclpy.

:class:`SimNodeLogic` owns a :class:`~tensegrity_sim.Simulator` and does everything the node does:

* **inputs** arrive as message objects through :meth:`SimNodeLogic.receive`; each is validated whole
  and either applied or refused with a reason (logged), leaving the state exactly as it was;
* **stepping** follows a real-time schedule on an injected monotonic clock (:meth:`~SimNodeLogic.tick`);
* **outputs** are built as ROS 2 messages and handed to a ``transport(key, message)`` callback (rclpy's
  publishers, a DDS writer, a list in a test), or as CDR bytes to a raw transport, and as CDR bytes to
  an optional recorder (the MCAP log). Between two publications the cable impulses of every step are
  summed and every contact event is queued, so publishing slower than stepping loses nothing. The
  outputs of every publication (clock, poses, cable states and impulses) are encoded straight from the
  arrays in one compiled pass (:class:`~.publication.PublicationCdr`), the markers (:mod:`.markers`) by
  :class:`~.cdr.CdrTemplate` objects (one per marker shape), so logging costs little; message objects
  are built only for a transport that takes them, and nothing at all when no one listens;
* the **services** (reset, pause, resume, single step) are plain methods returning ``(success, message)``;
* a **failed step** (a :class:`~tensegrity_sim.StepError`: a QP of the inextensible method without a
  solution, or a result that is not finite) never escapes: the inputs that made it impossible are refused
  after the fact, or the node pauses (:meth:`SimNodeLogic.step`);
* **runtime parameter changes** (:meth:`SimNodeLogic.update`) go out, and into the log, as
  ``/parameter_events``, so a replay applies them where the run did.

Topics are named by key (``"node_poses"``...); :data:`~.interface.TOPICS` gives their names, types,
direction and QoS; the parameters are :class:`~.interface.NodeSettings`. The node is single-threaded (one executor thread calls everything), so nothing here locks.

Publication is decided by the caller of :meth:`~SimNodeLogic.step` and :meth:`~SimNodeLogic.publish`
(the real-time :meth:`~SimNodeLogic.tick`, the single-step service, the offline runner, the replay), so a
replay can publish exactly where a log did.
"""
from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, replace
from datetime import datetime, timezone
from typing import Callable

import numpy as np

from .. import __version__
from .._system_kernels import member_kinematics
from ..checks import describe
from ..methods import StepError
from ..results import ContactEvent, StepResult, step_result
from ..simulator import Simulator
from . import messages as M
from .contact_messages import decode_contacts, encode_contacts
from .interface import (FAILURE_STATUS, RUNTIME_PARAMETERS, SERVICES, TOPICS, NodeSettings, Qos, TopicSpec,
                        resolve_topic, stamp_ns)
from .markers import Markers
from .publication import PUBLISHED, PublicationCdr, PublicationTemplates

# the node's interface (.interface) and its contact messages (.contact_messages) are re-exported, for the
# code that imports them with the node logic
__all__ = ["Qos", "TopicSpec", "TOPICS", "SERVICES", "NodeSettings", "SimNodeLogic", "stamp_ns", "encode_contacts",
           "decode_contacts", "RUNTIME_PARAMETERS", "FAILURE_STATUS", "resolve_topic"]


_WAKE_AFTER_DUE = 1e-6  # s after a tick of the schedule's grid that next_tick wakes it
# The most steps the node's Simulator computes ahead in one compiled call (and never past the next publication,
# SimNodeLogic.step): a tick that computed 64 (a robot held still between commands) was among its slowest; 16 of
# the rolling icosahedron cost ~0.1 ms
NODE_STEPS_AHEAD = 16
# No tick holds the executor longer than this, wall-clock (services and subscriptions wait for a tick).
TICK_WALL_LIMIT = 0.1           # s
# s of wall-clock time between two repeats of the publication a lockstep node waits on (SimNodeLogic.tick): a
# controller that subscribed after it was sent gets it (one that has it ignores a stamp it has seen)
LOCKSTEP_REPEAT = 0.5


class TickDurations:
    """The wall-clock duration of every tick since start (or of another recurring piece of work), in a fixed
    histogram (a node runs for hours: its memory stays bounded, and a tick only adds one to a bin), for the
    percentiles of the summary.

    Bins are logarithmic, :attr:`BINS_PER_DECADE` to a decade from :attr:`LOW` to :attr:`HIGH` s (the first
    and the last take whatever falls below or above), so a percentile is known to within one bin, a relative
    1.2 %; it is reported as the bin's upper edge (never below the duration it stands for) or the longest
    tick, whichever is shorter. The longest tick is kept exactly.
    """

    LOW = 1e-6               # s
    HIGH = 100.0             # s
    BINS_PER_DECADE = 200

    def __init__(self):
        decades = round(math.log10(self.HIGH / self.LOW))
        self.upper_edges = self.LOW * 10.0 ** (np.arange(1, decades * self.BINS_PER_DECADE + 1) / self.BINS_PER_DECADE)
        self.counts = np.zeros(self.upper_edges.size, dtype=np.int64)
        self.ticks = 0
        self.longest = 0.0   # s

    def add(self, duration: float) -> None:
        """Count one tick of ``duration`` s."""
        i = int(math.log10(duration / self.LOW) * self.BINS_PER_DECADE) if duration > self.LOW else 0
        self.counts[min(i, self.counts.size - 1)] += 1
        self.ticks += 1
        self.longest = max(self.longest, duration)

    def percentile(self, q: float) -> float:
        """The duration (s) that ``q`` percent of the ``n`` ticks took at most (nearest rank: the duration of
        the ``ceil(q n / 100)``-th shortest tick), to within one bin; 0 before the first tick."""
        if self.ticks == 0:
            return 0.0
        rank = max(1, math.ceil(q / 100.0 * self.ticks))
        i = int(np.searchsorted(np.cumsum(self.counts), rank))
        return min(float(self.upper_edges[i]), self.longest)


# --------------------------------------------------------------------------- the node logic
Transport = Callable[[str, object], None]


class SimNodeLogic:
    """Everything the node does, driven by its caller (see the module docstring).

    sim: the simulator (its scene, method and dt). settings: :class:`NodeSettings`.
    transport(key, message): sends an output; None sends nothing (offline, replay tests).
    raw_transport: the transport takes the CDR bytes (``bytes``, encapsulation header first) of every
    output instead of a message object: for a transport that sends raw CDR (a DDS writer, rclpy's
    ``publish`` of bytes) and for the replay; an output is then encoded once, for it and the log alike.
    clock(): monotonic wall-clock seconds (``time.monotonic``; a fake one in tests).
    cpu_clock(): the CPU time (s) of the thread that ticks (``time.thread_time``; a fake one in tests): it tells
    the catch-up ticks that the node's own work caused from those the machine did (:meth:`tick`).
    logger: where refusals, warnings (``warning``) and the reason of a pause after a failed step (``error``)
    go (a ``logging.Logger``-like object).
    recorder: an object with ``record(records, log_time_ns)`` (``records``: the (topic name, CDR bytes) of
    the messages at that time, in order: a publication's outputs in one call) and ``restart(run_info)``
    (the MCAP log, :class:`~tensegrity_sim.ros.log.LogRecorder`), or None; it can be attached after
    construction.

    idle_outputs: the markers and contact events of a publication wait for :meth:`send_waiting` (the live
    loop's idle time, :func:`~.live.spin`) instead of going out in the tick that publishes, and so do the log
    records of the inputs that arrive meanwhile; False (the default): every output goes out at once.
    """

    def __init__(self, sim: Simulator, settings: NodeSettings, *, transport: Transport | None = None,
                 raw_transport: bool = False, clock: Callable[[], float] = time.monotonic,
                 cpu_clock: Callable[[], float] = time.thread_time, logger=None, recorder=None):
        self.sim = sim
        self.settings = settings
        self.recorder = recorder
        self.idle_outputs = False
        self._waiting: tuple | None = None   # what publish left to send_waiting: _send_rest's arguments
        # the log's records of the inputs that arrived while _waiting waits, (records, ns) each: they follow it
        self._waiting_inputs: list[tuple[list[tuple[str, bytes]], int]] = []
        self._transport = transport
        self._raw = raw_transport
        self._clock = clock
        self._cpu_clock = cpu_clock
        self._log = logger if logger is not None else logging.getLogger("tensegrity_sim")
        self.topic_names = {k: resolve_topic(s.name, settings.node_name) for k, s in TOPICS.items()}
        scene = sim.scene
        self._cable_names = list(scene.cable_names)
        self._cable_index = {n: i for i, n in enumerate(scene.cable_names)}
        self._node_index = {n: i for i, n in enumerate(scene.node_names)}
        self._inputs = {"cable_rest_lengths": self._apply_rest_lengths, "external_wrench": self._apply_wrench}
        self._markers = Markers(sim, settings.frame_id)
        n_cables = len(self._cable_names)
        self._markers.prepare(step_result(sim.time, sim.positions, sim.velocities, np.zeros(n_cables),
                                          np.zeros(n_cables), sim.slack(), (), None))
        # the bytes of every publication's outputs, in one compiled pass
        self._cdr = PublicationCdr(PublicationTemplates(settings.frame_id, len(scene.node_names), self._cable_names,
                                                        sim.system.cable_nodes, sim.system.cable_weights))
        # the cable lengths (m) and elongation rates (m/s) of a publication's message objects, worked out in place
        # (at the cables' real ends: a cable attached along a strut is measured there)
        self._cable_nodes = np.ascontiguousarray(sim.system.cable_nodes, dtype=np.int64)
        self._cable_weights = np.ascontiguousarray(sim.system.cable_weights, dtype=float)
        self._length = np.empty(len(self._cable_names))
        self._rate = np.empty(len(self._cable_names))
        # counters for diagnostics and the summary
        self.refused = {k: 0 for k in self._inputs}
        self.received = {k: 0 for k in self._inputs}
        self.overruns = 0
        self.max_lag = 0.0          # wall-clock s behind the schedule, the worst seen
        self._tick_durations = TickDurations()
        self._idle_durations = TickDurations()   # of send_waiting's sending
        self.max_steps_per_tick = 0
        self.burst_ticks = 0        # ticks that ran more steps than their nominal share (catching up)
        self.own_burst_ticks = 0    # of them, those after over a tick period of the ticking thread's CPU time
        self.late_wakeups = 0       # the loop's wake-ups over a tick period after the time it slept to (woke)
        self.idle_look_aheads = 0   # the times look_ahead computed steps ahead
        self.max_wakeup_delay = 0.0  # s, the latest of them all
        self.publications = 0
        self.failed_steps = 0
        self._steps_run = 0
        self._started = clock()
        self._overruns_reported = 0
        self.paused = False
        self.failure: str | None = None          # why a failed step paused the node (None: none did)
        self.step_error: StepError | None = None  # the last step failure
        self._clear()
        self.restart_schedule()

    # ------------------------------------------------------------------ state kept between publications
    def _clear(self) -> None:
        n_cables = len(self._cable_names)
        self._target = self.sim.rest_lengths        # commanded rest lengths (rate limiting moves towards them)
        self._applied = self._target.copy()          # rest lengths the simulator has
        self._impulse_sum = np.zeros(n_cables)       # N*s since the previous publication
        self._contact_queue: list[ContactEvent] = []  # events since the previous publication
        self._active_contacts: dict[tuple[str, str], ContactEvent] = {}  # for the markers
        self._markers.clear()
        self._last: StepResult | None = None
        # what the inputs applied since the last step changed, to undo if the step fails with them:
        # (targets, applied rest lengths, external forces) before the first of them, and their topic keys
        self._undo: tuple[np.ndarray, np.ndarray, np.ndarray, list[str]] | None = None
        self._since_publish = 0
        self._until_markers = 0                      # publications to go until the next marker array
        self.awaiting = False                        # lockstep: no step until an input answers the publication
        self._awaited: list[tuple[str, object, bytes | None]] = []   # lockstep: that publication's first outputs
        self._repeat_at = 0.0                        # lockstep: when (clock, s) to send them again

    def restart_schedule(self) -> None:
        """Restart the real-time schedule here: step ``k`` is due at ``t0 + (k - k0) dt / rtf``."""
        self._anchor_time = self._clock()
        self._anchor_step = self.sim.step_count
        self._tick_cpu = self._cpu_clock()   # the ticking thread's CPU time (s) when the last tick began

    def next_tick(self, now: float) -> float | None:
        """When (s, on :attr:`clock`) a loop runs its next tick, ``now`` the clock after the last: the first
        time after ``now`` on the schedule's grid of ticks (its start plus whole tick periods, and a
        microsecond, so that the schedule's floor sees the steps of that tick due), or ``now`` itself if a
        whole tick's share of steps is due already (the last tick, or what the loop did after it, ran past a
        tick of the grid: those steps run at once, in a tick of their own, not a period late beside the next
        share); None while paused or stepping as fast as possible (no schedule). A loop that wakes its ticks
        there, not on a cadence of its own, has a whole tick period of slack before a late wake-up owes extra
        steps."""
        s = self.settings
        if self.paused or self.awaiting or s.real_time_factor == 0.0:
            return None
        steps_per_second = s.real_time_factor / s.dt
        behind = self._anchor_step + math.floor((now - self._anchor_time) * steps_per_second) - self.sim.step_count
        if behind >= max(1.0, steps_per_second / s.step_rate):
            return now
        period = 1.0 / s.step_rate
        k = math.floor((now - self._anchor_time - _WAKE_AFTER_DUE) / period) + 1
        wake = self._anchor_time + k * period + _WAKE_AFTER_DUE
        # rounding can put the grid's time at ``now`` exactly (a tick woken on it): then the one after
        return wake if wake > now else self._anchor_time + (k + 1) * period + _WAKE_AFTER_DUE

    @property
    def clock(self) -> Callable[[], float]:
        """The monotonic clock (s) the schedule runs on."""
        return self._clock

    def warm_up(self) -> None:
        """Take a publication's worth of steps and one publication with markers on a throwaway node of the
        same scene and method (no transport, no log): what compiles on first use in a process (numba's
        kernels, the publication encoders) is done before the first tick rather than in it (measured: 110 ms
        for the first step, 28 ms for the first publication, each then owed to the schedule as a catch-up
        burst). The caller restarts the schedule (:meth:`restart_schedule`) when its ticks begin."""
        sim = self.sim
        spare = Simulator(sim.scene, method=sim.method, dt=sim.dt)
        twin = SimNodeLogic(spare, self.settings, transport=lambda key, message: None, raw_transport=self._raw,
                            clock=self._clock, logger=self._log)
        for _ in range(self.settings.publish_every):
            twin._advance()

    # ------------------------------------------------------------------ info
    def stamp_ns(self) -> int:
        """The simulation time now, ns."""
        return stamp_ns(self.sim.time)

    def channels(self) -> list[tuple[str, str, Qos]]:
        """(topic name, type, QoS) of every topic, inputs first: what a log registers."""
        return [(self.topic_names[k], s.typename, s.qos) for k, s in TOPICS.items()]

    def run_info(self) -> dict[str, str]:
        """Everything a log must embed to be re-run alone (strings, for MCAP metadata)."""
        sim = self.sim
        return {
            "format": "tensegrity_sim-log/1",
            "package_version": __version__,
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "scene_name": sim.scene.name,
            "scene_yaml": sim.scene.to_yaml(),
            "method": sim.method,
            "method_reason": sim.method_reason,
            "dt": repr(sim.dt),
            "method_settings": json.dumps(sim.method_settings, sort_keys=True, default=_jsonable),
            "node_settings": json.dumps(asdict(self.settings), sort_keys=True),
            "topics": json.dumps({k: self.topic_names[k] for k in TOPICS}, sort_keys=True),
        }

    # ------------------------------------------------------------------ inputs
    def receive(self, key: str, message, *, decoded: bool = False) -> str | None:
        """Take one message of input topic ``key``; returns None if it was applied, else the reason it was
        refused (also logged). A refused message changes nothing. Every message is recorded, refused or
        not, at the simulation time it arrived (it acts from the next step on), except one that is not of
        the topic's type at all (it has no CDR form); the handlers see the message as the log holds it
        (decoded from its CDR bytes), so a field of a wrong Python type is refused like any bad value. An
        applied message is still refused after the fact if the next step fails with it (:meth:`step`).
        ``decoded``: the caller decoded ``message`` from CDR itself (a transport's sample), so it is already
        what decoding the logged bytes gives, and is not decoded again (~15-45 us of a command)."""
        self.received[key] += 1
        typename = TOPICS[key].typename
        try:
            data = M.serialize(message, typename)
        except Exception as exc:  # noqa: BLE001 - what a serialiser raises for a foreign object varies
            return self._refuse(key, f"not a {typename} message ({type(exc).__name__}: {describe(str(exc))}): "
                                     f"{describe(message)}")
        if self.recorder is not None:
            # the log keeps the order of events: behind a publication's waiting outputs, the input waits too
            # (it acts on the simulation now; only its record waits, so the input costs no marker drawing)
            records = [(self.topic_names[key], data)]
            if self._waiting is not None:
                self._waiting_inputs.append((records, self.stamp_ns()))
            else:
                self.recorder.record(records, self.stamp_ns())
        if not decoded:
            message = M.deserialize(data, typename)
        undo = self._undo or (self._target, self._applied, self.sim.external_forces, [])
        try:
            self._inputs[key](message)
        except ValueError as exc:
            return self._refuse(key, str(exc))
        undo[3].append(key)
        self._undo = undo
        if self.awaiting:   # lockstep: the controller answered; the wait is not owed to the schedule
            self.awaiting = False
            self.restart_schedule()
        return None

    def _refuse(self, key: str, reason: str) -> str:
        self.refused[key] += 1
        self._log.warning(f"{self.topic_names[key]}: refused: {reason}")
        return reason

    def _apply_rest_lengths(self, msg) -> None:
        names = list(msg.name)
        position = np.asarray(msg.position, dtype=float)
        if not names:
            raise ValueError("name is empty: no cable to set")
        if position.shape != (len(names),):
            raise ValueError(f"position has {position.size} values for {len(names)} names")
        for name in ("velocity", "effort"):
            n = len(getattr(msg, name))
            if n not in (0, len(names)):
                raise ValueError(f"{name} has {n} values for {len(names)} names (must be empty or match)")
        unknown = [n for n in names if n not in self._cable_index]
        if unknown:
            raise ValueError(f"unknown cable {unknown[0]!r} (cables: {', '.join(self._cable_names)})")
        if len(set(names)) != len(names):
            twice = next(n for n in names if names.count(n) > 1)
            raise ValueError(f"cable {twice!r} is named more than once")
        bad = np.flatnonzero(~np.isfinite(position) | (position <= 0))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"position[{i}] ({names[i]!r}): a rest length must be finite and > 0 m, "
                             f"got {float(position[i])!r}")
        target = self._target.copy()
        target[[self._cable_index[n] for n in names]] = position
        if self.settings.max_rest_length_rate == 0.0:
            self.sim.set_rest_lengths(target)
            self._applied = target.copy()
        self._target = target

    def _apply_wrench(self, msg) -> None:
        node = msg.header.frame_id
        if node not in self._node_index:
            raise ValueError(f"header.frame_id {node!r} is not a node of the scene "
                             f"(nodes: {', '.join(self._node_index)})")
        f, tq = msg.wrench.force, msg.wrench.torque
        force = [f.x, f.y, f.z]
        torque = [tq.x, tq.y, tq.z]
        if not all(math.isfinite(v) for v in force):
            raise ValueError(f"wrench.force must be finite, got {force}")
        if any(v != 0.0 for v in torque):  # NaN != 0 too
            raise ValueError(f"wrench.torque must be zero (a node is a point and takes no torque), got {torque}")
        self.sim.set_external_forces({node: force})

    # ------------------------------------------------------------------ stepping
    def step(self) -> StepResult | None:
        """One simulation step: move rate-limited rest lengths towards their targets, step, and add the
        step's impulses and contact events to what the next publication reports.

        Returns None if the step failed (a :class:`~tensegrity_sim.StepError`): a QP error, the inextensible
        method finding the commanded motion impossible (shortening a cable of a locked structure), or a
        result that is not finite (an absurd force); the simulator is then as before the step. What made it
        fail is given up, the first of these that applies:

        1. the input messages applied since the last step: each is refused after the fact (logged and
           counted as refused), and the rest lengths, their targets and the forces are what they were
           before them;
        2. this step's rate-limited move: the rest-length targets are refused after the fact, and the
           rest lengths stay where they are (a motor that stalls);
        3. nothing: the node pauses, :attr:`failure` says why, until it is resumed or reset.

        Every failure is reported on ``/diagnostics`` at once, so the log has it (a replay attempts a step
        there and must fail the same way). After 1 and 2 the next step tries again without what was given up.
        """
        before_move = None
        rate = self.settings.max_rest_length_rate
        if rate > 0.0 and not np.array_equal(self._applied, self._target):
            max_change = rate * self.sim.dt
            diff = self._target - self._applied
            before_move = self._applied
            # land exactly on the target (applied + diff may round off it)
            self._applied = np.where(np.abs(diff) <= max_change, self._target,
                                     self._applied + np.copysign(max_change, diff))
            self.sim.set_rest_lengths(self._applied)
        self._limit_ahead()
        try:
            r = self.sim.step()
        except StepError as exc:
            self._step_failed(exc, before_move)
            return None
        self._undo = None
        self._impulse_sum += r.impulses
        if r.contacts:
            self._contact_queue.extend(r.contacts)
        self._last = r
        self._since_publish += 1
        self._steps_run += 1
        return r

    def _limit_ahead(self) -> None:
        """The steps computed ahead end at the next publication (at most NODE_STEPS_AHEAD of them): the tick
        that publishes hands out a step computed before, it does not compute the next ones too. With the live
        loop's idle time (:attr:`idle_outputs`), the step after an input that dropped them is computed alone,
        and the loop computes the rest in its idle time (:meth:`look_ahead`), not the tick that took the input."""
        limit = min(NODE_STEPS_AHEAD, max(1, self.settings.publish_every - self._since_publish))
        self.sim.max_steps_ahead = 1 if self.idle_outputs and self._undo is not None else limit

    def look_ahead(self) -> bool:
        """Compute the simulator's next steps ahead now, up to the next publication, if none are left
        (:meth:`.Simulator.look_ahead`): what the live loop does in its idle time, so that its ticks hand out
        steps computed before rather than computing them (a controller's command that moves a rest length
        drops them: the tick that takes it computes its own step, and the loop the rest). Nothing while
        paused or while a rate-limited rest length moves (every step changes it). A step that would fail here
        is left to the step that meets it (:meth:`step`), which fails there as without this. Nothing while
        waiting for a controller's answer in lockstep either (it would drop them). Whether steps computed ahead
        wait now."""
        if self.paused or self.awaiting:
            return False
        if self.sim.steps_ahead:
            return True
        if not np.array_equal(self._applied, self._target):
            return False
        self._limit_ahead()
        try:
            ready = self.sim.look_ahead()
        except StepError:
            return False
        self.idle_look_aheads += ready
        return ready

    def _step_failed(self, error: StepError, before_move: np.ndarray | None) -> None:
        """Give up what made the step from now fail (:meth:`step`); log and report it. ``before_move``: the
        rest lengths before the step's rate-limited move (None: no move)."""
        self.failed_steps += 1
        self.step_error = error
        what = f"the step from t = {self.sim.time:.6f} s failed: {error}"
        if self._undo is not None:
            self._target, applied, forces, keys = self._undo
            self.sim.set_external_forces(forces)
            done = "the input message(s) since the previous step are refused after the fact"
        elif before_move is not None:
            self._target = applied = before_move
            keys = ["cable_rest_lengths"]
            done = "the rest-length targets are refused after the fact; the rest lengths stay where they are"
        else:
            self.paused = True
            self.failure = f"{what}; paused: change the inputs and resume, or reset"
            self._log.error(self.failure)
            self._report_failure(2, self.failure)
            return
        self._undo = None
        self._applied = applied
        self.sim.set_rest_lengths(applied)
        for key in keys:
            self.refused[key] += 1
            self._log.warning(f"{self.topic_names[key]}: refused after the fact: {what}")
        self._report_failure(1, f"{what}; {done}")

    def _report_failure(self, level: int, text: str) -> None:
        """``/diagnostics`` of one failed step (WARN: stepping goes on; ERROR: paused), stamped with the
        time the step started from; nothing in it depends on the wall clock, so a replay compares it."""
        ns = self.stamp_ns()
        self._send(ns, [self._output("diagnostics", M.new(
            "diagnostic_msgs/msg/DiagnosticArray", header=M.header(ns, ""),
            status=[self._status(FAILURE_STATUS, level, text, {})]))])

    @property
    def publication_due(self) -> bool:
        return self._since_publish >= self.settings._publish_every

    def woke(self, delay: float) -> None:
        """The loop's thread woke ``delay`` s after the time it slept to (:func:`~.live.spin`): over a tick
        period late, the OS owes the schedule a step, which the next tick catches up (``late_wakeups``)."""
        self.max_wakeup_delay = max(self.max_wakeup_delay, delay)
        if delay > 1.0 / self.settings.step_rate:
            self.late_wakeups += 1
        self._tick_cpu = self._cpu_clock()   # what the thread did before it slept did not make the next tick late

    def tick(self) -> int:
        """Run the steps that are due on the real-time schedule (publishing whenever due); returns how
        many ran. Called by the node's steady-time timer at ``step_rate``.

        Step ``k`` is due at ``t0 + (k - k0) dt / rtf`` on the steady clock (absolute times, so the rate
        does not drift). A tick runs at most twice its nominal share of steps, so a late tick catches up
        without starving the executor. A tick that ends more than one tick period behind the schedule is
        an overrun: counted, reported in diagnostics and the summary, and the lag is kept (the node
        catches up later, or runs slower than real time, visibly). With ``real_time_factor == 0`` a tick
        steps for one tick period, as fast as possible. No tick runs longer than one tick period or
        :data:`TICK_WALL_LIMIT`, whichever is shorter, on the wall clock. A failed step (:meth:`step`) is
        not counted; one that pauses the node ends the tick, and so does a publication in lockstep (no step
        until an input answers it: :attr:`awaiting`).

        Every tick's wall-clock duration and steps go into the statistics (:meth:`statistics`: the
        duration percentiles, the most steps a tick ran, and the ticks that ran more than their nominal
        share, catching up). A catch-up tick is the node's own (``own_burst_ticks``) if the ticking thread
        used over a tick period of CPU time since the tick before began, or since the loop last woke if it
        slept after it (:meth:`woke`): its work alone would have fallen a period behind; the others are the
        machine's: the thread had less work than a period, but woke late or was held off its core (by another
        thread, process or the hypervisor). A virtual machine counts its host's pauses as the running thread's
        CPU time, so there some of the first are the machine's too (``bench/bench_wakeups.py`` counts them).
        """
        if self.paused:
            return 0
        if self.awaiting:
            self._repeat_awaited()
            return 0
        start = self._clock()
        cpu = self._cpu_clock()
        done, end = self._run_due(start)
        self._tick_durations.add(end - start)
        self.max_steps_per_tick = max(self.max_steps_per_tick, done)
        s = self.settings
        if s.real_time_factor > 0.0 and done > math.ceil(s.real_time_factor / (s.dt * s.step_rate) - 1e-9):
            self.burst_ticks += 1   # more than the nominal share (rounded up: 2.5 steps a tick run 2 or 3)
            if cpu - self._tick_cpu > 1.0 / s.step_rate:
                self.own_burst_ticks += 1
        self._tick_cpu = cpu
        return done

    def _repeat_awaited(self) -> None:
        """In lockstep, while no input answered the last publication: its clock, poses and cable states again
        every :data:`LOCKSTEP_REPEAT` s, to the transport only (the log has them)."""
        now = self._clock()
        if now < self._repeat_at:
            return
        self._repeat_at = now + LOCKSTEP_REPEAT
        self._transmit(self._awaited)

    def _run_due(self, start: float) -> tuple[int, float]:
        """The steps of a tick that started at ``start`` s on the clock (:meth:`tick`): (steps run, the
        clock at the tick's end, s)."""
        s = self.settings
        period = 1.0 / s.step_rate
        budget = min(period, TICK_WALL_LIMIT)
        done = 0
        if s.real_time_factor == 0.0:
            while not (self.paused or self.awaiting):   # a failed step may pause the node; lockstep waits
                done += self._advance()
                now = self._clock()
                if now - start >= budget:
                    break
            return done, now
        steps_per_second = s.real_time_factor / s.dt
        due = self._anchor_step + math.floor((start - self._anchor_time) * steps_per_second)
        cap = max(1, math.ceil(2.0 * steps_per_second * period))
        for _ in range(min(due - self.sim.step_count, cap)):
            done += self._advance()
            if self.paused or self.awaiting:
                return done, self._clock()
            if self._clock() - start >= budget:
                break
        # steps already due that this tick could not run: more than one tick's worth is an overrun
        now = self._clock()
        behind = self._anchor_step + math.floor((now - self._anchor_time) * steps_per_second) - self.sim.step_count
        if behind > steps_per_second * period:
            self.overruns += 1
            self.max_lag = max(self.max_lag, behind / steps_per_second)
        return done, now

    def _advance(self) -> bool:
        """One step, and a publication if due; False if the step failed."""
        if self.step() is None:
            return False
        if self.publication_due:
            self.publish()
        return True

    # ------------------------------------------------------------------ outputs
    def publish(self) -> None:
        """Send and record one message on every output topic (``markers`` at every ``markers_every``-th
        publication, ``contacts`` only if events are queued), stamped with the simulation time, then start
        summing afresh. Nothing before the first step; no message is made when no one listens.

        With :attr:`idle_outputs` the markers and contact events wait (:meth:`send_waiting`): the clock,
        poses, cable states and impulses go out at once, a controller's inputs."""
        r = self._last
        if r is None:
            return
        events = self._contact_queue
        for e in events:
            if e.kind == "begin":
                self._active_contacts[e.members] = e
            else:
                self._active_contacts.pop(e.members, None)
        markers = self._until_markers == 0
        if markers:
            self._until_markers = self.settings.markers_every
        self._until_markers -= 1
        if self._transport is not None or self.recorder is not None:
            ns = stamp_ns(self.sim.time)
            outputs = self._outputs(ns, r)
            self._send(ns, outputs)
            if self.settings.lockstep:
                self._awaited = outputs
                self._repeat_at = self._clock() + LOCKSTEP_REPEAT
            if markers or events:
                rest = (ns, r, list(self._active_contacts.values()) if markers else None, events)
                if self.idle_outputs:
                    self._waiting = rest
                else:
                    self._send_rest(*rest)
        self._impulse_sum.fill(0.0)  # the messages hold copies
        self._contact_queue = []
        self._since_publish = 0
        self.publications += 1
        self.awaiting = self.settings.lockstep

    def send_waiting(self) -> None:
        """Send and record the markers and contact events that the last publication left waiting
        (:attr:`idle_outputs`), if any: what the live loop does in its idle time (its duration goes into the
        statistics' ``idle_send_*``). Whatever is sent or recorded before sends them first, so the log holds
        every publication's messages in the same order either way; an input that arrives while they wait acts
        at once, and its record follows them, so a controller's command answering the publication does not
        draw its markers (timed phase by phase in a 60 s ``bench/bench_node.py`` run, a one-off: drawing them
        made 4.5 % of the polls take 0.3-1.4 ms)."""
        if self._waiting is not None:
            start = self._clock()
            self._send_waiting()
            self._idle_durations.add(self._clock() - start)

    def _send_waiting(self) -> None:
        if self._waiting is not None:
            rest, self._waiting = self._waiting, None
            self._send_rest(*rest)
            inputs, self._waiting_inputs = self._waiting_inputs, []
            for records, ns in inputs:
                self.recorder.record(records, ns)

    def _outputs(self, ns: int, r: StepResult) -> list[tuple[str, object, bytes | None]]:
        """(key, message object or None, CDR bytes or None) of :data:`~.publication.PUBLISHED` at ``ns``
        after step ``r``: objects where the transport takes them, bytes where the log or a raw transport
        takes them (:class:`~.publication.PublicationCdr`)."""
        takes_objects = self._transport is not None and not self._raw
        if self.recorder is not None or self._raw:
            data = self._cdr.encode(ns, r.positions, r.velocities, r.tensions, self._impulse_sum)
        else:
            data = [None] * len(PUBLISHED)
        if takes_objects:
            length, rate = self._length, self._rate
            member_kinematics(r.positions, r.velocities, self._cable_nodes, self._cable_weights, length, rate)
            messages = self._messages(ns, M.header(ns, self.settings.frame_id), r.positions, length, rate,
                                      r.tensions, self._impulse_sum)
        else:
            messages = [None] * len(data)
        return list(zip(PUBLISHED, messages, data))

    def _send_rest(self, ns: int, r: StepResult, active: list[ContactEvent] | None,
                   events: list[ContactEvent]) -> None:
        """Send and record the rest of the publication at ``ns`` after step ``r``: the markers with the
        contacts ``active`` then (None: no markers this time; the markers' templates give their bytes), then
        the contact ``events`` if any (serialised from their objects)."""
        takes_objects = self._transport is not None and not self._raw
        header = M.header(ns, self.settings.frame_id) if takes_objects or events else None
        outputs = []
        if active is not None:
            drawn = self._markers.content(r, active)
            data = self._markers.cdr(ns, drawn) if self.recorder is not None or self._raw else None
            outputs.append(("markers", self._markers.message(header, drawn) if takes_objects else None, data))
        if events:
            outputs.append(self._output("contacts", encode_contacts(events, header)))
        self._send(ns, outputs)

    def _messages(self, ns: int, header, positions, length, rate, tensions, impulses) -> list:
        """The message objects of :data:`~.publication.PUBLISHED` (the arrays as in
        :class:`~.publication.PublicationTemplates`); ``header``: stamped ``ns``, in the node's frame."""
        q = M.new("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0)
        poses = [M.new("geometry_msgs/msg/Pose", position=M.point(*p), orientation=q) for p in positions.tolist()]
        return [M.new("rosgraph_msgs/msg/Clock", clock=M.time(ns)),
                M.new("geometry_msgs/msg/PoseArray", header=header, poses=poses),
                M.joint_state(header, self._cable_names, length, rate, tensions),
                M.joint_state(header, self._cable_names, effort=impulses)]

    def _output(self, key: str, message) -> tuple[str, object, bytes | None]:
        """(key, message, its CDR bytes where the log or a raw transport takes them, else None)."""
        wants_bytes = self.recorder is not None or self._raw
        return key, message, M.serialize(message, TOPICS[key].typename) if wants_bytes else None

    def _send(self, ns: int, outputs: list[tuple[str, object, bytes | None]]) -> None:
        """Record and send ``outputs`` at ``ns``, in order: (key, message object or None if only bytes are
        taken, its CDR bytes or None if neither the log nor a raw transport takes them). The log takes them
        in one call (:meth:`~.log.LogRecorder.record`), then the transport one by one; what the last
        publication left waiting goes first (:meth:`send_waiting`)."""
        self._send_waiting()
        if self.recorder is not None:
            names = self.topic_names
            self.recorder.record([(names[key], data) for key, _, data in outputs], ns)
        self._transmit(outputs)

    def _transmit(self, outputs: list[tuple[str, object, bytes | None]]) -> None:
        """Hand ``outputs`` (as :meth:`_send` takes them) to the transport, if any, in order."""
        if self._transport is not None:
            for key, message, data in outputs:
                self._transport(key, data if self._raw else message)

    # ------------------------------------------------------------------ services
    def pause(self) -> tuple[bool, str]:
        if self.paused:
            return False, "already paused"
        self.paused = True
        return True, f"paused at t = {self.sim.time:.6f} s"

    def resume(self) -> tuple[bool, str]:
        if not self.paused:
            return False, "not paused"
        self.paused = False
        self.failure = None  # the next step tries again
        self.restart_schedule()  # the paused time is not owed: the schedule restarts now
        return True, f"resumed at t = {self.sim.time:.6f} s"

    def single_step(self) -> tuple[bool, str]:
        """While paused: one step, then publish (so the new state is seen at once)."""
        if not self.paused:
            return False, "not paused: call pause first"
        if self.step() is None:
            return False, f"step failed: {self.step_error} (see /diagnostics)"
        self.failure = None
        self.publish()
        return True, f"stepped to t = {self.sim.time:.6f} s"

    def reset(self) -> tuple[bool, str]:
        """Back to the scene's initial state (time 0, initial rest lengths, no external force). A log
        holds one run from the initial state, so the recorder starts a new file."""
        self._send_waiting()   # the publication before the reset, whole in its file
        self.sim.reset()
        self._clear()
        self.restart_schedule()
        self.failure = None
        text = "reset to the scene's initial state"
        if self.recorder is not None:  # the new file embeds the settings in force now
            text += f"; now logging to {self.recorder.restart(self.run_info())}"
        return True, text

    def update(self, **changes) -> NodeSettings:
        """Change runtime parameters (:data:`RUNTIME_PARAMETERS`); ``ValueError`` names a bad one and
        changes nothing. An accepted change is sent and recorded on ``/parameter_events`` at the simulation
        time it takes effect, with the values as validated (so a replay applies it there)."""
        fixed = sorted(set(changes) - set(RUNTIME_PARAMETERS))
        if fixed:
            raise ValueError(f"parameter {fixed[0]!r} is read-only while running (restart the node)")
        self.settings = replace(self.settings, **changes)
        self.restart_schedule()
        if changes:
            ns = self.stamp_ns()
            self._send(ns, [self._output("parameter_events", M.parameter_event(
                ns, self.settings.node_name, {name: getattr(self.settings, name) for name in changes}))])
        return self.settings

    # ------------------------------------------------------------------ reporting
    def publish_diagnostics(self) -> None:
        """Send (and record) ``/diagnostics``: ERROR while a failed step keeps the node paused, WARN while
        overruns keep happening, else OK."""
        new_overruns = self.overruns - self._overruns_reported
        self._overruns_reported = self.overruns
        if self.failure is not None:
            level, text = 2, self.failure
        elif new_overruns:
            level, text = 1, (f"{new_overruns} overrun(s) since the last report: the node cannot keep the "
                              f"real-time factor")
        else:
            level, text = 0, ("paused" if self.paused else "waiting for the controller (lockstep)" if self.awaiting
                              else "stepping")
        values = {k: str(v) for k, v in self.statistics().items()}
        ns = self.stamp_ns()
        self._send(ns, [self._output("diagnostics", M.new(
            "diagnostic_msgs/msg/DiagnosticArray", header=M.header(ns, ""),
            status=[self._status("stepping", level, text, values)]))])

    def _status(self, what: str, level: int, text: str, values: dict):
        """One DiagnosticStatus named ``"<node name>: <what>"``, hardware id = the scene's name."""
        return M.new("diagnostic_msgs/msg/DiagnosticStatus", level=M.byte(level),
                     name=f"{self.settings.node_name.lstrip('/')}: {what}", message=text,
                     hardware_id=self.sim.scene.name, values=M.key_values(values))

    def statistics(self) -> dict:
        """Counters for diagnostics and the summary (``msg_docs/diagnostics.md`` says what each is)."""
        wall = self._clock() - self._started
        ticks, idle = self._tick_durations, self._idle_durations
        return {
            "steps": self._steps_run, "sim_time_s": round(self.sim.time, 9),
            "real_time_factor_achieved": round(self._steps_run * self.sim.dt / wall, 4) if wall > 0 else 0.0,
            "real_time_factor_target": self.settings.real_time_factor,
            "overruns": self.overruns, "max_lag_ms": round(1e3 * self.max_lag, 3),
            "ticks": ticks.ticks, "tick_p50_ms": round(1e3 * ticks.percentile(50.0), 3),
            "tick_p99_ms": round(1e3 * ticks.percentile(99.0), 3),
            "tick_p999_ms": round(1e3 * ticks.percentile(99.9), 3), "tick_max_ms": round(1e3 * ticks.longest, 3),
            "max_steps_per_tick": self.max_steps_per_tick, "burst_ticks": self.burst_ticks,
            "own_burst_ticks": self.own_burst_ticks,
            "late_wakeups": self.late_wakeups, "max_wakeup_delay_ms": round(1e3 * self.max_wakeup_delay, 3),
            "idle_sends": idle.ticks, "idle_send_p999_ms": round(1e3 * idle.percentile(99.9), 3),
            "idle_send_max_ms": round(1e3 * idle.longest, 3), "idle_look_aheads": self.idle_look_aheads,
            "publications": self.publications, "failed_steps": self.failed_steps,
            "refused_rest_lengths": self.refused["cable_rest_lengths"],
            "refused_wrenches": self.refused["external_wrench"], "paused": self.paused,
        }

    def summary(self) -> list[str]:
        """What the node prints on exit."""
        return [f"{k:<27} {v}" for k, v in self.statistics().items()]


def _jsonable(value):
    """JSON for numpy scalars and arrays in method settings."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"method_settings: {type(value).__name__} is not JSON-serialisable")
