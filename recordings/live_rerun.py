"""A run streamed to a rerun viewer while it goes: the same entities and archetypes as the
.rrd replay (:mod:`recordings.replay`), drawn by the same code, a flush at a time.

:class:`LiveRerun` attaches to a bus like the recorder. Its bus handler only queues the
sample; a thread of its own decodes what came in every ``flush_interval_s``, feeds it to a
:class:`recordings.replay.ReplayBuilder` and sends the rows drawn since the last flush with
``send_columns``. Module tracks keep their state (placement, actuators, the move in progress,
lit IR) from one flush to the next. Timeline ``sim_time``: each sample's ``sim_time_ns``.
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from collections import deque
from typing import Any, Callable
from urllib.parse import urlsplit

import fastjsonschema
import rerun as rr

from bus.envelope import Envelope
from bus.keys import Keys
from bus.messages import RunMeta

from . import meta as meta_mod
from .reader import Sample, Undecodable
from .replay import APP_ID, ReplayBuilder, blueprint, send_grid, send_meta, send_styles
from .schemas import ChannelKind, kind_of

log = logging.getLogger(__name__)
_decode_json = json.JSONDecoder().decode

#: How far behind the newest sim time module tracks are drawn, at least. An IR burst is drawn
#: from its frame's first byte, but the frame arrives with its last one: events come up to a
#: frame's duration late (a 26-byte frame at 300 baud: 0.87 s). The longest one seen so far
#: widens the margin further.
HOLD_BACK_NS = 1_000_000_000
#: A lattice larger than this is not drawn (a pose far away, bogus or not, would stall flushes).
MAX_GRID_CELLS = 40_000


class LiveRerun:
    """Streams a run on a bus to ``recording`` (see :func:`open_stream`) while it goes.

    Thread-safe: samples may come from any thread. Call :meth:`close` at the end of the run:
    it draws what is still held back and flushes the stream (the stream stays open: the
    caller owns it).
    """

    def __init__(self, recording: rr.RecordingStream, *, fleet: str = "default", flush_interval_s: float = 0.1,
                 meta: dict[str, Any] | None = None, hold_back_ns: int = HOLD_BACK_NS,
                 anim_step_ns: int = 20_000_000) -> None:
        self.recording = recording
        self.keys = Keys(fleet)
        self.flush_interval_s = flush_interval_s
        self.hold_back_ns = hold_back_ns
        self.meta: dict[str, Any] = dict(meta or {})
        self.builder = ReplayBuilder(anim_step_ns=anim_step_ns)
        self.samples = 0  # decoded so far (undecodable ones included)
        self.undecodable = 0
        self.flushes = 0
        self.rows = 0  # rows sent so far
        self.flush_error: str | None = None  # why the last flush of the stream failed
        self._inbox: deque[tuple[str, Any]] = deque()  # appends and pops are atomic: no lock on the bus thread
        self._topics: dict[str, str] = {}  # key -> topic
        self._sim_ns = 0  # newest sim time seen
        self._late_ns = 0  # longest delay of an IR burst's start behind its frame's time
        self._grid_bounds: tuple[int, int, int, int] | None = None
        self._step_lock = threading.Lock()  # one flush at a time (the thread, or close())
        self._closed = False
        self._stop = threading.Event()
        send_styles(recording)
        send_meta(recording, self.meta)
        self._thread = threading.Thread(target=self._loop, name="live-rerun", daemon=True)
        self._thread.start()

    # -- the bus side ------------------------------------------------------------------------------
    def attach(self, bus: Any) -> None:
        """Subscribe to everything of ``bus``'s fleet (a :class:`bus.transport.Bus`)."""
        if bus.keys.root != self.keys.root:
            raise ValueError(f"live view is for {self.keys.root}, bus is {bus.keys.root}")
        bus.subscribe(self.keys.all, self.on_sample)

    def on_sample(self, key: str, payload: bytes) -> None:
        """Bus handler: queue one sample (decoded and drawn on the flush thread, so the bus
        clock's thread pays one append). Never raises: a bad payload is drawn as an error."""
        if not self._closed:
            self._inbox.append((key, payload))

    # -- the flush side ----------------------------------------------------------------------------
    def _loop(self) -> None:
        # A thread, not a timer on the bus clock: under a virtual clock that would be sim time.
        while not self._stop.wait(self.flush_interval_s):
            try:
                self._flush(final=False)
            except Exception:  # a drawing bug must not stop the live view, nor go unseen
                log.exception("live rerun: a flush failed")

    def _flush(self, *, final: bool) -> None:
        with self._step_lock:
            b = self.builder
            items = self._take()
            for item in items:
                try:
                    b.feed((item,))
                except Exception as exc:  # a value that fits its schema but not the drawing
                    self.undecodable += 1
                    b.feed(((item[0], item[1], Undecodable(item[1], f"{type(exc).__name__}: {exc}")),))
            # Module tracks are drawn up to a horizon held back behind the newest time (events
            # can still come for the times after it); the other rows are drawn as they come.
            if final:
                b.render()
            elif (horizon := self._sim_ns - max(self.hold_back_ns, self._late_ns)) > 0:
                b.render(horizon)
            self._send_grid()
            rows = b.scene.rows
            if rows:
                b.scene.send(self.recording)
                b.scene.clear()
                self.rows += rows
            self.flushes += 1

    def _take(self) -> list[tuple[int, Sample, Any]]:
        """Decode everything queued, in arrival order."""
        out: list[tuple[int, Sample, Any]] = []
        inbox = self._inbox
        while inbox:
            key, payload = inbox.popleft()
            item = self._decode(key, payload)
            if item is not None:
                out.append(item)
        return out

    def _decode(self, key: Any, payload: Any) -> tuple[int, Sample, Any] | None:
        """``(t_ns, sample, typed value or Undecodable)``; None for what is not ours."""
        if not isinstance(key, str):  # no topic to show it under
            self.undecodable += 1
            return None
        topic = self._topics.get(key)
        if topic is None:
            topic = self._topics[key] = self.keys.relative(key)
        self.samples += 1
        obj: Any = None
        reason = ""
        if isinstance(payload, (bytes, bytearray, memoryview)):
            data = bytes(payload)
            try:
                obj = _decode_json(data.decode("utf-8"))
            except ValueError as exc:  # UnicodeDecodeError is a ValueError
                reason = f"not JSON: {exc}"
        else:
            data, reason = b"", f"payload is a {type(payload).__name__}, not bytes"
        sim = obj.get("sim_time_ns") if isinstance(obj, dict) else None
        if isinstance(sim, int) and not isinstance(sim, bool) and sim >= 0:
            self._sim_ns = max(self._sim_ns, sim)
            t = sim
        else:  # no time of its own: the newest seen
            t = self._sim_ns
        sample = Sample(topic, t, time.time_ns(), data)
        if reason:
            self.undecodable += 1
            return t, sample, Undecodable(sample, reason)
        kind = kind_of(topic)
        # Drawing trusts the field types (a pose's cell must be integers...): a payload that
        # breaks its schema is shown as an error instead of failing a flush later.
        wrong = _misfit(obj, kind)
        if wrong:
            self.undecodable += 1
            return t, sample, Undecodable(sample, f"does not fit {kind.name}: {wrong}")
        try:
            value = kind.decode(obj)
        except Exception as exc:  # any other shape of bad payload: shown, never raised
            self.undecodable += 1
            return t, sample, Undecodable(sample, f"{type(exc).__name__}: {exc}")
        if isinstance(value, Envelope) and value.channel is not None and value.first_byte_ns is not None:
            self._late_ns = max(self._late_ns, value.sim_time_ns - value.first_byte_ns)
        elif isinstance(value, RunMeta):
            self.meta = meta_mod.merge(self.meta, value)
            send_meta(self.recording, self.meta)
        return t, sample, value

    def _send_grid(self) -> None:
        """The lattice again when the cells seen reach further."""
        cells = self.builder.cells_seen
        if not cells:
            return
        xs = [c[0] for c in cells]
        ys = [c[1] for c in cells]
        bounds = (min(xs), max(xs), min(ys), max(ys))
        size = (bounds[1] - bounds[0] + 5) * (bounds[3] - bounds[2] + 5)  # with the grid's margins
        if bounds != self._grid_bounds and size <= MAX_GRID_CELLS:
            self._grid_bounds = bounds
            send_grid(self.recording, self.builder.grid())

    def close(self, timeout_s: float = 30.0) -> None:
        """Draw and send everything pending, stop the flush thread and flush the stream
        (waiting at most ``timeout_s`` for it). Later samples are ignored.

        A viewer that cannot be reached does not fail the run that is ending: the reason is
        logged and kept in :attr:`flush_error`."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if threading.current_thread() is not self._thread:
            self._thread.join()
        self._flush(final=True)
        try:
            self.recording.flush(timeout_sec=timeout_s)
        except RuntimeError as exc:  # rerun's "unable to connect" and flush timeouts
            self.flush_error = str(exc)
            log.warning("live rerun: %s", exc)

    def __enter__(self) -> "LiveRerun":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_stream(*, connect: str | None = None, spawn: bool = False,
                recording_id: str | None = None) -> rr.RecordingStream:
    """A recording stream to a viewer, with the replay's blueprint.

    ``connect``: a viewer's or proxy's gRPC URL (``rerun+http://127.0.0.1:9876/proxy``).
    ``spawn``: start a viewer (on the port of ``connect`` if given, else rerun's default)
    unless one listens there already, and stream to it.
    """
    if connect is None and not spawn:
        raise ValueError("a live view needs a viewer URL to connect to or spawn=True")
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id or str(uuid.uuid4()))
    bp = blueprint()
    if spawn:
        port = urlsplit(connect).port if connect else None
        if port is None:
            rec.spawn(default_blueprint=bp)
        else:
            rec.spawn(port=port, default_blueprint=bp)
    else:
        rec.connect_grpc(connect, default_blueprint=bp)
    return rec


_checks: dict[str, Callable[[Any], Any]] = {}


def _misfit(value: Any, kind: ChannelKind) -> str | None:
    """Why ``value`` breaks ``kind``'s JSON Schema (``x must be integer``), or None; schemaless
    kinds take anything. Validators are compiled once per kind: every frame is checked."""
    check = _checks.get(kind.name)
    if check is None:
        check = _checks[kind.name] = fastjsonschema.compile(kind.schema) if kind.schema else (lambda v: v)
    try:
        check(value)
    except fastjsonschema.JsonSchemaValueException as exc:
        return exc.message.removeprefix("data.").removeprefix("data ")
    return None
