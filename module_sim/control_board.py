"""The control board program (Appendix A, first listing) on an emulated ATmega162.

It drives the joint solenoids and side magnets (Table 3-3), talks to the comm board
on UART0 and prints to a PC terminal on UART1 (the debug link).
"""

from __future__ import annotations

from collections import deque

from bus import codec, rotations
from bus.clock import Clock
from bus.functions import FUNCTIONS, Board
from bus.pins import (CONTROL_PULLUPS, CONTROL_UART_PINS, DIP_PORT, JOINT, MAGNET_NEG, MAGNET_POS, Pin,
                      dip_id, dip_levels, fold, port_masks)
from bus.timing import (BOOT_JTEST_ROUNDS, BOOT_JTEST_TICKS, BOOT_SETTLE_TICKS, FRAME_BYTE_TICKS,
                        HANDSHAKE_RETRY_TICKS, MAGNET_ON_LIMIT_TICKS, SELFTEST_PULSE_TICKS,
                        SOLENOID_ON_LIMIT_TICKS, THESIS_ROTATION_TIMING, TICK_NS, Baud)

from .avr import Delay, Mcu, Program, Rx, Tx, Uart
from .profiles import Profile

_R, _L, _STAR = ord("R"), ord("L"), ord("*")
_ALL_JOINTS = {p.port: 0 for p in JOINT.values()}
for _p in JOINT.values():
    _ALL_JOINTS[_p.port] |= _p.mask


#: The on-time limit of each group of coils: solenoids, magnets positive, negative.
_LIMIT = (SOLENOID_ON_LIMIT_TICKS, MAGNET_ON_LIMIT_TICKS, MAGNET_ON_LIMIT_TICKS)
#: Every coil as (group, side): group 0 solenoids, 1 magnets positive, 2 negative (as in ACT).
_COILS: tuple[tuple[int, int, Pin], ...] = tuple(
    (g, s, table[s]) for g, table in enumerate((JOINT, MAGNET_POS, MAGNET_NEG)) for s in range(1, 7))
#: The port bits an actuator report covers: solenoids and magnet relays (Table 3-3).
COIL_MASK = port_masks([pin for _, _, pin in _COILS])


def _keep_mask(port: str) -> int:
    """SxOffAll clears PORTB and PORTD except the UART pins."""
    return sum(p.mask for p in CONTROL_UART_PINS if p.port == port)


class ControlBoard(Mcu):
    """Emulates the control board. ``dip`` is the DIP switch byte (the hardware id)."""

    def __init__(self, clock: Clock, name: str, profile: Profile, dip: int = 0) -> None:
        super().__init__(clock, name)
        self.profile = profile
        self.port.update(port_masks(CONTROL_PULLUPS))  # board_init's pull-ups, at power-up
        self.pin_in[DIP_PORT] = dip_levels(dip & 0xFF)
        self.uart0 = Uart(self, "uart0", Baud.UART0)
        self.uart1 = Uart(self, "uart1", Baud.DEBUG)
        #: the last codes run (bounded: a long run's memory stays flat) and how many in all
        self.executed: deque[int] = deque(maxlen=1000)
        self.executed_total = 0
        # v2 actuator reports: sent once the board listens (not during the boot's joint
        # test, whose report would delay the banners and the handshake), from a transmit
        # buffer the UDRE interrupt empties, so the program never waits for them
        self._reporting = False
        self._report_due = False
        self._reported: bytes | None = None
        # the on-time limit (both profiles): the tick each coil has been on since
        self._coil_since: dict[tuple[int, int], int] = {}
        self._guard_due = False
        self._limit_timers: set[int] = set()

    # -- outputs (Table 3-3) ------------------------------------------------------------
    def _on(self, pin: Pin) -> None:
        self.set_bits(pin.port, pin.mask)

    def _off(self, pin: Pin) -> None:
        self.clear_bits(pin.port, pin.mask)

    def JxOpen(self, i: int) -> None:
        self._on(JOINT[fold(i)])

    def JxClose(self, i: int) -> None:
        self._off(JOINT[fold(i)])

    def JxOpenAll(self) -> None:
        for port, mask in _ALL_JOINTS.items():
            self.set_bits(port, mask)

    def JxCloseAll(self) -> None:
        for port, mask in _ALL_JOINTS.items():
            self.clear_bits(port, mask)

    # -- v2 actuator report (docs/protocol.md) --------------------------------------------------
    def _write(self, port: str, value: int) -> None:
        changed = self.port[port] ^ value
        super()._write(port, value)
        if not changed & COIL_MASK.get(port, 0):
            return
        if self._reporting and not self._report_due:
            self._report_due = True  # one report for all the bits a step changes at once
            self.clock.call_later(0, self._report)
        if not self._guard_due and self.driver is None:  # the C program has its own guard
            # after the report, as the C step does: the limit's switch-off is reported anew
            self._guard_due = True
            self.clock.call_later(0, self._coil_guard)

    # -- the coil on-time limit (ours, both profiles; bus/timing.py) ----------------------------
    def _coil_guard(self) -> None:
        """Note when each coil came on; book a check for its limit."""
        self._guard_due = False
        now_tick = self.tick_count()
        for g, s, pin in _COILS:
            if not self.port[pin.port] & pin.mask:
                self._coil_since.pop((g, s), None)
            elif (g, s) not in self._coil_since:
                self._coil_since[(g, s)] = now_tick
                due = now_tick + _LIMIT[g]
                if due not in self._limit_timers:  # one check for coils that came on together
                    self._limit_timers.add(due)
                    self.clock.call_at(self._boot_ns + due * TICK_NS, self._coil_limit, due)

    def _coil_limit(self, due: int) -> None:
        """Switch off every coil on since ``due - limit`` or earlier; say which (``LIM``)."""
        self._limit_timers.discard(due)
        now_tick = self.tick_count()
        over = [(g, s) for (g, s), since in self._coil_since.items() if since + _LIMIT[g] <= now_tick]
        if not over:
            return
        bits = [0, 0, 0]
        for g, s in over:
            bits[g] |= 1 << (s - 1)
            del self._coil_since[(g, s)]
        self.uart1.write(codec.encode_coil_limit(*bits), self.clock.now_ns())
        for g, s, pin in _COILS:
            if bits[g] >> (s - 1) & 1:
                self._off(pin)

    def actuator_bits(self) -> tuple[list[bool], list[int]]:
        """Solenoids J1..J6 (True = energised) and magnets S1..S6 as in
        :class:`bus.messages.Actuators` (+1, -1, 0, or 2 for both relays), from the ports."""
        port = self.port
        joints = [bool(port[JOINT[j].port] & JOINT[j].mask) for j in range(1, 7)]
        magnets = []
        for s in range(1, 7):
            pos = bool(port[MAGNET_POS[s].port] & MAGNET_POS[s].mask)
            neg = bool(port[MAGNET_NEG[s].port] & MAGNET_NEG[s].mask)
            magnets.append(2 if pos and neg else 1 if pos else -1 if neg else 0)
        return joints, magnets

    def _report(self) -> None:
        self._report_due = False
        line = codec.encode_actuator_report(*self.actuator_bits())
        if line != self._reported:
            self._reported = line
            self.uart1.write(line, self.clock.now_ns())

    def SxP(self, i: int) -> None:
        self._on(MAGNET_POS[fold(i)])

    def SxN(self, i: int) -> None:
        self._on(MAGNET_NEG[fold(i)])

    def SxOff(self, i: int) -> None:
        self._off(MAGNET_POS[fold(i)])
        self._off(MAGNET_NEG[fold(i)])

    def SxOffAll(self) -> None:
        for port in ("B", "D"):
            self.write_port(port, self.port[port] & _keep_mask(port))

    def TurnOffAll(self) -> None:
        self.SxOffAll()
        self.JxCloseAll()

    # -- timed functions (generators) ------------------------------------------------------
    def JTest(self, n: int, t: int) -> Program:
        for _ in range(n):
            for i in range(1, 7):
                self.JxOpen(i)
                yield Delay(t)
                self.JxClose(i)
                yield Delay(t)

    def _magnet_test(self, on, n: int, t: int) -> Program:
        for _ in range(n):
            for i in range(1, 7):
                on(i)
                yield Delay(t)
                self.SxOff(i)
                yield Delay(t)

    def SPTest(self, n: int, t: int) -> Program:
        yield from self._magnet_test(self.SxP, n, t)

    def SNTest(self, n: int, t: int) -> Program:
        yield from self._magnet_test(self.SxN, n, t)

    def SelfTest(self, switches: int) -> Program:
        """v2: each coil on for a pulse and off as long (the ACT reports show each), then the
        DIP id and the comm board's optical switches in a ``TST`` line."""
        for _, _, pin in _COILS:
            self._on(pin)
            yield Delay(SELFTEST_PULSE_TICKS)
            self._off(pin)
            yield Delay(SELFTEST_PULSE_TICKS)
        yield Tx(self.uart1, codec.encode_self_test(dip_id(self.pin_in[DIP_PORT]), switches))

    def WalterLog(self, round_: int, flags: int, position: int, delay: int) -> Program:
        """v2: a Walter round's line on the debug UART (the comm board decided; docs/protocol.md)."""
        yield Tx(self.uart1, codec.encode_walter_log(round_, flags, position, delay))

    def STwo(self, dirs: int, i1: int, i2: int) -> Program:
        """v2: the substrate of two rotations at once (two movers turn about it in one round)."""
        actions = {"open": self.JxOpen, "pos": self.SxP, "neg": self.SxN,
                   "close_all": self.JxCloseAll, "off_all": self.SxOffAll}
        for ticks in rotations.perform_together(rotations.two_substrates(dirs, i1, i2), *THESIS_ROTATION_TIMING,
                                                actions=actions):
            yield Delay(ticks)

    def _rotation(self, name: str, i: int, t1: int, t2: int, t3: int) -> Program:
        """Run a rotation of :mod:`bus.rotations` on the relays and solenoids."""
        actions = {"open": self.JxOpen, "pos": self.SxP, "neg": self.SxN,
                   "close_all": self.JxCloseAll, "off_all": self.SxOffAll}
        for ticks in rotations.perform(name, i, t1, t2, t3, actions=actions,
                                       sccw_both_negative=self.profile.sccw_both_negative):
            yield Delay(ticks)

    def MCW(self, i: int, t1: int, t2: int, t3: int) -> Program:
        yield from self._rotation("MCW", i, t1, t2, t3)

    def MCCW(self, i: int, t1: int, t2: int, t3: int) -> Program:
        yield from self._rotation("MCCW", i, t1, t2, t3)

    def SCW(self, i: int, t1: int, t2: int, t3: int) -> Program:
        yield from self._rotation("SCW", i, t1, t2, t3)

    def SCCW(self, i: int, t1: int, t2: int, t3: int) -> Program:
        # The firmware energises S(i-5) negative; its own comment (and v2) says positive.
        yield from self._rotation("SCCW", i, t1, t2, t3)

    # -- the program ----------------------------------------------------------------------------
    def program(self) -> Program:
        u0, u1 = self.uart0, self.uart1
        yield Delay(BOOT_SETTLE_TICKS)  # let the supplies settle
        self.TurnOffAll()
        yield from self.JTest(BOOT_JTEST_ROUNDS, BOOT_JTEST_TICKS)  # the joints click once: "ready"
        yield Tx(u1, codec.PREAMBLE)
        yield Tx(u1, codec.BANNERS["CTR_Ready"] + codec.EOL)
        yield Tx(u0, b"R")
        while (yield Rx(u0, HANDSHAKE_RETRY_TICKS)) != _R:
            yield Tx(u0, b"R")
        yield Tx(u1, codec.BANNERS["COMM_Ready"] + codec.EOL)
        yield Tx(u0, b"L")
        if self.profile.addressing:
            # v2: the DIP switches are the module's id; the comm board needs it for Select.
            yield Tx(u0, bytes([dip_id(self.pin_in[DIP_PORT])]))
        yield Tx(u1, codec.BANNERS["CTR_LST"] + codec.EOL)
        self._reporting = self.profile.actuator_report
        # the coils as the boot left them (all off) count as reported: a step that ends where
        # it began (a zero-tick pulse, JTest 1 0) changes no bit and sends no report, as in C
        self._reported = codec.encode_actuator_report(*self.actuator_bits())
        while True:
            yield from self.listen()

    def listen(self) -> Program:
        u0, u1 = self.uart0, self.uart1
        checked = self.profile.checked_frames
        while (yield Rx(u0)) != _STAR:
            pass
        msg = []
        for _ in range(5):
            # v2: each within FRAME_BYTE_TICKS: after a long command the remains of a frame
            # that overran the input end in a silence and are dropped, not read as the next one
            b = yield (Rx(u0, FRAME_BYTE_TICKS, tell_timeout=True) if checked else Rx(u0))
            if b is None:
                return
            msg.append(b)
        yield Tx(u0, bytes([msg[0]]))  # confirm to the comm board: echo the code
        yield Tx(u1, codec.PREAMBLE)
        yield Tx(u1, b"ACK" + bytes([msg[0]]) + codec.EOL)
        yield Tx(u1, codec.encode_debug_msg(bytes(msg)))
        if checked and (yield Rx(u0, FRAME_BYTE_TICKS, tell_timeout=True)) != codec.END[0]:
            return  # v2: not a whole frame: echoed, but not run
        yield from self.execute(msg[0], msg[1:])

    def execute(self, code: int, args: list[int]) -> Program:
        fn = FUNCTIONS[code]
        if fn.board is not Board.CONTROL:
            return  # the firmware's if-chain simply matches nothing
        self.executed.append(code)
        self.executed_total += 1
        result = getattr(self, fn.name)(*args[:len(fn.args)])
        if result is not None:
            yield from result
