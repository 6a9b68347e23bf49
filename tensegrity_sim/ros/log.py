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

**Crash safety.** What a crash that finishes nothing (SIGKILL, a power cut) can lose is bounded: messages
wait in memory until :data:`PENDING_SIZE` bytes of them wait, then go into the chunk in progress together;
a chunk is written out when it holds :data:`CHUNK_SIZE` bytes; and when :data:`FLUSH_PERIOD` seconds of
wall-clock time have passed since the last write-out, the waiting messages and the chunk, however small,
are written out and synced to the disk. Everything before the chunk in progress is complete on disk, so a
crash loses at most PENDING_SIZE + CHUNK_SIZE = 20 KiB of messages and FLUSH_PERIOD s of wall-clock time.
The sync (``os.fsync``, ~0.7 ms on the project's machine, against a node's median tick of ~0.2 ms) runs on a
thread of its own, so the tick that writes the chunk out does not wait for the disk (issue 28); the next
flush, and finishing, take its failure as the write's. Chunk CRCs and the data-section CRC are written, so a
reader can tell a damaged record from a cut-off one. ``tensegrity-sim info`` and ``replay`` read such an
unfinished log up to its last complete record, and ``tensegrity-sim recover`` writes a finished copy
(:mod:`.log_reader`). A write that fails (a full disk, a file-size limit) raises :class:`LogWriteError`
naming the file, what failed and what the file keeps; the file is then closed without a summary, as a
crash would leave it, and can be recovered.
"""
from __future__ import annotations

import errno
import os
import signal
import stat
import time
from concurrent.futures import Future, ThreadPoolExecutor
from datetime import datetime
from functools import cache
from pathlib import Path
from typing import Iterable, Mapping, NoReturn

import yaml
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from .. import __version__
from . import messages as M
from .interface import Qos

__all__ = ["RUN_INFO", "LogWriter", "LogWriteError", "LogRecorder", "SignalLatch", "log_file_path",
           "qos_profiles_yaml", "CHUNK_SIZE", "PENDING_SIZE", "FLUSH_PERIOD", "FLUSH_AHEAD"]

RUN_INFO = "tensegrity_sim"   # name of the metadata record that makes a log re-runnable
ROSBAG2_METADATA_VERSION = 9  # Jazzy
_INFINITE = {"sec": 9223372036, "nsec": 854775807}  # RMW_DURATION_INFINITE, as rosbag2 records it
# Crash safety (module docstring): the most a crash can lose is the messages waiting (at most PENDING_SIZE
# bytes) and one chunk in progress (at most CHUNK_SIZE bytes): 20 KiB, tens of publications of a small scene,
# and at most FLUSH_PERIOD s of wall-clock time. Messages wait because mcap's writer takes several in one run
# faster than one at a time (its Python code stays in the CPU's caches: ~0.5 us a step of the node path's ~10 us
# with 16 KiB waiting, issue 13). But a node pays for them in the tick that hands them on: with 16 KiB waiting
# and 64 KiB chunks that tick took 0.35-0.75 ms more (a chunk written out: 0.38 ms): 40 of the 48 ticks over
# 1 ms in 30,000 steps of bench_node's roll, logged at 100 Hz, in one process. With 4 KiB and 16 KiB, the same
# steps: 9-12 ticks over 1 ms, p99.9 0.80 ms against 1.08 (issue 28).
CHUNK_SIZE = 16 * 1024   # bytes (mcap's default: 1 MiB)
PENDING_SIZE = 4 * 1024  # bytes
FLUSH_PERIOD = 1.0       # s
FLUSH_AHEAD = 0.1        # s before the flush period ends that drain() does the write-out


class LogWriteError(OSError):
    """The log cannot be written (a bad path, a full disk...): the message names the file, the reason and
    what the file keeps."""


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
    """Where a log goes: ``spec`` ending in ``.mcap``, or naming something that exists and is not a
    directory (``/dev/null``), is the file; any other non-empty ``spec`` is a directory that gets
    ``<scene>_<YYYYmmdd-HHMMSS>.mcap`` (``_1``, ``_2``... if taken); "" means no log."""
    if not spec:
        return None
    path = Path(spec)
    if path.suffix == ".mcap" or (path.exists() and not path.is_dir()):
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
    chunk_size, pending_size (bytes), flush_period (s, None: never): the crash-safety bounds (module
    docstring).
    clock(): monotonic wall-clock seconds, for the flush period.
    Opening writes the header and the run info at once, so a path that cannot be written is refused here
    (:class:`LogWriteError`), before a run starts.
    """

    def __init__(self, path: str | Path, channels: Iterable[tuple[str, str, Qos]], run_info: Mapping[str, str],
                 *, chunk_size: int = CHUNK_SIZE, pending_size: int = PENDING_SIZE,
                 flush_period: float | None = FLUSH_PERIOD, clock=time.monotonic):
        self.path = Path(path)
        self.counts: dict[str, int] = {}
        self._finished = False
        self._file = None
        self._syncer: ThreadPoolExecutor | None = None   # the disk syncs' thread (started by the first flush)
        self._sync: Future | None = None                 # the last sync handed to it
        try:
            blocking = next((p for p in self.path.parents if p.exists() and not p.is_dir()), None)
            if blocking is not None:  # mkdir would only say "File exists"
                raise NotADirectoryError(errno.ENOTDIR, f"{blocking} is not a directory")
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "wb")
            # a device such as /dev/null has no disk to sync to (fsync refuses it)
            self._on_disk = stat.S_ISREG(os.fstat(self._file.fileno()).st_mode)
            self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.NONE,
                                  enable_data_crcs=True)
            self._writer.start(profile="ros2", library=f"tensegrity_sim {__version__}; {LIBRARY_IDENTIFIER}")
            self._writer.add_metadata(RUN_INFO, dict(run_info))
            self._file.flush()
        except OSError as exc:
            self._close_quietly()
            self._finished = True
            raise LogWriteError(f"{self.path}: cannot write the log: {exc.strerror or exc}") from None
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
        self._channel_ids = {topic: channel[0] for topic, channel in self._channels.items()}
        self.counts = {topic: 0 for topic in self._channels}
        self._start: int | None = None
        self._end = 0
        self._clock = clock
        self._flush_period = flush_period
        self._next_flush = clock() + flush_period if flush_period is not None else None
        self._pending: list[tuple[int, str, bytes, int]] = []  # (channel id, topic, data, log time) waiting
        self._pending_bytes = 0
        self._pending_size = pending_size

    def write(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Append ``data`` (a message of the topic's type in CDR, encapsulation header first, as
        :func:`.messages.serialize` gives it) at ``log_time_ns``. Raises :class:`LogWriteError` if the file
        cannot take it (it then keeps every chunk written before)."""
        self.write_all(((topic, data),), log_time_ns)

    def write_all(self, records: Iterable[tuple[str, bytes]], log_time_ns: int) -> None:
        """Append every ``(topic, data)`` of ``records`` in turn at ``log_time_ns``, as :meth:`write` does
        one: the same file as that many :meth:`write` calls (a publication's outputs at once). They wait in
        memory with the messages before them until the crash-safety bounds send them on (module
        docstring); a :class:`LogWriteError` may so come from a later call than the message it names."""
        pending, ids = self._pending, self._channel_ids
        for topic, data in records:
            pending.append((ids[topic], topic, data, log_time_ns))
            self._pending_bytes += len(data)
        if self._start is None:
            self._start = log_time_ns
        if log_time_ns > self._end:
            self._end = log_time_ns
        flush = self._next_flush is not None and self._clock() >= self._next_flush
        if flush or self._pending_bytes >= self._pending_size:
            self._drain(flush)

    def drain(self) -> None:
        """Hand the waiting messages to mcap's writer now (a chunk that fills is written out), rather than
        when the crash-safety bounds would, and write out and sync the chunk in progress if the flush period
        ends within :data:`FLUSH_AHEAD` s: what a node does in the idle time between its ticks, called often
        enough that the write that would find the flush due (inside a tick) rarely does."""
        flush = self._next_flush is not None and self._clock() >= self._next_flush - FLUSH_AHEAD
        if self._pending or flush:
            self._drain(flush)

    def _drain(self, flush: bool) -> None:
        """Hand the waiting messages to mcap's writer in turn; with ``flush``, then write the chunk in
        progress out, however small, and sync the file to the disk."""
        add, counts = self._writer.add_message, self.counts
        pending, self._pending, self._pending_bytes = self._pending, [], 0
        log_time_ns = self._end
        try:
            for channel_id, topic, data, log_time_ns in pending:
                sequence = counts[topic]
                add(channel_id, log_time_ns, data, log_time_ns, sequence)
                counts[topic] = sequence + 1
            if flush:
                self._writer.flush()          # the chunk in progress, however small, goes out
                self._synced(wait=False)
                if self._sync is None and self._on_disk:   # and to the disk, not only the OS, beside the caller
                    if self._syncer is None:
                        self._syncer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="log-sync")
                    self._sync = self._syncer.submit(os.fsync, self._file.fileno())
                self._next_flush = self._clock() + self._flush_period
        except OSError as exc:
            self._failed(exc, log_time_ns)

    def _stop_syncer(self) -> None:
        """Wait for the sync thread to finish its work, and end it."""
        if self._syncer is not None:
            self._syncer.shutdown(wait=True)
            self._syncer = None

    def _synced(self, wait: bool) -> None:
        """Take the last disk sync's outcome if it is over (``wait``: wait for it): raises its ``OSError``.
        A sync still running is left to run (the next flush does not start another beside it)."""
        sync = self._sync
        if sync is None or not (wait or sync.done()):
            return
        self._sync = None
        sync.result()

    def _failed(self, exc: OSError, log_time_ns: int) -> NoReturn:
        """A write failed: close the file as a crash would leave it and raise :class:`LogWriteError`."""
        self._finished = True
        self._close_quietly()
        total = sum(self.counts.values())
        raise LogWriteError(f"{self.path}: writing the log failed at t = {log_time_ns * 1e-9:.6f} s after {total} "
                            f"messages: {exc.strerror or exc}; the file keeps the messages written before the last "
                            f"chunk (tensegrity-sim recover {self.path} OUT.mcap makes a finished copy)") from None

    def _close_quietly(self) -> None:
        """Close the file, whatever the buffered bytes still in it meet (a full disk fails them again), once
        the sync thread is done with it."""
        self._stop_syncer()
        if self._file is not None:
            try:
                self._file.close()
            except OSError:
                pass

    def finish(self) -> None:
        """Write the rosbag2 metadata and the summary and close the file; later calls do nothing."""
        if self._finished:
            return
        self._drain(False)
        self._finished = True
        try:
            self._synced(wait=True)
            self._writer.add_metadata("rosbag2", {"serialized_metadata": self._rosbag2_metadata()})
            self._writer.finish()
            self._stop_syncer()
            self._file.close()
        except OSError as exc:
            self._failed(exc, self._end)

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

    def record(self, records: Iterable[tuple[str, bytes]], log_time_ns: int) -> None:
        """Append every (topic, CDR data) of ``records`` at ``log_time_ns`` (see :meth:`LogWriter.write_all`)."""
        self._writer.write_all(records, log_time_ns)

    def drain(self) -> None:
        """:meth:`LogWriter.drain` on the current file."""
        self._writer.drain()

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
