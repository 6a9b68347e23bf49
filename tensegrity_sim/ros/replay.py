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
"""
from __future__ import annotations

import array
import json
import struct
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader

from .. import __version__
from ..scene import Scene
from ..simulator import Simulator
from . import messages as M
from .log import RUN_INFO
from .node_logic import FAILURE_STATUS, TOPICS, NodeSettings, SimNodeLogic, _jsonable, decode_contacts

__all__ = ["LogError", "Mismatch", "ReplayReport", "replay", "log_info"]


class LogError(ValueError):
    """A file that is not a readable tensegrity_sim log; the message names the file and the reason."""


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
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.mismatch is None

    def lines(self) -> list[str]:
        out = [f"log              {self.path}", f"replayed         {self.steps} steps"]
        out += [f"input            {t}: {n} messages" for t, n in self.inputs.items()]
        out += [f"reproduced       {t}: {n} messages" for t, n in self.compared.items()]
        out += [f"note             {n}" for n in self.notes]
        out.append("result           every logged state reproduced bit for bit" if self.ok
                   else f"result           MISMATCH at {self.mismatch}")
        return out


# --------------------------------------------------------------------------- reading
@contextmanager
def _reading(path: Path):
    """An MCAP reader of ``path``; unreadable files raise :class:`LogError`."""
    try:
        with open(path, "rb") as f:
            yield make_reader(f)
    except OSError as exc:
        raise LogError(f"{path}: cannot read: {exc.strerror}") from None
    except McapError as exc:
        raise LogError(f"{path}: not a readable MCAP file: {exc}") from None


_RUN_INFO_KEYS = ("dt", "method", "method_reason", "method_settings", "node_settings", "package_version",
                  "scene_name", "scene_yaml", "topics")


def _run_info(reader, path: Path) -> dict[str, str]:
    for record in reader.iter_metadata():
        if record.name == RUN_INFO:
            missing = [k for k in _RUN_INFO_KEYS if k not in record.metadata]
            if missing:
                raise LogError(f"{path}: {RUN_INFO!r} metadata lacks {', '.join(missing)}")
            return dict(record.metadata)
    raise LogError(f"{path}: no {RUN_INFO!r} metadata: not a tensegrity_sim log")


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
    with _reading(path) as reader:
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

        for _, channel, message in reader.iter_messages(log_time_order=False):
            key = key_of.get(channel.topic)
            if key is None:
                raise LogError(f"{path}: topic {channel.topic!r} is not one of the node's")
            spec = TOPICS[key]
            t = message.log_time
            logged = M.deserialize(message.data, spec.typename) if key in ("diagnostics", "parameter_events") else None
            if key == "diagnostics" and not (logged.status and logged.status[0].name == failure_name):
                continue  # the periodic report: wall-clock statistics, not a state
            if spec.direction == "in" or logged is not None:
                # what the run did at a time (an input, a parameter change, a failed step), not a publication
                if pending:
                    missing = pending[0][0]
                    report.mismatch = Mismatch(sim.step_count, t, logic.topic_names[missing], "message",
                                               "none", "a message")
                    break
                if not advance_to(t, channel.topic):
                    break
                if spec.direction == "in":
                    logic.receive(key, M.deserialize(message.data, spec.typename))
                    report.inputs[channel.topic] = report.inputs.get(channel.topic, 0) + 1
                    continue
                if key == "parameter_events":  # apply it; the replay's own event is compared below
                    try:
                        logic.update(**M.parameter_changes(logged))
                    except ValueError as exc:
                        report.mismatch = Mismatch(sim.step_count, t, channel.topic, "changed_parameters",
                                                   "a change the node took", f"refused: {exc}")
                        break
                elif logic.step() is not None:  # a failed step: the replay's must fail, and report the same
                    report.mismatch = Mismatch(sim.step_count, t, channel.topic, "message",
                                               logged.status[0].message, "the step succeeded")
                    break
            elif not pending:
                if not advance_to(t, channel.topic):
                    break
                logic.publish()
            if not pending:
                report.mismatch = Mismatch(sim.step_count, t, channel.topic, "message", "a message", "none")
                break
            got_key, replayed = pending.popleft()
            if got_key != key:
                report.mismatch = Mismatch(sim.step_count, t, logic.topic_names[got_key], "message", "none",
                                           "a message")
                break
            if replayed != bytes(message.data):
                diff = _first_difference(M.deserialize(message.data, spec.typename),
                                         M.deserialize(replayed, spec.typename))
                if diff is not None:
                    report.mismatch = Mismatch(sim.step_count, t, channel.topic, *diff)
                    break
            report.compared[channel.topic] = report.compared.get(channel.topic, 0) + 1
            if on_publication is not None and key == "cable_states":
                on_publication(sim)
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
    snap is a slack-to-taut change between two consecutive messages (so at the publish rate)."""
    path = Path(path)
    with _reading(path) as reader:
        info = _run_info(reader, path)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            raise LogError(f"{path}: no summary section (the writer did not finish)")
        scene = yaml.safe_load(info["scene_yaml"])
        stats = summary.statistics
        topics = {k: v for k, v in json.loads(info["topics"]).items()}
        out = [
            f"log              {path}",
            f"scene            {info['scene_name']} ({len(scene['nodes'])} nodes, {len(scene.get('struts') or [])} "
            f"struts, {len(scene.get('cables') or [])} cables)",
            f"method           {info['method']} ({info['method_reason']}), dt {float(info['dt']):g} s",
            *_settings_lines(json.loads(info["method_settings"])),
            f"written by       tensegrity_sim {info['package_version']} at {info['created']}",
            f"sim time         {stats.message_start_time * 1e-9:.6f} s to {stats.message_end_time * 1e-9:.6f} s "
            f"({round((stats.message_end_time - stats.message_start_time) * 1e-9 / float(info['dt']))} steps)",
            f"messages         {stats.message_count}",
        ]
        for cid, channel in sorted(summary.channels.items()):
            schema = summary.schemas[channel.schema_id]
            out.append(f"  {channel.topic:<40} {schema.name:<38} {stats.channel_message_counts.get(cid, 0):>8}")
        names: list[str] = []
        previous = None
        slack_count = snaps = publications = 0
        max_tension, max_at = 0.0, ("-", 0.0)
        begins = ends = 0
        pairs: set[tuple[str, str]] = set()
        deepest = None
        for _, channel, message in reader.iter_messages(topics=[topics["cable_states"], topics["contacts"]],
                                                        log_time_order=False):
            if channel.topic == topics["cable_states"]:
                msg = M.deserialize(message.data, TOPICS["cable_states"].typename)
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
            else:
                for e in decode_contacts(M.deserialize(message.data, TOPICS["contacts"].typename)):
                    begins += e.kind == "begin"
                    ends += e.kind == "end"
                    pairs.add(e.members)
                    deepest = e.distance if deepest is None else min(deepest, e.distance)
        if publications:
            share = ", ".join(f"{n} {100.0 * c / publications:.0f}%" for n, c in zip(names, slack_count) if c)
            out += [f"slack            {share or 'no cable ever slack'} (of {publications} cable_states messages)",
                    f"snaps            {snaps} slack-to-taut changes",
                    f"max tension      {max_tension:.6g} N ({max_at[0]} at t = {max_at[1]:.6f} s)"]
        out.append(f"contacts         {begins} begin, {ends} end, {len(pairs)} member pairs"
                   + (f", smallest distance {deepest:.6g} m" if deepest is not None else ""))
    return out
