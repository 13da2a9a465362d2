"""Reading recordings back: tolerant of files without a footer (a killed recorder), of
rotated parts, and of samples that do not decode (they come back as data, not exceptions).

mcap's ``make_reader`` needs the footer (its seeking reader starts from the summary), so this
module scans records from the start with mcap's ``StreamReader`` and stops quietly at the first
record that is cut short or corrupt: everything flushed before the kill is recovered.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, Message, Metadata
from mcap.stream_reader import StreamReader, breakup_chunk

from bus.envelope import Envelope

from .meta import METADATA_NAME, from_mcap, merge
from .schemas import kind_of
from .stats import Tally

# What a cut-short or corrupt file raises from mcap's reader (EndOfFile is a McapError;
# struct.error for a cut length field; zstd/lz4 raise their own errors on torn chunk data).
_TRUNCATION_ERRORS: tuple[type[BaseException], ...] = (McapError, struct.error, ValueError,
                                                       EOFError, RuntimeError, MemoryError)


@dataclass(frozen=True)
class Sample:
    """One recorded message."""

    topic: str  # key relative to the fleet root, "frame/side/m3.comm"
    log_time_ns: int
    publish_time_ns: int
    data: bytes  # the payload exactly as it was on the bus
    sequence: int = 0

    def json(self) -> Any:
        return json.loads(self.data)

    def decode(self) -> Any:
        """The typed value: an Envelope, a bus.messages record, or a dict for other topics."""
        return kind_of(self.topic).decode(self.json())


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
        self.compression: set[str] = set()

    def samples(self, topics: Iterable[str] | None = None) -> Iterator[Sample]:
        """Messages in file order (for our files: the order they were recorded)."""
        wanted = None if topics is None else set(topics)
        size = self.path.stat().st_size
        with open(self.path, "rb") as f:
            reader = StreamReader(f, emit_chunks=True, record_size_limit=max(size, 1))
            records = reader.records
            while True:
                try:
                    record = next(records)
                    inner = self._unpack(record)
                except StopIteration:  # the footer and the closing magic were read
                    self.complete = True
                    return
                except _TRUNCATION_ERRORS as exc:
                    self.truncated = True
                    self.error = f"{type(exc).__name__}: {exc}".rstrip(": ")
                    return
                for rec in inner:
                    if isinstance(rec, Message):
                        ch = self.channels.get(rec.channel_id)
                        if ch is None:
                            continue  # a message before its channel: not written by us
                        if wanted is None or ch.topic in wanted:
                            yield Sample(ch.topic, rec.log_time, rec.publish_time, rec.data, rec.sequence)

    def _unpack(self, record: Any) -> list[Any]:
        """Records of a top-level record (a chunk's contents, CRC-checked), tracking state."""
        if isinstance(record, Chunk):
            self.compression.add(record.compression or "none")
            inner = breakup_chunk(record, validate_crc=True)
        else:
            inner = [record]
        for rec in inner:
            if isinstance(rec, Channel):
                self.channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                self.metadata.append((rec.name, dict(rec.metadata)))
        return inner


# --- convenience iterators -------------------------------------------------------------------
def iter_samples(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[Sample]:
    """All samples of a recording (every part), in recorded order."""
    topics = None if topics is None else list(topics)
    for part in parts_of(path):
        yield from RecordingFile(part).samples(topics)


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
    undecodable: int = 0
    compression: list[str] = field(default_factory=list)
    channels: dict[str, str] = field(default_factory=dict)  # topic -> schema name

    @property
    def duration_s(self) -> float:
        return self.tally.duration_ns / 1e9

    def to_dict(self) -> dict[str, Any]:
        return {"paths": [str(p) for p in self.paths], "complete": self.complete,
                "truncated": self.truncated, "duration_s": self.duration_s,
                "undecodable": self.undecodable, "compression": self.compression,
                "metadata": self.metadata, "channels": self.channels, **self.tally.to_dict()}


def summary(path: str | Path) -> Summary:
    """Scan a recording (all parts, truncated or not) and count what it holds."""
    tally = Tally()
    meta: dict[str, Any] = {}
    paths = parts_of(path)
    out = Summary(paths, tally, meta, complete=True)
    compression: set[str] = set()
    for part in paths:
        rf = RecordingFile(part)
        for s in rf.samples():
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
    out.metadata = meta
    out.compression = sorted(compression)
    return out
