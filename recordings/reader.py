"""Reading recordings back: tolerant of files without a footer (a killed recorder), of
rotated parts, and of samples that do not decode (they come back as data, not exceptions).

mcap's ``make_reader`` needs the footer (its seeking reader starts from the summary), so this
module scans records from the start with mcap's ``StreamReader`` and stops quietly at the first
record that is cut short or corrupt: everything flushed before the kill is recovered.
"""

from __future__ import annotations

import json
import struct
import zlib
from io import BytesIO
from dataclasses import dataclass, field
from pathlib import Path
from collections import Counter
from typing import Any, Iterable, Iterator

from mcap.exceptions import McapError
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, MessageIndex, Metadata, Schema
from mcap.stream_reader import StreamReader

from bus.envelope import Envelope
from bus.errors import UsageError

from .meta import METADATA_NAME, from_mcap, merge
from .schemas import kind_of
from .stats import Tally

# What a cut-short or corrupt file raises from mcap's reader (EndOfFile is a McapError;
# struct.error for a cut length field; OverflowError or MemoryError for a huge one).
_TRUNCATION_ERRORS: tuple[type[BaseException], ...] = (McapError, struct.error, ValueError,
                                                       EOFError, RuntimeError, MemoryError,
                                                       OverflowError)
MAGIC = b"\x89MCAP0\r\n"


class NotMcap(UsageError):
    """A file that does not start with the MCAP magic (exit 2 in the CLI)."""


@dataclass(frozen=True)
class Damage:
    """A chunk that could not be read (torn compression, CRC, a record past its end): skipped."""

    path: Path
    offset: int  # of the chunk record in the file
    lost: int | None  # messages in it, from the message indexes after it (None: unknown)
    reason: str

    def describe(self) -> str:
        lost = "an unknown number of" if self.lost is None else str(self.lost)
        return f"{self.path}: damaged chunk at byte {self.offset} skipped ({self.reason}): {lost} message(s) lost"


_decode_json = json.JSONDecoder().decode  # payloads are UTF-8: skip json.loads' encoding sniffing


@dataclass(frozen=True)
class Sample:
    """One recorded message."""

    topic: str  # key relative to the fleet root, "frame/side/m3.comm"
    log_time_ns: int
    publish_time_ns: int
    data: bytes  # the payload exactly as it was on the bus
    sequence: int = 0

    def json(self) -> Any:
        """The decoded payload (``ValueError`` if it is not UTF-8 JSON)."""
        return _decode_json(self.data.decode("utf-8"))

    def decode(self) -> Any:
        """The typed value: an Envelope, a bus.messages record, or a dict for other topics
        (the protobuf bytes as they are for a derived Foxglove channel)."""
        kind = kind_of(self.topic)
        if kind.foxglove:
            return self.data
        return kind.decode(self.json())


@dataclass(frozen=True)
class Undecodable:
    """A sample whose payload does not decode as its channel's type (errors are data)."""

    sample: Sample
    reason: str


def parts_of(path: str | Path) -> list[Path]:
    """The files of a recording: ``run.mcap`` itself, or its rotated parts ``run_0001.mcap``..."""
    p = Path(path)
    if p.exists():
        return [p]
    parts = sorted(p.parent.glob(f"{p.stem}_[0-9][0-9][0-9][0-9]{p.suffix or '.mcap'}"))
    if not parts:
        raise FileNotFoundError(f"no recording {p} (nor rotated parts {p.stem}_0001{p.suffix})")
    return parts


class RecordingFile:
    """A sequential scan of one MCAP file that survives truncation.

    After :meth:`samples` has run to its end, ``complete`` tells whether the footer was
    reached, ``truncated`` whether the scan stopped early (with ``error`` saying why), and
    ``metadata`` holds the metadata records seen, in file order.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.complete = False
        self.truncated = False
        self.error = ""
        self.metadata: list[tuple[str, dict[str, str]]] = []
        self.channels: dict[int, Channel] = {}
        self.schemas: dict[int, Schema] = {}
        self.compression: set[str] = set()
        self.damaged: list[Damage] = []

    def samples(self, topics: Iterable[str] | None = None, *, derived: bool = False) -> Iterator[Sample]:
        """Messages in file order (for our files: the order they were recorded).

        The channels the recorder derives for Foxglove (protobuf, not bus samples) come only
        with ``derived=True`` or when ``topics`` names them."""
        wanted = None if topics is None else set(topics)

        def keep(ch: Channel) -> bool:
            return ch.topic in wanted if wanted is not None else derived or ch.message_encoding == "json"

        size = self.path.stat().st_size
        with open(self.path, "rb") as f:
            if f.read(len(MAGIC)) != MAGIC:
                raise NotMcap(f"{self.path} is not an MCAP file (it does not start with the MCAP magic)")
            f.seek(0)
            reader = StreamReader(f, emit_chunks=True, record_size_limit=max(size, 1))
            records = reader.records
            last_damage: list[Any] = []  # [offset, lost, reason] of the chunk just skipped
            while True:
                offset = f.tell()
                try:
                    record = next(records)
                except StopIteration:  # the footer and the closing magic were read
                    self.complete = True
                    self._damaged(last_damage)
                    return
                except _TRUNCATION_ERRORS as exc:
                    self.truncated = True
                    self.error = f"{type(exc).__name__}: {exc}".rstrip(": ")
                    self._damaged(last_damage)
                    return
                if isinstance(record, MessageIndex):
                    if last_damage:  # the index of a skipped chunk counts what it held
                        last_damage[1] = (last_damage[1] or 0) + len(record.records)
                    continue
                self._damaged(last_damage)
                try:
                    inner = self._unpack(record)
                except Exception as exc:  # zstd, lz4, CRC, a record past the chunk's end
                    if not isinstance(record, Chunk):
                        raise
                    last_damage[:] = [offset, None, f"{type(exc).__name__}: {exc}".rstrip(": ")[:200]]
                    continue
                channels = self.channels
                for rec in inner:
                    if type(rec) is tuple:  # a message: (channel id, sequence, log, publish, data)
                        ch = channels.get(rec[0])
                        if ch is None:
                            continue  # a message before its channel: not written by us
                        if keep(ch):
                            yield Sample(ch.topic, rec[2], rec[3], rec[4], rec[1])
                    elif isinstance(rec, Message):
                        ch = channels.get(rec.channel_id)
                        if ch is not None and keep(ch):
                            yield Sample(ch.topic, rec.log_time, rec.publish_time, rec.data, rec.sequence)

    def _damaged(self, last: list[Any]) -> None:
        if last:
            self.damaged.append(Damage(self.path, last[0], last[1], last[2]))
            last.clear()

    def _unpack(self, record: Any) -> list[Any]:
        """Records of a top-level record (a chunk's contents, CRC-checked), tracking state.
        Messages inside chunks come back as plain tuples (see :func:`chunk_records`)."""
        if isinstance(record, Chunk):
            self.compression.add(record.compression or "none")
            inner = chunk_records(record)
        else:
            inner = [record]
        for rec in inner:
            if isinstance(rec, Channel):
                self.channels[rec.id] = rec
            elif isinstance(rec, Schema):
                self.schemas[rec.id] = rec
            elif isinstance(rec, Metadata):
                self.metadata.append((rec.name, dict(rec.metadata)))
        return inner


_RECORD_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")


def chunk_records(chunk: Chunk) -> list[Any]:
    """The records of a chunk, CRC-checked: messages as ``(channel id, sequence, log time,
    publish time, data)`` tuples (mcap's ``breakup_chunk`` builds a record object through a
    stream per field: several times slower), schemas and channels as mcap records."""
    data = _decompress(chunk)
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError(f"chunk CRC mismatch at log time {chunk.message_start_time}")
    out: list[Any] = []
    append = out.append
    i, n = 0, len(data)
    head, message = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
    while i < n:
        opcode, length = head(data, i)
        i += 9
        end = i + length
        if end > n:
            raise ValueError("a record runs past the end of its chunk")
        if opcode == Opcode.MESSAGE:
            append((*message(data, i), data[i + 22:end]))
        elif opcode in (Opcode.CHANNEL, Opcode.SCHEMA):
            stream = ReadDataStream(BytesIO(data[i:end]))
            append(Channel.read(stream) if opcode == Opcode.CHANNEL else Schema.read(stream))
        i = end
    return out


def _decompress(chunk: Chunk) -> bytes:
    if chunk.compression == "zstd":
        import zstandard
        return zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    if chunk.compression == "lz4":
        import lz4.frame
        return lz4.frame.decompress(chunk.data)
    if chunk.compression:
        raise ValueError(f"unknown chunk compression {chunk.compression!r}")
    return bytes(chunk.data)


# --- convenience iterators -------------------------------------------------------------------
def iter_samples(path: str | Path, topics: Iterable[str] | None = None, *, derived: bool = False) -> Iterator[Sample]:
    """All samples of a recording (every part), in recorded order (``derived``: with the
    channels the recorder derives for Foxglove, see :meth:`RecordingFile.samples`)."""
    topics = None if topics is None else list(topics)
    for part in parts_of(path):
        yield from RecordingFile(part).samples(topics, derived=derived)


def iter_records(path: str | Path) -> Iterator[tuple[Sample, Any]]:
    """``(sample, typed value)`` pairs; a value that does not decode is an :class:`Undecodable`."""
    for s in iter_samples(path):
        try:
            yield s, s.decode()
        except (ValueError, TypeError, KeyError) as exc:
            yield s, Undecodable(s, f"{type(exc).__name__}: {exc}")


def read_frames(path: str | Path) -> Iterator[Envelope]:
    """Every frame envelope, in recorded order, recovering what a truncated file holds."""
    for s in iter_samples(path):
        if s.topic.startswith("frame/"):
            try:
                yield Envelope.from_json(s.data)
            except (ValueError, TypeError, KeyError):
                continue  # counted as undecodable by summary(); iter_records() shows it


def run_metadata(files: Iterable[RecordingFile]) -> dict[str, Any]:
    """The run's metadata from scanned files (every ``hexbench`` record, later ones win)."""
    out: dict[str, Any] = {}
    for rf in files:
        for name, data in rf.metadata:
            if name == METADATA_NAME:
                out = merge(out, from_mcap(data))
    return out


def sim_origin(meta: dict[str, Any]) -> int:
    """What to subtract from a sim-time recording's log times to get sim times: its start
    instant (0 for a wall-time recording, or one older than start instants)."""
    if meta.get("log_time", "sim") != "sim":
        return 0
    try:
        return int(meta.get("start_time_ns") or 0)
    except (TypeError, ValueError):
        return 0


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The run's metadata (scans the files: metadata may follow any chunk)."""
    files = [RecordingFile(p) for p in parts_of(path)]
    for rf in files:
        for _ in rf.samples(topics=()):
            pass
    return run_metadata(files)


# --- summary -----------------------------------------------------------------------------------
@dataclass
class Summary:
    """What ``hexbench info`` prints."""

    paths: list[Path]
    tally: Tally
    metadata: dict[str, Any]
    complete: bool  # every part has its footer
    truncated: list[str] = field(default_factory=list)  # "path: why" of parts cut short
    damaged: list[Damage] = field(default_factory=list)  # chunks skipped
    undecodable: int = 0
    compression: list[str] = field(default_factory=list)
    channels: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    #: Messages of the channels the recorder derives for Foxglove, per topic: not bus
    #: samples, so not in the tally (the recorder's and the reader's tallies agree).
    derived: Counter[str] = field(default_factory=Counter)

    @property
    def duration_s(self) -> float:
        return self.tally.duration_ns / 1e9

    def messages_on(self, topic: str) -> int:
        """How many messages the recording holds on ``topic`` (a bus topic or a derived one)."""
        return self.tally.by_topic.get(topic, 0) + self.derived.get(topic, 0)

    def to_dict(self) -> dict[str, Any]:
        return {"paths": [str(p) for p in self.paths], "complete": self.complete,
                "truncated": self.truncated, "damaged": [d.describe() for d in self.damaged], "duration_s": self.duration_s,
                "undecodable": self.undecodable, "compression": self.compression,
                "metadata": self.metadata, "channels": self.channels,
                "derived_by_topic": dict(sorted(self.derived.items())), **self.tally.to_dict()}


def summary(path: str | Path) -> Summary:
    """Scan a recording (all parts, truncated or not) and count what it holds."""
    tally = Tally()
    meta: dict[str, Any] = {}
    paths = parts_of(path)
    out = Summary(paths, tally, meta, complete=True)
    compression: set[str] = set()
    for part in paths:
        rf = RecordingFile(part)
        for s in rf.samples(derived=True):
            if kind_of(s.topic).foxglove:  # protobuf of the recorder's own: counted apart
                out.derived[s.topic] += 1
                continue
            try:
                obj = s.json()
            except ValueError:
                obj = None
                out.undecodable += 1
            tally.add(s.topic, obj, s.log_time_ns)
        meta = merge(meta, run_metadata([rf]))
        for ch in rf.channels.values():
            out.channels[ch.topic] = kind_of(ch.topic).name or "(schemaless json)"
        compression |= rf.compression
        if not rf.complete:
            out.complete = False
        if rf.truncated:
            out.truncated.append(f"{part}: {rf.error or 'no footer'}")
        out.damaged += rf.damaged
    out.metadata = meta
    out.compression = sorted(compression)
    return out
