"""An ATmega162 as the firmware sees it: ports, the Timer0 tick, two UARTs, and a
program written as a generator.

A program yields operations instead of busy-waiting:

* ``yield Delay(n)`` — ``DelayXts(n)``: resumes on the n-th Timer0 overflow after now.
  The timer runs freely from power-up, so the first tick comes anywhere in (0, 9.984] ms.
* ``b = yield Rx(uart)`` — ``ReceiveByte``: resumes with the next received byte.
* ``b = yield Rx(uart, n)`` — ``ReceiveByteTL(n)``: or with ``'~'`` on the n-th tick.
* ``b = yield Rx(uart, n, tell_timeout=True)`` — the same, but None on the n-th tick, so a
  received ``'~'`` is a byte like any other (v2's id byte).
* ``yield Tx(uart, data)`` — ``TransmitByte`` for each byte: resumes when the last byte
  has been written to UDR. The UART double-buffers (UDR + shift register), so the program
  runs on while the last one or two bytes are still on the wire, exactly as on the chip.

Nothing here sleeps: every wait is an event on the run's clock, and a board with nothing
to do (waiting for a byte) costs nothing.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Generator

from bus.clock import Clock, Timer
from bus.timing import TICK_NS, byte_time_ns

TIMEOUT = ord("~")


@dataclass(slots=True)
class Delay:
    ticks: int


@dataclass(slots=True)
class Rx:
    uart: "Uart"
    timeout_ticks: int | None = None
    tell_timeout: bool = False


@dataclass(slots=True)
class Tx:
    uart: "Uart"
    data: bytes


Program = Generator[Any, Any, None]


class Uart:
    """One 8N1 UART: TX double buffer, RX two-byte FIFO plus the shift register.

    ``on_tx(data, starts_ns)`` is told about every burst the program writes, with each
    byte's start time on the wire (a byte ends ``byte_ns`` later).
    """

    RX_DEPTH = 3  # two in the FIFO and one waiting in the receive shift register

    def __init__(self, mcu: "Mcu", name: str, baud: int) -> None:
        self.mcu = mcu
        self.name = name
        self.baud = baud
        self.byte_ns = byte_time_ns(baud)
        self.on_tx: Callable[[bytes, list[int]], None] | None = None
        self.on_overrun: Callable[[int], None] | None = None
        self._udr_free_at = 0
        self._line_free_at = 0
        self._rx: deque[int] = deque()
        self.overruns = 0

    # -- transmit ---------------------------------------------------------------------------
    def write(self, data: bytes, now: int) -> int:
        """Queue ``data``; return the time the program finishes writing the last byte."""
        w = now
        starts: list[int] = []
        for _ in data:
            w = max(w, self._udr_free_at)  # wait for UDRE
            start = max(w, self._line_free_at)
            starts.append(start)
            self._udr_free_at = start  # UDR empties when the byte moves to the shift register
            self._line_free_at = start + self.byte_ns
        if self.on_tx is not None and data:
            self.on_tx(bytes(data), starts)
        return w

    @property
    def idle_at(self) -> int:
        """When the last queued byte leaves the wire."""
        return self._line_free_at

    # -- receive ----------------------------------------------------------------------------
    def receive(self, byte: int) -> None:
        """A byte has completed on RX (called at its stop bit).

        With the FIFO full and a byte waiting in the shift register, the new byte's start
        bit overruns (DOR): the waiting byte is lost and the new one takes its place, as
        the datasheet describes (and simavr's harness does)."""
        if len(self._rx) >= self.RX_DEPTH:
            self.overruns += 1
            lost = self._rx[-1]
            self._rx[-1] = byte
            if self.on_overrun is not None:
                self.on_overrun(lost)
            return
        self._rx.append(byte)
        self.mcu._rx_ready(self)

    def read(self) -> int | None:
        return self._rx.popleft() if self._rx else None

    def flush_rx(self) -> None:
        self._rx.clear()


class Mcu:
    """Ports PORTA..PORTE, the Timer0 tick and a program runner."""

    def __init__(self, clock: Clock, name: str) -> None:
        self.clock = clock
        self.name = name
        self.port: dict[str, int] = dict.fromkeys("ABCDE", 0)
        self.pin_in: dict[str, int] = dict.fromkeys("ABCDE", 0)  # levels on input pins
        self.on_ports: Callable[["Mcu"], None] | None = None
        self._boot_ns = 0
        self._program: Program | None = None
        self._waiting_rx: Uart | None = None
        self._rx_timer: Timer | None = None
        self._rx_timeout_value: int | None = TIMEOUT
        self.halted = False
        #: the C firmware running as this board's program (module_sim.firmware), if any
        self.driver = None

    # -- ports --------------------------------------------------------------------------------
    def set_bits(self, port: str, mask: int) -> None:
        self._write(port, self.port[port] | mask)

    def clear_bits(self, port: str, mask: int) -> None:
        self._write(port, self.port[port] & ~mask & 0xFF)

    def write_port(self, port: str, value: int) -> None:
        self._write(port, value & 0xFF)

    def _write(self, port: str, value: int) -> None:
        if value != self.port[port]:
            self.port[port] = value
            if self.on_ports is not None:
                self.on_ports(self)

    # -- timer ----------------------------------------------------------------------------------
    def tick_count(self) -> int:
        """Timer0 overflows since power-up: what the firmware's free-running tick reads."""
        return (self.clock.now_ns() - self._boot_ns) // TICK_NS

    def tick_deadline(self, ticks: int) -> int:
        """When ``ts`` reaches ``ticks`` after ``ts = 0`` now: the ticks-th overflow after now."""
        now = self.clock.now_ns()
        if ticks <= 0:
            return now
        elapsed = (now - self._boot_ns) // TICK_NS
        return self._boot_ns + (elapsed + ticks) * TICK_NS

    # -- program ----------------------------------------------------------------------------------
    def start(self, program: Program) -> None:
        """Power up now: the timer starts counting and the program runs."""
        self._boot_ns = self.clock.now_ns()
        self._program = program
        self.clock.call_at(self._boot_ns, self._resume, None)

    def _resume(self, value: Any) -> None:
        prog = self._program
        if prog is None or self.halted:
            return
        now = self.clock.now_ns()
        while True:
            try:
                op = prog.send(value)
            except StopIteration:
                self._program = None
                return
            value = None
            kind = type(op)
            if kind is Rx:
                b = op.uart.read()
                if b is not None:
                    value = b
                    continue
                self._waiting_rx = op.uart
                if op.timeout_ticks is not None:
                    self._rx_timeout_value = None if op.tell_timeout else TIMEOUT
                    self._rx_timer = self.clock.call_at(self.tick_deadline(op.timeout_ticks),
                                                        self._rx_timeout)
                return
            if kind is Delay:
                if op.ticks <= 0:
                    continue
                self.clock.call_at(self.tick_deadline(op.ticks), self._resume, None)
                return
            if kind is Tx:
                done = op.uart.write(op.data, now)
                if done > now:
                    self.clock.call_at(done, self._resume, None)
                    return
                continue
            raise TypeError(f"{self.name}: program yielded {op!r}")

    def firmware_port_write(self, port: str, value: int) -> None:
        """A port write of the C program (module_sim.firmware)."""
        self._write(port, value)

    def _rx_ready(self, uart: Uart) -> None:
        if self.driver is not None:
            self.driver.step()
            return
        if self._waiting_rx is uart:
            self._waiting_rx = None
            if self._rx_timer is not None:
                self._rx_timer.cancel()
                self._rx_timer = None
            self._resume(uart.read())

    def _rx_timeout(self) -> None:
        self._rx_timer = None
        if self._waiting_rx is not None:
            self._waiting_rx = None
            self._resume(self._rx_timeout_value)
