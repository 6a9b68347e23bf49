"""Reading a log record by record, finished or not, checking every CRC; recovering an unfinished one.

mcap's own readers need the summary at the end of a file (the seeking reader) or give nothing back for a
file cut off in the middle (the non-seeking reader, in its default time order). A log cut off by a crash
(SIGKILL, a power cut, a full disk: see :mod:`.log`) still holds every chunk written before the one in
progress, so :class:`LogReader` walks the data section itself, with mcap's record parsers:

* a record that ends past the end of an unfinished file is where the writer was cut off: reading stops
  there and :attr:`LogReader.unfinished` says what was read (a finished file, one that ends in the MCAP
  magic, has no such excuse: there it is corruption);
* a finished file's data-section and summary CRCs are checked first, so a damaged record is found before
  anything of the file is used; every chunk's CRC is checked as it is read; a record that fails a check or
  does not parse raises :class:`LogCorruptError` with its byte offset and the topics it holds. (An
  unfinished file has no data-section CRC yet: its chunks are checked, the records between them are not.)

:func:`recover` copies what an unfinished log holds into a finished log (:class:`~.log.LogWriter`: summary,
statistics, rosbag2 metadata), which every MCAP reader opens.
"""
from __future__ import annotations

import io
import json
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import yaml
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import MAGIC_SIZE, CRCValidationError, breakup_chunk
from mcap.writer import MCAP0_MAGIC

from .log import RUN_INFO, LogWriter
from .interface import TOPICS, Qos

__all__ = ["LogError", "LogCorruptError", "LogReader", "LogMessage", "log_channels", "recover"]

_PARSERS = {Opcode.HEADER: Header.read, Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read,
            Opcode.CHUNK: Chunk.read, Opcode.METADATA: Metadata.read, Opcode.DATA_END: DataEnd.read,
            Opcode.FOOTER: Footer.read}
_RECORD_HEADER = 9  # opcode (1 byte) and length (8 bytes)
_FOOTER = _RECORD_HEADER + 8 + 8 + 4   # summary start, summary offset start, summary CRC
_DATA_END = _RECORD_HEADER + 4         # data section CRC


class LogError(ValueError):
    """A file that is not a readable tensegrity_sim log; the message names the file and the reason."""


class LogCorruptError(LogError):
    """A record of a log that fails its CRC or does not parse: ``offset`` is its byte position, ``topics``
    the topics of the messages it holds (empty if that cannot be told)."""

    def __init__(self, message: str, offset: int, topics: tuple[str, ...] = ()):
        super().__init__(message)
        self.offset = offset
        self.topics = topics


@dataclass(frozen=True)
class LogMessage:
    """One message as the log holds it: ``topic``, ``log_time`` ns, ``data`` (CDR bytes), ``sequence``;
    ``position`` says where: ``"byte N"`` of its chunk, and its index in the chunk."""

    topic: str
    log_time: int
    data: bytes
    sequence: int
    position: str


class LogReader:
    """The records of the MCAP log at ``path``, in file order (see the module docstring).

    After construction, :attr:`metadata` holds the metadata records met before the first chunk (the run
    info is written first) and :attr:`channels` the channels by id. :meth:`messages` then yields every
    message; when it is done, :attr:`finished` says whether the file was finished and :attr:`unfinished`
    describes where an unfinished one was cut off (None for a finished one).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            self._file = open(self.path, "rb")
            self.size = self.path.stat().st_size
        except OSError as exc:
            raise LogError(f"{self.path}: cannot read: {exc.strerror}") from None
        if self._file.read(MAGIC_SIZE) != MCAP0_MAGIC:
            self._file.close()
            raise LogError(f"{self.path}: not an MCAP file (it does not start with the MCAP magic)")
        self.finished = False  # a finished file also ends in the magic
        if self.size >= 2 * MAGIC_SIZE:
            self._file.seek(self.size - MAGIC_SIZE)
            self.finished = self._file.read(MAGIC_SIZE) == MCAP0_MAGIC
        try:
            if self.finished:
                self._check_sections()
            self._start()
            # up to the first chunk (header, run info), and that chunk's schemas and channels: the writer
            # registers every channel before the first message
            for offset, record in self._records:
                if isinstance(record, Chunk):
                    self._pending = (offset, self._unpack(offset, record))
                    break
        except LogError:
            self._file.close()
            raise

    def _start(self) -> None:
        """Back to the first record."""
        self._file.seek(MAGIC_SIZE)
        self._crc = zlib.crc32(MCAP0_MAGIC)
        self.offset = MAGIC_SIZE       # bytes read and checked so far
        self.metadata: dict[str, dict[str, str]] = {}
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.unfinished: str | None = None
        self.messages_read = 0
        self._pending: tuple[int, list] | None = None
        self._records = self._top_level()

    def _crc_of(self, start: int, end: int) -> int:
        """CRC-32 of the file's bytes ``[start, end)``."""
        self._file.seek(start)
        crc, left = 0, end - start
        while left > 0:
            block = self._file.read(min(left, 1 << 20))
            if not block:
                break
            crc, left = zlib.crc32(block, crc), left - len(block)
        return crc

    def _check_sections(self) -> None:
        """A finished file: its data section and its summary against their CRCs (in the data end record and
        the footer). A damaged data section is then walked chunk by chunk to name the damaged record."""
        footer_at = self.size - MAGIC_SIZE - _FOOTER
        self._file.seek(footer_at)
        footer = self._file.read(_FOOTER)
        if footer_at < MAGIC_SIZE or footer[0] != Opcode.FOOTER:
            raise self._corrupt(max(footer_at, 0), "the footer is damaged")
        summary_start, _, summary_crc = struct.unpack_from("<QQI", footer, _RECORD_HEADER)
        data_end_at = (summary_start or footer_at) - _DATA_END
        if not MAGIC_SIZE <= data_end_at <= footer_at - _DATA_END:
            raise self._corrupt(footer_at, f"the footer is damaged (summary start {summary_start})")
        self._file.seek(data_end_at)
        data_end = self._file.read(_DATA_END)
        if data_end[0] != Opcode.DATA_END:
            raise self._corrupt(data_end_at, "the data end record is damaged")
        stored = struct.unpack_from("<I", data_end, _RECORD_HEADER)[0]
        if stored and self._crc_of(0, data_end_at) != stored:
            # walk it: a damaged chunk raises with its place and topics, else the data end's check does
            self._start()
            for offset, record in self._records:
                if isinstance(record, Chunk):
                    self._unpack(offset, record)
        if summary_start and summary_crc and self._crc_of(summary_start, footer_at + _FOOTER - 4) != summary_crc:
            raise self._corrupt(summary_start, "the summary section (indexes, statistics) fails its CRC: other "
                                               "readers may misread the file (tensegrity-sim recover rewrites it)")

    def __enter__(self) -> "LogReader":
        return self

    def __exit__(self, *exc) -> None:
        self._file.close()

    # ------------------------------------------------------------------ records
    def _corrupt(self, offset: int, what: str, topics: tuple[str, ...] = ()) -> LogCorruptError:
        on = f" (messages on {', '.join(topics)})" if topics else ""
        return LogCorruptError(f"{self.path}: corrupt record at byte {offset}{on}: {what}", offset, topics)

    def _top_level(self) -> Iterator[tuple[int, object]]:
        """(offset, record) of every record of the data section that matters here; stops at the data end,
        or where an unfinished file was cut off."""
        while True:
            offset = self.offset
            head = self._file.read(_RECORD_HEADER)
            if len(head) < _RECORD_HEADER or offset + _RECORD_HEADER + struct.unpack_from("<Q", head, 1)[0] > self.size:
                if self.finished:
                    raise self._corrupt(offset, "a record runs past the end of the file")
                self.unfinished = (f"unfinished log (not closed by its writer): read up to byte {offset} of "
                                   f"{self.size}, the last complete record")
                return
            opcode, length = head[0], struct.unpack_from("<Q", head, 1)[0]
            body = self._file.read(length)
            if opcode == Opcode.DATA_END:
                record = self._parse(offset, opcode, body)
                if record.data_section_crc not in (0, self._crc):
                    raise self._corrupt(offset, f"the data section fails its CRC (stored "
                                                f"{record.data_section_crc:#010x}, computed {self._crc:#010x}) while "
                                                f"every chunk passes its own: a record outside the chunks (the header, "
                                                f"the run info) is damaged")
                self.offset += _RECORD_HEADER + length
                return
            self._crc = zlib.crc32(body, zlib.crc32(head, self._crc))
            self.offset += _RECORD_HEADER + length
            if opcode in _PARSERS:
                record = self._parse(offset, opcode, body)
                if isinstance(record, Metadata):
                    self.metadata[record.name] = dict(record.metadata)
                else:
                    self._register(record)
                yield offset, record

    def _parse(self, offset: int, opcode: int, body: bytes):
        try:
            stream = ReadDataStream(io.BytesIO(body))
            return _PARSERS[opcode](stream)
        except (McapError, struct.error, UnicodeDecodeError, ValueError, IndexError) as exc:
            raise self._corrupt(offset, f"a {Opcode(opcode).name} record that does not parse "
                                        f"({type(exc).__name__}: {exc})") from None

    def _register(self, record) -> None:
        if isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            self.channels[record.id] = record

    def _chunk_topics(self, chunk: Chunk) -> tuple[str, ...]:
        """The topics of a damaged chunk's messages, as far as its records still parse."""
        try:
            records = breakup_chunk(chunk, validate_crc=False)
        except Exception:  # noqa: BLE001 - a damaged chunk may fail anywhere; the topics are only a hint
            return ()
        ids = {r.channel_id for r in records if isinstance(r, Message)}
        channels = {**self.channels, **{r.id: r for r in records if isinstance(r, Channel)}}
        return tuple(sorted(channels[i].topic for i in ids if i in channels))

    def _unpack(self, offset: int, chunk: Chunk) -> list:
        """The records of a chunk, its CRC checked; its schemas and channels registered."""
        try:
            inner = breakup_chunk(chunk, validate_crc=True)
        except Exception as exc:  # noqa: BLE001 - a CRC mismatch, or a chunk whose records do not parse
            what = ("its CRC does not match" if isinstance(exc, CRCValidationError)
                    else f"its records do not parse ({type(exc).__name__}: {exc})")
            raise self._corrupt(offset, f"chunk of t = {chunk.message_start_time * 1e-9:.6f} to "
                                        f"{chunk.message_end_time * 1e-9:.6f} s: {what}",
                                self._chunk_topics(chunk)) from None
        for r in inner:
            self._register(r)
        return inner

    def messages(self) -> Iterator[LogMessage]:
        """Every message, in file order (the order the node wrote them)."""
        chunks = [self._pending] if self._pending is not None else []
        self._pending = None
        chunks = _chain(chunks, ((offset, self._unpack(offset, record)) for offset, record in self._records
                                 if isinstance(record, Chunk)))
        for offset, inner in chunks:
            index = 0
            for r in inner:
                if isinstance(r, Message):
                    channel = self.channels.get(r.channel_id)
                    if channel is None:
                        raise self._corrupt(offset, f"message {index} of the chunk names channel {r.channel_id}, "
                                                    f"which the log never defined")
                    yield LogMessage(channel.topic, r.log_time, bytes(r.data), r.sequence,
                                     f"byte {offset} (message {index} of its chunk)")
                    self.messages_read += 1
                    index += 1


def _chain(first, rest):
    yield from first
    yield from rest


def log_channels(reader: LogReader) -> list[tuple[str, str, Qos]]:
    """(topic, type name, QoS) of every channel ``reader`` has met: what a :class:`~.log.LogWriter` of a copy
    of the log takes."""
    channels = []
    for channel in reader.channels.values():
        profile = (yaml.safe_load(channel.metadata.get("offered_qos_profiles", "")) or [{}])[0]
        qos = Qos(reliability=profile.get("reliability", "reliable"), depth=profile.get("depth", 10),
                  durability=profile.get("durability", "volatile"))
        channels.append((channel.topic, reader.schemas[channel.schema_id].name, qos))
    return channels


def recover(source: str | Path, target: str | Path) -> tuple[int, str | None]:
    """Write a finished copy of the log ``source`` (finished or not) to ``target``: the run info, every
    channel with its QoS, every complete message in order; returns (messages copied, how the source was
    cut off or None). A corrupt record raises :class:`LogCorruptError`; nothing after it is copied."""
    if Path(target).resolve() == Path(source).resolve():
        raise LogError(f"{target}: the copy must go to another file than the log itself")
    with LogReader(source) as reader:
        run_info = reader.metadata.get(RUN_INFO)
        if run_info is None:
            raise LogError(f"{source}: no {RUN_INFO!r} metadata: not a tensegrity_sim log")
        channels = log_channels(reader)
        if not channels:  # cut off before its first chunk: the node's topics, as the run info names them
            names = json.loads(run_info.get("topics", "{}"))
            channels = [(names[k], spec.typename, spec.qos) for k, spec in TOPICS.items() if k in names]
        with LogWriter(target, channels, run_info) as writer:
            for message in reader.messages():
                writer.write(message.topic, message.data, message.log_time)
        return reader.messages_read, reader.unfinished
