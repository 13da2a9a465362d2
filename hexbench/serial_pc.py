"""The PC's central IR transceiver on a serial port, for a conversation with one board.

:class:`SerialPc` is a :class:`~hil.bridge.CentreBridge` and a
:class:`~planner_svc.endpoint.PcEndpoint` on a private bus with the wall clock: what
``hexbench boards`` asks each port, and what the pytest plugin's serial targets talk through.
:func:`ask` sends one frame and waits for its ACK, on any PC endpoint (``hexbench send`` uses it
on a running fleet's bus).
"""

from __future__ import annotations

import itertools
import os
from typing import Callable

import serial

from bus.clock import WallClock
from bus.session import SessionOptions
from bus.timing import Baud
from bus.transport import Bus
from hil.bridge import CentreBridge
from hil.port import open_port
from planner_svc.endpoint import ExpectTimeout, PcEndpoint, Received

_buses = itertools.count()


def ask(pc: PcEndpoint, frame: bytes, *, timeout_s: float) -> tuple[list[Received], Received | None]:
    """Send ``frame`` and wait up to ``timeout_s`` (run time) for an ACK line.

    Returns what arrived from the send up to and including the ACK, and the ACK; when none came,
    everything that arrived (a partial frame pending in the framer flushed as noise) and None."""
    mark = len(pc.received)
    pc.send_raw(frame)
    try:
        ack = pc.expect("ack", since=mark, timeout_s=timeout_s)
    except ExpectTimeout:
        pc.flush()
        return pc.received[mark:], None
    got = pc.received[mark:]
    return got[:next(i for i, r in enumerate(got) if r is ack) + 1], ack


def run_until_quiet(pc: PcEndpoint, count: Callable[[], int], *, quiet_bytes: int = 4,
                    timeout_s: float = 10.0) -> bool:
    """Run ``pc``'s clock until ``count()`` (bytes or frames heard) stayed the same for
    ``quiet_bytes`` byte times, at most ``timeout_s``; then flush the PC's framer (a partial
    frame counts as ended). Returns whether it went quiet."""
    clock = pc.bus.clock
    quiet_ns = quiet_bytes * pc.byte_ns
    deadline = clock.now_ns() + int(timeout_s * 1e9)
    last = [clock.now_ns(), count()]
    wake = [0]

    def quiet() -> bool:
        now, n = clock.now_ns(), count()
        if n != last[1]:
            last[:] = [now, n]
        if now - last[0] >= quiet_ns:
            return True
        if wake[0] != last[0] + quiet_ns:  # a wall clock would look again only 0.2 s later
            wake[0] = last[0] + quiet_ns
            clock.call_at(wake[0], lambda: None)
        return False

    clock.run(until=quiet, until_ns=deadline)
    pc.flush()
    return quiet()


def open_exclusive(url: str, baud: int) -> serial.SerialBase:
    """:func:`hil.port.open_port`, but a local port another program holds locked is refused
    instead of shared (two readers of one tty steal each other's bytes)."""
    if "://" in url:
        return open_port(url, baud)
    return serial.Serial(url, baudrate=baud, timeout=0.05, write_timeout=None, exclusive=True)


class SerialPc:
    """A PC endpoint whose transceiver is the serial port ``url`` (any pyserial URL), on its own
    isolated bus with the wall clock. Raises what pyserial raises when the port cannot be opened
    (:class:`serial.SerialException`, or :class:`ValueError` for a malformed URL)."""

    def __init__(self, url: str, *, baud: int = Baud.IR, name: str = "serialpc",
                 opener: Callable[[str, int], serial.SerialBase] = open_port) -> None:
        self.url = url
        self.clock = WallClock()
        self.bus = Bus(self.clock, f"{name}{os.getpid()}x{next(_buses)}",
                       options=SessionOptions(isolated=True))
        try:
            self.bridge = CentreBridge(self.bus, url, baud=baud, opener=opener).start()
        except BaseException:
            self.bus.close()
            raise
        self.pc = PcEndpoint(self.bus, baud=baud)

    def quiet(self, *, quiet_bytes: int = 4, timeout_s: float = 10.0) -> bool:
        """Run until no byte arrived for ``quiet_bytes`` byte times (a line the module was still
        sending when the port opened is over), at most ``timeout_s``; whatever is pending in the
        framer then counts as ended. Returns whether the line went quiet."""
        port = self.bridge.port
        return run_until_quiet(self.pc, lambda: port.bytes_in, quiet_bytes=quiet_bytes,
                               timeout_s=timeout_s)

    def ask(self, frame: bytes, *, timeout_s: float) -> tuple[list[Received], Received | None]:
        return ask(self.pc, frame, timeout_s=timeout_s)

    def close(self) -> None:
        self.bridge.close()
        self.bus.close()

    def __enter__(self) -> "SerialPc":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["SerialPc", "ask", "open_exclusive", "run_until_quiet"]
