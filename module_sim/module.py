"""A virtual HexBot module: both boards wired by their UART0, on the bus.

It publishes every byte on every wire as frames — UART0 both ways, the control
board's debug UART1, and what its IR transceivers send — plus its actuator and LED
state, and takes IR light from the bus (``ir/rx/m<id>``).
"""

from __future__ import annotations

from typing import Callable

from bus.codec import Link
from bus.framer import Framer
from bus.ir import IrReceiver, IrTransmitter
from bus.keys import board_endpoint, module_endpoint
from bus.messages import Actuators
from bus.pins import JOINT, LED_JOINT, LED_NEG, LED_POS, MAGNET_NEG, MAGNET_POS
from bus.transport import Bus

from .avr import Mcu, Uart
from .comm_board import CommBoard
from .control_board import ControlBoard
from .profiles import Profile


class VirtualModule:
    def __init__(self, bus: Bus, module_id: int, profile: Profile, *, ir_baud: int = 300) -> None:
        self.bus = bus
        self.id = module_id
        self.name = module_endpoint(module_id)
        clock = bus.clock
        self.ctrl = ControlBoard(clock, board_endpoint(module_id, "ctrl"), profile, dip=module_id)
        self.comm = CommBoard(clock, board_endpoint(module_id, "comm"), profile, ir_baud,
                              neighbours=lambda: self.switches)
        self.switches = [False] * 6  # optical switches, from the world
        self.overruns = 0
        # UART0: each board's TX is the other's RX
        self._wire(self.ctrl.uart0, self.comm.uart0, Link.UART0_UP, self.comm.name)
        self._wire(self.comm.uart0, self.ctrl.uart0, Link.UART0_DOWN, self.ctrl.name)
        self._sniff(self.ctrl.uart1, Link.DEBUG, self.ctrl.name, "terminal")
        # IR: bursts out on the bus, light in from the world's medium
        self._ir_out = IrTransmitter(bus.put, bus.keys.ir_tx(self.comm.name), self.comm.name)
        # one framer per transceiver: the centre carries centre-link frames, sides side-link ones
        self._ir_frames = {k: self._framer_publisher(Link.CENTRE if k == 0 else Link.SIDE,
                                                     self.comm.name, "pc" if k == 0 else f"side{k}",
                                                     channel=k) for k in range(7)}
        self.comm.uart1.on_tx = self._ir_tx
        self._ir_in = IrReceiver(clock, self._ir_rx)
        for board in (self.ctrl, self.comm):
            board.on_ports = self._ports_changed
            for uart in (board.uart0, board.uart1):
                uart.on_overrun = self._overrun(board, uart)
        self._actuators_pending = False
        bus.subscribe(bus.keys.ir_rx(self.name), self._ir_in.on_message)
        bus.subscribe_json(f"{bus.keys.root}/world/switches/{self.name}", self._on_switches)

    def power_up(self) -> None:
        self.ctrl.start(self.ctrl.program())
        self.comm.start(self.comm.program())

    # -- wires ------------------------------------------------------------------------------
    def _wire(self, tx: Uart, rx: Uart, link: Link, dst: str) -> None:
        clock = self.bus.clock
        publish = self._framer_publisher(link, tx.mcu.name, dst)

        def on_tx(data: bytes, starts: list[int]) -> None:
            for b, s in zip(data, starts):
                clock.call_at(s + tx.byte_ns, rx.receive, b)
            publish(data, starts, tx.byte_ns)
        tx.on_tx = on_tx

    def _sniff(self, tx: Uart, link: Link, src: str, dst: str) -> None:
        publish = self._framer_publisher(link, src, dst)
        tx.on_tx = lambda data, starts: publish(data, starts, tx.byte_ns)

    def _framer_publisher(self, link: Link, src: str, dst: str,
                          channel: int | None = None) -> Callable[[bytes, list[int], int], None]:
        """Frame the bytes a wire carries and publish each frame when its last byte ends."""
        framer = Framer(link)
        bus = self.bus

        def publish(data: bytes, starts: list[int], byte_ns: int) -> None:
            for t in framer.feed(data, [s + byte_ns for s in starts]):
                first = t.t_first_ns - byte_ns
                bus.clock.call_at(t.t_last_ns, self._publish_frame, t.frame, src, dst, t.t_last_ns,
                                  first, channel)
        return publish

    def _publish_frame(self, frame, src, dst, t_last, first, channel) -> None:
        self.bus.publish_frame(frame, src=src, dst=dst, sim_time_ns=t_last, first_byte_ns=first,
                               channel=channel)

    # -- IR -----------------------------------------------------------------------------------
    def _ir_tx(self, data: bytes, starts: list[int]) -> None:
        k = self.comm.ir_transceiver
        if k is None:
            return  # channel Y7 is not wired: the light goes nowhere
        u = self.comm.uart1
        self._ir_out.send(k, data, starts, u.byte_ns)
        self._ir_frames[k](data, starts, u.byte_ns)

    def _ir_rx(self, transceiver: int, byte: int, start: int, corrupt: bool) -> None:
        if self.comm.accepts_ir(transceiver, start):
            self.comm.uart1.receive(byte)

    def _on_switches(self, key: str, d: dict) -> None:
        self.switches = [bool(v) for v in d["present"]]

    # -- state out -------------------------------------------------------------------------------
    def _overrun(self, board: Mcu, uart: Uart) -> Callable[[int], None]:
        def on(byte: int) -> None:
            self.overruns += 1
            self.bus.event(board.name, "uart-overrun", uart=uart.name, lost=byte)
        return on

    def _ports_changed(self, mcu: Mcu) -> None:
        if not self._actuators_pending:
            self._actuators_pending = True
            self.bus.clock.call_later(0, self._publish_actuators)

    def actuators(self) -> Actuators:
        c, m = self.ctrl.port, self.comm.port

        def bit(ports: dict[str, int], pin) -> bool:
            return bool(ports[pin.port] & pin.mask)

        magnets = []
        for s in range(1, 7):
            pos, neg = bit(c, MAGNET_POS[s]), bit(c, MAGNET_NEG[s])
            magnets.append(2 if pos and neg else 1 if pos else -1 if neg else 0)
        return Actuators(
            module=self.name, sim_time_ns=self.bus.clock.now_ns(),
            joints_open=[bit(c, JOINT[j]) for j in range(1, 7)], magnets=magnets,
            led_pos=[not bit(m, LED_POS[s]) for s in range(1, 7)],
            led_neg=[not bit(m, LED_NEG[s]) for s in range(1, 7)],
            led_joint=[not bit(m, LED_JOINT[j]) for j in range(1, 7)],
            ir_channel=self.comm.ir_transceiver,
            ports={"ctrl": dict(c), "comm": dict(m)})

    def _publish_actuators(self) -> None:
        self._actuators_pending = False
        self.bus.put(self.bus.keys.actuators(self.name), self.actuators().to_json())
