"""IR light on the bus: bursts of bytes with exact times (keys ``ir/tx/<src>``, ``ir/rx/<dst>``).

A transmitter publishes a burst when it starts: its bytes, each byte's start time and
the byte time, so receivers can deliver each byte at its stop bit, causally, without a
message per byte. The world's IR medium forwards bursts to the transceivers the light
reaches, and when a later burst overlaps one already forwarded it publishes a ``garble``
correction for the bytes that collided (they arrive as the AND of both: the line is low
while either transmitter's carrier is on).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any, Callable

from .clock import Clock


@dataclass
class Burst:
    src: str  # transmitting endpoint ("m3.comm", "pc")
    burst: int  # per-source burst number
    transceiver: int  # 0 centre, 1..6 body side of the transmitter
    data: bytes
    starts: list[int]  # start of each byte (ns, sim time)
    byte_ns: int
    dst: str = ""  # set by the medium: receiving endpoint
    rx_transceiver: int = 0  # set by the medium: the receiver's transceiver
    corrupt: list[bool] = field(default_factory=list)

    def to_json(self) -> bytes:
        d = asdict(self)
        d["data"] = self.data.hex()
        d["type"] = "burst"
        return json.dumps(d, separators=(",", ":")).encode()

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Burst":
        d = dict(d)
        d.pop("type", None)
        d["data"] = bytes.fromhex(d["data"])
        return cls(**d)


def garble_message(src: str, burst: int, dst: str, index: list[int], values: list[int],
                   with_src: str) -> bytes:
    return json.dumps({"type": "garble", "src": src, "burst": burst, "dst": dst, "index": index,
                       "values": values, "with": with_src}, separators=(",", ":")).encode()


class IrReceiver:
    """Turns ``ir/rx`` messages into bytes at their stop bits.

    ``deliver(transceiver, byte, start_ns, corrupt)`` runs on the clock thread at the
    moment each byte completes.
    """

    def __init__(self, clock: Clock, deliver: Callable[[int, int, int, bool], None]) -> None:
        self.clock = clock
        self.deliver = deliver
        self._pending: dict[tuple[str, int], list[list[Any]]] = {}

    def on_message(self, key: str, payload: bytes) -> None:
        d = json.loads(payload)
        if d.get("type") == "garble":
            entries = self._pending.get((d["src"], d["burst"]))
            if entries:
                for i, v in zip(d["index"], d["values"]):
                    if i < len(entries):
                        entries[i][1] = v
                        entries[i][3] = True
            return
        b = Burst.from_dict(d)
        corrupt = b.corrupt or [False] * len(b.data)
        entries = [[start, value, b.rx_transceiver, bad, None]
                   for start, value, bad in zip(b.starts, b.data, corrupt)]
        k = (b.src, b.burst)
        self._pending[k] = entries
        for n, e in enumerate(entries):
            e[4] = self.clock.call_at(e[0] + b.byte_ns, self._complete, k, n)

    def _complete(self, k: tuple[str, int], n: int) -> None:
        entries = self._pending.get(k)
        if entries is None:
            return
        start, value, transceiver, bad, _ = entries[n]
        if n == len(entries) - 1:
            del self._pending[k]
        self.deliver(transceiver, value, start, bad)


class IrTransmitter:
    """Publishes bursts for one endpoint."""

    def __init__(self, put: Callable[[str, bytes], None], key: str, src: str) -> None:
        self._put = put
        self._key = key
        self.src = src
        self._n = 0

    def send(self, transceiver: int, data: bytes, starts: list[int], byte_ns: int) -> Burst:
        b = Burst(self.src, self._n, transceiver, bytes(data), list(starts), byte_ns)
        self._n += 1
        self._put(self._key, b.to_json())
        return b

