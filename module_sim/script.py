"""One virtual module driven by a byte script on its centre transceiver, on the virtual
clock, with a log of everything it does: the reference side of the firmware differential.

:mod:`hil.firmware` runs the same script against the C programs in simavr and writes the
same log, so the two can be compared line by line (``hexbench firmware diff``).

A script is a list of ``(time_ns, bytes)``: the bytes arrive at the centre transceiver one
byte time apart from ``time_ns`` on (after the previous entry's bytes). The log is a list of
:class:`Event`, in time order:

* ``ir <byte>``: a byte the comm board sent on the centre transceiver (time: its start bit);
* ``irside <byte> <channel>``: a byte sent while the multiplexer selected CD4051 channel
  ``channel`` (a side: it left by that side);
* ``debug <byte>``: a byte of the control board's UART1;
* ``port <board> <letter> <value>``: a PORTx register of ``comm`` or ``control`` changed;
* ``irdrop <byte> <channel>``: a script byte that arrived while the multiplexer selected a
  side (the comm board never saw it);
* ``overrun <board> <uart> <byte>``: a byte lost to a full receiver (FIFO and shift register).
"""

from __future__ import annotations

from dataclasses import dataclass

from bus.clock import VirtualClock
from bus.pins import IR_TRANSCEIVER_CHANNEL, PORTS
from bus.session import SessionOptions
from bus.timing import NS_PER_S, byte_time_ns
from bus.transport import Bus

from .avr import Mcu
from .module import VirtualModule
from .profiles import profile as get_profile

Script = list[tuple[int, bytes]]


@dataclass(frozen=True, order=True)
class Event:
    t_ns: int
    what: str  # "ir", "irside", "debug", "port"
    detail: str  # "2a"; "ff 0"; "comm A e7"

    def __str__(self) -> str:
        return f"{self.t_ns} {self.what} {self.detail}"

    @classmethod
    def parse(cls, line: str) -> "Event":
        """One line of a log: ``<time_ns> <what> <detail...>``."""
        t, what, *detail = line.split()
        return cls(int(t), what, " ".join(detail))


def parse_script(text: str) -> Script:
    """Lines ``<time_ns> <hex bytes>`` (``#`` comments and blank lines allowed)."""
    out: Script = []
    for n, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            t, data = line.split(None, 1)
            out.append((int(t), bytes.fromhex(data)))
        except ValueError:
            raise ValueError(f"script line {n}: expected '<time_ns> <hex bytes>', got {line!r}") from None
    return out


def format_script(script: Script) -> str:
    return "".join(f"{t} {data.hex()}\n" for t, data in script)


def run_script(script: Script, seconds: float, *, profile: str = "v2", module_id: int = 1,
               switches: int = 0, ir_baud: int = 300, mux_cut: bool = False,
               program: str = "model") -> list[Event]:
    """Power a virtual module up at time 0, play ``script`` to its centre transceiver and
    return what it did in the first ``seconds`` of sim time. ``mux_cut``: a multiplexer
    switch during a transmit burst moves the rest of it (:class:`VirtualModule`)."""
    clock = VirtualClock()
    bus = Bus(clock, f"script{id(script)}", options=SessionOptions(isolated=True))
    try:
        module = VirtualModule(bus, module_id, get_profile(profile), ir_baud=ir_baud, mux_cut=mux_cut,
                               program=program)
        module.switches = [bool(switches >> k & 1) for k in range(6)]
        log: list[Event] = []
        _watch(module, log)
        byte_ns = byte_time_ns(ir_baud)
        free = 0
        for t, data in script:
            for byte in data:
                start = max(t, free)
                free = start + byte_ns
                clock.call_at(free, _deliver, module, log, byte, start)
        module.power_up()
        clock.run(until_ns=int(seconds * NS_PER_S))
        return sorted(log, key=lambda e: e.t_ns)  # stable: same-instant events keep their order
    finally:
        bus.close()


def _channel(transceiver: int | None) -> int:
    """The CD4051 channel a transceiver is on (7: the unwired Y7)."""
    return 7 if transceiver is None else IR_TRANSCEIVER_CHANNEL.get(transceiver, 7)


def _deliver(module: VirtualModule, log: list[Event], byte: int, start: int) -> None:
    if not module.comm.accepts_ir(0, start):
        log.append(Event(start, "irdrop", f"{byte:02x} {_channel(module.comm.ir_transceiver)}"))
    module._ir_rx(0, byte, start, False)


def _watch(module: VirtualModule, log: list[Event]) -> None:
    clock = module.bus.clock
    comm, ctrl = module.comm, module.ctrl

    ir_tx = comm.uart1.on_tx

    def on_ir(data: bytes, starts: list[int]) -> None:
        k = comm.ir_transceiver
        for byte, start in zip(data, starts):
            if k == 0:
                log.append(Event(start, "ir", f"{byte:02x}"))
            else:
                log.append(Event(start, "irside", f"{byte:02x} {_channel(k)}"))
        if ir_tx is not None:
            ir_tx(data, starts)

    comm.uart1.on_tx = on_ir

    debug_tx = ctrl.uart1.on_tx

    def on_debug(data: bytes, starts: list[int]) -> None:
        log.extend(Event(start, "debug", f"{byte:02x}") for byte, start in zip(data, starts))
        if debug_tx is not None:
            debug_tx(data, starts)

    ctrl.uart1.on_tx = on_debug

    for board, name in ((comm, "comm"), (ctrl, "control")):
        for n, uart in enumerate((board.uart0, board.uart1)):
            def on_overrun(byte: int, name=name, n=n, uart=uart, chained=uart.on_overrun) -> None:
                # at the new byte's start bit, when the chip loses the waiting one
                log.append(Event(clock.now_ns() - uart.byte_ns, "overrun", f"{name} {n} {byte:02x}"))
                if chained is not None:
                    chained(byte)
            uart.on_overrun = on_overrun
        seen = dict(board.port)
        chained = board.on_ports

        def on_ports(mcu: Mcu, seen=seen, name=name, chained=chained) -> None:
            now = clock.now_ns()
            for letter in PORTS:
                if mcu.port[letter] != seen[letter]:
                    seen[letter] = mcu.port[letter]
                    log.append(Event(now, "port", f"{name} {letter} {mcu.port[letter]:02x}"))
            if chained is not None:
                chained(mcu)

        board.on_ports = on_ports
