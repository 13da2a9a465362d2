"""The recorder: every sample under ``hexbot/<fleet>/**`` into MCAP (ARCHITECTURE: "every byte
is visible"; rosbag2/MCAP as the model).

* One channel per key (topic = the key relative to the fleet root), message encoding ``json``,
  a JSON Schema per channel kind (:mod:`recordings.schemas`).
* Log time = a start instant plus the sample's ``sim_time_ns`` (``time_source="sim"``, virtual
  runs: the file shows a real date; the instant is the metadata's ``start_time_ns``, by default
  when the recorder started) or the wall time it was received (``"wall"``, live runs); publish
  time = the envelope's ``wall_time_ns`` or the receive wall time.
* For Foxglove (:mod:`recordings.foxglove`), beside the bus's channels: ``foxglove/scene``
  (``foxglove.SceneUpdate``, from the world's and the planner's records, the whole scene again
  when the file closes) and ``foxglove/log`` (``foxglove.Log``, a line per frame). Every channel
  has a schema.
* Flushed at least every ``flush_interval_s`` wall seconds by a background thread, so a killed
  recorder loses at most that much; :mod:`recordings.reader` reads files without a footer.
* Optional rotation by size or duration into ``<stem>_0001.mcap``, ``<stem>_0002.mcap``...
* Errors are data: a sample that is not JSON, or lacks its schema's required fields, is written
  as a ``_recorder/error`` record carrying the key and the raw bytes, never dropped.
* Fast: payloads are written exactly as they came from the bus (never re-serialised), frames
  and schemaless keys without being decoded (see :class:`_Route`), into large chunks by
  :class:`recordings.mcap_writer.FastMcapWriter`; ``strict=True`` decodes every payload.
  :meth:`Recorder.write_batch` writes many samples under one lock: the records ``write``
  would; :meth:`Recorder.write_packed` the same from a batch in ``pack_batch``'s bytes, in C
  for every sample C can take (what :meth:`Recorder.attach` subscribes with, so a batch from
  ``Bus.put_batch``, ``Bus.put_packed`` or another process is written without a Python object
  per sample that nothing acts on).
"""

from __future__ import annotations

import ctypes
import json
import re
import struct
import threading
import time
from array import array
from collections import Counter
from itertools import accumulate
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Mapping, Sequence

from bus.envelope import Envelope
from bus.keys import Keys
from bus.messages import RunMeta
from bus.transport import unpack_batch

from . import meta as meta_mod
from . import native
from .foxglove import FoxgloveView, timestamp_field
from .lines import describe
from .foxglove import SCENE_TOPICS
from .schemas import BUS_EVENT, FRAME, IR_LIGHT, LOG_TOPIC, RECORDER_ERROR_TOPIC, SCENE_TOPIC, UNTYPED, kind_of
from .sink import CHUNK_SIZE, McapSink
from .stats import Tally, kind_field

TimeSource = Literal["auto", "sim", "wall"]
#: A sim or wall time at or past this is no time (2^62 ns: year 2116): the sample is kept, its
#: log time is the last sim time (and its publish time the receive time).
MAX_TIME_NS = 1 << 62
_NATIVE_FROM = 16  # samples: a smaller batch is written sample by sample
_CHECK_SIZE_EVERY = 64  # messages between file-size checks (tell() is a syscall)
_decode = json.JSONDecoder().decode  # skips json.loads' encoding sniffing (payloads are UTF-8)
_INT = re.compile(rb"\s*(-?\d+)\s*[,}]")
_SIM_TIME = re.compile(rb'"sim_time_ns":(0|[1-9][0-9]{0,18})(?=[,}])')  # as JSON writes an int
_RECORDS_SEEN = 1 << 16  # distinct records kept decoded (a bound: cleared when full)
#: The records kept decoded, one cache for the process (an object depends on its bytes alone):
#: one per recorder kept 40 at 40 fleets (10 000 modules recorded: peak RSS 4.3 GB, 1.9 GB with one).
_RECORDS: dict[tuple[str, bytes, bytes], dict[str, Any]] = {}
#: An actuator record's tail (the bytes after its time) decoded, for every module (write_packed)
_TAILS: dict[bytes, dict[str, Any]] = {}
#: An envelope as :meth:`bus.envelope.Envelope.to_json` writes it: its times and kind in one match
#: (the fields before it, link, src, dst and raw, are the rest of the required ones).
_ENVELOPE = re.compile(rb',"sim_time_ns":(\d+),"wall_time_ns":(\d+),"seq":\d+,"kind":"([^"\\]*)"')
_ENVELOPE_HEAD = (b'{"link":', b',"src":', b',"dst":', b',"raw":')
_STRING = re.compile(rb'\s*"([^"\\]*)"')
#: The same from the first byte, as the bus writes every envelope (:meth:`Recorder.write_batch`):
#: the part before its times (link, src, dst, raw: what its Foxglove line depends on), its times,
#: its kind. No quote inside those strings, so the first ``,"sim_time_ns":`` is this one and
#: ``_ENVELOPE`` finds the same fields.
_ENVELOPE_AT_START = re.compile(rb'(\{"link":"[^"\\]*","src":"[^"\\]*","dst":"[^"\\]*","raw":"[^"\\]*")'
                                rb',"sim_time_ns":(\d+),"wall_time_ns":(\d+),"seq":\d+,"kind":"([^"\\]*)"')
_KIND_NAMES: dict[bytes, str] = {}  # a frame kind's bytes -> its name
_ACTUATORS = "world/actuators/"  # the records the C batch path writes too, once seen here
_PLAIN = re.compile(r"[ !#-.0-\[\]-~]+")  # printable ASCII but quote, backslash and slash: JSON as it is
_BATCH_ITEM = struct.Struct("<HI")  # a packed sample's key and payload lengths (bus.transport.pack_batch)


def _tail_record(tail: bytes, module: str, sim: int) -> dict[str, Any]:
    """The decoded actuator record of ``module`` at ``sim`` whose bytes after its time are
    ``tail`` (a tail C knows: a valid record's), its tail decoded once for every module."""
    template = _TAILS.get(tail)
    if template is None:
        if len(_TAILS) >= _RECORDS_SEEN:
            _TAILS.clear()
        template = _TAILS[tail] = _decode('{"module":"","sim_time_ns":0' + tail.decode())
    obj = dict(template)
    obj["module"], obj["sim_time_ns"] = module, sim
    return obj


def _kind_name(raw: bytes) -> str:
    name = raw.decode("utf-8", "replace")
    if len(_KIND_NAMES) < 256:
        _KIND_NAMES[raw] = name
    return name


class _NoChannel(dict):
    """key -> channel id; 0 for a key without one yet."""

    def __missing__(self, key: str) -> int:
        return 0


def part_path(out: Path, index: int) -> Path:
    """``run.mcap``, 3 -> ``run_0003.mcap``."""
    return out.with_name(f"{out.stem}_{index:04d}{out.suffix or '.mcap'}")


def _required(topic: str) -> tuple[str, ...]:
    schema = kind_of(topic).schema
    return tuple(schema.get("required", ())) if schema else ()


@dataclass(frozen=True)
class _Route:
    """How samples of one key are recorded.

    ``fast`` routes (frames and schemaless keys such as ``ir/*``: the bulk of a run) are not
    decoded: a payload that is a JSON object carrying every required field name is written
    as it is, with its sim time, publish time and kind read straight from the bytes. Anything
    else — no braces, a required field missing, a time that is not an integer — takes the
    careful path, which decodes it and records what is wrong as a ``_recorder/error``.
    (A payload that looks like an object but is not valid JSON is still kept byte for byte on
    its channel; :func:`recordings.reader.summary` counts it as undecodable.) Records
    (world, planner, meta, events) are rare and always decoded.
    """

    topic: str
    fast: bool
    frame: bool  # a frame/* key (logged for Foxglove too)
    required: tuple[bytes, ...]  # b'"name":' of every required field
    kind: bytes | None  # b'"kind":' if the tally counts this topic by a field

    @classmethod
    def of(cls, topic: str) -> "_Route":
        kind = kind_of(topic)
        fast = kind is FRAME or kind is IR_LIGHT or (kind is UNTYPED and topic != RECORDER_ERROR_TOPIC)
        field_name = kind_field(topic)
        return cls(topic, fast, kind is FRAME, tuple(f'"{k}":'.encode() for k in _required(topic)),
                   None if field_name is None else f'"{field_name}":'.encode())

    def scan(self, payload: bytes) -> tuple[int | None, int | None, str | None] | None:
        """``(sim_time_ns, wall_time_ns, kind)`` read from the bytes, or None: decode it."""
        if payload[-1:] != b"}":
            return None
        if self.frame and payload[:8] == b'{"link":':  # the common case: one match, no field scan
            m = _ENVELOPE.search(payload)
            if m is not None:
                head = payload[:m.start()]
                sim, pub = int(m.group(1)), int(m.group(2))
                if all(name in head for name in _ENVELOPE_HEAD) and sim < MAX_TIME_NS and pub < MAX_TIME_NS:
                    return sim, pub, m.group(3).decode("utf-8", "replace")
        if payload[:1] != b"{":
            return None
        for name in self.required:
            if name not in payload:
                return None
        sim = int_field(payload, b'"sim_time_ns":')
        if sim is False or (sim is not None and not 0 <= sim < MAX_TIME_NS):
            return None
        pub = int_field(payload, b'"wall_time_ns":')
        if pub is False or (pub is not None and not 0 <= pub < MAX_TIME_NS):
            return None
        kind = None
        if self.kind is not None:
            i = payload.find(self.kind)
            if i >= 0:
                m = _STRING.match(payload, i + len(self.kind))
                kind = m.group(1).decode("utf-8", "replace") if m else "?"
        return sim, pub, kind


def _is_time(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value < MAX_TIME_NS


def int_field(payload: bytes, name: bytes) -> int | None | bool:
    """The integer after the first ``name``; None if absent; False if not an integer."""
    i = payload.find(name)
    if i < 0:
        return None
    m = _INT.match(payload, i + len(name))
    return int(m.group(1)) if m else False


class Recorder:
    """Writes bus samples to MCAP. Thread-safe: samples may come from any thread."""

    def __init__(self, out: str | Path, *, fleet: str = "default",
                 meta: Mapping[str, Any] | RunMeta | None = None, time_source: TimeSource = "auto",
                 compression: str = "zstd", chunk_size: int = CHUNK_SIZE,
                 flush_interval_s: float = 0.5, rotate_bytes: int | None = None,
                 rotate_s: float | None = None, argv: list[str] | None = None,
                 strict: bool = False, start_ns: int | None = None, foxglove: bool = True) -> None:
        self.out = Path(out)
        self.keys = Keys(fleet)
        self.time_source: TimeSource = time_source
        self.compression = compression
        self.chunk_size = chunk_size
        self.flush_interval_s = flush_interval_s
        self.rotate_bytes = rotate_bytes
        self.rotate_ns = None if rotate_s is None else int(rotate_s * 1e9)
        self.meta: dict[str, Any] = meta_mod.merge(meta_mod.base_metadata(fleet, argv), meta)
        if time_source != "auto":
            self.meta["log_time"] = time_source  # how to read log times (the replay needs it)
        # The start instant: a sim-time log time is this plus the sim time (seconds, ns).
        self.start_ns = time.time_ns() // 1_000_000 * 1_000_000 if start_ns is None else int(start_ns)
        self.meta["start_time_ns"] = self.start_ns
        self.meta["start_time"] = meta_mod.iso_time(self.start_ns)
        self._origin = 0  # added to sim times; set to start_ns once the time source is sim
        self._fox = FoxgloveView() if foxglove else None
        self._done = Tally()  # counts of the closed parts
        self._part = Tally()  # counts of the open part (written into it when it closes)
        self.strict = strict
        self._routes: dict[str, _Route] = {}  # key -> how its samples are recorded
        self._cids: dict[str, int] = {}  # topic -> channel id in the open part
        self._frame_cids = _NoChannel()  # key of a frame -> its channel id in the open part (native path)
        # the compiled batch path (from the start: the Log lines it makes are FrameLog's too)
        self._native: native.FrameBatch | None = native.FrameBatch() if native.lib() is not None else None
        if self._native is not None and self._fox is not None:
            self._fox.log.shared = self._native
        self._key_topics: list[str] = []  # by key number in the C key table (write_packed)
        self._key_events: list[bool] = []  # whether the key's samples are events (counted by kind)
        self._topic_keys: dict[str, list[int]] = {}  # topic -> its keys' numbers
        self._looks: dict[tuple[Any, ...], int] = {}  # a placed module's look but its coils -> its number in C
        self._act_modules: dict[int, str] = {}  # an actuator channel's id -> its module
        # its frames counted by key, not yet in the open part's tally (see _fold)
        self._pending: Counter[str] = Counter()
        self._pending_noise: Counter[str] = Counter()
        self._pending_frames = 0
        self._packed_pending = False  # counts wait in C (write_packed)
        self._native_live = False  # C holds the open chunk's end (write_packed; McapSink.held)
        self.paths: list[Path] = []
        self._required: dict[str, tuple[str, ...]] = {}
        self._last_sim_ns = 0
        self._since_size_check = 0
        self._part_first_ns: int | None = None
        self._lock = threading.RLock()  # reentrant: write_batch holds it around write's own paths
        self._closed = False
        if self.time_source == "sim":
            self._origin = self.start_ns
        self._sink = self._open_part()
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="recorder-flush", daemon=True)
        self._flusher.start()

    # -- attaching --------------------------------------------------------------------------
    def attach(self, bus: Any) -> None:
        """Subscribe to everything of ``bus``'s fleet (a :class:`bus.transport.Bus`).

        Handlers run on the bus clock's thread, so a virtual clock waits for the recorder
        like for any participant: when a virtual run settles, everything is written. With the
        compiled path, batches come packed (:meth:`write_packed`), as they travel between
        processes and as the fleet core may put them (``Bus.put_packed``).
        """
        if bus.keys.root != self.keys.root:
            raise ValueError(f"recorder is for {self.keys.root}, bus is {bus.keys.root}")
        if self.time_source == "auto":
            self.time_source = "sim" if getattr(bus.clock, "kind", "") == "virtual" else "wall"
            with self._lock:
                self._origin = self.start_ns if self.time_source == "sim" else 0
                self.meta["log_time"] = self.time_source
                self._sink.add_metadata(self.meta)
        if self._native is not None:  # batches as they travel, written in C (write_packed)
            bus.subscribe_batch(self.keys.all, self.on_packed, packed=True)
        else:
            bus.subscribe_batch(self.keys.all, self.on_samples)

    def on_sample(self, key: str, payload: bytes) -> None:
        """Bus handler: record one sample received now."""
        self.write(key, payload)

    def on_samples(self, samples: Sequence[tuple[str, bytes]]) -> None:
        """Bus batch handler (``Bus.subscribe_batch``): record samples received now."""
        self.write_batch(samples)

    def on_packed(self, data: bytes) -> None:
        """Packed bus batch handler (``Bus.subscribe_batch(..., packed=True)``): record the
        samples of a batch in ``pack_batch``'s bytes, received now."""
        self.write_packed(data)

    def write_packed(self, data: bytes, *, receive_wall_ns: int | None = None) -> None:
        """Record the samples of a batch in :func:`bus.transport.pack_batch`'s bytes (a packed
        batch handler: ``Bus.subscribe_batch(..., packed=True)``): what :meth:`write_batch`
        writes of them, the same file byte for byte, written in C (framebatch.c ``fb_packed``)
        for every sample it can take: frames and their Log lines, actuator records that change
        no coil, events, light. Python writes the rest in its place (a first record or a coil
        change, for the scene; anything unusual, by the careful path). ``ValueError`` if
        ``data`` is no such bytes; a rotating or strict recorder, or one without the compiled
        path, writes the unpacked samples."""
        wall = time.time_ns() if receive_wall_ns is None else receive_wall_ns
        fb = self._native
        if fb is not None and not self.strict and not self.rotating:
            with self._lock:
                if self._closed:
                    return
                st = fb.state
                st.packed, st.packed_len, st.pos, st.samples = data, len(data), 0, 0
                try:
                    if self._write_packed_native(fb, data, wall):
                        return
                finally:
                    st.packed = None
        self.write_batch(unpack_batch(data), receive_wall_ns=wall)

    # -- writing ----------------------------------------------------------------------------
    def write(self, key: str, payload: bytes, *, receive_wall_ns: int | None = None) -> None:
        """Record one sample of ``key`` (full key or relative topic), its bytes as they are."""
        wall = time.time_ns() if receive_wall_ns is None else receive_wall_ns
        route = self._routes.get(key)
        if route is None:
            route = self._routes[key] = _Route.of(self.keys.relative(key))
        self._write_one(route, key, payload, wall)

    def write_batch(self, samples: Sequence[tuple[str, bytes]], *, receive_wall_ns: int | None = None) -> None:
        """Record ``(key, payload)`` samples in order, all received at ``receive_wall_ns``
        (default now): the records :meth:`write` makes of each (the same topics, channels,
        times, sequence numbers, Foxglove messages and counts), under one lock and with a
        frame's fields read in one match. Frames as the bus writes them take that path;
        anything else in the batch takes write's own, in its place. A rotating or strict
        recorder writes a batch sample by sample."""
        wall = time.time_ns() if receive_wall_ns is None else receive_wall_ns
        if self.strict or self.rotating:
            for key, payload in samples:
                self.write(key, payload, receive_wall_ns=wall)
            return
        if len(samples) < _NATIVE_FROM:  # a sample put alone: write's path costs less than C's setup
            with self._lock:
                for key, payload in samples:
                    self.write(key, payload, receive_wall_ns=wall)
            return
        if self._native is not None:
            self._write_batch_native(samples, wall)
            return
        routes = self._routes
        match = _ENVELOPE_AT_START.match
        kinds = _KIND_NAMES
        log = self._fox.log if self._fox is not None else None
        seen = log.seen if log is not None else {}
        out: list[tuple[int, int, int, bytes]] = []  # (channel, log time, publish time, data)
        topics: list[str] = []  # of the frames written here, for the tally
        times: list[int] = []
        noise: list[str] = []
        with self._lock:
            if self._closed:
                return
            sink = self._sink
            cids = self._cids
            by_sim = self.time_source != "wall"
            origin = self._origin
            last_sim = self._last_sim_ns
            log_cid = cids.get(LOG_TOPIC)
            stamped, stamp = -1, b""  # the last log time and its encoded Foxglove timestamp
            for key, payload in samples:
                route = routes.get(key)
                if route is None:
                    route = routes[key] = _Route.of(self.keys.relative(key))
                m = match(payload) if route.frame else None
                if m is not None:
                    head, sim_b, pub_b, kind_b = m.groups()
                    sim, pub = int(sim_b), int(pub_b)
                if m is None or payload[-1] != 125 or sim >= MAX_TIME_NS or pub >= MAX_TIME_NS:
                    sink.write_many(out)  # not ending in "}", or no time: write's own path
                    out = []
                    self._last_sim_ns = last_sim
                    self._write_one(route, key, payload, wall)
                    last_sim = self._last_sim_ns
                    log_cid = cids.get(LOG_TOPIC)
                    continue
                if sim > last_sim:
                    last_sim = sim
                log_time = origin + sim if by_sim else wall
                topic = route.topic
                cid = cids.get(topic)
                if cid is None:  # registered between the messages before it and its own
                    sink.write_many(out)
                    out = []
                    cid = cids[topic] = sink.channel(topic)
                out.append((cid, log_time, pub, payload))
                topics.append(topic)
                times.append(log_time)
                kind = kinds.get(kind_b) or _kind_name(kind_b)
                if kind == "noise":
                    noise.append(topic)
                if log is None:
                    continue
                rest = seen.get((head, kind))  # FrameLog.log_payload, its cache read here
                if rest is None:
                    try:
                        rest = log.rest(payload, (head, kind))
                    except (ValueError, KeyError, TypeError):
                        continue
                if log_time != stamped:
                    stamped, stamp = log_time, timestamp_field(log_time)
                if log_cid is None:
                    sink.write_many(out)
                    out = []
                    log_cid = cids[LOG_TOPIC] = sink.channel(LOG_TOPIC)
                out.append((log_cid, log_time, log_time, stamp + rest))
            sink.write_many(out)
            self._last_sim_ns = last_sim
            if times:
                if self._part_first_ns is None:
                    self._part_first_ns = times[0]
                self._part.add_counts(Counter(topics), Counter(noise))
                self._part.span(min(times), max(times))

    def _write_batch_native(self, samples: Sequence[tuple[str, bytes]], wall: int) -> None:
        """write_batch in C (:mod:`recordings.native`): the frames' records packed there, the
        rest — other samples, new channels and Foxglove lines, full chunks — here, in place."""
        fb = self._native
        assert fb is not None
        n = len(samples)
        if not n:
            return
        keys, payloads = zip(*samples)
        buf = b"".join(payloads)
        offs = array("q", accumulate(map(len, payloads), initial=0))
        fb.prepare(n)
        st = fb.state
        routes = self._routes
        log = self._fox.log if self._fox is not None else None
        slow: list[int] = []  # items written by write's own path
        with self._lock:
            if self._closed:
                return
            cids = array("i", map(self._frame_cids.__getitem__, keys))
            st.buf, st.offs, st.n, st.cids = buf, offs.buffer_info()[0], n, cids.buffer_info()[0]
            st.by_sim, st.origin, st.wall = self.time_source != "wall", self._origin, wall
            st.rests, st.limit = fb.rests, self._sink.writer.chunk_size
            ix_cid, ix_time, ix_off = fb.ix
            st.ix_cid, st.ix_time, st.ix_off = (a.buffer_info()[0] for a in fb.ix)
            st.ix_cap, st.frames, st.last_sim = len(ix_cid), 0, self._last_sim_ns
            st.noise, st.item, st.phase, st.no_log = ctypes.addressof(fb.noise), 0, 0, 0

            def load() -> None:  # after Python wrote: the sink's state into C's
                sink = self._sink
                st.chunk_bytes, st.chunk_messages, st.chunk_start, st.chunk_end = sink.writer.chunk_state
                st.seqs, st.nseqs = sink.sequences.buffer_info()
                st.log_cid = -1 if log is None else self._cids.get(LOG_TOPIC, 0)
                st.out, st.out_cap, st.out_len, st.ix_len = ctypes.addressof(fb.out), len(fb.out), 0, 0

            def commit() -> None:  # before Python writes: C's records into the sink
                k = st.ix_len
                self._sink.writer.add_records(
                    ctypes.string_at(fb.out, st.out_len), ix_cid[:k], ix_time[:k], ix_off[:k],
                    (st.chunk_bytes, st.chunk_messages, st.chunk_start, st.chunk_end))
                self._sink.dirty = True
                st.out_len = st.ix_len = 0

            load()
            while True:
                code = fb.run()
                if code == native.DONE:
                    commit()
                    break
                if code == native.REST_MISS:  # a Foxglove line not seen yet: FrameLog makes it
                    head = buf[st.head_at:st.head_at + st.head_len]
                    kind_b = buf[st.kind_at:st.kind_at + st.kind_len]
                    kind = _KIND_NAMES.get(kind_b) or _kind_name(kind_b)
                    assert log is not None
                    rest = log.seen.get((head, kind))
                    if rest is None:
                        try:
                            rest = log.rest(payloads[st.item], (head, kind))
                        except (ValueError, KeyError, TypeError):  # no envelope after all: no line
                            st.no_log = 1
                            continue
                    fb.remember(head, kind_b, rest)
                    continue
                if code == native.OUT_FULL and st.out_len == 0:  # one record larger than the buffer
                    fb.grow_out(2 * len(payloads[st.item]) + 4096)
                    load()
                    continue
                commit()
                if code == native.CHUNK_FULL:
                    self._sink.writer.close_chunk()
                elif code == native.NEW_LOG_CHANNEL:
                    self._cids[LOG_TOPIC] = self._sink.channel(LOG_TOPIC)
                elif code in (native.NEW_CHANNEL, native.NOT_FRAME):
                    i = st.item
                    key = keys[i]
                    route = routes.get(key)
                    if route is None:
                        route = routes[key] = _Route.of(self.keys.relative(key))
                    if code == native.NEW_CHANNEL and route.frame:
                        cid = self._cids.get(route.topic)
                        if cid is None:
                            cid = self._cids[route.topic] = self._sink.channel(route.topic)
                        cids[i] = self._frame_cids[key] = cid
                    else:  # not a frame, or not one as the bus writes it: write's own path
                        self._last_sim_ns = st.last_sim
                        self._write_one(route, key, payloads[i], wall)
                        st.last_sim = self._last_sim_ns
                        slow.append(i)
                        st.item = i + 1
                elif code != native.OUT_FULL:
                    raise RuntimeError(f"framebatch.c answered {code}")
                load()
            self._last_sim_ns = st.last_sim
            if st.frames:
                self._count_frames(keys, slow, fb.noise.raw[:n], st.tmin, st.tmax)

    def _write_packed_native(self, fb: native.FrameBatch, data: bytes, wall: int) -> bool:
        """write_packed's loop (under the lock): C writes, Python does what C stops for; False
        if C takes none of it (bytes that do not frame, a key that is not ASCII). The end of
        the open chunk stays in C between batches (``McapSink.held`` gives it to the file
        before anything else is written there)."""
        st = fb.state
        log = self._fox.log if self._fox is not None else None
        st.by_sim, st.origin, st.wall = self.time_source != "wall", self._origin, wall
        st.frames, st.last_sim, st.phase, st.no_log = 0, self._last_sim_ns, 0, 0
        if not self._native_live:
            self._native_load()

        def sample() -> tuple[str, bytes, int]:  # the sample C stopped at: key, payload, where the next starts
            klen, plen = _BATCH_ITEM.unpack_from(data, st.pos)
            start = st.pos + 6 + klen
            return data[st.pos + 6:start].decode(), data[start:start + plen], start + plen

        while True:
            code = fb.run_packed()
            if code == native.DONE:
                break
            if code == native.BAD_BATCH:
                return False
            if code == native.NEW_KEY:
                self._new_key(fb, sample()[0])
            elif code == native.REST_MISS:  # a Foxglove line C cannot make: FrameLog makes it
                assert log is not None
                head = data[st.head_at:st.head_at + st.head_len]
                kind_b = data[st.kind_at:st.kind_at + st.kind_len]
                kind = _KIND_NAMES.get(kind_b) or _kind_name(kind_b)
                payload = sample()[1]
                rest = log.seen.get((head, kind))
                if rest is None:
                    try:
                        rest = log.rest(payload, (head, kind))
                    except (ValueError, KeyError, TypeError):  # no envelope after all: no line
                        st.no_log = 1
                        continue
                    env = Envelope.from_json(payload)
                    if env.to_json() == payload:  # its describe text makes the lines of its likes
                        fb.describe(payload, describe(env).encode())
                fb.remember(head, kind_b, rest)
            elif code == native.OUT_FULL:  # C's records into the file (and a larger buffer for a large one)
                empty = st.out_len == 0
                self._sink.release_held()
                if empty:
                    fb.grow_out(2 * len(sample()[1]) + 4096)
            elif code == native.CHUNK_FULL:
                self._sink.writer.close_chunk()
            elif code == native.NEW_LOG_CHANNEL:
                self._cids[LOG_TOPIC] = self._sink.channel(LOG_TOPIC)
            elif code == native.NEW_SCENE_CHANNEL:
                self._cids[SCENE_TOPIC] = self._sink.channel(SCENE_TOPIC)
            elif code == native.NEW_CHANNEL:
                topic = self._key_topics[st.key_id]
                cid = self._cids.get(topic)
                if cid is None:
                    cid = self._cids[topic] = self._sink.channel(topic)
                for kid in self._topic_keys[topic]:
                    fb.key_channel(kid, cid)
            elif code == native.COILS:  # a coil change C wrote (a known record): the scene's
                writer = self._sink.writer
                if writer.chunk_state[0] > writer.chunk_size:  # closed after the record, as write_to does
                    writer.close_chunk()
                at, st.pos = st.pos, st.item
                key, payload, _ = sample()
                st.pos = at
                self._coil_change(key, payload, wall)
            elif code == native.PYTHON:
                key, payload, st.pos = sample()
                route = self._routes.get(key)
                if route is None:
                    route = self._routes[key] = _Route.of(self.keys.relative(key))
                self._last_sim_ns = st.last_sim
                self._write_one(route, key, payload, wall)
                st.last_sim = self._last_sim_ns
            else:
                raise RuntimeError(f"framebatch.c answered {code}")
            if not self._native_live:  # Python wrote: the file's state into C's
                self._native_load()
        self._last_sim_ns = st.last_sim
        if st.frames:
            self._sink.dirty = True
            self._pending_frames += st.frames
            self._packed_pending = True
            if self._part_first_ns is None:
                self._part_first_ns = st.tmin
            self._part.span(st.tmin, st.tmax)
        return True

    def _native_load(self) -> None:
        """The open file's state into C's (write_packed), which holds the chunk's end from now
        until something else is written there."""
        fb = self._native
        assert fb is not None
        st, sink = fb.state, self._sink
        st.chunk_bytes, st.chunk_messages, st.chunk_start, st.chunk_end = sink.writer.chunk_state
        st.seqs, st.nseqs = sink.sequences.buffer_info()
        st.log_cid = -1 if self._fox is None else self._cids.get(LOG_TOPIC, 0)
        st.scene_cid = -1 if self._fox is None else self._cids.get(SCENE_TOPIC, 0)
        st.rests, st.limit = fb.rests, self.chunk_size
        if len(fb.ix[0]) < fb.PACKED_INDEX:
            fb.prepare(fb.PACKED_INDEX // 2)
        st.ix_cid, st.ix_time, st.ix_off = (a.buffer_info()[0] for a in fb.ix)
        st.ix_cap = len(fb.ix[0])
        st.out, st.out_cap, st.out_len, st.ix_len = ctypes.addressof(fb.out), len(fb.out), 0, 0
        self._native_live = True
        sink.held = self._native_release

    def _native_release(self) -> None:
        """C's records into the file (``McapSink.held``: before anything else is written there)."""
        fb = self._native
        assert fb is not None
        self._native_live = False
        st = fb.state
        k = st.ix_len
        if not k:
            return
        ix_cid, ix_time, ix_off = fb.ix
        self._sink.writer.add_records(ctypes.string_at(fb.out, st.out_len), ix_cid[:k], ix_time[:k], ix_off[:k],
                                      (st.chunk_bytes, st.chunk_messages, st.chunk_start, st.chunk_end))
        self._sink.dirty = True
        st.out_len = st.ix_len = 0

    def _coil_change(self, key: str, payload: bytes, wall: int) -> None:
        """An actuator record C wrote whose coils are not its channel's (its head and tail are
        known: a valid record of its key's module): what the careful path does after writing
        it, the scene's update and the channel's coils (under the lock)."""
        topic = self._routes[key].topic
        m = _SIM_TIME.search(payload)  # the head's (C checked: the only one)
        assert m is not None
        sim = int(m.group(1))
        name = topic[len(_ACTUATORS):]
        obj = _tail_record(payload[m.end(1):], name, sim)
        log_time = wall if self.time_source == "wall" else self._origin + sim
        if self._fox is not None:
            self._scene_sync()
            scene = self._fox.scene
            update = scene.feed_record(topic, obj, log_time)
            if update is not None:
                self._derived(SCENE_TOPIC, update, log_time)
                placed = scene.placed_look(name)
                if placed is not None:  # C draws this look with these coils from now on
                    fb = self._native
                    assert fb is not None
                    fb.scene_put(self._looks.setdefault(placed, len(self._looks) + 1), payload, scene.entity_rest(name))
            self._push_look(name)
        self._record_seen(key, topic, payload, obj, sim)

    def _scene_sync(self) -> None:
        """The scene's modules take the last records of the coil changes C wrote since the last
        call (it draws them, or finds them not placed), before Python reads or feeds the scene."""
        fb = self._native
        if fb is None or self._fox is None:
            return
        changed = fb.scene_changed()
        if changed:
            modules = self._fox.scene.modules
            for cid, sim, tail in changed:
                name = self._act_modules[cid]
                modules[name].actuators = kind_of(_ACTUATORS + name).decode(_tail_record(tail, name, sim))

    def _push_look(self, name: str) -> None:
        """Tell C the look of module ``name`` apart from its coils, as the scene has it now."""
        cid = self._cids.get(_ACTUATORS + name)
        fb = self._native
        if cid is None or fb is None or self._fox is None:
            return
        scene = self._fox.scene
        placed = scene.placed_look(name)
        self._act_modules[cid] = name
        if placed is not None:
            fb.scene_look(cid, self._looks.setdefault(placed, len(self._looks) + 1))
        else:
            fb.scene_look(cid, -1 if name in scene.modules else 0)

    def _new_key(self, fb: native.FrameBatch, key: str) -> None:
        """Enter a key in C's key table: how its samples are written there, on which channel."""
        route = self._routes.get(key)
        if route is None:
            route = self._routes[key] = _Route.of(self.keys.relative(key))
        topic = route.topic
        module = topic[len(_ACTUATORS):] if topic.startswith(_ACTUATORS) else ""
        if route.frame:
            how = native.KEY_FRAME
        elif module and _PLAIN.fullmatch(module):
            how = native.KEY_RECORD
        elif route.fast:
            how = native.KEY_FAST
        elif kind_of(topic) is BUS_EVENT:
            how = native.KEY_EVENT
        else:
            how = native.KEY_PYTHON
        kid = fb.key(key.encode(), how, self._cids.get(topic, 0))
        self._key_topics.append(topic)
        self._key_events.append(how == native.KEY_EVENT)
        self._topic_keys.setdefault(topic, []).append(kid)

    def _count_frames(self, keys: Sequence[str], slow: list[int], noise: bytes, first: int, last: int) -> None:
        """Count the frames of a native batch (every key but those of ``slow``): by key now,
        by topic and link when the tally is read (:meth:`_fold`)."""
        pending = self._pending
        pending.update(keys)
        for i in slow:
            pending[keys[i]] -= 1
        self._pending_frames += len(keys) - len(slow)
        i = noise.find(1)
        while i >= 0:
            self._pending_noise[keys[i]] += 1
            i = noise.find(1, i + 1)
        if self._part_first_ns is None:
            self._part_first_ns = first
        self._part.span(first, last)

    def _fold(self) -> None:
        """The frames counted by key into the open part's tally (under the lock)."""
        if not self._pending_frames:
            return
        if self._packed_pending:  # what fb_packed wrote, counted by key and event kind in C
            self._packed_pending = False
            fb = self._native
            assert fb is not None
            counts: Counter[str] = Counter()
            events: Counter[str] = Counter()
            noisy: Counter[str] = Counter()
            for kid, k, noise_k in fb.key_counts():
                topic = self._key_topics[kid]
                (events if self._key_events[kid] else counts)[topic] += k
                if noise_k:
                    noisy[topic] += noise_k
                self._pending_frames -= k
            self._part.add_counts(counts, noisy)
            self._part.add_events(events, fb.kind_counts())
            if not self._pending_frames:
                return
        by_topic: Counter[str] = Counter()
        for key, k in self._pending.items():
            if k:
                by_topic[self._routes[key].topic] += k
        noise: Counter[str] = Counter()
        for key, k in self._pending_noise.items():
            noise[self._routes[key].topic] += k
        self._part.add_counts(by_topic, noise)
        self._pending.clear()
        self._pending_noise.clear()
        self._pending_frames = 0

    def _write_one(self, route: _Route, key: str, payload: bytes, wall: int) -> None:
        fields = route.scan(payload) if route.fast and not self.strict else None
        if fields is None:
            self._write_checked(route, key, payload, wall)
            return
        sim, pub, kind = fields
        with self._lock:
            if sim is None:
                sim = self._last_sim_ns
            elif sim > self._last_sim_ns:
                self._last_sim_ns = sim
            log_time = wall if self.time_source == "wall" else self._origin + sim
            if self._closed:
                return
            if self.rotating:
                self._maybe_rotate(log_time)
            if self._part_first_ns is None:
                self._part_first_ns = log_time
            cid = self._cids.get(route.topic)
            if cid is None:
                cid = self._cids[route.topic] = self._sink.channel(route.topic)
            self._sink.write_to(cid, payload, log_time, wall if pub is None else pub)
            self._part.add_kind(route.topic, kind, log_time)
            if route.frame and self._fox is not None:
                self._derive(route.topic, payload, log_time, kind=kind)

    def _write_checked(self, route: _Route, key: str, payload: bytes, wall: int) -> None:
        """The careful path: decode the whole payload, check its schema's required fields."""
        topic = route.topic
        try:
            obj = self._decode_record(topic, payload)
        except ValueError as exc:  # UnicodeDecodeError is a ValueError
            self._error(topic, key, payload, wall, "not-json", str(exc))
            return
        sim = obj.get("sim_time_ns") if isinstance(obj, dict) else None
        if not _is_time(sim):
            sim = None
        required = self._required.get(topic)
        if required is None:
            required = self._required[topic] = _required(topic)
        if required:
            missing = [k for k in required if k not in obj] if isinstance(obj, dict) else list(required)
            if missing:
                self._error(topic, key, payload, wall, "missing-fields", f"{kind_of(topic).name} needs {missing}", sim)
                return
        pub = obj.get("wall_time_ns") if isinstance(obj, dict) else None
        with self._lock:
            if sim is not None and sim > self._last_sim_ns:
                self._last_sim_ns = sim
            log_time = wall if self.time_source == "wall" else self._origin + (self._last_sim_ns if sim is None else sim)
            self._write_locked(topic, payload, obj, log_time, pub if _is_time(pub) else wall)
            if self._closed:
                return
            if self._fox is not None:
                kind = obj.get("kind") if isinstance(obj, dict) else None
                self._derive(topic, payload, log_time, obj=obj, kind=kind if isinstance(kind, str) else None)
            if self._native is not None and topic.startswith(_ACTUATORS):
                self._record_seen(key, topic, payload, obj, sim)
            if topic == "meta" and isinstance(obj, dict) and not self._closed:
                self.meta = meta_mod.merge(self.meta, RunMeta.from_dict(obj))
                self._sink.add_metadata(self.meta)

    def _record_seen(self, key: str, topic: str, payload: bytes, obj: Any, sim: int | None) -> None:
        """Tell the C batch path an actuator record was written here (under the lock): the
        channel's coils are the scene's now, and the same bytes at another sim time may be
        written in C (framebatch.c ``record``), which this path would write, count by topic
        and derive nothing from. Where the scene did not take this record's coils, the
        channel's next record stays here."""
        fb = self._native
        assert fb is not None
        cid = self._cids[topic]
        self._act_modules[cid] = topic[len(_ACTUATORS):]
        module = obj.get("module") if isinstance(obj, dict) else None
        if self._fox is not None:
            m = self._fox.scene.modules.get(module) if isinstance(module, str) else None
            act = m.actuators if m is not None else None
            if (act is None or topic != f"{_ACTUATORS}{module}" or act.magnets != obj.get("magnets")
                    or act.joints_open != obj.get("joints_open")):
                fb.forget_coils(cid)
                own = self._cids.get(f"{_ACTUATORS}{module}") if isinstance(module, str) else None
                if own is not None and own != cid:  # the scene took another channel's module's coils
                    fb.forget_coils(own)
                return
        # its head as the fleet writes it: then its tail means the same after any module's head
        known = (sim is not None and "wall_time_ns" not in obj and isinstance(module, str)
                 and _PLAIN.fullmatch(module) is not None
                 and payload.startswith(b'{"module":"%s","sim_time_ns":' % module.encode()))
        fb.record_seen(cid, payload, known)
        self._frame_cids[key] = cid

    def _decode_record(self, topic: str, payload: bytes) -> Any:
        """The payload decoded; a record that differs from one seen before only in its
        ``sim_time_ns`` digits (an actuator record repeats a handful of port states all run
        long) is the earlier one's object with its own time, without decoding it again."""
        m = _SIM_TIME.search(payload)
        if m is None or topic == "meta":
            return _decode(payload.decode("utf-8"))
        sim = int(m.group(1))
        key = (topic, payload[:m.start(1)], payload[m.end(1):])
        seen = _RECORDS.get(key)
        if seen is not None:
            obj = seen.copy()
            obj["sim_time_ns"] = sim
            return obj
        obj = _decode(payload.decode("utf-8"))
        # the time found is the object's own, and no other field can look like it
        if isinstance(obj, dict) and obj.get("sim_time_ns") == sim and payload.count(b'"sim_time_ns":') == 1:
            if len(_RECORDS) >= _RECORDS_SEEN:
                _RECORDS.clear()
            _RECORDS[key] = obj.copy()
        return obj

    def _error(self, topic: str, key: str, payload: bytes, wall: int, reason: str, detail: str,
               sim: int | None = None) -> None:
        record = {"key": key, "topic": topic, "reason": reason, "detail": detail, "payload_hex": payload.hex(),
                  "wall_time_ns": wall, "sim_time_ns": sim}
        data = json.dumps(record, separators=(",", ":")).encode()
        with self._lock:
            log_time = wall if self.time_source == "wall" else self._origin + (self._last_sim_ns if sim is None else sim)
            self._write_locked(RECORDER_ERROR_TOPIC, data, record, log_time, wall)

    def _write_locked(self, topic: str, data: bytes, obj: Any, log_time: int, publish_time: int) -> None:
        if self._closed:
            return
        self._maybe_rotate(log_time)
        if self._part_first_ns is None:
            self._part_first_ns = log_time
        cid = self._cids.get(topic)
        if cid is None:
            cid = self._cids[topic] = self._sink.channel(topic)
        self._sink.write_to(cid, data, log_time, publish_time)
        self._part.add(topic, obj, log_time)

    # -- what the recorder derives for Foxglove ------------------------------------------------------
    def _derive(self, topic: str, payload: bytes, log_time: int, **known: Any) -> None:
        """The sample's Foxglove message, if it leads to one (under the lock)."""
        assert self._fox is not None
        scene = self._native is not None and topic.startswith(SCENE_TOPICS)
        if scene:
            self._scene_sync()
        out = self._fox.derive(topic, payload, log_time, **known)
        if out is not None:
            self._derived(*out, log_time)
        if scene:  # the module's look may have changed (placed, fixed, moving): C's copy too
            obj = known.get("obj")
            module = obj.get("module") if isinstance(obj, dict) else None
            if isinstance(module, str):
                self._push_look(module)

    def _derived(self, topic: str, data: bytes, log_time: int) -> None:
        """A message of the recorder's own (not a bus sample: not in the tally)."""
        cid = self._cids.get(topic)
        if cid is None:
            cid = self._cids[topic] = self._sink.channel(topic)
        self._sink.write_to(cid, data, log_time, log_time)

    def _snapshot(self) -> None:
        """The whole scene, at the latest time written: each part ends on (and a reader of the
        last scene message finds) every module where it is."""
        self._scene_sync()
        if self._fox is not None and self._fox.scene.modules:
            t = max((x for x in (self._part.last_ns, self._done.last_ns) if x is not None), default=0)
            self._derived(SCENE_TOPIC, self._fox.scene.snapshot(t), t)

    # -- parts and rotation --------------------------------------------------------------------
    @property
    def rotating(self) -> bool:
        return self.rotate_bytes is not None or self.rotate_ns is not None

    def _close_part(self) -> None:
        self._fold()
        self._snapshot()
        self._sink.close(self._part)
        self._done.merge(self._part)
        self._part = Tally()

    def _open_part(self) -> McapSink:
        path = part_path(self.out, len(self.paths) + 1) if self.rotating else self.out
        path.parent.mkdir(parents=True, exist_ok=True)
        sink = McapSink(path, fleet=self.keys.fleet, compression=self.compression,
                        chunk_size=self.chunk_size)
        sink.add_metadata(self.meta)
        sink.flush()  # the header and metadata reach the disk at once
        self.paths.append(path)
        self._part_first_ns = None
        self._cids = {}  # channel ids are per file
        self._frame_cids = _NoChannel()
        self._native_live = False
        self._act_modules = {}
        if getattr(self, "_native", None) is not None:
            self._native.reset_records()
        return sink

    def _maybe_rotate(self, log_time: int | None) -> None:
        """Start the next part if this one is old or big enough (``log_time`` None: size only)."""
        if not self.rotating or self._part_first_ns is None:
            return
        due = (log_time is not None and self.rotate_ns is not None
               and log_time - self._part_first_ns >= self.rotate_ns)
        if not due and self.rotate_bytes is not None:
            self._since_size_check += 1
            if log_time is None or self._since_size_check >= _CHECK_SIZE_EVERY:
                self._since_size_check = 0
                due = self._sink.size() >= self.rotate_bytes
        if due:
            self._close_part()
            self._sink = self._open_part()

    # -- flushing and closing ----------------------------------------------------------------
    def flush(self) -> None:
        """Hand everything written so far to the OS now."""
        with self._lock:
            if not self._closed:
                self._sink.flush()

    def _flush_loop(self) -> None:
        # Why a thread: under a virtual clock, a flush timer on the clock would be sim time
        # (and would keep the run from ever running out of events).
        while not self._stop.wait(self.flush_interval_s):
            with self._lock:
                if self._closed:
                    return
                if self._sink.dirty:
                    self._sink.flush()
                    self._maybe_rotate(None)

    def close(self) -> Tally:
        """Write footers and return the counts; later samples are ignored.

        Subscriptions stay declared (the Bus owns them and closes them): undeclaring one
        behind the Bus's back would leave a virtual clock waiting for its deliveries.
        """
        with self._lock:
            if not self._closed:
                self._closed = True
                self._close_part()
        self._stop.set()
        if self._flusher.is_alive() and threading.current_thread() is not self._flusher:
            self._flusher.join()
        return self.tally

    @property
    def tally(self) -> Tally:
        """Counts of everything written so far (all parts)."""
        with self._lock:
            self._fold()
            out = Tally()
            out.merge(self._done)
            out.merge(self._part)
        return out

    @property
    def messages(self) -> int:
        """Samples written so far (cheap; for polling)."""
        return self._done.messages + self._part.messages + self._pending_frames

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
