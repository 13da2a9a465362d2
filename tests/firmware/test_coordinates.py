"""Coordinates at the edge of what the protocol carries (docs/protocol.md, ``COORD_LIMIT``),
in both programs: the Python model and the C firmware (its host build, and the AVR image in
simavr).

One v2 module, its side IR driven by the test as a neighbour would: a MSG1 heard on body
side 1 localizes it anywhere, so a cell 100 or 127 cells from the reference needs no line of
a hundred modules. The old programs split a coordinate into two decimal digits (the C
dropped the hundreds, the model raised) and POS wrapped x + 128 in one byte."""

from __future__ import annotations

import pytest

from bus import codec
from bus.clock import VirtualClock
from bus.codec import COORD_LIMIT, Kind, Link, encode_command
from bus.framer import frames
from bus.lattice import Cell, Direction, Joint, move_rule
from bus.session import SessionOptions
from bus.timing import NS_PER_S, TICK_NS, byte_time_ns, localize_step_ticks
from bus.transport import Bus
from toolchain import needs_avr

pytestmark = needs_avr

PROGRAMS = ["model", "firmware", "simavr"]
BYTE_NS = byte_time_ns(300)
STEP_NS = localize_step_ticks(300) * TICK_NS
LIMIT = COORD_LIMIT["v2"]


class Module:
    """One v2 module on the virtual clock: frames to its centre transceiver, MSG1 bytes to its
    side 1, and what it sends (centre, and per side)."""

    def __init__(self, program: str, switches: int) -> None:
        from module_sim.module import VirtualModule
        from module_sim.profiles import V2

        self.bus = Bus(VirtualClock(), f"coords-{program}", options=SessionOptions(isolated=True))
        self.m = VirtualModule(self.bus, 9, V2, program=program)
        self.m.switches = [bool(switches >> k & 1) for k in range(6)]
        self.centre = bytearray()
        self.sides: dict[int, bytearray] = {}
        self.log: list[tuple[int, int, int]] = []  # (start bit, transceiver, byte)

        def on_tx(data: bytes, starts: list[int]) -> None:
            k = self.m.comm.ir_transceiver
            (self.centre if k == 0 else self.sides.setdefault(k, bytearray())).extend(data)
            self.log.extend((t, k, b) for t, b in zip(starts, data))
        self.m.comm.uart1.on_tx = on_tx
        self.m.power_up()
        self.now = 10 * NS_PER_S
        self.bus.clock.run(until_ns=self.now)

    def close(self) -> None:
        self.bus.close()

    def deliver(self, data: bytes, transceiver: int, at_ns: int) -> int:
        for k, b in enumerate(data):
            end = at_ns + (k + 1) * BYTE_NS
            self.bus.clock.call_at(end, self.m._ir_rx, transceiver, b, end - BYTE_NS, False)
        return at_ns + len(data) * BYTE_NS

    def command(self, name: str, *args: int, wait_s: float = 3.0) -> None:
        end = self.deliver(encode_command(name, *args), 0, self.now)
        self.now = end + int(wait_s * NS_PER_S)
        self.bus.clock.run(until_ns=self.now)

    def localize(self, msg1: bytes | None = None) -> None:
        """One Localize step; ``msg1`` (the 7 bytes after '*') heard on side 1 in window 0."""
        end = self.deliver(encode_command("Localize"), 0, self.now)
        if msg1 is not None:
            self.deliver(codec.START + msg1, 1, end + NS_PER_S // 2)
        self.now = end + STEP_NS + NS_PER_S
        self.bus.clock.run(until_ns=self.now)

    def report(self) -> dict:
        mark = len(self.centre)
        self.command("Report")
        (pos,) = [f for f in frames(Link.CENTRE, bytes(self.centre[mark:])) if f.kind is Kind.POSITION]
        return pos.view


@pytest.fixture(params=PROGRAMS)
def module(request):
    made: list[Module] = []

    def make(switches: int = 0b000001) -> Module:
        made.append(Module(request.param, switches))
        return made[-1]
    yield make
    for m in made:
        m.close()


def msg1(x: int, y: int, side: int) -> bytes:
    """MSG1 after '*', written out byte by byte (sign, |v| div 10, |v| mod 10), so the test
    does not lean on the codec it checks."""
    out = []
    for v in (x, y):
        out += [int(v < 0), abs(v) // 10, abs(v) % 10]
    return bytes(out + [side])


@pytest.mark.parametrize("x, y", [(100, -120), (-LIMIT, LIMIT), (99, -99)])
def test_a_module_told_a_far_cell_reports_it(module, x, y):
    """MSG1 beyond two digits localizes the module, and POS reports the cell unwrapped
    (the old C read tens 10 as invalid, so did the model: the module stayed unlocalized)."""
    m = module()
    m.localize(msg1(x, y, 4))
    v = m.report()
    assert (v["localized"], v["x"], v["y"], v["yref"]) == (True, x, y, 3)


@pytest.mark.parametrize("x", [LIMIT + 1, 199])
def test_a_msg1_beyond_the_limit_is_not_taken(module, x):
    """A tens byte past the limit (12 9 = 129, 19 9 = 199) is not a cell: the module stays
    unlocalized rather than taking a coordinate POS cannot carry."""
    m = module()
    m.localize(msg1(x, 0, 4))
    v = m.report()
    assert (v["localized"], v["x"], v["y"]) == (False, 0, 0)


def _joint_towards(cell: Cell, yref: int, dx: int) -> int:
    """A body joint whose CW rotation takes ``cell`` one further in x by ``dx``."""
    for body in range(1, 7):
        goal = move_rule(Joint.of(body + yref), Direction.CW).cells(cell)[2]
        if goal.x == cell.x + dx:
            return body
    raise AssertionError("no joint")


def test_a_move_past_the_limit_unlocalizes_instead_of_wrapping(module):
    """At x = 127 a Move to x = 128: POS cannot carry it (x + 128 = 256 wrapped to -128 before);
    the module drops its localization (L = 0, its boot state) and says so in the report."""
    m = module()
    m.localize(msg1(LIMIT, 0, 4))
    yref = m.report()["yref"]
    mi = _joint_towards(Cell(LIMIT, 0), yref, +1)
    m.command("Move", 1, 9, mi, 0, 1, 8, 4, 9, wait_s=5.0)
    v = m.report()
    assert (v["localized"], v["x"], v["y"], v["yref"]) == (False, 0, 0, 0)
    # and within the limit a Move keeps the cell, as before
    m2 = module()
    m2.localize(msg1(LIMIT, 0, 4))
    back = _joint_towards(Cell(LIMIT, 0), yref, -1)
    m2.command("Move", 1, 9, back, 0, 1, 8, 4, 9, wait_s=5.0)
    v = m2.report()
    assert v["localized"] and v["x"] == LIMIT - 1


def test_a_localized_module_tells_only_cells_msg1_carries(module):
    """At (127, 0) with a neighbour on every side, the module tells the four neighbours whose
    cells MSG1 carries and stays dark towards the two at x = 128 (the model raised there and
    the run died; the C sent 128 as 28, a wrong cell)."""
    m = module(switches=0b111111)
    m.localize(msg1(LIMIT, 0, 1))
    assert m.report()["localized"]
    m.localize()  # now a sender: six windows of six slots
    told = set()
    for side, data in m.sides.items():
        for f in frames(Link.SIDE, bytes(data)):
            if f.kind is Kind.MSG1:
                assert f.view["valid"], f.view
                told.add((f.view["x"], f.view["y"]))
    here = Cell(LIMIT, 0)
    carried = {(c.x, c.y) for c in here.neighbours() if max(abs(c.x), abs(c.y)) <= LIMIT}
    assert len(carried) == 4 and told == carried


def test_both_programs_send_the_same_bytes_at_the_same_times_at_the_edge():
    """The differential at (127, 0): localized by a MSG1, a sender step, a Move past the limit,
    the reports: every IR byte, its transceiver and its start bit equal in the model and the
    host C build (the same comm.c the AVR image runs)."""
    logs = []
    for program in ("model", "firmware"):
        m = Module(program, 0b111111)
        try:
            m.localize(msg1(LIMIT, 0, 1))
            m.localize()
            yref = m.report()["yref"]
            m.command("Move", 1, 9, _joint_towards(Cell(LIMIT, 0), yref, +1), 0, 1, 8, 4, 9, wait_s=5.0)
            m.report()
            logs.append(m.log)
        finally:
            m.close()
    assert len(logs[0]) > 300 and logs[0] == logs[1]
