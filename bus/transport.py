"""The participant's view of the bus: publish and subscribe through zenoh,
with callbacks run on the clock thread (and counted, so a virtual clock knows
when every sample has been delivered)."""

from __future__ import annotations

import atexit
import itertools
import json
import os
from typing import Any, Callable

import zenoh

from .clock import Clock, make_clock
from .codec import Frame
from .envelope import SCHEMA_VERSION, Envelope
from .errors import UsageError
from .keys import Keys, check_chunk
from .session import SessionOptions, open_session


class Bus:
    """One zenoh session shared by the participants of a process."""

    def __init__(self, clock: Clock, fleet: str = "default", *,
                 session: zenoh.Session | None = None, options: SessionOptions | None = None) -> None:
        self.clock = clock
        self.keys = Keys(fleet)
        self._own_session = session is None
        self.session = session if session is not None else open_session(options)
        self._subs: list[tuple[zenoh.KeyExpr, Any]] = []
        self._match_cache: dict[str, int] = {}
        self._exact: dict[str, int] = {}  # subscriptions to one key (canonical), by key
        self._wild: list[zenoh.KeyExpr] = []  # subscriptions with wildcards
        self._publishers: dict[str, Any] = {}
        self._pub_order = itertools.count()
        self._seq: dict[str, int] = {}
        self.published = 0
        self.closed = False
        # Attachment = this Bus's token + publish order: receivers know which samples are
        # local (counted by the delivery barrier) and in which order they were published.
        self._token = os.urandom(8)
        atexit.register(self.close)

    # -- publishing ----------------------------------------------------------------------
    def _local_matches(self, key: str) -> int:
        n = self._match_cache.get(key)
        if n is None:
            # a subscription without wildcards matches only its own key
            n = self._exact.get(key, 0)
            if self._wild:
                ke = zenoh.KeyExpr(key)
                n += sum(1 for k in self._wild if k.intersects(ke))
            self._match_cache[key] = n
        return n

    def put(self, key: str, payload: bytes) -> None:
        """Publish raw bytes; attachments carry the publish order for deterministic handling."""
        if self.closed:
            return
        order = next(self._pub_order)
        self.clock.expect(self._local_matches(key))
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._publishers[key] = self.session.declare_publisher(key)
        pub.put(payload, attachment=self._token + order.to_bytes(8, "big"))
        self.published += 1

    def put_json(self, key: str, obj: Any) -> None:
        self.put(key, _dumps(obj).encode())

    def next_seq(self, src: str) -> int:
        n = self._seq.get(src, 0)
        self._seq[src] = n + 1
        return n

    def publish_frame(self, frame: Frame, *, src: str, dst: str, sim_time_ns: int | None = None,
                      **extra: Any) -> Envelope:
        env = Envelope.of(frame, src=src, dst=dst,
                          sim_time_ns=self.clock.now_ns() if sim_time_ns is None else sim_time_ns,
                          wall_time_ns=self.clock.wall_ns(), seq=self.next_seq(src), **extra)
        self.put(self.keys.frame(frame.link.value, src), _envelope_json(env))
        return env

    def event(self, src: str, kind: str, **fields: Any) -> None:
        """Errors are data: publish an event (overrun, collision, timeout, fault...)."""
        self.put_json(self.keys.event(src), {"kind": kind, "src": src,
                                             "sim_time_ns": self.clock.now_ns(), **fields})

    # -- subscribing ---------------------------------------------------------------------
    def subscribe(self, keyexpr: str, handler: Callable[[str, bytes], None]) -> Any:
        """``handler(key, payload)`` runs on the clock thread."""
        index = len(self._subs)
        clock = self.clock
        token = self._token

        def on_sample(sample: zenoh.Sample) -> None:
            att = sample.attachment
            att = att.to_bytes() if att is not None else b""
            key = str(sample.key_expr)
            data = sample.payload.to_bytes()
            if len(att) == 16 and att[:8] == token:
                clock.post_delivered(handler, (key, data), (float(int.from_bytes(att[8:], "big")), index))
            else:
                clock.post(handler, key, data)

        sub = self.session.declare_subscriber(keyexpr, on_sample)
        ke = zenoh.KeyExpr(keyexpr)
        self._subs.append((ke, sub))
        canon = str(ke)
        if "*" in canon or "$" in canon:
            self._wild.append(ke)
        else:
            self._exact[canon] = self._exact.get(canon, 0) + 1
        self._match_cache.clear()
        return sub

    def subscribe_json(self, keyexpr: str, handler: Callable[[str, Any], None]) -> Any:
        """``handler(key, obj)`` with the payload decoded from JSON."""
        return self.subscribe(keyexpr, lambda k, p: handler(k, json.loads(p)))

    def subscribe_frames(self, handler: Callable[[Envelope], None], link: str | None = None, *,
                         keyexpr: str | None = None) -> Any:
        """``handler(envelope)`` for every frame (of one ``link``, or under ``keyexpr``):
        receivers get typed envelopes, as python-can's listeners get messages."""
        if keyexpr is None:
            keyexpr = self.keys.frames if link is None else self.keys.frames_of(link)
        return self.subscribe(keyexpr, lambda k, p: handler(Envelope.from_json(p)))

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for _, sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
        if self._own_session:
            self.session.close()


def open_bus(args: Any, clock: Clock | None = None) -> Bus:
    """The one way a CLI opens its bus (python-can's ``create_bus_from_namespace``): from the
    options of :func:`bus.session.add_arguments` (``--fleet``, ``--connect``, ``--listen``,
    ``--mode``, ``--isolated``) and ``--clock`` (``wall`` unless the parser has one).
    A fleet name unusable in a key is a :class:`~bus.errors.UsageError`."""
    fleet = getattr(args, "fleet", None) or "default"
    try:
        check_chunk(fleet, "fleet")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if clock is None:
        clock = make_clock(getattr(args, "clock", None) or "wall")
    return Bus(clock, fleet, options=SessionOptions.from_args(args))


_dumps = json.JSONEncoder(separators=(",", ":")).encode


def _envelope_json(e: Envelope) -> bytes:
    """``Envelope.to_json()`` byte for byte (same keys, same order), without asdict's deep copies."""
    return _dumps({"link": e.link, "src": e.src, "dst": e.dst, "raw": e.raw.hex(),
                   "sim_time_ns": e.sim_time_ns, "wall_time_ns": e.wall_time_ns, "seq": e.seq,
                   "kind": e.kind, "view": e.view, "first_byte_ns": e.first_byte_ns,
                   "origin": e.origin, "channel": e.channel, "v": SCHEMA_VERSION}).encode()
