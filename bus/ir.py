"""IR light on the bus: bursts of bytes with exact times (keys ``ir/tx/<src>``, ``ir/rx/<dst>``).

A transmitter publishes a burst when it starts: its bytes, each byte's start time and
the byte time, so receivers can deliver each byte at its stop bit, causally, without a
message per byte. The world's IR medium forwards bursts to the transceivers the light
reaches, and when a later burst overlaps one already forwarded it publishes one ``garble``
correction listing the bytes of earlier bursts that collision changed (they arrive as the
AND of both: the line is low while either transmitter's carrier is on). Bytes already
known to be garbled whose value the collision does not change are not repeated.
"""

from __future__ import annotations

import json
from bisect import bisect_left
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


def garble_fixes(dst: str, with_src: str, fixes: list[list[Any]]) -> bytes:
    """Every correction one new burst causes at ``dst``: ``[src, burst, index, value]`` each."""
    return _dumps({"type": "garble", "dst": dst, "with": with_src, "fixes": fixes}).encode()


class IrReceiver:
    """Turns ``ir/rx`` messages into bytes at their stop bits.

    ``deliver(transceiver, byte, start_ns, corrupt)`` runs on the clock thread at the
    moment each byte completes.
    """

    def __init__(self, clock: Clock, deliver: Callable[[int, int, int, bool], None]) -> None:
        self.clock = clock
        self.deliver = deliver
        self._pending: dict[tuple[str, int], list[list[Any]]] = {}
        self._line_busy: dict[int, int] = {}  # transceiver -> end of the last byte delivered

    def on_message(self, key: str, payload: bytes) -> None:
        d = json.loads(payload)
        if d.get("type") == "cut":  # the transmitter's multiplexer moved on mid-burst
            entries = self._pending.get((d["src"], d["burst"]))
            if entries:
                i = d["index"]
                if d.get("value") is not None and i < len(entries):
                    entries[i][1] = d["value"]
                    entries[i][3] = True
                    i += 1
                for e in entries[i:]:
                    e[4].cancel()
                del entries[i:]
                if not entries:
                    del self._pending[(d["src"], d["burst"])]
            return
        if d.get("type") == "garble":
            pending = self._pending
            if "fixes" in d:
                for src, burst, i, v in d["fixes"]:
                    entries = pending.get((src, burst))
                    if entries and i < len(entries):
                        entries[i][1] = v
                        entries[i][3] = True
                return
            entries = pending.get((d["src"], d["burst"]))
            if entries:
                for i, v in zip(d["index"], d["values"]):
                    if i < len(entries):
                        entries[i][1] = v
                        entries[i][3] = True
            return
        data = bytes.fromhex(d["data"])
        rx = d["rx_transceiver"]
        byte_ns = d["byte_ns"]
        corrupt = d["corrupt"] or [False] * len(data)
        entries = [[start, value, rx, bad, None]
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
        start, value, transceiver, bad, _ = entries[n]
        if n == len(entries) - 1:
            del self._pending[k]
        # Two garbled bytes overlapping on one transceiver are one byte on the UART line:
        # the first to complete carries the mixture, the other never forms a stop bit.
        if bad and start < self._line_busy.get(transceiver, -1):
            return
        self._line_busy[transceiver] = self.clock.now_ns()
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



class Air:
    """What is in the air at one receiving transceiver: the bytes forwarded to it that have not
    ended yet, for the IR medium's collision model.

    Bytes are kept in slots by exact time span ``(start, end)``; in a slot, bytes known to be
    garbled are grouped by value. A new byte that overlaps bytes in the air arrives as the AND
    of itself and all of them, and each of them becomes the AND of itself and the new byte
    (the line is low while either carrier is on). Only bytes whose value or garbled state
    changes need a correction, so a pile-up of n identical transmissions costs O(n), not O(n^2).
    """

    __slots__ = ("keys", "slots", "longest")

    def __init__(self) -> None:
        self.keys: list[tuple[int, int]] = []  # slot spans, sorted
        # parallel to keys: [clean members, {value: garbled members}, sources, AND, OR of the
        # garbled values]; member = [src, burst, index, value]
        self.slots: list[list[Any]] = []
        self.longest = 0

    def collide(self, src: str, burst: int, data: bytes, starts: list[int], byte_ns: int,
                now: int) -> tuple[list[int], list[bool], list[list[Any]], set[str]]:
        """A new burst reaches this receiver: returns the values it arrives with, which bytes
        are garbled, the corrections to earlier bursts ``[src, burst, index, value]`` and the
        sources it collided with. :meth:`add` then puts it in the air."""
        keys, slots = self.keys, self.slots
        longest = self.longest
        if keys and keys[0][0] + longest <= now:  # forget what has ended
            cut = bisect_left(keys, (now - longest + 1,))
            del keys[:cut]
            del slots[:cut]
        values = list(data)
        corrupt = [False] * len(values)
        fixes: list[list[Any]] = []
        hits: list[set[str]] = []
        if keys:
            nkeys = len(keys)
            for i, start in enumerate(starts):
                end = start + byte_ns
                v = values[i]
                acc = v
                hit = False
                for j in range(bisect_left(keys, (start - longest + 1,)), nkeys):
                    span = keys[j]
                    if span[0] >= end:
                        break
                    if span[1] <= start:
                        continue
                    slot = slots[j]
                    clean, garbled, srcs, s_and, s_or = slot
                    if len(srcs) <= 1 and (not srcs or src in srcs):
                        continue  # empty, or a transmitter never collides with itself (one UART)
                    hit = True
                    hits.append(srcs)
                    acc &= s_and
                    if s_or & v != s_or:  # some known-garbled bytes change again
                        for w in [w for w in garbled if w & v != w]:
                            members = garbled.pop(w)
                            nw = w & v
                            for m in members:
                                m[3] = nw
                                fixes.append(m[:])
                            garbled.setdefault(nw, []).extend(members)
                        slot[4] = s_or & v
                        slot[3] = s_and & v
                    if clean:  # first collision of these bytes
                        a, o = slot[3], slot[4]
                        for m in clean:
                            acc &= m[3]
                            nw = m[3] & v
                            m[3] = nw
                            fixes.append(m[:])
                            garbled.setdefault(nw, []).append(m)
                            a &= nw
                            o |= nw
                        slot[3], slot[4] = a, o
                        clean.clear()
                if hit:
                    values[i] = acc
                    corrupt[i] = True
        return values, corrupt, fixes, set().union(*hits) if hits else set()

    def cut(self, src: str, burst: int, data: bytes, starts: list[int], byte_ns: int, index: int,
            lost_mask: int | None) -> int | None:
        """A forwarded burst was cut short at byte ``index`` (see :func:`cut_message`): the
        bytes after it leave the air; if ``lost_mask`` is not None, the cut byte stays with
        those bits idle (1). Returns the value the cut byte now arrives with (or None)."""
        keys, slots = self.keys, self.slots
        result = None
        for i in range(index, len(starts)):
            span = (starts[i], starts[i] + byte_ns)
            j = bisect_left(keys, span)
            partial = i == index and lost_mask is not None
            if j >= len(keys) or keys[j] != span:
                if partial:
                    result = data[i] | lost_mask
                continue
            slot = slots[j]
            clean, garbled = slot[0], slot[1]
            mine = [m for m in clean if m[0] == src and m[1] == burst]
            clean[:] = [m for m in clean if not (m[0] == src and m[1] == burst)]
            for w in list(garbled):
                ms = garbled[w]
                mine += [m for m in ms if m[0] == src and m[1] == burst]
                ms[:] = [m for m in ms if not (m[0] == src and m[1] == burst)]
                if not ms:
                    del garbled[w]
            if partial:
                for m in mine:
                    m[3] |= lost_mask
                    garbled.setdefault(m[3], []).append(m)
                    result = m[3]
                if result is None:
                    result = data[i] | lost_mask
            slot[2] = {m[0] for m in clean} | {m[0] for ms in garbled.values() for m in ms}
            slot[3], slot[4] = 0xFF, 0
            for w in garbled:
                slot[3] &= w
                slot[4] |= w
        return result

    def add(self, src: str, burst: int, values: list[int], corrupt: list[bool], starts: list[int],
            byte_ns: int) -> None:
        """Put a forwarded burst's bytes (with the values it arrives with) in the air."""
        keys, slots = self.keys, self.slots
        if byte_ns > self.longest:
            self.longest = byte_ns
        for i, start in enumerate(starts):
            span = (start, start + byte_ns)
            j = bisect_left(keys, span)
            if j < len(keys) and keys[j] == span:
                slot = slots[j]
            else:
                slot = [[], {}, set(), 0xFF, 0x00]
                keys.insert(j, span)
                slots.insert(j, slot)
            v = values[i]
            m = [src, burst, i, v]
            if corrupt[i]:
                slot[1].setdefault(v, []).append(m)
                slot[3] &= v
                slot[4] |= v
            else:
                slot[0].append(m)
            slot[2].add(src)


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
