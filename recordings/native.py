"""The recorder's compiled batch path for frames, actuator records, events and light
(``native/framebatch.c``, loaded with ctypes).

A frame costs the pure-Python recorder a few microseconds (its fields read by a regex, two
records packed, indexed and counted, its Foxglove line stamped); a fleet puts hundreds of
thousands a second. :class:`FrameBatch` hands a whole batch of frame envelopes to C, which
writes the records :meth:`recordings.recorder.Recorder.write` would (the same bytes, sequence
numbers, chunk offsets) and stops whenever Python must act: a sample that is not an envelope
as the bus writes it, a channel or a Foxglove line not seen yet, a full chunk. It writes an
actuator record too when its head (``{"module":"<its module>","sim_time_ns":``) is one Python
wrote on that channel, its tail (the bytes after its time) one Python wrote on any channel,
and its coils the channel's last (:meth:`FrameBatch.record_seen`): what the careful path would
write, count by topic and derive nothing from. :func:`index_records` writes a chunk's
MessageIndex records.

A batch in ``bus.transport.pack_batch``'s bytes (:meth:`recordings.recorder.Recorder.write_packed`)
goes to C whole (``fb_packed``): C keeps the recorder's keys (how each key's samples are
written, on which channel), writes frames, actuator records, events and light, makes the Log
line of a frame whose describe text it holds (:meth:`FrameBatch.describe`), and counts by key
and event kind until Python folds the counts into its tally. The Log lines live in C for both
paths and for Python's own (``FrameLog.shared``), so a line once made is its frame's line
everywhere.

The library is built with ``make -C recordings/native`` when missing or older than its source
(only a C compiler is needed). Without it — no compiler, or ``HEXBENCH_NATIVE=0`` — :data:`LIB`
is None and the recorder takes its pure-Python path, record for record the same.
"""

from __future__ import annotations

import ctypes
import fcntl
import os
import subprocess
import threading
from array import array
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent / "native"
LIB_PATH = HERE / "build" / "libframebatch.so"
#: fb_frames's and fb_packed's answers (framebatch.c)
(DONE, NOT_FRAME, NEW_CHANNEL, NEW_LOG_CHANNEL, REST_MISS, CHUNK_FULL, OUT_FULL, GROW_SEQS, NEW_KEY, PYTHON,
 BAD_BATCH, COILS, NEW_SCENE_CHANNEL) = range(13)
#: how fb_packed writes the samples of a key (framebatch.c FB_KEY_*)
KEY_PYTHON, KEY_FRAME, KEY_RECORD, KEY_FAST, KEY_EVENT = range(5)
_p = ctypes.c_void_p
_i32, _i64 = ctypes.c_int32, ctypes.c_int64


class _Batch(ctypes.Structure):
    """batch_t of framebatch.c."""

    _fields_ = [("buf", ctypes.c_char_p), ("offs", _p), ("n", _i64), ("cids", _p), ("log_cid", _i32), ("by_sim", _i32),
                ("origin", _i64), ("wall", _i64), ("seqs", _p), ("nseqs", _i64), ("rests", _p),
                ("out", _p), ("out_cap", _i64), ("out_len", _i64),
                ("chunk_bytes", _i64), ("chunk_messages", _i64), ("chunk_start", _i64), ("chunk_end", _i64),
                ("limit", _i64), ("ix_cid", _p), ("ix_time", _p), ("ix_off", _p), ("ix_cap", _i64),
                ("ix_len", _i64), ("frames", _i64), ("tmin", _i64), ("tmax", _i64), ("last_sim", _i64),
                ("noise", _p), ("item", _i64), ("phase", _i32), ("no_log", _i32),
                ("head_at", _i64), ("head_len", _i64), ("kind_at", _i64), ("kind_len", _i64),
                ("log_time", _i64), ("recs", _p), ("records", _i64),
                ("packed", ctypes.c_char_p), ("packed_len", _i64), ("pos", _i64), ("key_id", _i64), ("samples", _i64),
                ("keys", _p), ("kinds", _p), ("events", _i64),
                ("scene_cid", _i32), ("scene_rest", _p), ("scene_rest_len", _i64)]


def _build() -> None:
    """``make`` the library if it is missing or older than its source, one process at a time
    (pytest's workers start together); in a read-only install, use what is there."""
    source = HERE / "framebatch.c"
    try:
        LIB_PATH.parent.mkdir(exist_ok=True)
        lock = open(LIB_PATH.parent / ".lock", "w")
    except OSError:
        return
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if source.exists() and (not LIB_PATH.exists() or source.stat().st_mtime > LIB_PATH.stat().st_mtime):
            subprocess.run(["make", "-s", "-C", str(HERE)], check=True, capture_output=True, timeout=120)


def _load() -> Any:
    if os.environ.get("HEXBENCH_NATIVE", "1") == "0":
        return None
    try:
        _build()
        lib = ctypes.CDLL(str(LIB_PATH))
    except (OSError, subprocess.SubprocessError):
        return None  # no compiler, no make, no library: the pure-Python path
    lib.fb_table_new.restype = _p
    lib.fb_table_free.argtypes = [_p]
    lib.fb_table_put.argtypes = [_p, ctypes.c_char_p, _i32, ctypes.c_char_p, _i32, ctypes.c_char_p, _i32]
    lib.fb_table_put.restype = ctypes.c_int
    lib.fb_frames.argtypes = [ctypes.POINTER(_Batch)]
    lib.fb_frames.restype = ctypes.c_int
    lib.fb_index.argtypes = [_p, _p, _p, _i64, _p, _p, _p, ctypes.POINTER(_i64)]
    lib.fb_index.restype = _i64
    lib.fb_records_new.restype = _p
    lib.fb_records_free.argtypes = [_p]
    lib.fb_record_seen.argtypes = [_p, _i32, ctypes.c_char_p, _i64, _i32]
    lib.fb_record_seen.restype = ctypes.c_int
    lib.fb_table_get.argtypes = [_p, ctypes.c_char_p, _i32, ctypes.c_char_p, _i32, _p, _i64]
    lib.fb_table_get.restype = _i64
    lib.fb_keys_new.restype = _p
    lib.fb_keys_free.argtypes = [_p]
    lib.fb_key_put.argtypes = [_p, ctypes.c_char_p, _i32, _i32, _i32]
    lib.fb_key_put.restype = _i64
    lib.fb_key_set_cid.argtypes = [_p, _i64, _i32]
    lib.fb_keys_new_file.argtypes = [_p]
    lib.fb_key_counts.argtypes = [_p, _p, _p, _p]
    lib.fb_key_counts.restype = _i64
    lib.fb_kind_counts.argtypes = [_p, _p, _i64]
    lib.fb_kind_counts.restype = _i64
    lib.fb_describe_put.argtypes = [_p, ctypes.c_char_p, _i64, ctypes.c_char_p, _i32]
    lib.fb_describe_put.restype = ctypes.c_int
    lib.fb_scene_look.argtypes = [_p, _i32, _i32]
    lib.fb_scene_look.restype = ctypes.c_int
    lib.fb_scene_put.argtypes = [_p, _i32, ctypes.c_char_p, _i64, ctypes.c_char_p, _i32]
    lib.fb_scene_put.restype = ctypes.c_int
    lib.fb_scene_changed.argtypes = [_p, _p, _p, _p, _p, _i64]
    lib.fb_scene_changed.restype = _i64
    lib.fb_packed.argtypes = [ctypes.POINTER(_Batch)]
    lib.fb_packed.restype = ctypes.c_int
    return lib


_lock = threading.Lock()
_lib: Any = False  # not loaded yet


def lib() -> Any:
    """The loaded library, or None (the pure-Python path)."""
    global _lib
    if _lib is False:
        with _lock:
            if _lib is False:
                _lib = _load()
    return _lib


def _address(a: array) -> int:
    return a.buffer_info()[0]


def index_records(cids: array, times: array, offsets: array) -> tuple[bytes, list[tuple[int, int]]] | None:
    """A chunk's MessageIndex records (channels in the order of their first message) and, per
    channel, ``(id, offset of its record in those bytes)``; None without the library."""
    native = lib()
    if native is None:
        return None
    n = len(cids)
    out = ctypes.create_string_buffer(15 * n + 16 * n)
    chan = array("i", bytes(4 * n))
    at = array("q", bytes(8 * n))
    size = _i64(0)
    channels = native.fb_index(_address(cids), _address(times), _address(offsets), n, out, _address(chan),
                               _address(at), ctypes.byref(size))
    if channels < 0:
        raise MemoryError("fb_index")
    return out.raw[:size.value], list(zip(chan[:channels], at[:channels]))


class FrameBatch:
    """The C side of one recorder's batches: its table of Foxglove lines (and of the describe
    texts they are made from), its records, its keys, its buffers."""

    OUT_BYTES = 1 << 20
    PACKED_INDEX = 1 << 14  # index entries of a packed batch's records between two commits

    def __init__(self) -> None:
        native = lib()
        assert native is not None
        self.lib = native
        self.rests = native.fb_table_new()
        self.records = native.fb_records_new()
        self.keys = native.fb_keys_new()
        self.kinds = native.fb_table_new()
        if not self.rests or not self.records or not self.keys or not self.kinds:
            raise MemoryError("fb_table_new")
        self.state = _Batch()
        self.state.recs = self.records
        self.state.keys = self.keys
        self.state.kinds = self.kinds
        self.out = ctypes.create_string_buffer(self.OUT_BYTES)
        self.noise = ctypes.create_string_buffer(0)
        self.ix: tuple[array, array, array] = (array("i"), array("q"), array("q"))
        self.nkeys = 0
        self._line = ctypes.create_string_buffer(1024)
        self._changed = (array("i", bytes(4 * 1024)), array("q", bytes(8 * 1024)), array("Q", bytes(8 * 1024)),
                         array("i", bytes(4 * 1024)))

    def __del__(self) -> None:
        for name, free in (("rests", "fb_table_free"), ("records", "fb_records_free"), ("keys", "fb_keys_free"),
                           ("kinds", "fb_table_free")):
            handle = getattr(self, name, None)
            setattr(self, name, None)
            if handle:
                getattr(self.lib, free)(handle)

    def remember(self, head: bytes, kind: bytes, rest: bytes) -> None:
        """A Foxglove line of (head, kind), for the next frames that have them."""
        if self.lib.fb_table_put(self.rests, head, len(head), kind, len(kind), rest, len(rest)) != 0:
            raise MemoryError("fb_table_put")

    def line(self, head: bytes, kind: bytes) -> bytes | None:
        """The Foxglove line of (head, kind) remembered or made here, or None."""
        n = self.lib.fb_table_get(self.rests, head, len(head), kind, len(kind), self._line, len(self._line))
        if n > len(self._line):
            self._line = ctypes.create_string_buffer(n)
            n = self.lib.fb_table_get(self.rests, head, len(head), kind, len(kind), self._line, n)
        return None if n < 0 else self._line.raw[:n]

    def describe(self, envelope: bytes, text: bytes) -> None:
        """``text`` describes every frame with this envelope's link, kind, raw and view (the
        envelope exactly as ``Envelope.to_json`` writes it): fb_packed makes their lines."""
        if self.lib.fb_describe_put(self.rests, envelope, len(envelope), text, len(text)) < 0:
            raise MemoryError("fb_describe_put")

    def key(self, key: bytes, how: int, cid: int) -> int:
        """Enter a key (``how``: KEY_*; ``cid``: its channel, 0 none yet); its number."""
        kid = self.lib.fb_key_put(self.keys, key, len(key), how, cid)
        if kid < 0:
            raise MemoryError("fb_key_put")
        self.nkeys = kid + 1
        return kid

    def key_channel(self, kid: int, cid: int) -> None:
        self.lib.fb_key_set_cid(self.keys, kid, cid)

    def key_counts(self) -> list[tuple[int, int, int]]:
        """``(key number, samples, noise frames)`` written in C since the last call."""
        n = self.nkeys
        if not n:
            return []
        ids, counts, noise = array("q", bytes(8 * n)), array("q", bytes(8 * n)), array("q", bytes(8 * n))
        m = self.lib.fb_key_counts(self.keys, _address(ids), _address(counts), _address(noise))
        return list(zip(ids[:m], counts[:m], noise[:m]))

    def kind_counts(self) -> dict[str, int]:
        """Events written in C since the last call, by kind."""
        size = 4096
        while True:
            out = ctypes.create_string_buffer(size)
            n = self.lib.fb_kind_counts(self.kinds, out, size)
            if n >= 0:
                break
            size *= 4
        raw, got, i = out.raw[:n], {}, 0
        while i < n:
            j = raw.index(0, i)
            got[raw[i:j].decode()] = int.from_bytes(raw[j + 1:j + 9], "little")
            i = j + 9
        return got

    def scene_look(self, cid: int, look: int) -> None:
        """The look of channel ``cid``'s module apart from its coils: a number (> 0) that stands
        for it, -1 not placed (drawn nowhere), 0 unknown (its next coil change is Python's)."""
        if self.lib.fb_scene_look(self.records, cid, look) != 0:
            raise MemoryError("fb_scene_look")

    def scene_put(self, look: int, record: bytes, rest: bytes) -> None:
        """``rest`` draws ``look`` with ``record``'s coils: C writes the scene's update of the
        next such coil change itself."""
        if self.lib.fb_scene_put(self.records, look, record, len(record), rest, len(rest)) < 0:
            raise MemoryError("fb_scene_put")

    def scene_changed(self) -> list[tuple[int, int, bytes]]:
        """``(channel, sim time, tail)`` of the last record of each channel whose coils C
        changed since the last call (the scene's module must take it)."""
        cids, sims, tails, lens = self._changed
        got: list[tuple[int, int, bytes]] = []
        while True:
            n = self.lib.fb_scene_changed(self.records, _address(cids), _address(sims), _address(tails),
                                          _address(lens), len(cids))
            got += [(cids[i], sims[i], ctypes.string_at(tails[i], lens[i])) for i in range(n)]
            if n < len(cids):
                return got

    def run_packed(self) -> int:
        return self.lib.fb_packed(ctypes.byref(self.state))

    def record_seen(self, cid: int, payload: bytes, known: bool) -> None:
        """Python wrote record ``payload`` on channel ``cid``: its coils are the channel's now
        (the scene's), and, if ``known``, the same bytes with another sim time may be written
        in C from now on (the careful path would write, count and derive them alike)."""
        if self.lib.fb_record_seen(self.records, cid, payload, len(payload), int(known)) != 0:
            raise MemoryError("fb_record_seen")

    def reset_records(self) -> None:
        """A new file: its channel ids are new, so nothing Python saw holds for them."""
        fresh = self.lib.fb_records_new()
        if not fresh:
            raise MemoryError("fb_records_new")
        self.lib.fb_records_free(self.records)
        self.records = self.state.recs = fresh
        self.lib.fb_keys_new_file(self.keys)

    def forget_coils(self, cid: int) -> None:
        """The channel's next record is Python's (its scene state is not known here)."""
        self.lib.fb_record_seen(self.records, cid, b"", 0, 0)

    def grow_out(self, at_least: int) -> None:
        size = max(at_least, 2 * len(self.out))
        self.out = ctypes.create_string_buffer(size)

    def prepare(self, n: int) -> None:
        """Room for the index entries and noise flags of ``n`` samples (two records each)."""
        if len(self.ix[0]) < 2 * n:
            more = 2 * n - len(self.ix[0])
            self.ix[0].frombytes(bytes(4 * more))
            self.ix[1].frombytes(bytes(8 * more))
            self.ix[2].frombytes(bytes(8 * more))
        if len(self.noise) < n:
            self.noise = ctypes.create_string_buffer(n)
        else:
            ctypes.memset(self.noise, 0, n)

    def run(self) -> int:
        return self.lib.fb_frames(ctypes.byref(self.state))
