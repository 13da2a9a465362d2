"""Section 5 of Walter, Tsai & Amato as a round model: every module runs Figure 10 itself.

This is the reference the fleet is held to (``hexbench run --planner walter`` compares the
modules' own moves with it round by round). Pure Python, deterministic, no bus.

API::

    model = RoundModel(goal, start_chain, substrate, orientation=k)
    rounds = model.run()            # list[Round], one per lockstep round, round 1 first
    rounds[r].moves                 # [RoundMove(module, direction, from_cell, to_cell, substrate)]
    rounds[r].states                # {module: ModuleState} after the round (the debug line)
    model.report()                  # Report: rounds, moves, reached, collisions, world refusals

* ``goal``: the goal cells G (any iterable of :class:`bus.lattice.Cell`).
* ``start_chain``: I, a straight chain of ``n = |G|`` cells; exactly one of its two ends is in
  G (the intersection, whose module never moves). Modules are named by their *position* in
  I: ``0`` is the free end, ``n - 1`` the module in G.
* ``substrate``: the substrate path, Definition 3's way: it begins with the intersection
  cell. ``orientation`` is the turn (:func:`.frame.turn`) in which the path runs west to east
  over north-south columns; :func:`planner_svc.planners.walter.choose` returns all three.

Per round every module, from its own cell, its contacts (which of its six sides touch a
module at the start of the round) and what it counted, does one of: nothing, count, wait,
move one step, stop. ``RoundMove.direction`` is the rotation's sense (CW/CCW, geometric);
``substrate`` the neighbour it turns about; ``from_cell``/``to_cell`` adjacent cells.

The rule (Figure 10, and what we chose where the paper is silent, docs/planner.md):

1. A module still in I is *free* when the cell of I beyond it (away from G) is empty, its
   contacts form one run (``flips == 2``) and it has fewer than five contacts. Until then it
   counts the modules that pass: a mover passes a module when it turns about it (the
   mover asks its substrate for the magnets, so the substrate knows it and the sense).
2. When it is first free its position is ``cw + ccw`` passers (module 0 knows it is the
   free end). From the position, n, G and the substrate path (every module knows them) it
   takes its direction, delay and goal cell from :class:`Schedule` (the paper's patterns:
   (0,0)-bidirectional, (1,0)-bidirectional, unidirectional; chosen by the path's cost).
3. A free module whose delay is not yet 0 waits a round and decrements it; at 0 it moves
   every round, one step in its direction around the structure (its first step turns about
   its neighbour in I towards G; then it keeps the structure on its right (CW) or left (CCW),
   turning about the contact it last turned about or the next one round).
4. A module in its goal cell stops and never leaves it.

Every round is checked against the paper's move rule (section 3: the target empty, an
immobile substrate adjacent to it, the cell beyond the target empty, one mover per
target) -> ``Report.collisions``; and against the project's world, Table 4-3 via
:func:`planner_svc.planners.rules.move_violation` (a HexBot turns 120 degrees about a vertex
and sweeps more cells than the paper's model) -> ``Report.world_refusals``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterable, NamedTuple, Sequence

from bus.lattice import Cell, Direction, Side

from ..rules import RULE_OFFSETS, move_violation, to_move, xy
from .frame import columns, heading, turn, unturn
from .graph import path_cost

CW, CCW = Direction.CW, Direction.CCW


class RoundMove(NamedTuple):
    """One module's step in one round."""

    module: int
    direction: Direction
    from_cell: Cell
    to_cell: Cell
    substrate: Cell


@dataclass(frozen=True)
class ModuleState:
    """What a module knows after a round (the line it writes on its debug UART)."""

    cell: Cell
    free: bool
    position: int | None
    delay: int
    direction: Direction | None
    goal: Cell | None
    done: bool


@dataclass
class Round:
    number: int
    moves: list[RoundMove]
    states: dict[int, ModuleState] = field(default_factory=dict)


@dataclass(frozen=True)
class Assignment:
    """What a module at a position does: its direction, delay after free, goal cell."""

    position: int
    direction: Direction
    delay: int
    goal: Cell | None
    pattern: str


# --- the schedule: positions -> direction, delay, goal ------------------------------------------
def _opposite(d: Direction) -> Direction:
    return CCW if d is CW else CW


@dataclass(frozen=True)
class Delays:
    """Rounds a module waits after it is free, per pattern (section 5's "time units").

    ``paper``: the text's numbers. ``hexbot``: one more round wherever the paper lets two
    movers on one side follow each other one empty cell apart: a HexBot turns 120 degrees
    about a vertex and sweeps three cells besides its target (Table 4-3), so movers on one
    route need the two empty cells between them that section 4 designs for.
    """

    bidir_cw: int       # (0,0)-bidirectional: CW movers after the first
    bidir_ccw: int      # ... CCW movers
    climb_cw: int       # (1,0)-bidirectional (climbing over p): CW movers
    climb_ccw: int
    turn: int           # the first module off p, (0,1)-bidirectional's start
    uni: int            # unidirectional, after the first module of the direction


DELAYS = {
    "paper": Delays(bidir_cw=0, bidir_ccw=0, climb_cw=1, climb_ccw=0, turn=2, uni=2),
    "hexbot": Delays(bidir_cw=1, bidir_ccw=0, climb_cw=2, climb_ccw=1, turn=2, uni=3),
}


class Schedule:
    """The paper's patterns of rotation and delay, per position (section 5).

    Every module can build this from n, G, the substrate path and the orientation; a module
    reads its own entry once it knows its position. Cells are in lattice coordinates.
    A module filling p has ``goal`` None here: it stops in the first cell of p it enters
    (with a bend, modules reach the tail out of order; :class:`RoundModel` fills the goals
    in from that arrival order, which every module can compute the same way).
    """

    def __init__(self, goal: Iterable[Cell], substrate: Sequence[Cell], orientation: int,
                 delays: Delays = DELAYS["hexbot"], free_end: Cell | None = None) -> None:
        k = orientation
        goal_t = {turn(c, k) for c in goal}
        path_t = [turn(c, k) for c in substrate]
        self.cost = path_cost(path_t)
        self.delays = delays
        on_path = set(path_t)
        cols = columns(goal_t)
        top = {x: max(c.y for c in path_t if c.x == x) for x in cols}
        bottom = {x: min(c.y for c in path_t if c.x == x) for x in cols}
        north: list[Cell] = []
        south: list[Cell] = []
        for x in sorted(cols, reverse=True):  # east to west, each column outwards from p
            north += sorted((c for c in cols[x] if c.y > top[x]), key=lambda c: c.y)
            south += sorted((c for c in cols[x] if c.y < bottom[x]), key=lambda c: -c.y)
        off = goal_t - on_path - set(north) - set(south)
        if off:
            raise ValueError(f"goal cells {', '.join(map(str, sorted(unturn(c, k) for c in off)))}"
                             " lie between two cells of the substrate path in their column")
        self.path = [unturn(c, k) for c in path_t]
        self.north = [unturn(c, k) for c in north]
        self.south = [unturn(c, k) for c in south]
        self.n = len(goal_t)
        self.first = CW
        if self.cost == 1 and free_end is not None:
            self.first = CCW if free_end.distance(self.bend) % 2 else CW
        self.entries = self._build()

    @property
    def bend(self) -> Cell:
        """The cell of p where a cost-1 path turns (its last cell otherwise)."""
        hs = [heading(a, b) for a, b in zip(self.path, self.path[1:])]
        return next((self.path[i] for i in range(1, len(hs)) if hs[i] is not hs[i - 1]),
                    self.path[-1])

    @property
    def cost_class(self) -> str:
        return "0" if self.cost == 0 else "1" if self.cost == 1 else ">1"

    def _build(self) -> list[Assignment]:
        dl = self.delays
        P = len(self.path) - 1
        out: list[Assignment] = []
        first: set[Direction] = set()

        def delay(d: Direction, cw: int, ccw: int) -> int:
            w = 0 if d not in first else (cw if d is CW else ccw)
            first.add(d)
            return w

        for i in range(P):
            if self.cost <= 1:
                d = self.first if i % 2 == 0 else _opposite(self.first)
                out.append(Assignment(i, d, delay(d, dl.bidir_cw, dl.bidir_ccw), None,
                                      "(0,0)-bidirectional"))
            else:
                out.append(Assignment(i, CW, delay(CW, dl.uni, dl.uni), None, "unidirectional"))
        north, south = list(self.north), list(self.south)
        last = out[-1].direction if out else CCW
        nxt = _opposite(last) if self.cost <= 1 else CCW
        for i in range(P, self.n - 1):
            if not (north if nxt is CW else south):
                nxt = _opposite(nxt)
            both = bool(north) and bool(south)
            cell = (north if nxt is CW else south).pop(0)
            if i == P and both:
                w, pattern = max(dl.turn, delay(nxt, 0, 0)), "(0,1)-bidirectional"
            elif both:
                w, pattern = delay(nxt, dl.climb_cw, dl.climb_ccw), "(1,0)-bidirectional"
            else:
                w, pattern = delay(nxt, dl.uni, dl.uni), "unidirectional"
            out.append(Assignment(i, nxt, w, cell, pattern))
            if both:
                nxt = _opposite(nxt)
        return out

    def __getitem__(self, position: int) -> Assignment:
        return self.entries[position]


# --- the modules -----------------------------------------------------------------------------
@dataclass
class _Module:
    position_true: int
    cell: Cell
    beyond: Cell | None        # the cell of I next further from G (empty once it left)
    towards: Cell | None       # the cell of I next towards G
    anchor: bool = False
    free: bool = False
    position: int | None = None
    cw: int = 0
    ccw: int = 0
    passed_by: set[int] = field(default_factory=set)
    delay: int = 0
    direction: Direction | None = None
    goal: Cell | None = None
    moving: bool = False
    done: bool = False
    pivot: Cell | None = None  # the contact it last turned about


def _sides_occupied(cell: Cell, occupied: set[Cell]) -> list[bool]:
    """contacts[i] for sides 1..6 (index 0 is side 1)."""
    return [cell.neighbour(s) in occupied for s in Side]


def flips(contacts: Sequence[bool]) -> int:
    return sum(contacts[i] != contacts[(i + 1) % 6] for i in range(6))


def contact_pattern(contacts: Sequence[bool], held: bool) -> str:
    """Figure 9's classes: ``trapped`` (its contacts are not one run, or five or more: the
    hardware cannot move it), ``other`` (it could move, but the algorithm holds it: the cell
    of I beyond it is still occupied, or it stopped in its goal cell) or ``free``."""
    if flips(contacts) != 2 or sum(contacts) >= 5:
        return "trapped"
    return "other" if held else "free"


def step(cell: Cell, direction: Direction, pivot: Cell, occupied: set[Cell]) -> tuple[Cell, Cell] | None:
    """One step around the structure: ``(substrate, target)``, or None if it cannot turn.

    CW keeps the structure on the mover's right: from the side facing ``pivot`` it looks
    counter-clockwise past every occupied side; the last occupied one is the substrate and
    the empty side after it the target. CCW is the mirror image.
    """
    side = cell.side_towards(pivot)
    if side is None or pivot not in occupied:
        return None
    d = -1 if direction is CW else 1
    s = int(side)
    for _ in range(6):
        nxt = Side.of(s + d)
        if cell.neighbour(nxt) not in occupied:
            return cell.neighbour(s), cell.neighbour(nxt)
        s = int(nxt)
    return None


@dataclass
class Report:
    rounds: int
    moves: int
    reached: bool
    collisions: list[str]
    world_refusals: list[str]
    stuck: str = ""


class RoundModel:
    """Figure 10, every module, lockstep rounds (see the module docstring).

    ``rules``: ``"hexbot"`` (default, the delays our world needs, :data:`DELAYS`) or
    ``"paper"`` (the text's delays, held only to the paper's move rule).
    """

    def __init__(self, goal: Iterable[Cell], start_chain: Sequence[Cell], substrate: Sequence[Cell],
                 orientation: int = 0, rules: str = "hexbot", max_rounds: int | None = None,
                 stop_on_refusal: bool = False, _schedule: "Schedule | None" = None) -> None:
        self.goal = frozenset(goal)
        chain = list(start_chain)
        if chain[0] in self.goal and chain[-1] not in self.goal:
            chain.reverse()
        if chain[-1] not in self.goal or sum(c in self.goal for c in chain) != 1:
            raise ValueError("I must meet G in exactly one cell, at one end of I")
        if len(chain) != len(self.goal):
            raise ValueError(f"I has {len(chain)} cells, G {len(self.goal)}")
        path = list(substrate)
        if path[0] != chain[-1]:
            raise ValueError(f"the substrate path begins at {path[0]}, not at the intersection "
                             f"{chain[-1]} of I and G")
        if rules not in DELAYS:
            raise ValueError(f"rules {rules!r}: expected one of {', '.join(DELAYS)}")
        self.rules = rules
        self.stop_on_refusal = stop_on_refusal
        self.chain = chain
        self.n = len(chain)
        self.max_rounds = max_rounds or 30 * self.n + 60
        self.on_path = frozenset(path[1:])
        if _schedule is None:
            _schedule = Schedule(self.goal, path, orientation, DELAYS[rules], chain[0])
            self.schedule = _schedule
            try:
                self._arrivals()
            except ValueError:
                if _schedule.cost != 1:
                    raise
                # With a bend the first module's sense decides who reaches the tail when
                # (section 5's parity rule); our world's delays can shift that parity, so
                # the PC tries the other sense too and sends the one that works.
                _schedule.first = _opposite(_schedule.first)
                _schedule.entries = _schedule._build()
                self._arrivals()
        self.schedule = _schedule
        self.modules = [
            _Module(i, c, chain[i - 1] if i > 0 else None, chain[i + 1] if i + 1 < self.n else None,
                    anchor=(i == self.n - 1))
            for i, c in enumerate(chain)]
        self.rounds: list[Round] = []
        self.collisions: list[str] = []
        self.world_refusals: list[str] = []
        self.stuck = ""

    def _arrivals(self) -> None:
        """Fill in the goals on p from the order modules reach it (a dry run in which a
        module stops in the first empty cell of p it enters). When a module meant for a
        cell off p takes the last cell of p first (a bend's tail, section 5's parity case),
        it and the module that was to go there swap goals."""
        dry = RoundModel(self.goal, self.chain, self.schedule.path, rules=self.rules,
                         max_rounds=self.max_rounds, _schedule=self.schedule)
        dry._dynamic = True
        dry.run()
        entries = list(self.schedule.entries)
        for m in dry.modules:
            if m.anchor or m.position is None:
                continue
            e = entries[m.position]
            if m.done and m.cell in self.on_path:
                if e.goal is not None:  # took p's last cell before the module meant for it
                    late = next(x for x in entries if x.goal is None and
                                not any(o.done and o.position == x.position for o in dry.modules))
                    entries[late.position] = replace(late, goal=e.goal)
                entries[m.position] = replace(e, goal=m.cell)
        missing = [e.position for e in entries if e.goal is None]
        if missing:
            self.schedule.entries = entries
            raise ValueError(f"modules {missing} do not reach the substrate path "
                             f"({dry.stuck or 'dry run'})")
        self.schedule.entries = entries

    _dynamic = False

    # -- one round ---------------------------------------------------------------------------
    def _decide(self, m: _Module, occupied: set[Cell]) -> RoundMove | None:
        if m.anchor or m.done:
            return None
        if not m.free:
            contacts = _sides_occupied(m.cell, occupied)
            first = m.position_true == 0
            if first or contact_pattern(contacts, m.beyond in occupied) == "free":
                m.free = True
                m.position = 0 if first else m.cw + m.ccw
                if m.position != m.position_true:
                    self.collisions.append(f"module {m.position_true} counted {m.position} "
                                           "passers: its position is wrong")
                    m.position = m.position_true
                a = self.schedule[m.position]
                m.direction, m.delay, m.goal = a.direction, a.delay, a.goal
                m.pivot = m.towards
            else:
                return None
        if m.delay > 0 and not m.moving:
            m.delay -= 1
            return None
        m.moving = True
        turned = step(m.cell, m.direction, m.pivot, occupied)
        if turned is None:
            self.collisions.append(f"module {m.position_true} at {m.cell} cannot turn "
                                   f"{m.direction.value} (no contact to turn about)")
            return None
        sub, target = turned
        return RoundMove(m.position_true, m.direction, m.cell, target, sub)

    def _check(self, moves: list[RoundMove], occupied: set[Cell], number: int) -> list[RoundMove]:
        """The paper's move rule (section 3); moves that break it are refused and logged."""
        movers = {mv.from_cell for mv in moves}
        targets: dict[Cell, int] = {}
        for mv in moves:
            targets[mv.to_cell] = targets.get(mv.to_cell, 0) + 1
        ok = []
        for mv in moves:
            why = ""
            side_t = mv.from_cell.side_towards(mv.to_cell)
            if mv.to_cell in occupied:
                why = f"target {mv.to_cell} is occupied"
            elif mv.substrate not in occupied or mv.substrate in movers:
                why = f"substrate {mv.substrate} is not an immobile module"
            elif mv.to_cell.side_towards(mv.substrate) is None:
                why = f"substrate {mv.substrate} is not adjacent to the target"
            elif targets[mv.to_cell] > 1:
                why = f"another module also moves into {mv.to_cell}"
            else:
                d = -1 if mv.direction is CW else 1
                beyond = mv.from_cell.neighbour(side_t + d)
                if beyond in occupied:
                    why = f"the cell beyond the target, {beyond}, is occupied"
            if why:
                self.collisions.append(f"round {number}: module {mv.module} {mv.from_cell}->"
                                       f"{mv.to_cell} {mv.direction.value}: {why}")
            else:
                ok.append(mv)
        if not self._dynamic:
            self._world(ok, occupied, number)
        return ok

    def _world(self, moves: list[RoundMove], occupied: set[Cell], number: int) -> None:
        """Table 4-3 (the world's rotation) for the round's moves, all at once."""
        occ = {xy(c) for c in occupied}
        as_moves = []
        for mv in moves:
            rule = next((r for r, so, _, go in RULE_OFFSETS
                         if (mv.from_cell.x + go[0], mv.from_cell.y + go[1]) == xy(mv.to_cell)
                         and (mv.from_cell.x + so[0], mv.from_cell.y + so[1]) == xy(mv.substrate)
                         and r.direction is mv.direction), None)
            as_moves.append(None if rule is None else to_move(occ, xy(mv.from_cell), rule))
        fixed = self.chain[-1]
        for k, (mv, wm) in enumerate(zip(moves, as_moves)):
            if wm is None:
                self.world_refusals.append(f"round {number}: module {mv.module}: no Table 4-3 "
                                           f"rotation {mv.from_cell}->{mv.to_cell} about {mv.substrate}")
                continue
            others = [o for i, o in enumerate(as_moves) if i != k and o is not None]
            why = move_violation(occupied, wm, fixed, (), others)
            if why:
                self.world_refusals.append(f"round {number}: module {mv.module} "
                                           f"{mv.from_cell}->{mv.to_cell}: {why}")

    def world_moves(self) -> list[list]:
        """The rounds as Table 4-3 moves (:class:`planner_svc.planners.rules.Move`), rounds
        without a move left out: a :class:`Plan`'s steps."""
        occ = {xy(c) for c in self.chain}
        out = []
        for r in self.rounds:
            step_moves = []
            for mv in r.moves:
                rule = next(r_ for r_, so, _, go in RULE_OFFSETS
                            if (mv.from_cell.x + go[0], mv.from_cell.y + go[1]) == xy(mv.to_cell)
                            and (mv.from_cell.x + so[0], mv.from_cell.y + so[1]) == xy(mv.substrate))
                step_moves.append(to_move(occ, xy(mv.from_cell), rule))
            for mv in r.moves:
                occ.discard(xy(mv.from_cell))
            occ.update(xy(mv.to_cell) for mv in r.moves)
            if step_moves:
                out.append(step_moves)
        return out

    def _count(self) -> None:
        """A module waiting in I counts every mover that touches it once, by its sense (a
        HexBot knows: the mover asks it for its latches when it leaves its side)."""
        at = {m.cell: m for m in self.modules}
        for m in self.modules:
            if not (m.free and not m.done):
                continue
            for n in m.cell.neighbours():
                s = at.get(n)
                if s is not None and not s.free and not s.anchor and m.position_true not in s.passed_by:
                    s.passed_by.add(m.position_true)
                    if m.direction is CW:
                        s.cw += 1
                    else:
                        s.ccw += 1

    def _arrived(self, m: _Module, occupied_before: set[Cell]) -> bool:
        if not m.free or m.anchor:
            return False
        if m.goal is not None and not self._dynamic:
            return m.cell == m.goal
        if m.cell in self.on_path:
            return True  # dry run: the first empty cell of p it enters
        return m.goal is not None and m.cell == m.goal

    def step_round(self) -> Round:
        number = len(self.rounds) + 1
        occupied = {m.cell for m in self.modules}
        decided = [mv for m in self.modules if (mv := self._decide(m, occupied)) is not None]
        moves = self._check(decided, occupied, number)
        by_module = {m.position_true: m for m in self.modules}
        for mv in moves:
            m = by_module[mv.module]
            m.cell, m.pivot = mv.to_cell, mv.substrate
        for m in self.modules:
            if not m.done and self._arrived(m, occupied):
                m.done, m.moving = True, False
        self._count()
        r = Round(number, moves, {m.position_true: ModuleState(
            m.cell, m.free, m.position, m.delay, m.direction, m.goal, m.done or m.anchor)
            for m in self.modules})
        self.rounds.append(r)
        return r

    def finished(self) -> bool:
        return all(m.done or m.anchor for m in self.modules)

    def run(self) -> list[Round]:
        """Rounds until every module is in its goal cell, or :attr:`max_rounds`."""
        if self.rounds:
            return self.rounds
        idle = 0
        while not self.finished() and len(self.rounds) < self.max_rounds:
            r = self.step_round()
            idle = idle + 1 if not r.moves else 0
            if self.stop_on_refusal and self.world_refusals:
                self.stuck = "stopped at the first move the world refuses"
                break
            if idle > 4:
                self.stuck = f"no module moved in rounds {r.number - 4}..{r.number}"
                break
        if not self.finished() and not self.stuck:
            self.stuck = f"gave up after {self.max_rounds} rounds"
        return self.rounds

    def report(self) -> Report:
        self.run()
        return Report(len(self.rounds), sum(len(r.moves) for r in self.rounds), self.finished(),
                      list(self.collisions), list(self.world_refusals), self.stuck)
