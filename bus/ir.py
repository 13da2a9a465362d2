"""IR light on the bus: bursts of bytes with exact times (keys ``ir/tx/<src>``, ``ir/rx/<dst>``).

A transmitter publishes a burst when it starts: its bytes, each byte's start time and
the byte time, so receivers can deliver each byte at its stop bit, causally, without a
message per byte. The world's IR medium (:mod:`module_sim.air`) forwards bursts to the transceivers the light
reaches, and when a later burst overlaps one already forwarded it publishes one ``garble``
correction listing the bytes of earlier bursts that collision changed (they arrive as the
AND of both: the line is low while either transmitter's carrier is on). Bytes already
known to be garbled whose value the collision does not change are not repeated.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
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
        # the same object (and key order) as dataclasses.asdict, without its deep copies
        return _dumps({"src": self.src, "burst": self.burst, "transceiver": self.transceiver,
                       "data": self.data.hex(), "starts": self.starts, "byte_ns": self.byte_ns,
                       "dst": self.dst, "rx_transceiver": self.rx_transceiver,
                       "corrupt": self.corrupt, "type": "burst"}).encode()

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Burst":
        d = dict(d)
        d.pop("type", None)
        d["data"] = bytes.fromhex(d["data"])
        return cls(**d)


_dumps = json.JSONEncoder(separators=(",", ":")).encode

#: a start time or byte time a burst may carry: the fleet core keeps times in 64 bits, byte
#: times in 32 (ns; a byte at 2400 baud is 4 166 667)
MAX_START_NS = 2**63 - 1
MAX_BYTE_NS = 2**32 - 1


def burst_light(d: dict[str, Any]) -> tuple[bytes, list[int], int, list[bool]]:
    """The bytes, their start times, the byte time and the corrupt flags (``[]``: none) of
    the burst sample ``d`` (an ``ir/tx`` sample's dict), checked against each other: a
    sample from elsewhere may be anything, and the medium indexes ``starts`` and
    ``corrupt`` by byte. ValueError says what is wrong (a ``bad-sample`` event)."""
    data = d["data"]
    if not isinstance(data, str):
        raise ValueError(f"burst data is {type(data).__name__}, not a hex string")
    try:
        data = bytes.fromhex(data)
    except ValueError as exc:
        raise ValueError(f"burst data is not hex: {exc}") from None
    starts, byte_ns, corrupt = d["starts"], d["byte_ns"], d.get("corrupt") or []
    if not isinstance(starts, list) or len(starts) != len(data):
        raise ValueError(f"burst of {len(data)} bytes has "
                         f"{len(starts) if isinstance(starts, list) else type(starts).__name__} start times")
    if not all(type(s) is int and 0 <= s <= MAX_START_NS for s in starts):
        raise ValueError(f"burst start times must be integers in 0..{MAX_START_NS} ns")
    if type(byte_ns) is not int or not 0 < byte_ns <= MAX_BYTE_NS:
        raise ValueError(f"burst byte_ns {byte_ns!r} is not an integer in 1..{MAX_BYTE_NS}")
    if not isinstance(corrupt, list) or (corrupt and len(corrupt) != len(data)) \
            or not all(type(c) is bool for c in corrupt):
        raise ValueError(f"burst of {len(data)} bytes: corrupt must be [] or {len(data)} booleans")
    return data, starts, byte_ns, corrupt


def one_byte_burst(src_json: str, burst: int, value: int, start: int, byte_ns: int, tail: str,
                   corrupt: bool) -> bytes:
    """:meth:`Burst.to_json` of a one-byte burst received, for a sender of many (the fleet
    core, a byte for the PC at a time): ``src_json`` the source's JSON string and ``tail``
    the receiver's part, :func:`burst_tail`, each made once."""
    return (f'{{"src":{src_json},"burst":{burst},"transceiver":0,"data":"{value:02x}",'
            f'"starts":[{start}],"byte_ns":{byte_ns}{tail}{"true" if corrupt else "false"}],'
            f'"type":"burst"}}').encode()


def burst_tail(dst: str, rx_transceiver: int) -> str:
    """The receiver's part of :func:`one_byte_burst`."""
    return f',"dst":{_dumps(dst)},"rx_transceiver":{rx_transceiver},"corrupt":['


def garble_fixes(dst: str, with_src: str, fixes: list[list[Any]]) -> bytes:
    """Every correction one new burst causes at ``dst``: ``[src, burst, index, value]`` each."""
    return _dumps({"type": "garble", "dst": dst, "with": with_src, "fixes": fixes}).encode()


#: The event a receiver puts when a correction of the medium comes after its byte's stop bit.
IR_CONFLICT = "ir-conflict"


class IrReceiver:
    """Turns ``ir/rx`` messages into bytes at their stop bits.

    ``deliver(transceiver, byte, start_ns, corrupt)`` runs on the clock thread at the
    moment each byte completes. A correction (``garble``, ``cut``) of a byte whose stop bit
    has passed cannot change what was delivered: it is a conflict, counted in
    :attr:`conflicts` and told to ``on_conflict(src, burst, index)`` (the medium's lookahead
    contract, docs/bus.md "Shards", makes it impossible; a broken one shows here).
    """

    def __init__(self, clock: Clock, deliver: Callable[[int, int, int, bool], None],
                 on_conflict: Callable[[str, int, int], None] | None = None) -> None:
        self.clock = clock
        self.deliver = deliver
        self.on_conflict = on_conflict
        self.conflicts = 0
        self._pending: dict[tuple[str, int], list[list[Any]]] = {}
        self._line_busy: dict[int, int] = {}  # transceiver -> end of the last byte delivered

    def _late(self, src: str, burst: int, index: int) -> None:
        self.conflicts += 1
        if self.on_conflict is not None:
            self.on_conflict(src, burst, index)

    def _fix(self, src: str, burst: int, i: int, value: int) -> None:
        entries = self._pending.get((src, burst))
        if entries is None:  # every byte of the burst is delivered already
            self._late(src, burst, i)
        elif i < len(entries):  # (past the end: a cut took the byte off the air)
            if entries[i][4] is None:  # delivered already
                self._late(src, burst, i)
            else:
                entries[i][1] = value
                entries[i][3] = True

    def on_message(self, key: str, payload: bytes) -> None:
        d = json.loads(payload)
        if d.get("type") == "cut":  # the transmitter's multiplexer moved on mid-burst
            src, burst = d["src"], d["burst"]
            entries = self._pending.get((src, burst))
            i = d["index"]
            if entries is None:  # (a burst that never came here: light after a move)
                return
            if d.get("value") is not None and i < len(entries):
                self._fix(src, burst, i, d["value"])
                i += 1
            for n, e in enumerate(entries[i:], i):
                if e[4] is None:
                    self._late(src, burst, n)
                else:
                    e[4].cancel()
            del entries[i:]
            if not entries:
                del self._pending[(src, burst)]
            return
        if d.get("type") == "garble":
            if "fixes" in d:
                for src, burst, i, v in d["fixes"]:
                    self._fix(src, burst, i, v)
                return
            for i, v in zip(d["index"], d["values"]):
                self._fix(d["src"], d["burst"], i, v)
            return
        data = bytes.fromhex(d["data"])
        rx = d["rx_transceiver"]
        byte_ns = d["byte_ns"]
        corrupt = d["corrupt"] or [False] * len(data)
        entries = [[start, value, rx, bad, None, start + byte_ns]
                   for start, value, bad in zip(d["starts"], data, corrupt)]
        k = (d["src"], d["burst"])
        self._pending[k] = entries
        call_at, complete = self.clock.call_at, self._complete
        for n, e in enumerate(entries):
            e[4] = call_at(e[0] + byte_ns, complete, k, n)

    def _complete(self, k: tuple[str, int], n: int) -> None:
        entries = self._pending.get(k)
        if entries is None:
            return
        entry = entries[n]
        start, value, transceiver, bad, _, end = entry
        entry[4] = None  # decided: a correction from now on comes too late
        if n == len(entries) - 1:
            del self._pending[k]
        # Two garbled bytes overlapping on one transceiver are one byte on the UART line:
        # the first to complete carries the mixture, the other never forms a stop bit.
        if bad and start < self._line_busy.get(transceiver, -1):
            return
        # its stop bit (now, unless the fleet core handed it over at its window's end)
        self._line_busy[transceiver] = end
        self.deliver(transceiver, value, start, bad)


class IrTransmitter:
    """Publishes bursts for one endpoint."""

    def __init__(self, put: Callable[[str, bytes], None], key: str, src: str) -> None:
        self._put = put
        self._key = key
        self.src = src
        self._n = 0

    def send(self, transceiver: int, data: bytes, starts: list[int], byte_ns: int,
             corrupt: list[bool] | None = None) -> Burst:
        """Publish a burst; ``corrupt`` marks bytes already garbled when sent (a multiplexer
        switch cut them)."""
        b = Burst(self.src, self._n, transceiver, bytes(data), list(starts), byte_ns,
                  corrupt=list(corrupt) if corrupt else [])
        self._n += 1
        self._put(self._key, b.to_json())
        return b

    def cut(self, b: Burst, index: int, lost_mask: int | None, at: int) -> None:
        """The multiplexer left ``b``'s transceiver at ``at``, during byte ``index`` (its bits
        ``lost_mask`` did not go out there) or before it (``lost_mask`` None)."""
        self._put(self._key, cut_message(b.src, b.burst, index, None, transceiver=b.transceiver,
                                         data=b.data.hex(), starts=b.starts, byte_ns=b.byte_ns,
                                         lost_mask=lost_mask, at=at))


def cut_message(src: str, burst: int, index: int, value: int | None, **extra: Any) -> bytes:
    """A burst cut short at byte ``index``: that byte becomes ``value`` (garbled) if not None,
    the bytes after it (or from it, if ``value`` is None) never come on this transceiver."""
    return _dumps({"type": "cut", "src": src, "burst": burst, "index": index, "value": value,
                   **extra}).encode()


def cut_masks(start: int, byte_ns: int, at: int) -> tuple[int, int]:
    """A byte (8N1, LSB first) switched from one transceiver to another at ``at``: the masks of
    its data bits sent before and after the switch. A receiver sees idle (1) for the bits
    that did not reach it."""
    bit = byte_ns / 10
    before = 0
    for k in range(8):
        if start + (1.5 + k) * bit < at:  # the UART samples data bit k in its middle
            before |= 1 << k
    return before, 0xFF & ~before


def forwarded(d: dict[str, Any], n: int) -> Callable[[str, int], bytes]:
    """Encoder of an ``ir/rx`` burst that arrives as sent (no byte garbled), for many
    receivers: the same bytes as ``Burst(...).to_json()`` with ``dst``/``rx_transceiver``."""
    head = _dumps({"src": d["src"], "burst": d["burst"], "transceiver": d["transceiver"],
                   "data": d["data"], "starts": d["starts"], "byte_ns": d["byte_ns"]})[:-1]
    tail = ',"corrupt":' + _dumps([False] * n) + ',"type":"burst"}'

    def encode(dst: str, rx: int) -> bytes:
        return f'{head},"dst":{_dumps(dst)},"rx_transceiver":{rx}{tail}'.encode()
    return encode
