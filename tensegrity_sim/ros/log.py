"""MCAP logs of a run, in the form rosbag2 writes them, so ``ros2 bag info`` and Foxglove open them.

A log is one MCAP file with

* profile ``ros2``; one channel per topic (every input and output topic of the node, registered up front
  so a topic without messages still shows), message encoding ``cdr``; schemas ``ros2msg`` holding the
  type's definition followed by every dependent definition; channel metadata ``offered_qos_profiles``
  (rosbag2's version-9 YAML) and ``topic_type_hash`` (RIHS01), as Jazzy's rosbag2 MCAP plugin writes;
* log time = publish time = the simulation time in integer nanoseconds at which the message was published
  (outputs) or took effect (inputs, which act from the next step on);
* a metadata record ``tensegrity_sim`` (:data:`RUN_INFO`) with the scene YAML, the method and its
  settings, ``dt``, the node settings and the package version: enough to re-run the log alone;
* on finish: a metadata record ``rosbag2`` with ``serialized_metadata`` (the bag's metadata.yaml, version
  9, as rosbag2 writes it into MCAP) and the summary section (schemas, channels, statistics with
  per-channel counts, chunk and metadata indexes, summary offsets).

Chunks are not compressed (rosbag2's default too): compressing would cost step time while logging.
:class:`LogWriter` finishes idempotently, as a context manager, so exceptions finish the file;
:class:`SignalLatch` turns SIGINT/SIGTERM into an exception at a safe point (never inside a write).
"""
from __future__ import annotations

import signal
from datetime import datetime
from functools import cache
from pathlib import Path
from typing import Iterable, Mapping

import yaml
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from .. import __version__
from . import messages as M
from .node_logic import Qos

__all__ = ["RUN_INFO", "LogWriter", "LogRecorder", "SignalLatch", "log_file_path", "qos_profiles_yaml"]

RUN_INFO = "tensegrity_sim"   # name of the metadata record that makes a log re-runnable
ROSBAG2_METADATA_VERSION = 9  # Jazzy
_INFINITE = {"sec": 9223372036, "nsec": 854775807}  # RMW_DURATION_INFINITE, as rosbag2 records it


def _qos_profile(qos: Qos) -> dict:
    """One QoS profile in rosbag2's version-9 spelling (enum names as strings, durations as sec/nsec);
    new dicts at every call, so YAML never writes them as aliases of each other."""
    return {"history": "keep_last", "depth": qos.depth, "reliability": qos.reliability,
            "durability": qos.durability, "deadline": dict(_INFINITE), "lifespan": dict(_INFINITE),
            "liveliness": "automatic", "liveliness_lease_duration": dict(_INFINITE),
            "avoid_ros_namespace_conventions": False}


@cache  # pure-Python YAML is slow, and a node has a handful of distinct QoS
def qos_profiles_yaml(qos: Qos) -> str:
    """The ``offered_qos_profiles`` channel metadata: a YAML list of one profile (:func:`_qos_profile`)."""
    return yaml.safe_dump([_qos_profile(qos)], sort_keys=False)


def log_file_path(spec: str, scene_name: str, now: datetime | None = None) -> Path | None:
    """Where a log goes: ``spec`` ending in ``.mcap`` is the file; any other non-empty ``spec`` is a
    directory that gets ``<scene>_<YYYYmmdd-HHMMSS>.mcap`` (``_1``, ``_2``... if taken); "" means no log."""
    if not spec:
        return None
    path = Path(spec)
    if path.suffix == ".mcap":
        return path
    stem = f"{scene_name}_{(now or datetime.now()):%Y%m%d-%H%M%S}"
    candidate, n = path / f"{stem}.mcap", 0
    while candidate.exists():
        n += 1
        candidate = path / f"{stem}_{n}.mcap"
    return candidate


class LogWriter:
    """One MCAP log file (see the module docstring).

    channels: (topic name, type name "pkg/msg/Name", :class:`Qos`) of every topic, in order.
    run_info: the ``tensegrity_sim`` metadata (strings), written first so even a cut-off file has it.
    """

    def __init__(self, path: str | Path, channels: Iterable[tuple[str, str, Qos]], run_info: Mapping[str, str]):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file, compression=CompressionType.NONE)
        self._writer.start(profile="ros2", library=f"tensegrity_sim {__version__}; {LIBRARY_IDENTIFIER}")
        self._writer.add_metadata(RUN_INFO, dict(run_info))
        self._channels: dict[str, tuple[int, str, Qos]] = {}
        schemas: dict[str, int] = {}
        for topic, typename, qos in channels:
            if typename not in schemas:
                schemas[typename] = self._writer.register_schema(
                    name=typename, encoding="ros2msg", data=M.schema_text(typename).encode())
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=schemas[typename],
                metadata={"offered_qos_profiles": qos_profiles_yaml(qos), "topic_type_hash": M.type_hash(typename)})
            self._channels[topic] = (channel_id, typename, qos)
        self.counts = {topic: 0 for topic in self._channels}
        self._start: int | None = None
        self._end = 0
        self._finished = False

    def write(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Append ``data`` (a message of the topic's type in CDR, encapsulation header first, as
        :func:`.messages.serialize` gives it) at ``log_time_ns``."""
        channel_id = self._channels[topic][0]
        self._writer.add_message(channel_id=channel_id, log_time=log_time_ns, publish_time=log_time_ns,
                                 data=data, sequence=self.counts[topic])
        self.counts[topic] += 1
        if self._start is None:
            self._start = log_time_ns
        self._end = max(self._end, log_time_ns)

    def finish(self) -> None:
        """Write the rosbag2 metadata and the summary and close the file; later calls do nothing."""
        if self._finished:
            return
        self._finished = True
        try:
            self._writer.add_metadata("rosbag2", {"serialized_metadata": self._rosbag2_metadata()})
            self._writer.finish()
        finally:
            self._file.close()

    def _rosbag2_metadata(self) -> str:
        start = self._start or 0
        duration = self._end - start
        total = sum(self.counts.values())
        return yaml.safe_dump({
            "version": ROSBAG2_METADATA_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": total,
            "topics_with_message_count": [{
                "topic_metadata": {
                    "name": topic, "type": typename, "serialization_format": "cdr",
                    "offered_qos_profiles": [_qos_profile(qos)],
                    "type_description_hash": M.type_hash(typename),
                },
                "message_count": self.counts[topic],
            } for topic, (_, typename, qos) in self._channels.items()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.path.name],
            "files": [{"path": self.path.name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": total}],
            "custom_data": {},
            "ros_distro": "jazzy",
        }, sort_keys=False)

    def __enter__(self) -> "LogWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.finish()


class LogRecorder:
    """What the node logic records through: a :class:`LogWriter` that starts a new file on reset.

    A log holds one run from the scene's initial state on one simulation-time axis, so a reset (which
    sends the time back to 0) finishes the current file and opens ``<stem>_reset<n>.mcap`` beside it,
    with the run info of then (runtime parameters may have changed). ``paths`` lists every file written.
    """

    def __init__(self, path: str | Path, channels: Iterable[tuple[str, str, Qos]], run_info: Mapping[str, str]):
        self._channels = list(channels)
        self.paths = [Path(path)]
        self._writer = LogWriter(path, self._channels, run_info)

    @property
    def path(self) -> Path:
        return self.paths[-1]

    def record(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Append CDR ``data`` on ``topic`` at ``log_time_ns`` (see :meth:`LogWriter.write`)."""
        self._writer.write(topic, data, log_time_ns)

    def restart(self, run_info: Mapping[str, str]) -> Path:
        """Finish this file and start the next, embedding ``run_info``; returns its path."""
        self._writer.finish()
        first = self.paths[0]
        self.paths.append(first.with_name(f"{first.stem}_reset{len(self.paths)}{first.suffix}"))
        self._writer = LogWriter(self.paths[-1], self._channels, run_info)
        return self.paths[-1]

    def finish(self) -> None:
        self._writer.finish()

    def __enter__(self) -> "LogRecorder":
        return self

    def __exit__(self, *exc) -> None:
        self.finish()


class SignalLatch:
    """While active (a context manager, main thread), SIGINT and SIGTERM only set :attr:`signum`; the
    loop calls :meth:`raise_if_signalled` at a safe point, which raises ``KeyboardInterrupt`` for SIGINT
    and ``SystemExit(128 + signum)`` for SIGTERM, so a log is never cut inside a write and is finished by
    the ``with`` blocks the exception leaves."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.signum: int | None = None
        self._previous: dict[int, object] = {}

    def _handler(self, signum, frame) -> None:
        self.signum = signum

    def raise_if_signalled(self) -> None:
        if self.signum == signal.SIGINT:
            raise KeyboardInterrupt
        if self.signum is not None:
            raise SystemExit(128 + self.signum)

    def __enter__(self) -> "SignalLatch":
        for s in self.SIGNALS:
            self._previous[s] = signal.signal(s, self._handler)
        return self

    def __exit__(self, exc_type, *exc) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        if exc_type is None:  # a signal that came after the last safe point is not lost
            self.raise_if_signalled()
