"""A run served live to the Foxglove app over Foxglove's WebSocket protocol (foxglove-sdk's server).

The same channels as a recording (:mod:`recordings.recorder`): every bus key as a JSON channel with
its JSON Schema (:mod:`recordings.schemas`), the scene (``foxglove/scene``,
``foxglove.SceneUpdate``) and the frame log (``foxglove/log``, ``foxglove.Log``) made by
:mod:`recordings.foxglove`. Open ``ws://127.0.0.1:8765`` in Foxglove ("Open connection" →
Foxglove WebSocket). Loopback by default: the server has no authentication.

Times are those of the recording: a start instant plus sim time on the virtual clock, the wall
clock otherwise. A client that connects late gets each channel's messages from then on, plus the
whole scene again (a snapshot is sent on every new subscription to the scene).

The scene and the log channels are made before the server listens. The SDK tells a connected
client of a channel made later before it records that channel for the client, so a client that
subscribes as soon as it hears of one (the Foxglove app for an open panel) can be refused
("unknown channel"); channels that exist when a client connects are recorded before the SDK reads
anything from it. A bus key's channel is made the first time the key carries a sample.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import foxglove
from foxglove import Channel, Schema

from bus.keys import Keys

from .foxglove import FoxgloveView
from .recorder import int_field
from .schemas import DERIVED, SCENE_TOPIC, kind_of

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765


class LiveFoxglove:
    """Serves bus samples of one fleet on a Foxglove WebSocket while a run goes.

    ``port=0`` takes a free port (see :attr:`port`). Thread-safe: samples may come from any
    thread; the SDK's server sends them from its own."""

    def __init__(self, *, fleet: str = "default", host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 name: str = "hexbench", start_ns: int | None = None) -> None:
        self.keys = Keys(fleet)
        self.start_ns = time.time_ns() // 1_000_000 * 1_000_000 if start_ns is None else start_ns
        self._origin: int | None = None  # start_ns on a virtual clock, None: wall time
        self._context = foxglove.Context()
        self._channels: dict[str, Channel] = {}
        self._fox = FoxgloveView()
        self._lock = threading.Lock()
        self._last_ns = 0
        self._closed = False
        for topic in DERIVED:  # before any client connects: see the module's docstring
            self._channel(topic)
        self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context,
                                             server_listener=_Listener(self))
        self.port: int = self._server.port
        self.host = host

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def attach(self, bus: Any) -> None:
        """Serve everything of ``bus``'s fleet (a :class:`bus.transport.Bus`)."""
        if bus.keys.root != self.keys.root:
            raise ValueError(f"live view is for {self.keys.root}, bus is {bus.keys.root}")
        self._origin = self.start_ns if getattr(bus.clock, "kind", "") == "virtual" else None
        bus.subscribe(self.keys.all, self.on_sample)

    # -- samples -----------------------------------------------------------------------------------
    def _channel(self, topic: str) -> Channel:
        ch = self._channels.get(topic)
        if ch is None:
            kind = kind_of(topic)
            schema = Schema(name=kind.name, encoding=kind.schema_encoding, data=kind.schema_bytes)
            ch = self._channels[topic] = Channel(topic, schema=schema, message_encoding=kind.message_encoding,
                                                 context=self._context)
        return ch

    def on_sample(self, key: str, payload: bytes) -> None:
        """Bus handler: serve one sample (never raises on a bad payload: it is served as it came)."""
        topic = self.keys.relative(key)
        with self._lock:
            if self._closed:
                return
            t = self._time(payload)
            self._channel(topic).log(payload, log_time=t)
            out = self._fox.derive(topic, payload, t)
            if out is not None:
                self._channel(out[0]).log(out[1], log_time=t)

    def _time(self, payload: bytes) -> int:
        if self._origin is None:
            t = time.time_ns()
        else:
            sim = int_field(payload, b'"sim_time_ns":')
            t = self._origin + sim if isinstance(sim, int) and not isinstance(sim, bool) and sim >= 0 else self._last_ns
        self._last_ns = max(self._last_ns, t)
        return t

    def snapshot(self) -> None:
        """Send the whole scene again (a new viewer sees every module at once)."""
        with self._lock:
            if self._fox.scene.modules and not self._closed:
                self._channel(SCENE_TOPIC).log(self._fox.scene.snapshot(self._last_ns), log_time=self._last_ns)

    def close(self) -> None:
        """Stop serving (clients are disconnected)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._server.stop()

    def __enter__(self) -> "LiveFoxglove":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Listener(foxglove.ServerListener):
    """A client subscribing to the scene gets the whole scene at once."""

    def __init__(self, live: LiveFoxglove) -> None:
        self._live = live

    def on_subscribe(self, client: Any, channel: Any) -> None:
        # The SDK has added the client to the channel's sinks when it calls this: what is logged
        # now reaches it. Off the server's thread: snapshot() takes the lock.
        if channel.topic == SCENE_TOPIC:
            threading.Thread(target=self._live.snapshot, name="foxglove-snapshot", daemon=True).start()
