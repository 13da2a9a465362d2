"""A virtual HexBot module: both boards wired by their UART0, on the bus.

It publishes every byte on every wire as frames — UART0 both ways, the control
board's debug UART1, and what its IR transceivers send — plus its actuator and LED
state, and takes IR light from the bus (``ir/rx/m<id>``).
"""

from __future__ import annotations

import json
from typing import Any, Callable

from bus.codec import Link
from bus.framer import Framer
from bus.ir import IR_CONFLICT, Burst, IrReceiver, IrTransmitter, cut_masks
from bus.keys import board_endpoint, module_endpoint
from bus.messages import Actuators, Switches
from bus.pins import LED_JOINT, LED_NEG, LED_POS
from bus.scenario import PROGRAMS
from bus.timing import Baud
from bus.transport import Bus

from .avr import Mcu, Uart
from .comm_board import CommBoard
from .control_board import ControlBoard
from .profiles import Profile


class VirtualModule:
    """Both boards of one module. ``origin`` marks what it publishes: ``"virtual"``, or
    ``"twin"`` for the world's shadow copy of a real module (:mod:`module_sim.twin`)."""

    def __init__(self, bus: Bus, module_id: int, profile: Profile, *, ir_baud: int = 300,
                 mux_cut: bool = False, origin: str = "virtual", program: str = "model",
                 core: Any = None) -> None:
        """``core``: the :class:`module_sim.core.FleetCore` that runs this module's boards and
        its light (firmware program only); this object keeps their ports, frames and records."""
        if program not in PROGRAMS:
            raise ValueError(f"program {program!r}: expected one of {', '.join(PROGRAMS)}")
        #: "model": the Python programs; "firmware": the C programs (module_sim.firmware);
        #: "simavr": the images in simavr cores (module_sim.simavr)
        self.program = program
        if program in ("firmware", "simavr") and ir_baud != Baud.IR:
            # the C programs' localization slots are built for the IR baud rate (bus.cheader)
            raise ValueError(f"the {program} program is built for {int(Baud.IR)} baud IR, not {ir_baud}: "
                             "use program = \"model\" for other IR baud rates")
        self.bus = bus
        self.origin = origin
        #: side-IR bytes its comm board took in: light a real board beside virtual
        #: neighbours never gets, so a twin that heard some may know more than its board
        self.side_bytes_heard = 0
        # mux_cut: a multiplexer switch during an IR burst moves the rest of it to the new
        # transceiver (docs/protocol.md, emulation notes). Off: a burst goes out whole on the
        # transceiver selected when it was written.
        self.mux_cut = mux_cut
        self.id = module_id
        self.name = module_endpoint(module_id)
        clock = bus.clock
        self.ctrl = ControlBoard(clock, board_endpoint(module_id, "ctrl"), profile, dip=module_id)
        self.comm = CommBoard(clock, board_endpoint(module_id, "comm"), profile, ir_baud,
                              neighbours=lambda: self.switches)
        self.switches = [False] * 6  # optical switches, from the world
        self.overruns = 0
        self.core = core
        self.core_index = -1  # set by FleetCore.add_fleet
        # one framer per transceiver: the centre carries centre-link frames, sides side-link ones
        self._ir_frames = {k: self._framer_publisher(Link.CENTRE if k == 0 else Link.SIDE,
                                                     self.comm.name, "pc" if k == 0 else f"side{k}",
                                                     channel=k) for k in range(7)}
        self._actuators_pending = False
        self._actuators_ns = 0
        self._actuators_key = bus.keys.actuators(self.name)
        self._record_head = '{"module":' + _dumps(self.name) + ',"sim_time_ns":'
        bus.subscribe_json(bus.keys.switches(self.name), self._on_switches)
        if core is not None:
            # the core's wires, as it numbers them (core.c): UART0 up, down, debug, IR 0..6
            self._core_wires = [self._framer_publisher(Link.UART0_UP, self.ctrl.name, self.comm.name),
                                self._framer_publisher(Link.UART0_DOWN, self.comm.name, self.ctrl.name),
                                self._framer_publisher(Link.DEBUG, self.ctrl.name, "terminal")] + \
                [self._ir_frames[k] for k in range(7)]
            return
        # UART0: each board's TX is the other's RX
        self._wire(self.ctrl.uart0, self.comm.uart0, Link.UART0_UP, self.comm.name)
        self._wire(self.comm.uart0, self.ctrl.uart0, Link.UART0_DOWN, self.ctrl.name)
        self._sniff(self.ctrl.uart1, Link.DEBUG, self.ctrl.name, "terminal")
        # IR: bursts out on the bus, light in from the world's medium
        self._ir_out = IrTransmitter(bus.put, bus.keys.ir_tx(self.comm.name), self.comm.name)
        self.comm.uart1.on_tx = self._ir_tx
        # bursts still on the air: [burst, transceiver, timer of its end]; the multiplexer may
        # move the rest of one to another transceiver (docs/protocol.md, emulation notes)
        self._ir_flight: list[list] = []
        self._ir_k = self.comm.ir_transceiver
        self._ir_in = IrReceiver(clock, self._ir_rx, lambda src, burst, index: bus.event(
            self.comm.name, IR_CONFLICT, sender=src, burst=burst, index=index))
        for board in (self.ctrl, self.comm):
            board.on_ports = self._ports_changed
            for uart in (board.uart0, board.uart1):
                uart.on_overrun = self._overrun(board, uart)
        bus.subscribe(bus.keys.ir_rx(self.name), self._ir_in.on_message)
        if program == "simavr":  # made now: a missing image or library fails before the run
            from .simavr import SimavrDriver

            self._simavr = SimavrDriver(self)

    def power_up(self) -> None:
        if self.core is not None:
            self.core.power_up(self)
            return
        if self.program == "simavr":
            self._simavr.power_up()
            return
        if self.program == "firmware":
            from .firmware import FirmwareDriver, Program

            name = self.ctrl.profile.name
            FirmwareDriver(self.ctrl, Program.get("control", name)).power_up()
            FirmwareDriver(self.comm, Program.get("comm", name), lambda: self.switches).power_up()
            return
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
        bus, core = self.bus, self.core

        def publish(data: bytes, starts: list[int], byte_ns: int) -> None:
            for t in framer.feed(data, [s + byte_ns for s in starts]):
                first = t.t_first_ns - byte_ns
                if core is not None:
                    core.queue_frame(bus, t.t_last_ns, t.frame, src, dst, first, channel)
                else:
                    bus.clock.call_at(t.t_last_ns, self._publish_frame, t.frame, src, dst, t.t_last_ns,
                                      first, channel)
        # what the fleet core renders this wire's frames from (FleetCore.add_fleet)
        publish.framer, publish.link, publish.src, publish.dst, publish.channel = (  # type: ignore[attr-defined]
            framer, link, src, dst, channel)
        return publish

    def _publish_frame(self, frame, src, dst, t_last, first, channel) -> None:
        self.bus.publish_frame(frame, src=src, dst=dst, sim_time_ns=t_last, first_byte_ns=first,
                               channel=channel, origin=self.origin)

    # -- IR -----------------------------------------------------------------------------------
    def _ir_tx(self, data: bytes, starts: list[int]) -> None:
        k = self.comm.ir_transceiver
        if k is None:
            return  # channel Y7 is not wired: the light goes nowhere
        byte_ns = self.comm.uart1.byte_ns
        if not self.mux_cut:
            self._ir_out.send(k, data, starts, byte_ns)
            self._ir_frames[k](data, starts, byte_ns)
            return
        self._ir_send(k, bytes(data), list(starts), byte_ns, None)

    def _ir_send(self, k: int, data: bytes, starts: list[int], byte_ns: int,
                 corrupt: list[bool] | None) -> None:
        b = self._ir_out.send(k, data, starts, byte_ns, corrupt)
        entry = [b, k, None]
        entry[2] = self.bus.clock.call_at(starts[-1] + byte_ns, self._ir_sent, entry)
        self._ir_flight.append(entry)

    def _ir_sent(self, entry: list) -> None:
        """A burst has gone out whole on its transceiver: its bytes are frames of that wire."""
        self._ir_flight.remove(entry)
        b: Burst = entry[0]
        self._ir_frames[entry[1]](b.data, b.starts, b.byte_ns)

    def _ir_switched(self, k: int | None) -> None:
        """The multiplexer left the transceiver of the bursts on the air (CD4051: the UART's
        line follows the selection at once). A byte being sent is cut: the old transceiver
        got its first bits, the new one the rest, each sees idle (1) for the others, both
        garbled. The bytes after it go out on the new transceiver (none on Y7)."""
        now = self.bus.clock.now_ns()
        for entry in list(self._ir_flight):
            b: Burst = entry[0]
            old = entry[1]
            byte_ns, starts, data = b.byte_ns, b.starts, b.data
            idx = next((i for i, s in enumerate(starts) if s + byte_ns > now), None)
            if idx is None:
                continue  # ends now: it went out whole
            entry[2].cancel()
            self._ir_flight.remove(entry)
            partial = starts[idx] < now
            before, after = cut_masks(starts[idx], byte_ns, now) if partial else (0, 0)
            self._ir_out.cut(b, idx, after if partial else None, now)
            sent = bytearray(data[:idx])
            if partial:
                sent.append(data[idx] | after)
            if sent:
                self._ir_frames[old](bytes(sent), starts[:len(sent)], byte_ns)
            if k is not None:
                rest = bytearray(data[idx:])
                corrupt = [False] * len(rest)
                if partial:
                    rest[0] |= before
                    corrupt[0] = True
                self._ir_send(k, bytes(rest), starts[idx:], byte_ns, corrupt)

    def _ir_rx(self, transceiver: int, byte: int, start: int, corrupt: bool) -> None:
        if self.comm.accepts_ir(transceiver, start):
            if transceiver:
                self.side_bytes_heard += 1
            self.comm.uart1.receive(byte)

    def _on_switches(self, key: str, d: dict) -> None:
        self.switches = Switches.present_of(d)
        if self.core is not None:
            self.core.set_pins(self)
        elif self.comm.driver is not None:  # the C firmware reads them on its pins
            self.comm.driver.refresh_pins()

    # -- the fleet core's outputs (module_sim.core) ------------------------------------------
    def input_pins(self, mcu: Mcu) -> bytes:
        """The levels on ``mcu``'s input pins: its DIP switches, the comm board's optical
        switches (as :class:`module_sim.firmware.FirmwareDriver` hands them to the program)."""
        from .firmware import input_pins

        return input_pins(mcu, self.switches if mcu is self.comm else None)

    @property
    def ir_conflicts(self) -> int:
        """Corrections of the IR medium that came after their byte's stop bit (IrReceiver)."""
        return self._ir_in.conflicts

    def core_ports(self, ports: bytes) -> None:
        """Both boards' ports (control PORTA..PORTE, then comm) after the programs in the
        core wrote them (the core publishes the record: :meth:`publish_actuators`)."""
        c, m = self.ctrl.port, self.comm.port
        c["A"], c["B"], c["C"], c["D"], c["E"], m["A"], m["B"], m["C"], m["D"], m["E"] = ports

    def core_overrun(self, t: int, board: int, uart: int, lost: int, where: dict) -> None:
        """A UART of this module in the core overran at ``t`` (see :meth:`_overrun`)."""
        mcu = self.comm if board else self.ctrl
        u = mcu.uart1 if uart else mcu.uart0
        u.overruns += 1
        self.overruns += 1
        self.core.put(self.bus, self.bus.keys.event(mcu.name), _dumps({
            "kind": "uart-overrun", "src": mcu.name, "sim_time_ns": t, "uart": u.name, "lost": lost,
            **where}).encode())

    # -- state out -------------------------------------------------------------------------------
    def _overrun(self, board: Mcu, uart: Uart) -> Callable[[int], None]:
        def on(byte: int) -> None:
            self.overruns += 1
            # an IR byte says which transceiver it came through (recordings.health sorts by it)
            where = {"channel": self.comm.ir_transceiver} if uart is self.comm.uart1 else {}
            self.bus.event(board.name, "uart-overrun", uart=uart.name, lost=byte, **where)
        return on

    def _ports_changed(self, mcu: Mcu) -> None:
        if self.mux_cut and mcu is self.comm:
            k = self.comm.ir_transceiver
            if k != self._ir_k:
                self._ir_k = k
                if self._ir_flight:
                    self._ir_switched(k)
        self._actuators_ns = self.bus.clock.due_ns()  # when the port changed, not when told
        if not self._actuators_pending:
            self._actuators_pending = True
            self.bus.clock.call_later(0, self._publish_actuators)

    def actuators(self, sim_time_ns: int | None = None) -> Actuators:
        """The actuator record of the ports now (stamped ``sim_time_ns``, default now)."""
        c, m = self.ctrl.port, self.comm.port

        def bit(ports: dict[str, int], pin) -> bool:
            return bool(ports[pin.port] & pin.mask)

        joints, magnets = self.ctrl.actuator_bits()
        return Actuators(
            module=self.name,
            sim_time_ns=self.bus.clock.now_ns() if sim_time_ns is None else sim_time_ns,
            joints_open=joints, magnets=magnets,
            led_pos=[not bit(m, LED_POS[s]) for s in range(1, 7)],
            led_neg=[not bit(m, LED_NEG[s]) for s in range(1, 7)],
            led_joint=[not bit(m, LED_JOINT[j]) for j in range(1, 7)],
            ir_channel=self.comm.ir_transceiver,
            ports={"ctrl": dict(c), "comm": dict(m)}, origin=self.origin)

    def _publish_actuators(self) -> None:
        self._actuators_pending = False
        self.publish_actuators(self._actuators_ns)

    def publish_actuators(self, sim_time_ns: int) -> None:
        """Put the actuator record of the ports now, stamped ``sim_time_ns``."""
        c, m = self.ctrl.port, self.comm.port
        key = (c["A"], c["B"], c["C"], c["D"], c["E"], m["A"], m["B"], m["C"], m["D"], m["E"], self.origin)
        tail = _RECORD_TAILS.get(key)
        if tail is None:
            a = self.actuators(0)
            # ``a.to_json()`` byte for byte (same keys and order), without asdict's deep copies;
            # all but the module and the time depends on the ports alone: kept per ports
            tail = _RECORD_TAILS[key] = "," + _dumps({
                "joints_open": a.joints_open, "magnets": a.magnets, "led_pos": a.led_pos,
                "led_neg": a.led_neg, "led_joint": a.led_joint, "ir_channel": a.ir_channel,
                "ports": a.ports, "origin": a.origin, "type": Actuators.TOPIC})[1:]
        payload = f'{self._record_head}{sim_time_ns}{tail}'.encode()
        if self.core is None:
            self.bus.put(self._actuators_key, payload)
        else:  # with the window's other samples
            self.core.put(self.bus, self._actuators_key, payload)


_dumps = json.JSONEncoder(separators=(",", ":")).encode
#: the end of an actuator record (after its time) for each state of the ports
_RECORD_TAILS: dict[tuple[int | str, ...], str] = {}
