"""Figure 10 of Walter, Tsai & Amato (seed 003, §5) as one module runs it: the comm board's
decisions in a Walter round, from its own cell, its contacts and what its neighbours asked.

Pure state, no clock and no bus: :class:`module_sim.comm_board.CommBoard` feeds it at each
beat (:meth:`WalterState.decide`) and when a neighbour asks it to be its substrate
(:meth:`WalterState.passed`), and runs what it decides over the side links and on its own
control board (docs/protocol.md, "v2 distributed reconfiguration"). firmware/src/comm.c
holds the same rule.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bus.codec import walter_mode, walter_mode_view
from bus.functions import WalterFlag, WalterOp
from bus.lattice import Cell, Direction, Side, move_rule


@dataclass(frozen=True)
class Entry:
    """What the module at one position does once free: its goal, direction and delay."""

    goal: Cell
    cw: bool
    delay: int

    @classmethod
    def of(cls, x: int, y: int, mode: int) -> "Entry":
        return cls(Cell(x, y), *walter_mode_view(mode))

    @property
    def mode(self) -> int:
        return walter_mode(self.cw, self.delay)


@dataclass(frozen=True)
class Plan:
    """A move decided for this round: the Table 4-3 row and whom to ask (global sides)."""

    cw: bool
    joint: int  # the pivot, a global joint
    substrate: Side  # the global side the substrate touches
    holders: tuple[Side, ...]  # every other touching side: their pins must open

    def requests(self) -> dict[Side, WalterOp]:
        """Global side -> what to ask there."""
        out = {s: WalterOp.HOLD for s in self.holders}
        out[self.substrate] = WalterOp.PIVOT_CW if self.cw else WalterOp.PIVOT_CCW
        return out


def flips(contacts: list[bool]) -> int:
    """``IsFree``'s count: how often touching changes going once round the six sides."""
    return sum(contacts[i] != contacts[(i + 1) % 6] for i in range(6))


def plan_move(contacts: list[bool], cw: bool, pivot: Side) -> Plan | None:
    """One step round the structure (``contacts[s-1]``: global side s touches), starting from
    the side towards the contact it last turned about: CW keeps the structure on its right,
    so it looks counter-clockwise past every touching side; the last touching one is the
    substrate, the free one after it the target (Table 4-3 row (j, CW) with j the substrate's
    side). CCW is the mirror image (row (j, CCW), the substrate across side j - 1)."""
    if not contacts[pivot - 1]:
        return None
    step = -1 if cw else 1
    s = pivot
    for _ in range(6):
        nxt = Side.of(s + step)
        if not contacts[nxt - 1]:
            joint = int(s) if cw else int(Side.of(s + 1))
            move_rule(joint, Direction.CW if cw else Direction.CCW)  # a Table 4-3 row
            holders = tuple(h for h in Side if contacts[h - 1] and h != s)
            return Plan(cw, joint, Side(s), holders)
        s = nxt
    return None


def walter_pivots_apart(first: Side, second: Side) -> bool:
    """Whether a substrate can turn a second mover (across its global side ``second`` + 3)
    at the same time as one across ``first`` + 3 (``STwo``): not from sides side by side.
    Each turn makes the side facing its mover negative, and two negative sides that meet at a
    joint are a drive pair, which would turn the substrate itself (docs/physics.md); such a
    second mover turns in the late slot instead."""
    return (second - first) % 6 not in (0, 1, 5)


@dataclass
class WalterState:
    """One module's Figure 10 state (the paper's local variables and the uploaded problem)."""

    n: int
    path_len: int
    cost: int
    anchor: Cell
    table: dict[int, Entry] = field(default_factory=dict)
    start: Cell | None = None  # its cell when the first round began
    position: int | None = None
    passed_cw: int = 0
    passed_ccw: int = 0
    passed_by: set[int] = field(default_factory=set)  # positions of the modules that passed
    pivot: Cell | None = None  # the contact it last turned about
    plan: Plan | None = None  # this round's move
    free: bool = False
    delay: int = 0
    stopped: bool = False
    moved: bool = False  # this round
    unanswered: bool = False  # this round: a neighbour did not answer, so no move
    last_round: int = 0

    # -- the chain I -----------------------------------------------------------------------
    def _beyond(self) -> Side | None:
        """The global side of the start cell that points away from the anchor along I."""
        if self.start is None or self.start == self.anchor:
            return None
        for s in Side:
            c = self.anchor
            for _ in range(self.n):
                c = c.neighbour(s)
                if c == self.start:
                    return s
        return None

    @property
    def entry(self) -> Entry | None:
        return self.table.get(self.position) if self.position is not None else None

    @property
    def is_anchor(self) -> bool:
        return self.start == self.anchor

    def done(self) -> bool:
        """In its goal for good (or the anchor, which never leaves G)."""
        return self.stopped or self.is_anchor

    # -- Figure 10 ----------------------------------------------------------------------------
    def is_free(self, cell: Cell, contacts: list[bool]) -> bool:
        """``IsFree``: the chain cell beyond it is empty (sensed only while next to it), the
        contacts are one arc (two flips) and fewer than five sides touch."""
        beyond = self._beyond()
        if beyond is not None and cell == self.start and contacts[beyond - 1]:
            return False
        return flips(contacts) == 2 and sum(contacts) < 5

    def decide(self, round_: int, cell: Cell, contacts: list[bool]) -> Plan | None:
        """This round's move, or None. ``contacts[s-1]``: a neighbour across global side s."""
        self.last_round = round_
        self.moved = self.unanswered = False
        self.plan = None
        if self.start is None:
            self.start = cell
        if self.is_anchor or self.stopped:
            return None
        entry = self.entry
        if entry is not None and cell == entry.goal:
            self.stopped = True  # Figure 10: once stopped in its goal, never leaves
            return None
        if not self.free:
            if not self.is_free(cell, contacts):
                return None
            self.free = True
            self.position = self.passed_cw + self.passed_ccw
            beyond = self._beyond()
            self.pivot = cell.neighbour(Side.of(beyond + 3)) if beyond is not None else None
            entry = self.entry
            if entry is None:
                return None  # no goal for this position: the upload was short
            self.delay = entry.delay
        if entry is None or self.pivot is None:
            return None
        if self.delay > 0:
            self.delay -= 1
            return None
        towards = cell.side_towards(self.pivot)
        if towards is None or not contacts[towards - 1]:
            # the contact it last turned about has gone (it waited a round and that module
            # moved on): any contact of its one arc leads to the same end of it
            towards = next((s for s in Side if contacts[s - 1]), None) if flips(contacts) == 2 else None
        self.plan = None if towards is None else plan_move(contacts, entry.cw, towards)
        return self.plan

    def after_move(self, cell: Cell) -> None:
        """It made this round's move from ``cell``: it next turns about that substrate."""
        if self.plan is not None:
            self.pivot = cell.neighbour(self.plan.substrate)
            self.moved = True

    def settle(self, cell: Cell) -> None:
        """After the round's moves: a module that stands in its goal stops there for good."""
        entry = self.entry
        if self.free and entry is not None and cell == entry.goal:
            self.stopped = True

    def passed(self, op: WalterOp, position: int) -> None:
        """The mover at ``position`` asks this module something (to be its substrate, or to
        open the pin that holds it): it touches this module on its way, so while this module
        waits in I that mover passes it (Figure 10 counts every module passing, not only those
        that turn about it; once each). Its sense: the pivot it asks for, or for a ``hold``
        its goal table entry's."""
        if self.free or self.done() or position in self.passed_by:
            return
        self.passed_by.add(position)
        if op is WalterOp.HOLD:
            entry = self.table.get(position)
            cw = entry is not None and entry.cw
        else:
            cw = op is WalterOp.PIVOT_CW
        if cw:
            self.passed_cw += 1
        else:
            self.passed_ccw += 1

    def flags(self) -> int:
        """The ``WalterLog`` flags byte of this round."""
        entry = self.entry
        bits = [(self.free, WalterFlag.FREE), (self.moved, WalterFlag.MOVED),
                (entry is not None and entry.cw, WalterFlag.CW), (self.stopped, WalterFlag.STOPPED),
                (self.is_anchor, WalterFlag.ANCHOR), (self.unanswered, WalterFlag.UNANSWERED)]
        return sum(int(f) for on, f in bits if on)
