"""The one legality rule for module moves (spec §2, §8; thesis Table 4-3, Table 3-2).

Every planner, the plan validator and the thesis layer-5 actuation go through
:func:`move_violation` / :func:`legal_moves`, which share one rule check
(:func:`_rule_violation`). A move of the module at ``mobile`` is legal when:

* ``mobile`` is occupied and is not the fixed module;
* the (joint, direction) row of Table 4-3 puts the substrate and the goal where
  the move says they are (geometry comes from :data:`bus.lattice.MOVE_RULES`);
* the substrate cell is occupied by a module that is not moving in the same step;
* the goal and the row's three "must be empty" cells are free: not occupied, not an
  obstacle, and (in a parallel step) not the start, goal or swept cells of another
  move of the same step;
* the rest of the structure (occupied cells minus every module moving in the step)
  is connected: the mobile stays latched to its substrate throughout, so the
  structure is connected during and after the move.

Table 4-3 implies the two collision limits of §2 on its own: the goal cell ends with at
most three occupied neighbours and the mobile has at most three before moving.

Internally cells are ``(x, y)`` tuples: the complete planner evaluates millions of
rule checks and :class:`bus.lattice.Cell` construction dominates otherwise. All
offsets are derived at import time from :mod:`bus.lattice` (no table is re-typed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Callable, Collection, Iterable, Iterator, Sequence

import networkx as nx

from bus.lattice import MOVE_RULES, Cell, Direction, Joint, MoveRule, Side, NEIGHBOUR_OFFSET

Coord = tuple[int, int]

#: Neighbour offsets in side order 1..6 (Table 4-1, from bus.lattice).
SIDE_OFFSETS: tuple[Coord, ...] = tuple(NEIGHBOUR_OFFSET[s] for s in Side)


def _rule_offsets(rule: MoveRule) -> tuple[Coord, tuple[Coord, ...], Coord]:
    sub, empty, goal = rule.cells(Cell(0, 0))
    return (sub.x, sub.y), tuple((c.x, c.y) for c in empty), (goal.x, goal.y)


#: Table 4-3 rows with their offsets from the mobile cell: (rule, substrate, empty cells, goal).
RULE_OFFSETS: tuple[tuple[MoveRule, Coord, tuple[Coord, ...], Coord], ...] = tuple(
    (r, *_rule_offsets(r)) for r in MOVE_RULES)


def xy(cell: Cell | Coord) -> Coord:
    """A cell as an ``(x, y)`` tuple."""
    return (cell[0], cell[1]) if isinstance(cell, tuple) else (cell.x, cell.y)


def neighbours_xy(c: Coord) -> list[Coord]:
    """The six neighbours of ``c`` in side order 1..6."""
    x, y = c
    return [(x + dx, y + dy) for dx, dy in SIDE_OFFSETS]


def hex_distance(a: Coord, b: Coord) -> int:
    """Hex distance, as :meth:`bus.lattice.Cell.distance`, on tuples."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    return (abs(dx) + abs(dy) + abs(dx + dy)) // 2


# --- connectivity --------------------------------------------------------------------
def is_connected(cells: Collection[Coord]) -> bool:
    """Whether the occupancy graph of ``cells`` (edges between adjacent cells) is connected."""
    if not cells:
        return False
    cells = cells if isinstance(cells, (set, frozenset)) else set(cells)
    start = next(iter(cells))
    seen = {start}
    todo = [start]
    while todo:
        for n in neighbours_xy(todo.pop()):
            if n in cells and n not in seen:
                seen.add(n)
                todo.append(n)
    return len(seen) == len(cells)


def occupancy_graph(cells: Iterable[Coord]) -> nx.Graph:
    """The thesis connectivity graph (§4.3.5): a node per module, an edge per shared side."""
    cells = set(cells)
    g = nx.Graph()
    g.add_nodes_from(cells)
    for c in cells:
        for n in neighbours_xy(c):
            if n in cells:
                g.add_edge(c, n)
    return g


def articulation_cells(cells: Iterable[Coord]) -> set[Coord]:
    """Cells whose module cannot leave without disconnecting the structure (cut vertices)."""
    return set(_articulation_cells(frozenset(cells)))


@lru_cache(maxsize=16)  # a planner step asks several times of one structure
def _articulation_cells(cells: frozenset[Coord]) -> frozenset[Coord]:
    if len(cells) <= 12:
        # Tiny structures (the exact search): removing each module in turn is cheaper
        # than building a networkx graph, and is the definition itself.
        return frozenset(c for c in cells if len(cells) > 2 and not is_connected(cells - {c}))
    return frozenset(nx.articulation_points(occupancy_graph(cells)))


# --- moves ------------------------------------------------------------------------------
@dataclass(frozen=True)
class Move:
    """One rotation of one module (one row of Table 4-3 applied at ``mobile``).

    ``release`` lists ``(cell, joint)`` solenoids of the mobile's other neighbours that
    must open so the mobile can leave (Table 3-2): for each occupied neighbour other
    than the substrate, both joints of its side facing the mobile. (Our reading: the
    thesis's energy estimate counts one solenoid per neighbour; which of the two
    vertices latches is not stated, so we release both.)
    """

    mobile: Cell
    goal: Cell
    joint: Joint
    direction: Direction
    substrate: Cell
    release: tuple[tuple[Cell, Joint], ...] = field(default=())

    @property
    def rule(self) -> MoveRule:
        return next(r for r, *_ in RULE_OFFSETS
                    if r.joint == self.joint and r.direction == self.direction)

    @property
    def swept(self) -> tuple[Cell, ...]:
        """The three cells Table 4-3 requires empty for this rotation."""
        return self.rule.cells(self.mobile)[1]

    def describe(self) -> str:
        rel = ", ".join(f"{c}J{int(j)}" for c, j in self.release) or "none"
        return (f"{self.mobile} -> {self.goal}: joint {int(self.joint)} {self.direction.value} "
                f"about substrate {self.substrate}; release {rel}")

    def __str__(self) -> str:
        return f"{self.mobile}->{self.goal}"


def release_joints(occupied: Collection[Coord], mobile: Coord,
                   substrate: Coord) -> tuple[tuple[Cell, Joint], ...]:
    """Joints the mobile's other neighbours must open (Table 3-2), in side order."""
    out: list[tuple[Cell, Joint]] = []
    for side, n in zip(Side, neighbours_xy(mobile)):
        if n in occupied and n != substrate:
            facing = side.facing
            out.extend((Cell(*n), j) for j in facing.joints)
    return tuple(out)


def _rule_violation(occupied: Collection[Coord], blocked: Callable[[Coord], bool],
                    mobile: Coord, substrate_off: Coord, empty_offs: Sequence[Coord],
                    goal_off: Coord, moving: Collection[Coord]) -> str | None:
    """The local part of the rule: substrate present and still, goal and swept cells free."""
    mx, my = mobile
    sub = (mx + substrate_off[0], my + substrate_off[1])
    if sub not in occupied:
        return f"no substrate module at {Cell(*sub)}"
    if sub in moving:
        return f"substrate {Cell(*sub)} is itself moving in this step"
    goal = (mx + goal_off[0], my + goal_off[1])
    if blocked(goal):
        return f"goal {Cell(*goal)} is not free"
    for dx, dy in empty_offs:
        c = (mx + dx, my + dy)
        if blocked(c):
            return f"cell {Cell(*c)} must be empty for this rotation (Table 4-3)"
    return None


def legal_moves(occupied: Iterable[Cell | Coord], fixed: Cell | Coord,
                obstacles: Iterable[Cell | Coord] = ()) -> list[Move]:
    """Every legal single move of the configuration (one module moves, the rest stay)."""
    return [to_move(occ, m, r) for occ, m, r in legal_xy(
        {xy(c) for c in occupied}, xy(fixed), {xy(c) for c in obstacles})]


def legal_xy(occ: set[Coord], fixed: Coord, obstacles: set[Coord],
              movers: Iterable[Coord] | None = None
              ) -> Iterator[tuple[set[Coord], Coord, MoveRule]]:
    """Tuple-level enumeration behind :func:`legal_moves` (also used by the search planners)."""
    cut = articulation_cells(occ)
    def blocked(c: Coord) -> bool:
        return c in occ or c in obstacles
    for m in sorted(occ if movers is None else movers):
        if m == fixed or m in cut or m not in occ:
            continue
        for rule, so, eo, go in RULE_OFFSETS:
            if _rule_violation(occ, blocked, m, so, eo, go, ()) is None:
                yield occ, m, rule


def to_move(occupied: Collection[Coord], mobile: Coord, rule: MoveRule) -> Move:
    """The :class:`Move` for a Table 4-3 row applied at ``mobile`` in ``occupied``."""
    sub, _, goal = rule.cells(Cell(*mobile))
    return Move(Cell(*mobile), goal, rule.joint, rule.direction, sub,
                release_joints(occupied, mobile, xy(sub)))


def move_violation(occupied: Iterable[Cell | Coord], move: Move, fixed: Cell | Coord,
                   obstacles: Iterable[Cell | Coord] = (),
                   concurrent: Sequence[Move] = ()) -> str | None:
    """Why ``move`` is illegal in ``occupied`` (None when legal).

    ``concurrent`` are the other moves of the same parallel step: they count as
    moving (their modules cannot be substrates and are absent from the connectivity
    check) and their start, goal and swept cells are not free for this move.
    """
    occ = {xy(c) for c in occupied}
    obst = {xy(c) for c in obstacles}
    m = xy(move.mobile)
    if m not in occ:
        return f"no module at {move.mobile}"
    if m == xy(fixed):
        return f"{move.mobile} is the fixed module"
    row = next(((so, eo, go) for r, so, eo, go in RULE_OFFSETS
                if r.joint == move.joint and r.direction == move.direction), None)
    if row is None:
        return f"joint {move.joint} {move.direction} is not a row of Table 4-3"
    so, eo, go = row
    if (m[0] + so[0], m[1] + so[1]) != xy(move.substrate):
        return (f"joint {int(move.joint)} {move.direction.value} pivots on "
                f"{Cell(m[0] + so[0], m[1] + so[1])}, not on substrate {move.substrate}")
    if (m[0] + go[0], m[1] + go[1]) != xy(move.goal):
        return (f"joint {int(move.joint)} {move.direction.value} ends in "
                f"{Cell(m[0] + go[0], m[1] + go[1])}, not in {move.goal}")
    moving = {xy(o.mobile) for o in concurrent}
    if m in moving:
        return f"module {move.mobile} moves twice in one step"
    taken: set[Coord] = set(moving)
    for o in concurrent:
        taken.add(xy(o.goal))
        taken.update(xy(c) for c in o.swept)
    def blocked(c: Coord) -> bool:
        return c in occ or c in obst or c in taken
    why = _rule_violation(occ, blocked, m, so, eo, go, moving)
    if why:
        return why
    rest = occ - moving - {m}
    if not is_connected(rest):
        return "the structure would be disconnected"
    expected = release_joints(occ, m, xy(move.substrate))
    if set(expected) != set(move.release):
        want = ", ".join(f"{c}J{int(j)}" for c, j in expected) or "none"
        return f"wrong joints released (Table 3-2 needs: {want})"
    return None


def find_move(occupied: Iterable[Cell | Coord], mobile: Cell | Coord, goal: Cell | Coord,
              fixed: Cell | Coord, obstacles: Iterable[Cell | Coord] = (),
              concurrent: Sequence[Move] = ()) -> Move | None:
    """The legal Table 4-3 rotation that takes ``mobile`` to the adjacent ``goal``, if any."""
    occ = {xy(c) for c in occupied}
    m, g = xy(mobile), xy(goal)
    for rule, so, eo, go in RULE_OFFSETS:
        if (m[0] + go[0], m[1] + go[1]) != g:
            continue
        mv = to_move(occ, m, rule)
        if move_violation(occ, mv, fixed, obstacles, concurrent) is None:
            return mv
    return None


def apply_step(occupied: Iterable[Coord], moves: Iterable[Move]) -> set[Coord]:
    """The configuration after a step (no checks: see :func:`move_violation`)."""
    occ = set(occupied)
    moves = list(moves)
    occ.difference_update(xy(mv.mobile) for mv in moves)
    occ.update(xy(mv.goal) for mv in moves)
    return occ
