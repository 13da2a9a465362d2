"""A chunked MCAP writer with a fast message path.

mcap's own :class:`mcap.writer.Writer` builds every message through a record object and a
``BytesIO`` with one ``struct.pack`` per field (about 7 µs a message in CPython). The
recorder writes hundreds of thousands of small JSON messages a second, so this writer packs
a message's header in one ``struct.pack`` and appends it with the payload (as it came from
the bus, never re-serialised) to the open chunk. Everything else — header, schemas,
channels, chunk, message index, metadata, summary, footer — is serialised by mcap's own
record classes, so the file layout is the one mcap writes: schemas and channels inside the
first chunk that needs them, a message index per chunk, and a summary with repeated schemas
and channels, statistics, chunk and metadata indexes and summary offsets.
"""

from __future__ import annotations

import struct
import zlib
from collections import defaultdict
from typing import IO, Any

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, MessageIndex, Metadata,
                          MetadataIndex, Schema, Statistics, SummaryOffset)

from bus.errors import HexbenchError

MAGIC = bytes([137, 77, 67, 65, 80, 48, 13, 10])
#: opcode, record length, channel id, sequence, log time, publish time (then the data).
_MESSAGE_HEADER = struct.Struct("<BQHIQQ")
_MESSAGE_OVERHEAD = _MESSAGE_HEADER.size - 9  # record length counts the fields, not opcode+length
COMPRESSIONS = ("zstd", "lz4", "none")


class CompressionUnavailable(HexbenchError, RuntimeError):
    """The package a compression needs is not installed."""


def _compressor(name: str) -> Any:
    """``bytes -> bytes`` for a chunk compression, or raise :class:`CompressionUnavailable`."""
    if name == "zstd":
        try:
            import zstandard
        except ImportError:
            raise CompressionUnavailable("zstd needs the 'zstandard' package") from None
        return zstandard.ZstdCompressor(level=1).compress  # level 1: ~2x faster than 3, ~same size on JSON
    if name == "lz4":
        try:
            import lz4.frame
        except ImportError:
            raise CompressionUnavailable("lz4 needs the 'lz4' package") from None
        return lz4.frame.compress
    if name == "none":
        return None
    raise ValueError(f"unknown compression {name!r}: expected one of {', '.join(COMPRESSIONS)}")


class FastMcapWriter:
    """Writes one MCAP file to ``stream``. Not thread-safe (the recorder holds a lock)."""

    def __init__(self, stream: IO[bytes], *, compression: str = "zstd", chunk_size: int = 1024 * 1024) -> None:
        self._stream = stream
        self._compress = _compressor(compression)
        self.compression = compression
        self.chunk_size = chunk_size
        self._rb = RecordBuilder()
        # The open chunk: its records as byte strings, their total size, and per-channel indexes.
        self._chunk: list[bytes] = []
        self._chunk_bytes = 0
        self._chunk_messages = 0
        self._chunk_start = 0
        self._chunk_end = 0
        self._index: dict[int, list[int]] = {}  # channel -> [log_time, offset, log_time, offset...]
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: defaultdict[int, int] = defaultdict(int)
        self._message_count = 0
        self._start_time = 0
        self._end_time = 0
        self._chunk_count = 0
        self._metadata_count = 0
        self._offset = 0  # bytes written to the stream so far

    # -- records outside the message path ---------------------------------------------------------
    def _emit(self) -> None:
        data = self._rb.end()
        self._stream.write(data)
        self._offset += len(data)

    def _to_chunk(self, record: Any) -> None:
        rb = RecordBuilder()
        record.write(rb)
        data = rb.end()
        self._chunk.append(data)
        self._chunk_bytes += len(data)

    def start(self, *, profile: str = "", library: str = "") -> None:
        self._stream.write(MAGIC)
        self._offset += len(MAGIC)
        Header(profile, library).write(self._rb)
        self._emit()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self._schemas) + 1
        schema = self._schemas[sid] = Schema(id=sid, name=name, encoding=encoding, data=data)
        self._to_chunk(schema)
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict[str, str] | None = None) -> int:
        cid = len(self._channels) + 1
        channel = self._channels[cid] = Channel(id=cid, topic=topic, message_encoding=message_encoding,
                                                schema_id=schema_id, metadata=dict(metadata or {}))
        self._to_chunk(channel)
        return cid

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (closes the open chunk first, so the record order is time order)."""
        self._finish_chunk()
        start = self._offset
        Metadata(name=name, metadata=data).write(self._rb)
        length = self._rb.count
        self._emit()
        self._metadata_indexes.append(MetadataIndex(offset=start, length=length, name=name))
        self._metadata_count += 1

    # -- the message path ---------------------------------------------------------------------------
    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int) -> None:
        """Append one message to the open chunk (closed when it reaches ``chunk_size``)."""
        if self._chunk_messages == 0:
            self._chunk_start = self._chunk_end = log_time
        elif log_time < self._chunk_start:
            self._chunk_start = log_time
        elif log_time > self._chunk_end:
            self._chunk_end = log_time
        index = self._index.get(channel_id)
        if index is None:
            index = self._index[channel_id] = []
        index.append(log_time)
        index.append(self._chunk_bytes)
        header = _MESSAGE_HEADER.pack(Opcode.MESSAGE, _MESSAGE_OVERHEAD + len(data), channel_id, sequence,
                                      log_time, publish_time)
        self._chunk.append(header)
        self._chunk.append(data)
        self._chunk_bytes += _MESSAGE_HEADER.size + len(data)
        self._chunk_messages += 1
        self._counts[channel_id] += 1
        if self._chunk_bytes > self.chunk_size:
            self._finish_chunk()

    def _finish_chunk(self) -> None:
        """Write the open chunk (if it has messages) and its message indexes."""
        if self._chunk_messages == 0:
            return
        raw = b"".join(self._chunk)
        packed = self._compress(raw) if self._compress is not None else raw
        if self._message_count == 0:
            self._start_time, self._end_time = self._chunk_start, self._chunk_end
        else:
            self._start_time = min(self._start_time, self._chunk_start)
            self._end_time = max(self._end_time, self._chunk_end)
        self._message_count += self._chunk_messages
        chunk_start = self._offset
        Chunk(message_start_time=self._chunk_start, message_end_time=self._chunk_end,
              uncompressed_size=len(raw), uncompressed_crc=zlib.crc32(raw),
              compression="" if self._compress is None else self.compression, data=packed).write(self._rb)
        chunk_length = self._rb.count
        self._emit()
        index_start = self._offset
        offsets: dict[int, int] = {}
        for cid, flat in self._index.items():
            offsets[cid] = index_start + self._rb.count
            MessageIndex(channel_id=cid, records=list(zip(flat[0::2], flat[1::2]))).write(self._rb)
        index_length = self._rb.count
        self._emit()
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=self._chunk_start, message_end_time=self._chunk_end,
            chunk_start_offset=chunk_start, chunk_length=chunk_length, message_index_offsets=offsets,
            message_index_length=index_length, compression="" if self._compress is None else self.compression,
            compressed_size=len(packed), uncompressed_size=len(raw)))
        self._chunk_count += 1
        self._chunk = []
        self._chunk_bytes = 0
        self._chunk_messages = 0
        self._index = {}

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS."""
        self._finish_chunk()
        self._stream.flush()

    @property
    def pending_bytes(self) -> int:
        """Size of the open chunk (not yet in the file)."""
        return self._chunk_bytes

    # -- the end ----------------------------------------------------------------------------------------
    def finish(self) -> None:
        """Write the data end, the summary section, the footer and the closing magic."""
        if self._chunk_messages == 0 and self._chunk:  # schemas/channels with no message yet
            self._chunk_messages_only_defs()
        self._finish_chunk()
        DataEnd(data_section_crc=0).write(self._rb)
        self._emit()
        summary_start = self._offset
        rb = self._rb
        groups: list[SummaryOffset] = []

        def group(opcode: Opcode, records: list[Any]) -> None:
            begin = rb.count
            for r in records:
                r.write(rb)
            groups.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + begin,
                                        group_length=rb.count - begin))

        group(Opcode.SCHEMA, list(self._schemas.values()))
        group(Opcode.CHANNEL, list(self._channels.values()))
        group(Opcode.STATISTICS, [Statistics(
            message_count=self._message_count, schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0, metadata_count=self._metadata_count,
            chunk_count=self._chunk_count, message_start_time=self._start_time,
            message_end_time=self._end_time, channel_message_counts=dict(self._counts))])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        offsets_start = summary_start + rb.count
        for g in groups:
            g.write(rb)
        summary = rb.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offsets_start), crc)
        self._stream.write(summary)
        self._offset += len(summary)
        Footer(summary_start=summary_start, summary_offset_start=offsets_start, summary_crc=crc).write(self._rb)
        self._emit()
        self._stream.write(MAGIC)
        self._stream.flush()

    def _chunk_messages_only_defs(self) -> None:
        """Schemas and channels registered but never used: write them outside any chunk
        (a chunk without messages is not written, and they must not be lost)."""
        for data in self._chunk:
            self._stream.write(data)
            self._offset += len(data)
        self._chunk = []
        self._chunk_bytes = 0
