"""One open MCAP file: lazily registered schemas and channels, chunked and compressed."""

from __future__ import annotations

import json
from array import array
from pathlib import Path
from typing import Any, Callable, Mapping

from .mcap_writer import COMPRESSIONS, CompressionUnavailable, FastMcapWriter
from .meta import METADATA_NAME, STATS_NAME, to_mcap
from .schemas import ChannelKind, kind_of
from .stats import Tally

LIBRARY = "hexbench-recorder"
#: Default chunk size: large enough that zstd sees plenty of repetition and per-chunk costs
#: (index records, compression calls) vanish; the flush interval bounds what a crash loses.
CHUNK_SIZE = 1024 * 1024


def open_writer(stream: Any, compression: str, chunk_size: int) -> tuple[FastMcapWriter, str]:
    """A writer with ``compression`` if its package is installed, else the next one that is
    (in the order zstd, lz4, none)."""
    if compression not in COMPRESSIONS:
        raise ValueError(f"unknown compression {compression!r}: expected one of {', '.join(COMPRESSIONS)}")
    for name in COMPRESSIONS[COMPRESSIONS.index(compression):]:
        try:
            return FastMcapWriter(stream, chunk_size=chunk_size, compression=name), name
        except CompressionUnavailable:
            continue
    raise AssertionError("uncompressed MCAP is always available")  # pragma: no cover


class McapSink:
    """Writes samples of one recording part; channels appear when their first sample does."""

    def __init__(self, path: Path, *, fleet: str, compression: str = "zstd",
                 chunk_size: int = CHUNK_SIZE) -> None:
        self.path = path
        self.fleet = fleet
        self._file = open(path, "wb")
        self._writer, self.compression = open_writer(self._file, compression, chunk_size)
        self._writer.start(profile="", library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.sequences = array("I", [0])  # next sequence number, by channel id (recordings.native reads it)
        self.dirty = False
        self.closed = False
        #: records held elsewhere (the recorder's C path keeps the end of the open chunk between
        #: batches): called once before anything else touches the file
        self.held: Callable[[], None] | None = None

    def release_held(self) -> None:
        """Have the held records written now (see :attr:`held`)."""
        held = self.held
        if held is not None:
            self.held = None
            held()

    def channel(self, topic: str) -> int:
        """The id of ``topic``'s channel in this file (registered with its schema on first use)."""
        cid = self._channels.get(topic)
        if cid is None:
            self.release_held()
            kind: ChannelKind = kind_of(topic)
            sid = self._schemas.get(kind.name, 0)  # every channel has a schema
            if not sid:
                sid = self._schemas[kind.name] = self._writer.register_schema(
                    kind.name, kind.schema_encoding, kind.schema_bytes)
            # derived channels (_recorder/*, foxglove/*) are the recorder's own, not bus keys
            key = topic if topic.startswith("_") or kind.foxglove else f"hexbot/{self.fleet}/{topic}"
            cid = self._channels[topic] = self._writer.register_channel(
                topic, kind.message_encoding, sid, {"key": key, "fleet": self.fleet})
            self.sequences.append(0)
        return cid

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        """Append one message (``data`` exactly as it came from the bus)."""
        self.write_to(self.channel(topic), data, log_time_ns, publish_time_ns)

    def write_to(self, cid: int, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        """Append one message to a channel from :meth:`channel` (the recorder's hot path)."""
        if self.held is not None:
            self.release_held()
        seq = self.sequences[cid]
        self.sequences[cid] = seq + 1
        self._writer.add_message(cid, log_time_ns, data, publish_time_ns, seq)
        self.dirty = True

    def write_many(self, messages: list[tuple[int, int, int, bytes]]) -> None:
        """Append messages, each ``(channel id, log time, publish time, data)``, in order
        (:meth:`write_to` for each, in one call)."""
        if messages:
            self.release_held()
            self._writer.add_messages(messages, self.sequences)
            self.dirty = True

    @property
    def writer(self) -> FastMcapWriter:
        """The file's writer (for records packed elsewhere: :mod:`recordings.native`)."""
        self.release_held()
        return self._writer

    def add_metadata(self, meta: Mapping[str, Any], name: str = METADATA_NAME) -> None:
        self.release_held()
        self._writer.add_metadata(name, to_mcap(meta))
        self.dirty = True

    def flush(self) -> None:
        """Close the chunk in progress and hand everything to the OS: a killed process
        loses nothing written before this call (no fsync: an OS crash may)."""
        self.release_held()
        self._writer.flush()
        self.dirty = False

    def size(self) -> int:
        """Bytes in the file so far (the chunk in progress is not counted)."""
        self.release_held()
        return self._writer.written()

    def close(self, tally: Tally | None = None) -> None:
        """Write the counts (if given), the summary section and the footer."""
        if self.closed:
            return
        self.release_held()
        self.closed = True
        if tally is not None:
            self._writer.add_metadata(STATS_NAME, {"tally": json.dumps(tally.to_dict())})
        self._writer.finish()
        self._file.close()
