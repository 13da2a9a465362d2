"""The communication board program (Appendix A, second listing) on an emulated ATmega162.

UART1 (300 baud) reaches one of seven IR transceivers through the CD4051 multiplexer;
UART0 (4800 baud) talks to the control board. LEDs are active low (Table 3-4). The
v2 additions (docs/protocol.md) are enabled by the profile.
"""

from __future__ import annotations

from typing import Callable

from bus import codec, rotations
from bus.rotations import orientation_after
from bus.clock import Clock
from bus.functions import ACK_UNKNOWN, FUNCTIONS, Board, FunctionCode as F, WalterOp
from bus.lattice import Cell, Direction, Joint, Side, body_to_global, global_to_body, move_rule
from bus.pins import (COMM_PULLUPS, IR_SEL_A, IR_SEL_MASK, LED_JOINT, LED_NEG, LED_POS, Pin, fold,
                      ir_select_bits, ir_selected, port_masks)
from bus.timing import (BOOT_CIRCLE_ROUNDS, BOOT_CIRCLE_TICKS, BOOT_FLASH_ROUNDS, BOOT_FLASH_TICKS,
                        ECHO_TIMEOUT_TICKS, HANDSHAKE_RETRY_TICKS, LOCALIZE_BYTE_TICKS,
                        LOCALIZE_FAILED_CIRCLE_ROUNDS, LOCALIZE_FAILED_CIRCLE_TICKS,
                        LOCALIZE_LISTEN_TICKS, LOCALIZE_MUX_SETTLE_TICKS, SUBSTRATE_ACK_DELAY_TICKS,
                        THESIS_LOCALIZE_REPEATS, THESIS_LOCALIZE_ROUNDS, THESIS_LOCALIZE_SEND_TICKS,
                        THESIS_ROTATION_TIMING, WALTER_MUX_SETTLE_TICKS, YREF_FLASH_TICKS, YREF_SHOWS,
                        Baud, localize_slot_ticks, localize_step_ticks, localize_window_ticks,
                        walter_actuation_at, walter_busy_at, walter_hold_end_at, walter_late_at,
                        walter_log_at,
                        walter_window_ticks)

from .avr import TIMEOUT, Delay, Mcu, Program, Rx, Tx, Uart
from .framing import read_frame
from .profiles import Profile
from .walter import Entry, WalterState, walter_pivots_apart

_STAR, _R, _L = ord("*"), ord("R"), ord("L")
#: Relay frames of these functions carry 0, not 'N', as their first argument (Appendix A).
_ZERO_ARG = {F.JxOpenAll, F.JxCloseAll}


def _port_masks(table: dict[int, Pin]) -> dict[str, int]:
    """The bits of a pin table, per port that has any, in port order."""
    return {port: mask for port, mask in port_masks(list(table.values())).items() if mask}


class CommBoard(Mcu):
    """Emulates the communication board.

    ``neighbours()`` returns the optical switches: presence of a neighbour on body sides 1..6.
    """

    def __init__(self, clock: Clock, name: str, profile: Profile, ir_baud: int = Baud.IR,
                 neighbours: Callable[[], list[bool]] | None = None) -> None:
        super().__init__(clock, name)
        self.profile = profile
        self.uart0 = Uart(self, "uart0", Baud.UART0)
        self.uart1 = Uart(self, "uart1", ir_baud)
        self.neighbours = neighbours or (lambda: [False] * 6)
        self.port.update(port_masks(COMM_PULLUPS))  # board_init's pull-ups, at power-up
        # firmware globals
        self.M, self.S, self.L = 1, 0, 0
        self.X = self.Y = 0
        self.Yref = 0
        # v2 addressing
        self.id = 0
        self.selected = True
        self.addressed = False  # selected by id or cell (not by a broadcast)
        self.v2_active = False  # a Select has been seen since power-up
        self.mux_changed_at = 0
        #: v2 distributed reconfiguration: the problem and Figure 10's state (module_sim.walter)
        self.walter: WalterState | None = None

    # -- IR multiplexer (Table 3-5) -------------------------------------------------------
    @property
    def ir_transceiver(self) -> int | None:
        return ir_selected(self.port["A"])

    def IrSel(self, i: int) -> None:
        if not 0 <= i <= 6:
            return  # the firmware's if-chain ignores other values
        self.write_port(IR_SEL_A.port, (self.port[IR_SEL_A.port] & ~IR_SEL_MASK) | ir_select_bits(i))

    def _write(self, port: str, value: int) -> None:
        """Every write of the selector's port, the Python IrSel's or the C program's, tells
        when the multiplexer last moved (``accepts_ir``)."""
        if port != IR_SEL_A.port:
            super()._write(port, value)
            return
        before = self.ir_transceiver
        super()._write(port, value)
        if self.ir_transceiver != before:
            self.mux_changed_at = self.clock.now_ns()

    def accepts_ir(self, transceiver: int, start_ns: int) -> bool:
        """A byte reaches UART1 only if the mux stayed on its transceiver for the whole byte."""
        return self.ir_transceiver == transceiver and self.mux_changed_at <= start_ns

    # -- LEDs (Table 3-4, active low) ----------------------------------------------------------
    def _led(self, pin: Pin, on: bool) -> None:
        (self.clear_bits if on else self.set_bits)(pin.port, pin.mask)

    def _leds(self, table: dict[int, Pin], on: bool) -> None:
        # one write per port, as the C firmware does (a bit at a time costs it ~0.1 ms each)
        for port, mask in _port_masks(table).items():
            (self.clear_bits if on else self.set_bits)(port, mask)

    def SideOnP(self, i: int) -> None: self._led(LED_POS[fold(i)], True)
    def SideOffP(self, i: int) -> None: self._led(LED_POS[fold(i)], False)
    def SideOnN(self, i: int) -> None: self._led(LED_NEG[fold(i)], True)
    def SideOffN(self, i: int) -> None: self._led(LED_NEG[fold(i)], False)
    def JointOn(self, i: int) -> None: self._led(LED_JOINT[fold(i)], True)
    def JointOff(self, i: int) -> None: self._led(LED_JOINT[fold(i)], False)
    def SideOnAllP(self) -> None: self._leds(LED_POS, True)
    def SideOffAllP(self) -> None: self._leds(LED_POS, False)
    def SideOnAllN(self) -> None: self._leds(LED_NEG, True)
    def SideOffAllN(self) -> None: self._leds(LED_NEG, False)
    def JointOnAll(self) -> None: self._leds(LED_JOINT, True)
    def JointOffAll(self) -> None: self._leds(LED_JOINT, False)

    def LOn(self) -> None:
        self.SideOnAllP()
        self.SideOnAllN()
        self.JointOnAll()

    def LOff(self) -> None:
        self.SideOffAllP()
        self.SideOffAllN()
        self.JointOffAll()

    def _blink_each(self, on, off, n: int, t: int) -> Program:
        for _ in range(n):
            for i in range(1, 7):
                on(i)
                yield Delay(t)
                off(i)
                yield Delay(t)

    def SidePTest(self, n: int, t: int) -> Program:
        yield from self._blink_each(self.SideOnP, self.SideOffP, n, t)

    def SideNTest(self, n: int, t: int) -> Program:
        yield from self._blink_each(self.SideOnN, self.SideOffN, n, t)

    def JointTest(self, n: int, t: int) -> Program:
        yield from self._blink_each(self.JointOn, self.JointOff, n, t)

    def LCircle(self, n: int, t: int) -> Program:
        for _ in range(n):
            for i in range(1, 7):
                self.JointOn(i)
                yield Delay(t)
                self.JointOff(i)
                yield Delay(t)
                self.IrSel(i)
                yield Tx(self.uart1, bytes([0xFF]))
                yield Delay(t)
                yield Tx(self.uart1, bytes([0x00]))
                yield Delay(t)
                self.SideOnN(i)
                yield Delay(t)
                self.SideOffN(i)
                yield Delay(t)
                self.SideOnP(i)
                yield Delay(t)
                self.SideOffP(i)
                yield Delay(t)
        self.IrSel(0)

    def LColor(self, n: int, t: int) -> Program:
        for _ in range(n):
            for on, off in ((self.JointOnAll, self.JointOffAll), (self.SideOnAllN, self.SideOffAllN),
                            (self.SideOnAllP, self.SideOffAllP)):
                on()
                yield Delay(t)
                off()
                yield Delay(t)

    def LFlash1(self, n: int, t: int) -> Program:
        for _ in range(n):
            self.SideOnAllN()
            self.SideOffAllP()
            yield Delay(t)
            self.SideOffAllN()
            self.SideOnAllP()
            yield Delay(t)
        self.LOff()

    def LFlash2(self, n: int, t: int) -> Program:
        for _ in range(n):
            self.LOn()
            yield Delay(t)
            self.LOff()
            yield Delay(t)

    def LYref(self, i: int) -> Program:
        if i == 1:
            self.Yref += 1
        elif i == 2:
            self.Yref -= 1
        self.Yref %= 6
        s = 2 - self.Yref  # the body side that faces global +Y
        self.SideOnP(s)
        self.SideOffN(s)
        yield Delay(YREF_FLASH_TICKS)
        self.SideOnN(s)
        self.SideOffP(s)
        yield Delay(YREF_FLASH_TICKS)
        self.SideOffN(s)

    def _mirror(self, name: str, i: int, t1: int, t2: int, t3: int) -> Program:
        """Replay a rotation of :mod:`bus.rotations` on the LEDs, with the same waits."""
        actions = {"open": self.JointOn, "pos": self.SideOnP, "neg": self.SideOnN,
                   "close_all": self.JointOffAll, "off_all": self._magnet_leds_off}
        for ticks in rotations.perform(name, i, t1, t2, t3, actions=actions,
                                       sccw_both_negative=self.profile.sccw_both_negative):
            yield Delay(ticks)

    def LSTwo(self, dirs: int, i1: int, i2: int) -> Program:
        """v2: the LED mirror of ``STwo`` (a substrate of two rotations at once)."""
        actions = {"open": self.JointOn, "pos": self.SideOnP, "neg": self.SideOnN,
                   "close_all": self.JointOffAll, "off_all": self._magnet_leds_off}
        for ticks in rotations.perform_together(rotations.two_substrates(dirs, i1, i2),
                                                *THESIS_ROTATION_TIMING, actions=actions):
            yield Delay(ticks)

    def _magnet_leds_off(self) -> None:
        self.SideOffAllP()
        self.SideOffAllN()

    def LMCW(self, i: int, t1: int, t2: int, t3: int) -> Program:
        yield from self._mirror("LMCW", i, t1, t2, t3)

    def LMCCW(self, i: int, t1: int, t2: int, t3: int) -> Program:
        yield from self._mirror("LMCCW", i, t1, t2, t3)

    def LSCW(self, i: int, t1: int, t2: int, t3: int) -> Program:
        yield from self._mirror("LSCW", i, t1, t2, t3)

    def LSCCW(self, i: int, t1: int, t2: int, t3: int) -> Program:
        yield from self._mirror("LSCCW", i, t1, t2, t3)

    # -- roles and localization --------------------------------------------------------------
    @property
    def role(self) -> bytes:
        return codec.role_prefix(bool(self.M), bool(self.S))

    def _pre(self) -> Program:
        yield Tx(self.uart1, codec.PREAMBLE + self.role)

    def Ref(self) -> Program:
        self.M, self.S, self.L = 0, 1, 1
        self.X = self.Y = 0
        self.Yref = 0
        yield from self._show_yref()

    def _show_yref(self) -> Program:
        """Show the orientation: LYref(0), YREF_SHOWS times (Ref, a localization report)."""
        for _ in range(YREF_SHOWS):
            yield from self.LYref(0)

    def Localize(self) -> Program:
        if self.profile.fixed_side_localize:
            yield from self._localize_thesis()
        else:
            yield from self._localize_v2()

    def _localize_thesis(self) -> Program:
        u1 = self.uart1
        if self.L == 1:
            for _ in range(THESIS_LOCALIZE_ROUNDS):
                for side, msg in ((2, (0, 0, 0, 0, 0, 1, 5)), (3, (0, 0, 1, 0, 0, 0, 6))):
                    self.SideOnP(side)
                    self.SideOnN(side)
                    self.IrSel(side)
                    for _ in range(THESIS_LOCALIZE_REPEATS):
                        yield Delay(THESIS_LOCALIZE_SEND_TICKS)
                        yield from self._pre()
                        yield Tx(u1, codec.START + bytes(msg))
                    self.SideOffP(side)
                    self.SideOffN(side)
            self.IrSel(0)
            return
        msg1 = [0] * 8
        j = 1
        while j < 7:
            self.IrSel(j)
            self.SideOnP(j)
            self.SideOnN(j)
            b = yield Rx(u1, LOCALIZE_LISTEN_TICKS)
            while b not in (_STAR, TIMEOUT):
                b = yield Rx(u1, LOCALIZE_LISTEN_TICKS)
            if b == _STAR:
                for k in range(1, 8):
                    msg1[k] = yield Rx(u1)
                self.X, self.Y = msg1[2], msg1[6]  # the firmware's digits (a defect)
                self.Yref = (msg1[7] - j) % 6
                self.L = 1
                j = 7
                self.IrSel(0)
                self.LOff()
            self.SideOffP(j)  # (j == 7 after success: folds to side 1, as in C)
            self.SideOffN(j)
            j += 1
        if self.L == 1:
            yield from self._report_localized(msg1[7])
        else:
            yield from self.LCircle(LOCALIZE_FAILED_CIRCLE_ROUNDS, LOCALIZE_FAILED_CIRCLE_TICKS)
        self.IrSel(0)

    def _report_localized(self, side_heard: int) -> Program:
        self.IrSel(0)
        yield from self._pre()
        yield Tx(self.uart1, codec.encode_banner("LOC"))
        yield Tx(self.uart1, codec.encode_side_report(side_heard))
        yield Tx(self.uart1, codec.encode_yref_report(self.Yref))
        yield from self._show_yref()

    def _localize_v2(self) -> Program:
        """One step of general localization (Table 4-1, all six sides, optical switches).

        Every module that received the broadcast starts the step at the same instant. Time is
        cut into 6 listener windows of 6 sender slots: in window w a non-localized module
        listens on its body side w; in slot s of every window a localized module sends MSG1
        on its body side s. Only sides with a neighbour are used."""
        u1 = self.uart1
        slot, window = localize_slot_ticks(u1.baud), localize_window_ticks(u1.baud)
        here = self.neighbours()
        t0 = self.tick_count()  # slots count timer overflows, as the firmware can

        def until(ticks: int) -> int:
            """Ticks from now until t0 + ticks (<= 0: it has passed)."""
            return t0 + ticks - self.tick_count()

        def left(ticks: int) -> int:
            """The same, at least one (the C program's ticks_until)."""
            return max(1, until(ticks))

        if self.L == 1:
            for w in range(6):
                for s in range(1, 7):
                    yield Delay(until(w * window + (s - 1) * slot))
                    if not here[s - 1]:
                        continue
                    g = body_to_global(s, self.Yref)
                    there = Cell(self.X, self.Y).neighbour(g)
                    if not (codec.msg1_carries(there.x) and codec.msg1_carries(there.y)):
                        continue  # a cell MSG1 cannot carry: that neighbour stays unlocalized
                    self.IrSel(s)
                    yield Delay(LOCALIZE_MUX_SETTLE_TICKS)  # the listener is there
                    yield from self._pre()
                    yield Tx(u1, codec.START + codec.msg1_digits(there.x, there.y, Side(g).facing))
            yield Delay(until(localize_step_ticks(u1.baud)))
            self.IrSel(0)
            return
        heard = 0
        for w in range(1, 7):
            if not here[w - 1]:
                continue
            yield Delay(until((w - 1) * window))
            self.IrSel(w)
            b = yield Rx(u1, left(w * window))
            while b not in (_STAR, TIMEOUT):
                b = yield Rx(u1, left(w * window))
            if b != _STAR:
                continue
            body = []
            for _ in range(7):
                body.append((yield Rx(u1, LOCALIZE_BYTE_TICKS)))
            v = codec.msg1_view(codec.START + bytes(body))
            if not v["valid"]:
                continue
            self.X, self.Y = v["x"], v["y"]
            self.Yref = (v["side"] - w) % 6
            self.L = 1
            heard = v["side"]
            break
        self.IrSel(0)
        if self.L and heard and not self.v2_active:
            yield from self._report_localized(heard)  # v1 PCs see the thesis report lines

    # -- the program ----------------------------------------------------------------------------
    def program(self) -> Program:
        u0, u1 = self.uart0, self.uart1
        self.LOff()
        self.IrSel(0)
        yield from self._pre()
        yield Tx(u1, codec.encode_banner("COMM_Ready"))
        while (yield Rx(u0)) != _R:
            pass
        yield from self.LFlash1(BOOT_FLASH_ROUNDS, BOOT_FLASH_TICKS)
        yield Tx(u1, codec.encode_banner("CTR_Ready"))
        yield Tx(u0, b"R")
        while (yield Rx(u0, HANDSHAKE_RETRY_TICKS)) != _L:
            yield Tx(u0, b"R")
        if self.profile.addressing:
            # any byte is an id, '~' (126) too: only silence means none
            ident = yield Rx(u0, HANDSHAKE_RETRY_TICKS, tell_timeout=True)
            self.id = 0 if ident is None else ident
        yield from self.LFlash2(BOOT_FLASH_ROUNDS, BOOT_FLASH_TICKS)
        yield Tx(u1, codec.encode_banner("CTR_LST"))
        yield from self.LCircle(BOOT_CIRCLE_ROUNDS, BOOT_CIRCLE_TICKS)
        if self.profile.boot_assumes_yref:
            self.Yref = 1  # the thesis assumed its test orientation instead of localizing
        self.IrSel(0)
        # v2 keeps the banner so a v1 PC sees the same boot; it no longer claims L=1.
        yield Tx(u1, codec.encode_banner("LOC"))
        self.IrSel(0)
        yield from self.LColor(BOOT_FLASH_ROUNDS, BOOT_FLASH_TICKS)
        yield Tx(u1, codec.encode_banner("COMM_LST"))
        while True:
            yield from self.listen()

    def listen(self) -> Program:
        u1 = self.uart1
        if self.profile.checked_frames:
            msg = yield from read_frame(u1, codec.PC_FRAME_LEN)  # v2 reads the '#' too
            if msg is None:
                return
        else:
            while (yield Rx(u1)) != _STAR:
                pass
            msg = []
            for _ in range(9):
                msg.append((yield Rx(u1)))
        code, args = msg[0], msg[1:]
        self._substrate_turn = False
        ack = yield from self.dispatch(code, args)
        if ack is None:
            return  # v2: not for us, or a broadcast that nobody acknowledges
        if self.S or self._substrate_turn:
            yield Delay(SUBSTRATE_ACK_DELAY_TICKS)  # let the mobile module answer first
        yield Tx(u1, codec.encode_ack(ack, role=self.role))

    def dispatch(self, code: int, args: list[int]) -> Program:
        fn = FUNCTIONS[code]
        if self.profile.addressing:
            if code == F.Select:
                self._select(*args[:3])
                return code if self.addressed else None
            if code == F.Move:
                return (yield from self._move(*args[:8]))
            if not self.selected:
                return None
        elif fn.profile != "v1":
            fn = FUNCTIONS[0]  # a thesis module does not know our codes
        if fn.board is Board.CONTROL:
            ack = yield from self.relay(code, args)
            for mirror in fn.led_mirror if self._confirmed(code, ack) else ():
                result = getattr(self, mirror)(*args[:len(FUNCTIONS[code].args)])
                if result is not None:
                    yield from result
        elif fn.board is Board.COMM and fn.used:
            result = getattr(self, fn.name)(*args[:len(fn.args)])
            ack = code
            if result is not None:
                value = yield from result
                if code in (F.CW, F.CCW):
                    ack = value
        else:
            ack = ACK_UNKNOWN
        if self.profile.addressing and self.v2_active and not self.addressed:
            return None  # a broadcast: answers would collide on the centre channel
        return ack

    def relay(self, code: int, args: list[int]) -> Program:
        """Send a control-board function over UART0 and wait for its echo (``MSG`` in C)."""
        fn = FUNCTIONS[code]
        rargs = [0] if code in _ZERO_ARG else args[:len(fn.args)]
        if code == F.SelfTest:
            rargs = [self.switch_bits()]  # the control board reports them with its DIP id
        if not self.profile.checked_frames:
            yield Tx(self.uart0, codec.encode_relay(code, *rargs))
            return (yield Rx(self.uart0, ECHO_TIMEOUT_TICKS))  # any byte is the echo
        # v2: only the code itself is its echo. One that came after its wait is stale: it
        # would confirm the next relay of the same code, and every one after it, one late.
        self.uart0.flush_rx()
        yield Tx(self.uart0, codec.encode_relay(code, *rargs))
        due = self.tick_count() + ECHO_TIMEOUT_TICKS
        while True:
            echo = yield Rx(self.uart0, max(0, due - self.tick_count()), tell_timeout=True)
            if echo is None:
                return TIMEOUT
            if echo == code:
                return echo

    def _confirmed(self, code: int, ack: int) -> bool:
        """Whether the LEDs mirror a relayed code: v2 only when the control board echoed it
        (they would show a coil that is off); the thesis board always."""
        return ack == code or not self.profile.checked_frames

    def _rotate(self, mobile_code: int, substrate_code: int, role_mobile: bool,
                i: int, t1: int, t2: int, t3: int) -> Program:
        code = mobile_code if role_mobile else substrate_code
        ack = yield from self.relay(code, [i, t1, t2, t3])
        if self._confirmed(code, ack):
            yield from getattr(self, FUNCTIONS[code].led_mirror[0])(i, t1, t2, t3)
        return ack

    def CW(self, si, st1, st2, st3, mi, mt1, mt2, mt3) -> Program:
        ack = ACK_UNKNOWN  # C leaves it uninitialised when M = S = 0
        if self.M == 1:
            ack = yield from self._rotate(F.MCW, F.SCW, True, mi, mt1, mt2, mt3)
        if self.S == 1:
            ack = yield from self._rotate(F.MCW, F.SCW, False, si, st1, st2, st3)
        return ack

    def CCW(self, si, st1, st2, st3, mi, mt1, mt2, mt3) -> Program:
        ack = ACK_UNKNOWN
        if self.M == 1:
            ack = yield from self._rotate(F.MCCW, F.SCCW, True, mi, mt1, mt2, mt3)
        if self.S == 1:
            ack = yield from self._rotate(F.MCCW, F.SCCW, False, si, st1, st2, st3)
        return ack

    # -- v2 addressing -------------------------------------------------------------------------
    def _select(self, mode: int, a: int, b: int) -> None:
        self.v2_active = True
        if mode == 0:
            self.selected, self.addressed = True, False
        elif mode == 1:
            self.selected = self.addressed = self._named(a)
        elif mode == 2:
            self.selected = self.addressed = bool(self.L) and (self.X, self.Y) == (
                a - codec.COORD_OFFSET, b - codec.COORD_OFFSET)
        elif mode == 3:
            if self._named(a):
                self.selected = self.addressed = True
        else:
            self.selected = self.addressed = False

    def _named(self, ident: int) -> bool:
        """Whether ``ident`` names this module: id 0 ("no id": no DIP switch on, or no id byte
        at boot) is never an address, or every module without one would answer at once."""
        return ident != 0 and ident == self.id

    def _move(self, direction, mid, mi, sid, si, t1, t2, t3) -> Program:
        cw = direction == 1
        if self._named(mid):
            ack = yield from self._rotate(F.MCW if cw else F.MCCW, 0, True, mi, t1, t2, t3)
            if self.L and ack in (F.MCW, F.MCCW):
                self._moved(mi, cw)
            return ack
        if self._named(sid):
            self._substrate_turn = True
            return (yield from self._rotate(0, F.SCW if cw else F.SCCW, False, si, t1, t2, t3))
        return None

    def _moved(self, mi: int, cw: bool) -> None:
        """v2: a localized mobile module keeps its location through a ``Move`` it executed
        (the Table 4-3 goal of the rotation about its body joint ``mi``), so a ``Report``
        confirms the move. It cannot know whether the move happened: the PC compares."""
        rule = move_rule(Joint.of(mi + self.Yref), Direction.CW if cw else Direction.CCW)
        goal = rule.cells(Cell(self.X, self.Y))[2]
        if not (codec.msg1_carries(goal.x) and codec.msg1_carries(goal.y)):
            # beyond what POS can report: the module no longer knows a cell it can say, so it
            # is not localized (its boot state) rather than reporting a wrapped one
            self.X = self.Y = self.Yref = self.L = 0
            return
        self.X, self.Y = goal.x, goal.y
        self.Yref = orientation_after(self.Yref, rule.direction)

    def switch_bits(self) -> int:
        """The optical switches as one byte: bit s-1 = a neighbour on body side s."""
        return sum(1 << k for k, present in enumerate(self.neighbours()) if present)

    def Version(self) -> Program:
        """v2: the firmware's version and profile on the centre channel (the ACK follows)."""
        yield Tx(self.uart1, codec.encode_version(role=self.role))

    def Report(self) -> Program:
        """v2: id, X, Y, Yref and flags on the centre channel (the ACK follows)."""
        yield Tx(self.uart1, codec.encode_position(self.id, self.X, self.Y, self.Yref,
                                                   localized=bool(self.L), mobile=bool(self.M),
                                                   substrate=bool(self.S), role=self.role))

    # -- v2 distributed reconfiguration (Walter, Tsai & Amato; docs/protocol.md) ------------
    def WalterSetup(self, n: int, plen: int, cost: int, ax: int, ay: int) -> None:
        self.walter = WalterState(n, plen, cost, Cell(ax - codec.COORD_OFFSET, ay - codec.COORD_OFFSET))

    def WalterGoal(self, k: int, x: int, y: int, m: int, x2: int, y2: int, m2: int) -> None:
        if self.walter is None:
            return
        for at, (ex, ey, mode) in ((k, (x, y, m)), (k + 1, (x2, y2, m2))):
            if (ex or ey) and at < codec.WALTER_TABLE_CAPACITY:  # x = y = 0: no entry
                self.walter.table[at] = Entry.of(ex - codec.COORD_OFFSET, ey - codec.COORD_OFFSET, mode)

    def _contacts(self) -> list[bool]:
        """The optical switches in the global frame: [s-1] = a neighbour across global side s."""
        here = self.neighbours()
        out = [False] * 6
        for body in Side:
            if here[body - 1]:
                out[body_to_global(body, self.Yref) - 1] = True
        return out

    def _relay_mirrored(self, code: int, *args: int) -> Program:
        """A control-board code this board sends itself, with its LED mirror (as ``dispatch``)."""
        yield from self.relay(code, list(args))
        for mirror in FUNCTIONS[code].led_mirror:
            shown = getattr(self, mirror)(*args)
            if shown is not None:
                yield from shown

    def WalterBeat(self, r_hi: int, r_lo: int) -> Program:
        """One round of Figure 10 (docs/protocol.md): decide at the beat, ask the neighbours in
        the six side windows (or answer them), actuate together at the round's instant, log,
        and say on the centre channel whether this module is still on its way."""
        w, u1 = self.walter, self.uart1
        round_ = r_hi << 8 | r_lo
        if round_ == 0:
            self.walter = None
        if w is None or round_ == 0 or not self.L:
            return
        t0 = self.tick_count()
        baud = u1.baud

        def until(ticks: int) -> int:
            return t0 + ticks - self.tick_count()

        def left(ticks: int) -> int:
            return max(1, until(ticks))

        contacts = self._contacts()
        plan = w.decide(round_, Cell(self.X, self.Y), contacts)
        requests = plan.requests() if plan is not None else {}
        window = walter_window_ticks(baud)
        answered = True
        late = False  # its substrate turns it in the late slot
        pivots: list[tuple[WalterOp, Side]] = []  # asked to be a substrate: op, mover's side
        opened = False  # a pin of its own opened for a neighbour that moves
        for g in Side:
            end = g * window
            op = requests.get(g) if answered else None
            if op is not None:  # ask the neighbour across global side g
                yield Delay(until((g - 1) * window))
                self.IrSel(global_to_body(g, self.Yref))
                yield Delay(until((g - 1) * window + WALTER_MUX_SETTLE_TICKS))
                yield Tx(u1, codec.encode_walter_request(op, w.position))
                got = yield from self._walter_side(codec.WALTER_ANSWER_TAG[0], left, end, 2)
                if got is not None and op is not WalterOp.HOLD and got[0] is WalterOp.LATE:
                    late = True
                elif got is None or got[0] != op:
                    answered = False
                elif op is WalterOp.HOLD:  # and open its own pin on that side
                    yield from self._relay_mirrored(F.JxOpen, int(Joint.of(g + 1 - self.Yref)))
                    opened = True
                continue
            # listen for a mover across global side g + 3 (it sends on its side g)
            facing = Side.of(g + 3)
            if not contacts[facing - 1]:
                continue
            yield Delay(until((g - 1) * window))
            self.IrSel(global_to_body(facing, self.Yref))
            heard = yield from self._walter_side(codec.WALTER_REQUEST_TAG[0], left, end, 3)
            if heard is None:
                continue
            op, who = heard
            if plan is not None and op is not WalterOp.HOLD:
                continue  # a mover is nobody's substrate (it opens its own pin to a mover)
            if op is WalterOp.LATE or (op is not WalterOp.HOLD and len(pivots) == 2):
                continue  # a substrate turns two movers at most
            # a second mover beside the first: its turn comes late, after the first's (their
            # two repelling sides on together would be a drive pair of this module's own)
            slow = op is not WalterOp.HOLD and bool(pivots) and not walter_pivots_apart(pivots[0][1], g)
            yield Tx(u1, codec.encode_walter_answer(WalterOp.LATE if slow else op))
            w.passed(op, who)
            if op is WalterOp.HOLD:  # the pin at the end of the side facing the mover
                yield from self._relay_mirrored(F.JxOpen, int(Joint.of(facing + 1 - self.Yref)))
                opened = True
            else:
                pivots.append((op, g))
        # back to the centre when the windows are over: an answer's last byte is still on the
        # wire when the program moves on (the multiplexer would cut it)
        yield Delay(until(6 * window))
        self.IrSel(0)
        w.unanswered = plan is not None and not answered
        yield Delay(until(walter_actuation_at(baud)))
        if plan is not None and answered:
            if late:
                yield Delay(until(walter_late_at(baud)))
            mi = int(Joint.of(plan.joint - self.Yref))
            code = F.MCW if plan.cw else F.MCCW
            yield from self._rotate(code, 0, True, mi, *THESIS_ROTATION_TIMING)
            w.after_move(Cell(self.X, self.Y))
            self._moved(mi, plan.cw)
        elif pivots:
            # the pivot in this body: the mover's joint j (g for CW, g + 1 for CCW) - Yref
            turns = [(op is WalterOp.PIVOT_CW,
                      int(Joint.of((g if op is WalterOp.PIVOT_CW else g + 1) - self.Yref)))
                     for op, g in pivots]
            if len(turns) == 1 or not walter_pivots_apart(pivots[0][1], pivots[1][1]):
                for k, (cw, si) in enumerate(turns):  # one after the other: the late slot
                    if k:
                        yield Delay(until(walter_late_at(baud)))
                    yield from self._rotate(0, F.SCW if cw else F.SCCW, False, si,
                                            *THESIS_ROTATION_TIMING)
            else:
                dirs = sum(int(cw) << k for k, (cw, _) in enumerate(turns))
                yield from self._relay_mirrored(F.STwo, dirs, turns[0][1], turns[1][1])
        elif opened:  # a rotation ends with every joint closed; a holder closes them itself
            yield Delay(until(walter_hold_end_at(baud)))
            yield from self._relay_mirrored(F.JxCloseAll)
        yield Delay(until(walter_log_at(baud)))
        w.settle(Cell(self.X, self.Y))
        position = codec.WALTER_NO_POSITION if w.position is None else w.position
        yield from self.relay(F.WalterLog, [round_ & 0xFF, w.flags(), position, w.delay])
        yield Delay(until(walter_busy_at(baud)))
        if not w.done():
            yield Tx(u1, codec.WALTER_BUSY)

    def _walter_side(self, tag: int, left: Callable[[int], int], end: int, n: int) -> Program:
        """Wait until tick ``end`` for a side message: ``tag`` and ``n`` bytes. (op, the byte
        after its check, if any) or None."""
        u1 = self.uart1
        b = yield Rx(u1, left(end))
        while b not in (tag, TIMEOUT):
            b = yield Rx(u1, left(end))
        if b != tag:
            return None
        body = []
        for _ in range(n):
            body.append((yield Rx(u1, left(end))))
        op = codec.walter_side_op(bytes(body))
        return None if op is None else (WalterOp(op), body[2] if n > 2 else None)
