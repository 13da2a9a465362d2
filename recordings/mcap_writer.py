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

import queue
import struct
import threading
import zlib
from array import array
from collections import Counter, defaultdict
from typing import IO, Any, Iterable

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (DataEnd, Footer, Header, Metadata,
                          MetadataIndex, Schema, Statistics, SummaryOffset)

from bus.errors import HexbenchError

from . import native

MAGIC = bytes([137, 77, 67, 65, 80, 48, 13, 10])
#: opcode, record length, channel id, sequence, log time, publish time (then the data).
_MESSAGE_HEADER = struct.Struct("<BQHIQQ")
_MESSAGE_OVERHEAD = _MESSAGE_HEADER.size - 9  # record length counts the fields, not opcode+length
#: opcode, record length, channel id, length of the records (then the log time, offset pairs).
_INDEX_HEADER = struct.Struct("<BQHI")
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


def _index_records(cids: array, times: array, offsets: array) -> tuple[bytes, list[tuple[int, int]]]:
    """mcap's MessageIndex records of a chunk, one per channel in the order of its first
    message, and ``(channel, offset of its record)``: packed at once (mcap's own packs field
    by field), in C when :mod:`recordings.native` is there."""
    made = native.index_records(cids, times, offsets)
    if made is not None:
        return made
    flat: dict[int, list[int]] = {}
    for cid, t, off in zip(cids, times, offsets):
        pairs = flat.get(cid)
        if pairs is None:
            pairs = flat[cid] = []
        pairs += (t, off)
    parts, at, size = [], [], 0
    for cid, pairs in flat.items():
        n = len(pairs)
        record = _INDEX_HEADER.pack(Opcode.MESSAGE_INDEX, 6 + 8 * n, cid, 8 * n) + struct.pack(f"<{n}Q", *pairs)
        parts.append(record)
        at.append((cid, size))
        size += len(record)
    return b"".join(parts), at


def _string(text: str) -> bytes:
    """An MCAP string: its UTF-8 length (u32), then its bytes."""
    data = text.encode()
    return struct.pack("<I", len(data)) + data


class _Packed:
    """A record already packed, written where a record object would be."""

    __slots__ = ("data",)

    def __init__(self, data: bytes) -> None:
        self.data = data

    def write(self, rb: RecordBuilder) -> None:
        rb.write(self.data)


def _chunk_index(start: int, end: int, chunk_start: int, chunk_length: int, offsets: dict[int, int],
                 index_length: int, compression: str, compressed: int, uncompressed: int) -> _Packed:
    """mcap's ChunkIndex record, packed at once (its own write packs a field, and each of the
    chunk's channels, at a time)."""
    name = compression.encode()
    k = len(offsets)
    flat = [v for pair in offsets.items() for v in pair]
    body = (struct.pack("<QQQQI", start, end, chunk_start, chunk_length, 10 * k)
            + struct.pack("<" + "HQ" * k, *flat)
            + struct.pack(f"<QI{len(name)}sQQ", index_length, len(name), name, compressed, uncompressed))
    return _Packed(struct.pack("<BQ", Opcode.CHUNK_INDEX, len(body)) + body)


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
        # The open chunk's message index: per message, its channel, log time and offset in the chunk.
        self._index: tuple[array, array, array] = (array("i"), array("q"), array("q"))
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, _Packed] = {}
        self._chunk_indexes: list[_Packed] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: defaultdict[int, int] = defaultdict(int)
        self._message_count = 0
        self._start_time = 0
        self._end_time = 0
        self._chunk_count = 0
        self._metadata_count = 0
        self._offset = 0  # bytes written to the stream so far
        # Chunks closed and not yet in the file: compressed and written in order by a thread of
        # their own (zstd and crc32 let go of the GIL), which keeps _offset while it runs.
        self._jobs: queue.Queue | None = None
        self._error: BaseException | None = None

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
        """mcap's Channel record, packed at once (its own writes a field at a time; a fleet's
        recording has thousands of channels), in the open chunk and, at the end, the summary."""
        cid = len(self._channels) + 1
        meta = b"".join(_string(k) + _string(v) for k, v in (metadata or {}).items())
        body = (struct.pack("<HH", cid, schema_id) + _string(topic) + _string(message_encoding)
                + struct.pack("<I", len(meta)) + meta)
        record = struct.pack("<BQ", Opcode.CHANNEL, len(body)) + body
        self._channels[cid] = _Packed(record)
        self._chunk.append(record)
        self._chunk_bytes += len(record)
        return cid

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (closes the open chunk first, so the record order is time order)."""
        self._finish_chunk()
        self._settle()
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
        cids, times, offsets = self._index
        cids.append(channel_id)
        times.append(log_time)
        offsets.append(self._chunk_bytes)
        header = _MESSAGE_HEADER.pack(Opcode.MESSAGE, _MESSAGE_OVERHEAD + len(data), channel_id, sequence,
                                      log_time, publish_time)
        self._chunk.append(header)
        self._chunk.append(data)
        self._chunk_bytes += _MESSAGE_HEADER.size + len(data)
        self._chunk_messages += 1
        if self._chunk_bytes > self.chunk_size:
            self._finish_chunk()

    def add_messages(self, messages: Iterable[tuple[int, int, int, bytes]], sequences: Any) -> None:
        """Append many messages, each ``(channel_id, log_time, publish_time, data)``, as
        :meth:`add_message` one by one would (the same records, the same chunks), its
        sequence number the next of ``sequences[channel_id]`` (advanced)."""
        pack = _MESSAGE_HEADER.pack
        op, overhead, size = Opcode.MESSAGE, _MESSAGE_OVERHEAD, _MESSAGE_HEADER.size
        limit = self.chunk_size
        add = self._chunk.extend
        cids, times, offsets = self._index
        at = self._chunk_bytes
        n = self._chunk_messages
        start, end = self._chunk_start, self._chunk_end
        for cid, log_time, publish_time, data in messages:
            if n == 0:
                start = end = log_time
            elif log_time < start:
                start = log_time
            elif log_time > end:
                end = log_time
            cids.append(cid)
            times.append(log_time)
            offsets.append(at)
            seq = sequences[cid]
            sequences[cid] = seq + 1
            add((pack(op, overhead + len(data), cid, seq, log_time, publish_time), data))
            at += size + len(data)
            n += 1
            if at > limit:
                self._chunk_bytes, self._chunk_messages = at, n
                self._chunk_start, self._chunk_end = start, end
                self._finish_chunk()
                add = self._chunk.extend
                cids, times, offsets = self._index
                at, n = 0, 0
        self._chunk_bytes, self._chunk_messages = at, n
        self._chunk_start, self._chunk_end = start, end

    # -- records made elsewhere (recordings.native) ------------------------------------------------------
    @property
    def chunk_state(self) -> tuple[int, int, int, int]:
        """The open chunk's size, message count, first and last log time."""
        return self._chunk_bytes, self._chunk_messages, self._chunk_start, self._chunk_end

    def add_records(self, data: bytes, cids: array, times: array, offsets: array,
                    state: tuple[int, int, int, int]) -> None:
        """Message records packed elsewhere as :meth:`add_message` packs them, at the end of
        the open chunk, with their index entries; ``state`` is :attr:`chunk_state` after them.
        The caller closes a chunk that is full (:meth:`close_chunk`)."""
        if data:
            self._chunk.append(data)
            index = self._index
            index[0].extend(cids)
            index[1].extend(times)
            index[2].extend(offsets)
        self._chunk_bytes, self._chunk_messages, self._chunk_start, self._chunk_end = state

    def close_chunk(self) -> None:
        """Write the open chunk now (if it has messages)."""
        self._finish_chunk()

    def _finish_chunk(self) -> None:
        """Close the open chunk (if it has messages): compressed and written with its message
        indexes by the compression thread (in order), or here without compression."""
        if self._chunk_messages == 0:
            return
        raw = b"".join(self._chunk)
        if self._message_count == 0:
            self._start_time, self._end_time = self._chunk_start, self._chunk_end
        else:
            self._start_time = min(self._start_time, self._chunk_start)
            self._end_time = max(self._end_time, self._chunk_end)
        self._message_count += self._chunk_messages
        index, at = _index_records(*self._index)
        counts = self._counts
        for cid, n in Counter(self._index[0]).items():
            counts[cid] += n
        self._chunk_count += 1
        job = (raw, self._chunk_start, self._chunk_end, index, at)
        self._chunk = []
        self._chunk_bytes = 0
        self._chunk_messages = 0
        self._index = (array("i"), array("q"), array("q"))
        if self._compress is None:
            self._write_chunk(job)
            return
        if self._jobs is None:
            self._jobs = queue.Queue(maxsize=4)  # a compressor behind holds the writer up
            threading.Thread(target=self._compress_loop, name="mcap-compress", daemon=True).start()
        self._check()
        self._jobs.put(job)

    def _write_chunk(self, job: tuple[bytes, int, int, bytes, list[tuple[int, int]]]) -> None:
        """A chunk record and its MessageIndex records at the end of the file."""
        raw, start, end, index, at = job
        packed = self._compress(raw) if self._compress is not None else raw
        name = b"" if self._compress is None else self.compression.encode()
        body = struct.pack(f"<QQQII{len(name)}sQ", start, end, len(raw), zlib.crc32(raw), len(name), name,
                           len(packed))
        header = struct.pack("<BQ", Opcode.CHUNK, len(body) + len(packed)) + body
        chunk_start = self._offset
        self._stream.write(header)
        self._stream.write(packed)
        chunk_length = len(header) + len(packed)
        index_start = chunk_start + chunk_length
        self._stream.write(index)
        self._offset = index_start + len(index)
        self._chunk_indexes.append(_chunk_index(
            start, end, chunk_start, chunk_length, {cid: index_start + a for cid, a in at}, len(index),
            name.decode(), len(packed), len(raw)))

    def _compress_loop(self) -> None:
        jobs = self._jobs
        assert jobs is not None
        while True:
            job = jobs.get()
            try:
                if job is not None and self._error is None:
                    self._write_chunk(job)
            except BaseException as exc:  # raised again in the writer's thread (_check)
                self._error = exc
            finally:
                jobs.task_done()
            if job is None:
                return

    def _check(self) -> None:
        if self._error is not None:
            raise self._error

    def _settle(self) -> None:
        """Wait until every closed chunk is in the file (before anything else is written)."""
        if self._jobs is not None:
            self._jobs.join()
        self._check()

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS."""
        self._finish_chunk()
        self._settle()
        self._stream.flush()

    def written(self) -> int:
        """Bytes in the file once the closed chunks are (the open one is not counted)."""
        self._settle()
        return self._offset

    @property
    def pending_bytes(self) -> int:
        """Size of the open chunk (not yet in the file)."""
        return self._chunk_bytes

    # -- the end ----------------------------------------------------------------------------------------
    def finish(self) -> None:
        """Write the data end, the summary section, the footer and the closing magic."""
        if self._chunk_messages == 0 and self._chunk:  # schemas/channels with no message yet
            self._settle()
            self._chunk_messages_only_defs()
        self._finish_chunk()
        self._settle()
        if self._jobs is not None:
            self._jobs.put(None)  # the compression thread ends
            self._jobs = None
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
