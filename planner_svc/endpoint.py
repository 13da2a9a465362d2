"""The PC endpoint: the thesis PC's RS232 converter and central IR transceiver, on the bus.

It sends command frames on the centre channel (as IR bursts at the IR baud rate),
frames what comes back with the centre-link framer, and lets callers wait for frames
with timeouts on the run's clock. Real and virtual modules look the same from here.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Callable, Iterator

from bus.codec import Frame, Kind, Link, encode_command
from bus.framer import Framer
from bus.functions import Function
from bus.ir import IR_CONFLICT, IrReceiver, IrTransmitter
from bus.keys import PC
from bus.timing import NS_PER_S, byte_time_ns
from bus.transport import Bus


class ExpectTimeout(AssertionError):
    """Nothing matching arrived in time; the message lists what did arrive."""


@dataclass(frozen=True)
class Received:
    frame: Frame
    t_first_ns: int
    t_last_ns: int


class History:
    """The frames received, the last ``maxlen`` of them kept (a ring buffer, so a long run's
    memory stays flat). Indices count every frame since the start: ``len()`` is the total, and
    ``h[i]``, ``h[i:]`` and ``h.index(r)`` use those numbers; frames older than the last
    ``maxlen`` are gone (an index into them is an IndexError, a slice starts after them)."""

    def __init__(self, maxlen: int = 10_000) -> None:
        self.maxlen = maxlen
        self._items: deque[Received] = deque(maxlen=maxlen)
        self._dropped = 0

    def append(self, r: Received) -> None:
        if len(self._items) == self.maxlen:
            self._dropped += 1
        self._items.append(r)

    def clear(self) -> None:
        self._items.clear()
        self._dropped = 0

    def __len__(self) -> int:
        return self._dropped + len(self._items)

    def __iter__(self) -> Iterator[Received]:
        return iter(self._items)

    def __getitem__(self, i):
        if isinstance(i, slice):
            start, stop, step = i.indices(len(self))
            return [self._items[k - self._dropped] for k in range(max(start, self._dropped), stop, step)]
        if i < 0:
            i += len(self)
        if not self._dropped <= i < len(self):
            raise IndexError(f"frame {i}: {'not received yet' if i >= len(self) else f'older than the last {self.maxlen} kept'}")
        return self._items[i - self._dropped]

    def index(self, r: Received) -> int:
        items = self._items
        # the frame asked for is nearly always one of the last: look from the end, by identity
        for back, x in enumerate(reversed(items)):
            if x is r:
                return len(items) - 1 - back + self._dropped
        return items.index(r) + self._dropped


class PcEndpoint:
    def __init__(self, bus: Bus, *, baud: int = 300, name: str = PC) -> None:
        self.bus = bus
        self.name = name
        self.byte_ns = byte_time_ns(baud)
        self._tx = IrTransmitter(bus.put, bus.keys.ir_tx(name), name)
        self._framer = Framer(Link.CENTRE)
        self._rx = IrReceiver(bus.clock, self._on_byte, self._on_conflict)
        self._line_free_at = 0
        self.received = History()
        self.listeners: list[Callable[[Received], None]] = []
        bus.subscribe(bus.keys.ir_rx(name), self._rx.on_message)

    @property
    def conflicts(self) -> int:
        """Corrections of the IR medium that came after their byte's stop bit (IrReceiver)."""
        return self._rx.conflicts

    def _on_conflict(self, src: str, burst: int, index: int) -> None:
        self.bus.event(self.name, IR_CONFLICT, sender=src, burst=burst, index=index)

    # -- sending --------------------------------------------------------------------------------
    def send(self, fn: str | int | Function, *args: int, **kwargs: int) -> int:
        """Send a command frame by name or code; returns the sim time its last byte ends."""
        return self.send_raw(encode_command(fn, *args, **kwargs))

    def send_raw(self, data: bytes, *, origin: str = "virtual") -> int:
        """Send bytes as IR light; ``origin`` goes into the published frames (``"replay"``
        for a recording played back)."""
        now = self.bus.clock.now_ns()
        start = max(now, self._line_free_at)
        starts = [start + k * self.byte_ns for k in range(len(data))]
        self._line_free_at = starts[-1] + self.byte_ns if data else start
        self._tx.send(0, data, starts, self.byte_ns)
        f = Framer(Link.PC)
        for t in f.feed(data) + f.flush():
            self.bus.clock.call_at(self._line_free_at, self._publish, t.frame, start, origin)
        return self._line_free_at

    @property
    def line_free_at(self) -> int:
        """Sim time at which the last byte queued on the PC's transmitter ends."""
        return self._line_free_at

    def _publish(self, frame: Frame, first: int, origin: str = "virtual") -> None:
        self.bus.publish_frame(frame, src=self.name, dst="*", first_byte_ns=first, channel=0, origin=origin)

    # -- receiving --------------------------------------------------------------------------------
    def _on_byte(self, transceiver: int, byte: int, start: int, corrupt: bool) -> None:
        end = start + self.byte_ns
        for t in self._framer.feed(byte, end):
            r = Received(t.frame, t.t_first_ns - self.byte_ns, t.t_last_ns)
            if t.frame.is_noise:
                self.bus.event(self.name, "rx-noise", raw=t.frame.raw.hex(),
                               reason=t.frame.view["reason"])
            self.received.append(r)
            for cb in self.listeners:
                cb(r)

    def flush(self) -> None:
        """Treat a silence as the end of whatever partial frame is pending."""
        for t in self._framer.flush():
            self.received.append(Received(t.frame, t.t_first_ns - self.byte_ns, t.t_last_ns))

    # -- waiting -----------------------------------------------------------------------------------
    def expect(self, match: Callable[[Frame], bool] | str | None = None, *, timeout_s: float = 10.0,
               since: int | None = None, **fields: object) -> Received:
        """Run the clock until a frame received after ``since`` (index into ``received``, default:
        now) matches, or ``timeout_s`` of run time passes.

        ``match`` is a predicate, or a frame kind (``"ack"``, ``"banner"``...); keyword fields
        compare with the decoded view (``expect("ack", byte=21)``, ``expect("banner", banner="LOC")``).
        """
        start = len(self.received) if since is None else since
        pred = _predicate(match, fields)
        clock = self.bus.clock
        deadline = clock.now_ns() + int(timeout_s * NS_PER_S)
        found: list[Received] = []
        scan = [start]  # next index of ``received`` to look at

        def done() -> bool:
            while not found and scan[0] < len(self.received):
                r = self.received[scan[0]]
                scan[0] += 1
                if pred(r.frame):
                    found.append(r)
            return bool(found)

        clock.run(until=done, until_ns=deadline)
        if not found:
            seen = [r.frame.describe() for r in self.received[start:]]
            raise ExpectTimeout(f"no frame matching {match!r} {fields or ''} within {timeout_s} s of "
                                f"run time; received: {seen or 'nothing'}")
        return found[0]

    def ack(self, fn: str | int, *args: int, timeout_s: float = 10.0) -> Received:
        """Send a command and wait for its ACK line."""
        mark = len(self.received)
        self.send(fn, *args)
        return self.expect("ack", since=mark, timeout_s=timeout_s)


def _predicate(match: Callable[[Frame], bool] | str | None, fields: dict) -> Callable[[Frame], bool]:
    if callable(match):
        base = match
    elif match is None:
        base = lambda f: True  # noqa: E731
    else:
        kind = Kind(match)
        base = lambda f: f.kind is kind  # noqa: E731
    return lambda f: base(f) and all(f.view.get(k) == v for k, v in fields.items())


__all__ = ["ExpectTimeout", "History", "PcEndpoint", "Received"]
