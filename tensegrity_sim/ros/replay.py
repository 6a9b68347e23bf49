"""Replay a log bit for bit (``tensegrity-sim replay``) and summarise one (``tensegrity-sim info``).

**What a replay checks.** The log holds the scene, the method, ``dt`` and the node settings (metadata
``tensegrity_sim``), every input message at the simulation time it took effect, and every publication.
:func:`replay` rebuilds the simulator and the node logic from the log alone and walks the log in file
order, which is the order the node recorded things:

* an input message: step the replay up to the message's log time, then hand it to the node logic, which
  validates it (refusing what the node refused) and applies it, as the node did;
* a runtime parameter change (``/parameter_events``): step up to its log time and apply it, as the node
  did; the replay's own event must then be the logged one;
* a failed step (the ``/diagnostics`` status ``<node>: step failed``): step up to its log time and attempt
  a step, which must fail too and be reported the same way (so what the node gave up is given up here,
  at the same step, and a solver's warm start sees the same attempts);
* an output message: if the replay has no publication pending, step up to the message's log time and
  publish; then the replay's next output must be on the same topic with the same content.

So the recorded states are every published message: clock, node poses, cable states (lengths, rates,
tensions), summed cable impulses, contact events and markers, at the publication times of the log
(which also covers pauses and single steps). Content is compared as serialised CDR bytes; where the
bytes differ the two messages are decoded and compared field by field, floats bit for bit, and the
first difference is named: step, time, topic and field. The periodic ``/diagnostics`` (wall-clock
statistics) is not a state and is skipped. A replay is bit for bit on the machine (numpy/BLAS build)
that wrote the log; another build may round differently.

**Integrity.** The log is read with :class:`~.log_reader.LogReader`: every chunk's CRC is checked, and a
record that fails it, or a message that does not decode, ends the replay with its byte position and topic
(the report is then not ok). An unfinished log (its writer killed) is replayed up to its last complete
record, and the report says so.
"""
from __future__ import annotations

import array
import json
import struct
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from .. import __version__
from ..scene import Scene
from ..simulator import Simulator
from . import messages as M
from .log import RUN_INFO
from .log_reader import LogCorruptError, LogError, LogMessage, LogReader
from .node_logic import FAILURE_STATUS, TOPICS, NodeSettings, SimNodeLogic, _jsonable, decode_contacts

__all__ = ["LogError", "Mismatch", "ReplayReport", "replay", "log_info"]


@dataclass(frozen=True)
class Mismatch:
    """The first difference between a log and its replay."""

    step: int       # steps the replay had taken when the difference showed
    time_ns: int    # log time of the message
    topic: str
    field: str      # dotted path of the first differing field, or what is missing
    logged: str
    replayed: str

    def __str__(self) -> str:
        return (f"step {self.step} (t = {self.time_ns * 1e-9:.9f} s), {self.topic}: {self.field}: "
                f"logged {self.logged}, replayed {self.replayed}")


@dataclass
class ReplayReport:
    path: Path
    steps: int = 0
    inputs: dict[str, int] = field(default_factory=dict)    # topic -> messages applied (or refused again)
    compared: dict[str, int] = field(default_factory=dict)  # topic -> messages reproduced
    mismatch: Mismatch | None = None
    corrupt: str | None = None   # a record that fails its CRC or does not decode: where, which topic, why
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.mismatch is None and self.corrupt is None

    def lines(self) -> list[str]:
        out = [f"log              {self.path}", f"replayed         {self.steps} steps"]
        out += [f"input            {t}: {n} messages" for t, n in self.inputs.items()]
        out += [f"reproduced       {t}: {n} messages" for t, n in self.compared.items()]
        out += [f"note             {n}" for n in self.notes]
        if self.corrupt is not None:
            out.append(f"result           CORRUPT LOG: {self.corrupt}")
        elif self.mismatch is not None:
            out.append(f"result           MISMATCH at {self.mismatch}")
        else:
            out.append("result           every logged state reproduced bit for bit")
        return out


# --------------------------------------------------------------------------- reading
def _decode(path: Path, message: LogMessage, typename: str):
    """The message object of ``message``; one that does not decode is a corrupt record."""
    try:
        return M.deserialize(message.data, typename)
    except Exception as exc:  # noqa: BLE001 - what a decoder raises for garbage varies
        raise LogCorruptError(f"{path}: corrupt record at {message.position}, {message.topic} at t = "
                              f"{message.log_time * 1e-9:.9f} s: it does not decode as {typename} "
                              f"({type(exc).__name__})", 0, (message.topic,)) from None


_RUN_INFO_KEYS = ("dt", "method", "method_reason", "method_settings", "node_settings", "package_version",
                  "scene_name", "scene_yaml", "topics")


def _run_info(reader: LogReader, path: Path) -> dict[str, str]:
    info = reader.metadata.get(RUN_INFO)
    if info is None:
        raise LogError(f"{path}: no {RUN_INFO!r} metadata: not a tensegrity_sim log")
    missing = [k for k in _RUN_INFO_KEYS if k not in info]
    if missing:
        raise LogError(f"{path}: {RUN_INFO!r} metadata lacks {', '.join(missing)}")
    return info


def _rebuild(info: dict[str, str], path: Path) -> tuple[Simulator, NodeSettings]:
    """The simulator and node settings a log was written with, from the log alone."""
    scene = Scene.from_dict(yaml.safe_load(info["scene_yaml"]), source=f"{path} (embedded scene)")
    # the QP backend of the inextensible method is part of its settings
    solver = json.loads(info["method_settings"]).get("solver")
    sim = Simulator(scene, method=info["method"], dt=float(info["dt"]), solver=solver)
    # "solver_choice" says why the backend was picked ("requested" here, by size in the run): not a setting
    mine = json.loads(json.dumps(sim.method_settings, sort_keys=True, default=_jsonable))
    mine.pop("solver_choice", None)
    logged = json.loads(info["method_settings"])
    logged.pop("solver_choice", None)
    if mine != logged:
        raise LogError(f"{path}: method settings {info['method_settings']} cannot be reproduced: this version "
                       f"gives {json.dumps(mine, sort_keys=True)}")
    settings = NodeSettings(**{**json.loads(info["node_settings"]), "log_path": ""})
    return sim, settings


# --------------------------------------------------------------------------- comparing
def _first_difference(a, b, path: str = "") -> tuple[str, str, str] | None:
    """(field path, a, b) of the first difference between two decoded messages (floats bit for bit)."""
    if isinstance(a, (list, tuple)):
        if len(a) != len(b):
            return f"{path} length", str(len(a)), str(len(b))
        for i, (x, y) in enumerate(zip(a, b)):
            d = _first_difference(x, y, f"{path}[{i}]")
            if d is not None:
                return d
        return None
    if isinstance(a, (np.ndarray, array.array)):
        x, y = np.ascontiguousarray(a), np.ascontiguousarray(b)
        if x.shape != y.shape:
            return f"{path} length", str(x.size), str(y.size)
        if x.size == 0:
            return None
        differ = np.flatnonzero(np.any(x.view(np.uint8).reshape(x.size, -1) != y.view(np.uint8).reshape(y.size, -1),
                                       axis=1))
        return None if not differ.size else (f"{path}[{differ[0]}]", repr(x[differ[0]].item()),
                                             repr(y[differ[0]].item()))
    if isinstance(a, float):
        return None if struct.pack("<d", a) == struct.pack("<d", b) else (path, repr(a), repr(b))
    if isinstance(a, (int, str, bool, bytes)):
        return None if a == b else (path, repr(a), repr(b))
    for name in M.field_names(a):
        d = _first_difference(getattr(a, name), getattr(b, name), f"{path}.{name}" if path else name)
        if d is not None:
            return d
    return None


# --------------------------------------------------------------------------- replay
def _walk(reader: LogReader, path: Path, report: ReplayReport, logic: SimNodeLogic, sim: Simulator, key_of: dict,
          failure_name: str, advance_to, pending: deque, on_publication=None) -> None:
    """Replay every message of ``reader`` (see the module docstring); stops at the first mismatch, which it
    puts in ``report``. A corrupt record raises :class:`~.log_reader.LogCorruptError`. ``on_publication``:
    as :func:`replay`'s."""
    for message in reader.messages():
        key = key_of.get(message.topic)
        if key is None:
            raise LogError(f"{path}: topic {message.topic!r} is not one of the node's")
        spec = TOPICS[key]
        t = message.log_time
        logged = _decode(path, message, spec.typename) if key in ("diagnostics", "parameter_events") else None
        if key == "diagnostics" and not (logged.status and logged.status[0].name == failure_name):
            continue  # the periodic report: wall-clock statistics, not a state
        if spec.direction == "in" or logged is not None:
            # what the run did at a time (an input, a parameter change, a failed step), not a publication
            if pending:
                missing = pending[0][0]
                report.mismatch = Mismatch(sim.step_count, t, logic.topic_names[missing], "message",
                                           "none", "a message")
                return
            if not advance_to(t, message.topic):
                return
            if spec.direction == "in":
                logic.receive(key, _decode(path, message, spec.typename))
                report.inputs[message.topic] = report.inputs.get(message.topic, 0) + 1
                continue
            if key == "parameter_events":  # apply it; the replay's own event is compared below
                try:
                    logic.update(**M.parameter_changes(logged))
                except ValueError as exc:
                    report.mismatch = Mismatch(sim.step_count, t, message.topic, "changed_parameters",
                                               "a change the node took", f"refused: {exc}")
                    return
            elif logic.step() is not None:  # a failed step: the replay's must fail, and report the same
                report.mismatch = Mismatch(sim.step_count, t, message.topic, "message",
                                           logged.status[0].message, "the step succeeded")
                return
        elif not pending:
            if not advance_to(t, message.topic):
                return
            logic.publish()
        if not pending:
            report.mismatch = Mismatch(sim.step_count, t, message.topic, "message", "a message", "none")
            return
        got_key, replayed = pending.popleft()
        if got_key != key:
            report.mismatch = Mismatch(sim.step_count, t, logic.topic_names[got_key], "message", "none",
                                       "a message")
            return
        if replayed != message.data:
            diff = _first_difference(_decode(path, message, spec.typename),
                                     M.deserialize(replayed, spec.typename))
            if diff is not None:
                report.mismatch = Mismatch(sim.step_count, t, message.topic, *diff)
                return
        report.compared[message.topic] = report.compared.get(message.topic, 0) + 1
        if on_publication is not None and key == "cable_states":
            on_publication(sim)


class _Refusals:
    """The node logic's logger during a replay: keeps the refusals for the report instead of logging."""

    def __init__(self):
        self.messages: list[str] = []
        self.errors: list[str] = []

    def warning(self, text: str) -> None:
        self.messages.append(text)

    def error(self, text: str) -> None:
        self.errors.append(text)


def replay(path: str | Path, *, on_publication: Callable[[Simulator], None] | None = None) -> ReplayReport:
    """Re-simulate the log at ``path`` from what it holds and compare every published message.

    ``on_publication(sim)``, if given, sees the replaying simulator at every reproduced ``cable_states``
    message (what the log does not hold, such as velocities and energies, read there)."""
    path = Path(path)
    report = ReplayReport(path)
    try:
        reader = LogReader(path)
    except LogCorruptError as exc:  # found before anything is used: a finished log's CRCs
        report.corrupt = str(exc).removeprefix(f"{path}: ")
        return report
    with reader:
        info = _run_info(reader, path)
        if info.get("package_version") != __version__:
            report.notes.append(f"written by tensegrity_sim {info.get('package_version')}, "
                                f"replayed by {__version__}")
        sim, settings = _rebuild(info, path)
        pending: deque = deque()
        refusals = _Refusals()
        logic = SimNodeLogic(sim, settings, transport=lambda key, data: pending.append((key, data)),
                             raw_transport=True, logger=refusals)
        key_of = {name: key for key, name in logic.topic_names.items()}

        failure_name = f"{settings.node_name.lstrip('/')}: {FAILURE_STATUS}"

        def advance_to(t_ns: int, topic: str) -> bool:
            while logic.stamp_ns() < t_ns:
                if logic.step() is None:  # a failure the run did not have here
                    report.mismatch = Mismatch(sim.step_count, logic.stamp_ns(), logic.topic_names["diagnostics"],
                                               "message", "none", f"a failed step: {logic.step_error}")
                    return False
            if logic.stamp_ns() != t_ns:
                report.mismatch = Mismatch(sim.step_count, t_ns, topic, "log time", f"{t_ns} ns",
                                           f"no step there (replay is at {logic.stamp_ns()} ns)")
            return report.mismatch is None

        try:
            _walk(reader, path, report, logic, sim, key_of, failure_name, advance_to, pending, on_publication)
        except LogCorruptError as exc:
            report.corrupt = str(exc).removeprefix(f"{path}: ")
        if reader.unfinished:
            report.notes.append(f"{reader.unfinished}; replayed what it holds")
        if refusals.messages:
            report.notes.append(f"{len(refusals.messages)} input message(s) refused again, as in the run; "
                                f"the first: {refusals.messages[0]}")
        if refusals.errors:
            report.notes.append(f"{len(refusals.errors)} failed step(s) paused the run again; the first: "
                                f"{refusals.errors[0]}")
        if report.ok and pending:
            report.notes.append(f"the log ends {len(pending)} message(s) short of the last publication "
                                f"(cut off while writing it)")
        report.steps = sim.step_count
    return report


# --------------------------------------------------------------------------- info
def _settings_lines(settings: dict) -> list[str]:
    """The method settings, one per line; per-cable length offsets (m) summed up by count and range."""
    out = ["settings"]
    for name, value in sorted(settings.items()):
        if name == "length_offsets" and isinstance(value, dict) and value:
            largest = max(value, key=value.get)
            value = (f"{len(value)} cables, {min(value.values()):.6g} m to {value[largest]:.6g} m ({largest}); "
                     f"the log's metadata has each")
        out.append(f"  {name:<14} {value}")
    return out


def log_info(path: str | Path) -> list[str]:
    """A summary of a log: scene, settings, duration, topics and counts, slack/snap/contact statistics.

    A cable counts as slack in a ``cable_states`` message when its tension (effort) is exactly zero; a
    snap is a slack-to-taut change between two consecutive messages (so at the publish rate). The whole
    log is read (its CRCs checked): an unfinished log is summarised up to its last complete record, and
    says so; a corrupt record raises :class:`~.log_reader.LogCorruptError`."""
    path = Path(path)
    with LogReader(path) as reader:
        info = _run_info(reader, path)
        scene = yaml.safe_load(info["scene_yaml"])
        topics = json.loads(info["topics"])
        counts: dict[str, int] = {}
        start = end = None
        names: list[str] = []
        previous = None
        slack_count = snaps = publications = 0
        max_tension, max_at = 0.0, ("-", 0.0)
        begins = ends = 0
        pairs: set[tuple[str, str]] = set()
        deepest = None
        for message in reader.messages():
            counts[message.topic] = counts.get(message.topic, 0) + 1
            start = message.log_time if start is None else min(start, message.log_time)
            end = message.log_time if end is None else max(end, message.log_time)
            if message.topic == topics["cable_states"]:
                msg = _decode(path, message, TOPICS["cable_states"].typename)
                names = list(msg.name)
                effort = np.asarray(msg.effort, dtype=float)
                slack = effort == 0.0
                slack_count = slack_count + slack.astype(int)
                if previous is not None:
                    snaps += int(np.count_nonzero(previous & ~slack))
                previous = slack
                publications += 1
                k = int(np.argmax(effort)) if effort.size else -1
                if k >= 0 and effort[k] > max_tension:
                    max_tension, max_at = float(effort[k]), (names[k], message.log_time * 1e-9)
            elif message.topic == topics["contacts"]:
                for e in decode_contacts(_decode(path, message, TOPICS["contacts"].typename)):
                    begins += e.kind == "begin"
                    ends += e.kind == "end"
                    pairs.add(e.members)
                    deepest = e.distance if deepest is None else min(deepest, e.distance)
        start, end = start or 0, end or 0
        out = [
            f"log              {path}",
            f"scene            {info['scene_name']} ({len(scene['nodes'])} nodes, {len(scene.get('struts') or [])} "
            f"struts, {len(scene.get('cables') or [])} cables)",
            f"method           {info['method']} ({info['method_reason']}), dt {float(info['dt']):g} s",
            *_settings_lines(json.loads(info["method_settings"])),
            f"written by       tensegrity_sim {info['package_version']} at {info['created']}",
        ]
        if reader.unfinished:
            out.append(f"state            {reader.unfinished} (tensegrity-sim recover writes a finished copy)")
        out += [
            f"sim time         {start * 1e-9:.6f} s to {end * 1e-9:.6f} s "
            f"({round((end - start) * 1e-9 / float(info['dt']))} steps)",
            f"messages         {sum(counts.values())}",
        ]
        for channel in sorted(reader.channels.values(), key=lambda c: c.id):
            schema = reader.schemas[channel.schema_id]
            out.append(f"  {channel.topic:<40} {schema.name:<38} {counts.get(channel.topic, 0):>8}")
        if publications:
            share = ", ".join(f"{n} {100.0 * c / publications:.0f}%" for n, c in zip(names, slack_count) if c)
            out += [f"slack            {share or 'no cable ever slack'} (of {publications} cable_states messages)",
                    f"snaps            {snaps} slack-to-taut changes",
                    f"max tension      {max_tension:.6g} N ({max_at[0]} at t = {max_at[1]:.6f} s)"]
        out.append(f"contacts         {begins} begin, {ends} end, {len(pairs)} member pairs"
                   + (f", smallest distance {deepest:.6g} m" if deepest is not None else ""))
    return out
