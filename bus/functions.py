"""The function table: thesis Table 3-7 (both ``Listen`` functions), as data.

Codes 1..24 run on the control board (the comm board relays them over UART0 and
runs the LED mirror so the LEDs follow the actuators); 25..68 run on the comm
board alone. Codes marked ``v2`` are ours (protocol v2, spec §13); every other
free code is listed as unused so a reader can see the whole byte space.

Everything else in hexbench — codec, framer, both virtual boards, the planner,
the script language, ``hexbench decode`` — reads this table; nothing re-types a code.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum, IntEnum


class Board(str, Enum):
    """Which program executes a code."""

    CONTROL = "control"
    COMM = "comm"
    RESERVED = "reserved"
    UNUSED = "unused"


class Ack(str, Enum):
    """What the module -> PC acknowledgement byte carries after a code."""

    ECHO = "echo"  # the code byte the control board echoed, or '~' if it did not
    CODE = "code"  # the code itself (comm-board functions)
    NONE = "none"  # never acknowledged


@dataclass(frozen=True)
class Arg:
    """One argument byte of a frame. ``wraps``: the firmware folds it into 1..6."""

    name: str
    lo: int = 0
    hi: int = 255
    wraps: bool = False
    doc: str = ""

    def check(self, value: int) -> None:
        if not 0 <= value <= 255:
            raise ValueError(f"{self.name}={value}: a frame byte must be 0..255")
        if not self.wraps and not self.lo <= value <= self.hi:
            raise ValueError(f"{self.name}={value}: expected {self.lo}..{self.hi}")


# Argument kinds used across the table (names follow Table 3-8).
_I = Arg("i", 1, 6, wraps=True, doc="joint or side 1..6, folded into range by the firmware")
_N = Arg("n", 0, 255, doc="rounds")
_T = Arg("t", 0, 255, doc="ticks (~10 ms)")
_T1, _T2, _T3 = (Arg(f"t{k}", 0, 255, doc="ticks") for k in (1, 2, 3))
_ROT = (_I, _T1, _T2, _T3)


@dataclass(frozen=True)
class Function:
    code: int
    name: str
    board: Board
    args: tuple[Arg, ...] = ()
    led_mirror: tuple[str, ...] = ()  # comm-board LED functions run with a control code
    ack: Ack = Ack.CODE
    profile: str = "v1"  # "v1": thesis Table 3-7; "v2": our additions
    doc: str = ""

    @property
    def arg_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.args)

    @property
    def used(self) -> bool:
        return self.board not in (Board.UNUSED, Board.RESERVED)


def _ctl(code: int, name: str, args: tuple[Arg, ...], mirror: str, doc: str) -> Function:
    return Function(code, name, Board.CONTROL, args, tuple(mirror.split("+")), Ack.ECHO, doc=doc)


def _com(code: int, name: str, args: tuple[Arg, ...] = (), doc: str = "", profile: str = "v1",
         ack: Ack = Ack.CODE) -> Function:
    return Function(code, name, Board.COMM, args, (), ack, profile=profile, doc=doc)


_DEFINED: tuple[Function, ...] = (
    # --- Table 3-7, control board -------------------------------------------------
    _ctl(1, "JxOpen", (_I,), "JointOn", "energise joint solenoid i (joint open)"),
    _ctl(2, "JxClose", (_I,), "JointOff", "release joint solenoid i"),
    _ctl(3, "JxOpenAll", (), "JointOnAll", "energise all six joints"),
    _ctl(4, "JxCloseAll", (), "JointOffAll", "release all six joints"),
    _ctl(5, "JTest", (_N, _T), "JointTest", "n rounds: each joint open t ticks, closed t ticks"),
    _ctl(11, "SxP", (_I,), "SideOnP", "magnet i positive"),
    _ctl(12, "SxN", (_I,), "SideOnN", "magnet i negative"),
    _ctl(13, "SxOff", (_I,), "SideOffP+SideOffN", "magnet i off"),
    _ctl(14, "SxOffAll", (), "SideOffAllP+SideOffAllN", "all magnets off"),
    _ctl(15, "SPTest", (_N, _T), "SidePTest", "n rounds: each magnet positive t ticks, off t ticks"),
    _ctl(16, "SNTest", (_N, _T), "SideNTest", "n rounds: each magnet negative t ticks, off t ticks"),
    _ctl(20, "TurnOffAll", (), "LOff", "all magnets off, all joints released"),
    _ctl(21, "MCW", _ROT, "LMCW", "mobile module, clockwise rotation"),
    _ctl(22, "MCCW", _ROT, "LMCCW", "mobile module, counter-clockwise rotation"),
    _ctl(23, "SCW", _ROT, "LSCW", "substrate, clockwise rotation"),
    _ctl(24, "SCCW", _ROT, "LSCCW", "substrate, counter-clockwise rotation"),
    # --- Table 3-7, communication board -------------------------------------------
    _com(25, "IrSel", (Arg("i", 0, 6, doc="0 = centre, 1..6 = side"),), "select the IR channel"),
    _com(28, "SideOnP", (_I,), "positive-magnet LED of side i on"),
    _com(29, "SideOffP", (_I,), "positive-magnet LED of side i off"),
    _com(30, "SideOnAllP", (), "all positive-magnet LEDs on"),
    _com(31, "SideOffAllP", (), "all positive-magnet LEDs off"),
    _com(32, "SideOnN", (_I,), "negative-magnet LED of side i on"),
    _com(33, "SideOffN", (_I,), "negative-magnet LED of side i off"),
    _com(34, "SideOnAllN", (), "all negative-magnet LEDs on"),
    _com(35, "SideOffAllN", (), "all negative-magnet LEDs off"),
    _com(36, "SidePTest", (_N, _T), "positive-magnet LED test"),
    _com(37, "SideNTest", (_N, _T), "negative-magnet LED test"),
    _com(38, "JointOn", (_I,), "joint LED i on"),
    _com(39, "JointOff", (_I,), "joint LED i off"),
    _com(40, "JointOnAll", (), "all joint LEDs on"),
    _com(41, "JointOffAll", (), "all joint LEDs off"),
    Function(42, "Start", Board.RESERVED, doc="'*': start of a message"),
    _com(43, "JointTest", (_N, _T), "joint LED test"),
    _com(44, "LOn", (), "all LEDs on"),
    _com(45, "LOff", (), "all LEDs off"),
    _com(46, "LCircle", (_N, _T), "LED circle; also sends 0xFF, 0x00 on every side"),
    _com(47, "LColor", (_N, _T), "LED colour test"),
    _com(48, "LFlash1", (_N, _T), "LED flash (magnet colours alternate)"),
    _com(49, "LFlash2", (_N, _T), "LED flash (all on, all off)"),
    _com(50, "LYref", (Arg("i", 0, 2, doc="0 show, 1 Yref+1, 2 Yref-1"),),
         "change Yref and flash the side that faces global +Y"),
    _com(56, "LMCW", _ROT, "LED mirror of MCW"),
    _com(57, "LMCCW", _ROT, "LED mirror of MCCW"),
    _com(58, "LSCW", _ROT, "LED mirror of SCW"),
    _com(59, "LSCCW", _ROT, "LED mirror of SCCW"),
    _com(65, "Ref", (), "become the reference: M=0 S=1 L=1 X=Y=0 Yref=0"),
    _com(66, "Localize", (), "one localization step"),
    _com(67, "CW", (Arg("si", 1, 6, True), Arg("st1"), Arg("st2"), Arg("st3"),
                    Arg("mi", 1, 6, True), Arg("mt1"), Arg("mt2"), Arg("mt3")),
         "rotation for both modules: mobile runs MCW(mi..), substrate SCW(si..)", ack=Ack.ECHO),
    _com(68, "CCW", (Arg("si", 1, 6, True), Arg("st1"), Arg("st2"), Arg("st3"),
                     Arg("mi", 1, 6, True), Arg("mt1"), Arg("mt2"), Arg("mt3")),
         "as CW with MCCW/SCCW", ack=Ack.ECHO),
    # --- protocol v2 (ours, docs/protocol.md) -------------------------------------
    _com(60, "Select", (Arg("mode", 0, 4, doc="0 all, 1 id, 2 cell, 3 add id, 4 none"),
                        Arg("a", doc="id, or x+128"), Arg("b", doc="y+128")),
         "choose which modules obey the following frames", profile="v2"),
    _com(61, "Report", (), "report id, X, Y, Yref, L and role on the centre channel", profile="v2"),
    _com(62, "Move", (Arg("dir", 1, 2, doc="1 CW, 2 CCW"), Arg("mid", doc="mobile's id"),
                      Arg("mi", 1, 6, True), Arg("sid", doc="substrate's id"),
                      Arg("si", 1, 6, True), Arg("t1"), Arg("t2"), Arg("t3")),
         "addressed rotation: the two named modules act at once", profile="v2", ack=Ack.ECHO),
    _com(63, "Version", (), "report the firmware's version and profile on the centre channel",
         profile="v2"),
    Function(64, "SelfTest", Board.CONTROL,
             (Arg("switches", 0, 63, doc="the PC sends 0; the comm board relays its optical switches"),),
             (), Ack.ECHO, profile="v2",
             doc="each actuator in turn, briefly; the DIP id and the optical switches on the "
                 "debug UART"),
    # --- protocol v2: distributed reconfiguration (Walter, Tsai & Amato; docs/protocol.md) ---
    _com(51, "WalterSetup", (Arg("n", 2, 255, doc="modules"), Arg("plen", doc="|p|"),
                             Arg("cost", 0, 2, doc="0, 1, 2 = more"),
                             Arg("ax", doc="anchor x+128"), Arg("ay", doc="anchor y+128")),
         "a new reconfiguration problem: n, the substrate path's length and cost, the anchor "
         "(where I meets G)", profile="v2"),
    _com(52, "WalterGoal", (Arg("k", doc="entry"), Arg("x", doc="x+128"), Arg("y", doc="y+128"),
                            Arg("m", doc="bit 0 CW, bits 1..4 delay"), Arg("x2", doc="x+128"),
                            Arg("y2", doc="y+128"), Arg("m2", doc="as m")),
         "goal table entries k and k+1: the goal, direction and delay of position k", profile="v2"),
    _com(53, "WalterBeat", (Arg("r_hi"), Arg("r_lo")),
         "round r starts now (r = 0: leave the distributed mode)", profile="v2"),
    Function(17, "WalterLog", Board.CONTROL,
             (Arg("round"), Arg("flags"), Arg("position"), Arg("delay")), (), Ack.ECHO,
             profile="v2", doc="the round's line on the debug UART (WLK)"),
    Function(18, "STwo", Board.CONTROL,
             (Arg("dirs", 0, 3, doc="bit 0: the first CW, bit 1: the second CW"),
              Arg("i1", 1, 6, True), Arg("i2", 1, 6, True)), ("LSTwo",), Ack.ECHO, profile="v2",
             doc="substrate of two rotations at once (SCW/SCCW(i1) and SCW/SCCW(i2), thesis "
                 "timing): two movers turn about this module in one Walter round"),
    _com(54, "LSTwo", (Arg("dirs", 0, 3), Arg("i1", 1, 6, True), Arg("i2", 1, 6, True)),
         "LED mirror of STwo", profile="v2"),
    Function(126, "Timeout", Board.RESERVED, doc="'~': a receive timed out"),
)


class WalterOp(IntEnum):
    """What a mover asks a neighbour over the side link in a Walter round (docs/protocol.md)."""

    HOLD = 1  # open the pin that holds me during the actuation
    PIVOT_CW = 2  # be my substrate: SCW about the pivot next to me
    PIVOT_CCW = 3  # be my substrate: SCCW
    LATE = 4  # (an answer) yes, in the late slot: I turn a mover beside you first


#: Walter log line flags (the ``flags`` byte of ``WalterLog``).
class WalterFlag(IntEnum):
    FREE = 1
    MOVED = 2
    CW = 4
    STOPPED = 8
    ANCHOR = 16
    UNANSWERED = 32


#: Every defined code by its thesis name: ``FunctionCode.MCW == 21``. Generated from
#: the table above so the two can never drift.
FunctionCode = IntEnum("FunctionCode", {f.name: f.code for f in _DEFINED})  # type: ignore[misc]


#: code -> Function for every byte value 0..255 (undefined ones are ``Board.UNUSED``).
FUNCTIONS: dict[int, Function] = {
    c: Function(c, f"Unused{c}", Board.UNUSED, ack=Ack.NONE) for c in range(256)
}
FUNCTIONS.update({f.code: f for f in _DEFINED})
BY_NAME: dict[str, Function] = {f.name.lower(): f for f in _DEFINED}

#: ACK byte for a code the module does not know.
ACK_UNKNOWN = ord("N")
#: ACK byte when the control board did not echo in time; also a receive timeout.
ACK_TIMEOUT = ord("~")
#: Filler for unused arguments of the comm -> control frame.
ARG_UNUSED = ord("N")


def lookup(name_or_code: str | int) -> Function:
    """Find a function by code (int or decimal string) or by name, case-insensitive."""
    if isinstance(name_or_code, int) or str(name_or_code).isdigit():
        code = int(name_or_code)
        if not 0 <= code <= 255:
            raise KeyError(f"function code {code} is not a byte")
        return FUNCTIONS[code]
    try:
        return BY_NAME[str(name_or_code).lower()]
    except KeyError:
        raise KeyError(f"no function named {name_or_code!r}; known: "
                       + ", ".join(f.name for f in _DEFINED if f.used)) from None


def used_codes(profile: str = "v2") -> list[int]:
    """Codes a module of ``profile`` executes (v2 includes the v1 table)."""
    return [f.code for f in _DEFINED if f.used and (profile == "v2" or f.profile == "v1")]
