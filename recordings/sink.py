"""One open MCAP file: lazily registered schemas and channels, chunked and compressed."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

from mcap.exceptions import UnsupportedCompressionError
from mcap.writer import CompressionType, Writer

from .meta import METADATA_NAME, STATS_NAME, to_mcap
from .schemas import ChannelKind, kind_of
from .stats import Tally

#: Preference order; mcap's writer needs the ``zstandard`` / ``lz4`` packages for the first two.
_COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
LIBRARY = "hexbench-recorder"


def open_writer(stream: Any, compression: str, chunk_size: int) -> tuple[Writer, str]:
    """A writer with ``compression`` if its package is installed, else the next one that is."""
    names = list(_COMPRESSIONS)
    for name in names[names.index(compression):]:
        try:
            return Writer(stream, chunk_size=chunk_size, compression=_COMPRESSIONS[name]), name
        except UnsupportedCompressionError:
            continue
    raise AssertionError("uncompressed MCAP is always available")  # pragma: no cover


class McapSink:
    """Writes samples of one recording part; channels appear when their first sample does."""

    def __init__(self, path: Path, *, fleet: str, compression: str = "zstd",
                 chunk_size: int = 512 * 1024) -> None:
        self.path = path
        self.fleet = fleet
        self._file = open(path, "wb")
        self._writer, self.compression = open_writer(self._file, compression, chunk_size)
        self._writer.start(profile="", library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self.dirty = False
        self.closed = False

    def _channel(self, topic: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            kind: ChannelKind = kind_of(topic)
            sid = 0
            if kind.schema is not None:
                sid = self._schemas.get(kind.name, 0)
                if not sid:
                    sid = self._schemas[kind.name] = self._writer.register_schema(
                        kind.name, "jsonschema", kind.schema_bytes)
            key = f"hexbot/{self.fleet}/{topic}" if not topic.startswith("_") else topic
            cid = self._channels[topic] = self._writer.register_channel(
                topic, "json", sid, {"key": key, "fleet": self.fleet})
        return cid

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        """Append one message."""
        cid = self._channel(topic)
        seq = self._seq.get(cid, 0)
        self._seq[cid] = seq + 1
        self._writer.add_message(cid, log_time_ns, data, publish_time_ns, seq)
        self.dirty = True

    def add_metadata(self, meta: Mapping[str, Any], name: str = METADATA_NAME) -> None:
        self._writer.add_metadata(name, to_mcap(meta))
        self.dirty = True

    def flush(self) -> None:
        """Close the chunk in progress and hand everything to the OS: a killed process
        loses nothing written before this call (no fsync: an OS crash may)."""
        self._writer.flush()
        self.dirty = False

    def size(self) -> int:
        """Bytes in the file so far (the chunk in progress is not counted)."""
        return self._file.tell()

    def close(self, tally: Tally | None = None) -> None:
        """Write the counts (if given), the summary section and the footer."""
        if self.closed:
            return
        self.closed = True
        if tally is not None:
            self._writer.add_metadata(STATS_NAME, {"tally": json.dumps(tally.to_dict())})
        self._writer.finish()
        self._file.close()
