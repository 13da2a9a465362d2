"""The PC's part of a distributed reconfiguration while it runs (docs/protocol.md, "v2
distributed reconfiguration"): hand the fleet its problem, then beat the rounds.

Every frame is a broadcast: the problem goes out once (``WalterSetup``, the goal table in
``WalterGoal`` frames), then one ``WalterBeat`` a round. Nothing per move crosses the centre
channel; the PC listens in each round's busy slot, where every module still on its way sends
a byte, and stops beating at the first silent slot (or at the round limit).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from bus import codec
from bus.functions import FunctionCode as F
from bus.lattice import Cell, rotate_offset
from bus.scenario import Scenario
from bus.timing import TICK_NS, walter_busy_at, walter_round_ticks

from .endpoint import PcEndpoint

SELECT_ALL = 0
#: Ticks the PC waits past a round's nominal end before the next beat: each module's tick
#: grid lags the beat by up to a tick, and the busy byte is still on the wire.
ROUND_MARGIN_TICKS = 3


@dataclass(frozen=True)
class WalterProblem:
    """What every module is given, in the scenario's frame: n, the substrate path's length
    and cost class (0, 1, 2 = more), the anchor (where I meets G) and per position (0 = the
    free end of I) its goal cell, direction (True = CW) and delay after it is free."""

    n: int
    path_len: int
    cost: int
    anchor: Cell
    entries: tuple[tuple[Cell, bool, int], ...]


@dataclass
class RoundsResult:
    rounds: int
    done: bool  # a silent busy slot: every module reports it is in its goal
    busy: list[int]  # per round, the frames heard in its busy slot


def beyond_the_modules(n: int) -> str | None:
    """Why a module cannot hold a Walter problem of ``n`` modules (one line), or None: its goal
    table has an entry per position but the anchor's, and no more than the comm board's RAM
    holds (``bus.codec.WALTER_TABLE_CAPACITY``, the size of the C table too)."""
    if n <= codec.WALTER_MAX_MODULES:
        return None
    return (f"{n} modules, but a module holds a problem of at most {codec.WALTER_MAX_MODULES} "
            f"(its goal table: {codec.WALTER_TABLE_CAPACITY} entries)")


def problem_of(choice, model) -> WalterProblem:
    """What the fleet is given for a :class:`planner_svc.planners.walter.Choice`: its round
    model's schedule (every position's goal, direction and delay)."""
    from bus.lattice import Direction
    entries = tuple((a.goal, a.direction is Direction.CW, a.delay) for a in model.schedule.entries)
    cost = choice.cost
    return WalterProblem(len(choice.goal), len(choice.path), min(cost, 2), choice.chain[-1], entries)


def to_module_frame(scenario: Scenario, cell: Cell) -> Cell:
    """A scenario cell in the modules' frame: the reference (the fixed module) at (0, 0)
    with its orientation 0 (the inverse of ``BringUp.to_global``)."""
    o_ref = scenario.fixed_module.orientation
    dx, dy = rotate_offset((cell.x - scenario.fixed.x, cell.y - scenario.fixed.y), -o_ref)
    return Cell(dx, dy)


class RoundDriver:
    """Uploads a :class:`WalterProblem` and beats the rounds through a :class:`PcEndpoint`."""

    def __init__(self, pc: PcEndpoint, scenario: Scenario, *,
                 say: Callable[[str], None] = print) -> None:
        self.pc, self.scenario, self.say = pc, scenario, say

    def _send(self, frame: bytes) -> None:
        self.pc.send_raw(frame)

    def upload(self, problem: WalterProblem) -> None:
        """Broadcast the problem; returns when the last frame has left the PC."""
        too_many = beyond_the_modules(problem.n)
        if too_many:
            raise ValueError(too_many)
        anchor = to_module_frame(self.scenario, problem.anchor)
        self._send(codec.encode_command(F.Select, SELECT_ALL, 0, 0))
        self._send(codec.encode_command(F.WalterSetup, problem.n, problem.path_len, problem.cost,
                                        anchor.x + codec.COORD_OFFSET, anchor.y + codec.COORD_OFFSET))
        entries = []
        for goal, cw, delay in problem.entries:
            g = to_module_frame(self.scenario, goal)
            entries.append((g.x, g.y, cw, delay))
        for frame in codec.encode_walter_goals(entries):
            self._send(frame)
        self._run_until(self.pc.line_free_at)

    def _run_until(self, t_ns: int) -> None:
        clock = self.pc.bus.clock
        clock.run(until_ns=t_ns, until=lambda: clock.now_ns() >= t_ns)

    def beat(self, round_: int) -> int:
        """One round: its beat, then the whole round; the frames heard in its busy slot."""
        baud = self.scenario.ir_baud
        self._send(codec.encode_command(F.WalterBeat, round_ >> 8 & 0xFF, round_ & 0xFF))
        t0 = self.pc.line_free_at
        slot = t0 + (walter_busy_at(baud) - 1) * TICK_NS
        mark = len(self.pc.received)
        self._run_until(t0 + (walter_round_ticks(baud) + ROUND_MARGIN_TICKS) * TICK_NS)
        self.pc.flush()
        return sum(1 for r in list(self.pc.received)[mark:] if r.t_first_ns >= slot)

    def run(self, limit: int, *, progress: Callable[[int, int], None] | None = None) -> RoundsResult:
        """Beat rounds 1, 2, ... until a silent busy slot or ``limit`` rounds."""
        busy: list[int] = []
        for r in range(1, limit + 1):
            heard = self.beat(r)
            busy.append(heard)
            if progress is not None:
                progress(r, heard)
            if not heard:
                return RoundsResult(r, True, busy)
        return RoundsResult(limit, False, busy)

    def stop(self) -> None:
        """Leave the distributed mode (``WalterBeat`` round 0)."""
        self._send(codec.encode_command(F.WalterBeat, 0, 0))
        self._run_until(self.pc.line_free_at)
