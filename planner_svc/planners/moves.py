"""Lone-walker primitives over a still structure: cut vertices, Table 4-3 steps, walks.

A module may rotate when the rest of the structure stays connected without it (it is
no cut vertex) and a Table 4-3 row has its substrate there and its goal and sweep cells
free (:func:`lone_steps`, from a table of the six neighbours' patterns); a void can be
entered while some row can bring a walker in (:func:`enterable`). Walks chain such
rotations with the rest still: breadth-first (:func:`bfs`, every cell a walker reaches)
or A* (:func:`walk`). ``complete``'s phases, its window searches
(:mod:`planner_svc.planners.windows`), bound descent (:mod:`planner_svc.planners.descent`) and plan
shortening (:mod:`planner_svc.planners.shorten`) all use these.
"""

from __future__ import annotations

from collections import deque
from typing import Iterator

from .rules import RULE_OFFSETS, Coord, MoveRule

Path = list[tuple[Coord, MoveRule]]

#: Per Table 4-3 row: where its goal cell lies, as an offset from the mobile module.
GOAL_OFFSET = {r: go for r, _, _, go in RULE_OFFSETS}
_DIRS: tuple[Coord, ...] = ((-1, 1), (0, 1), (1, 0), (1, -1), (0, -1), (-1, 0))


# --- connectivity ------------------------------------------------------------------------
def is_cut(occ: set[Coord], c: Coord, limit: int | None = None) -> bool:
    """Whether removing the module at ``c`` disconnects ``occ``.

    Local test first: if the occupied neighbours of ``c`` form one contiguous arc they
    stay connected to each other around ``c``, so the rest stays connected. Otherwise
    searches from the arcs must meet without ``c`` (:func:`_arcs_meet`).
    With ``limit``, a breadth-first search from one neighbour that explores more than
    ``limit`` cells answers True: conservative (True may be wrong, the module then only
    waits; False never is).
    """
    x, y = c
    mask = ring_mask(occ, x, y)
    if ONE_ARC[mask]:
        return False
    if limit is None:
        # One neighbour per arc: the first of each run of occupied neighbours.
        return not _arcs_meet(occ, c, [(x + _DIRS[i][0], y + _DIRS[i][1])
                                       for i in _ARC_STARTS[mask]])
    nbrs = [(x + dx, y + dy) for i, (dx, dy) in enumerate(_DIRS) if mask >> i & 1]
    want = set(nbrs[1:])
    seen = {c, nbrs[0]}
    todo = deque([nbrs[0]])
    while todo:
        a, b = todo.popleft()
        for dx, dy in _DIRS:
            n = (a + dx, b + dy)
            if n in occ and n not in seen:
                seen.add(n)
                want.discard(n)
                if not want:
                    return False
                todo.append(n)
        if limit is not None and len(seen) > limit:
            return True
    return True


def _arcs_meet(occ: set[Coord], c: Coord, starts: list[Coord]) -> bool:
    """Whether the cells of ``starts`` stay connected in ``occ`` without ``c``.

    One breadth-first search per start, in turn a cell each; searches that touch
    merge. The answer comes when all have merged (connected) or when a merged group
    has nothing left to explore (it is a component without the others). So a cut
    costs about the smaller side, times the number of arcs, not the whole structure
    (a plain search from one side explores all of it when it starts on the big one).
    """
    k = len(starts)
    owner: dict[Coord, int] = {c: -1}
    group = list(range(k))                      # union-find over the searches
    pending = [1] * k                           # cells queued, per group root
    todo = [deque([s]) for s in starts]
    for i, s in enumerate(starts):
        owner[s] = i

    def root(i: int) -> int:
        while group[i] != i:
            group[i] = group[group[i]]
            i = group[i]
        return i

    groups = k
    while True:
        for i in range(k):
            if not todo[i]:
                continue
            a, b = todo[i].popleft()
            r = root(i)
            pending[r] -= 1
            for dx, dy in _DIRS:
                n = (a + dx, b + dy)
                if n not in occ:
                    continue
                o = owner.get(n)
                if o is None:
                    owner[n] = i
                    todo[i].append(n)
                    pending[r] += 1
                elif o >= 0 and (ro := root(o)) != r:
                    group[ro] = r
                    pending[r] += pending[ro]
                    groups -= 1
                    if groups == 1:
                        return True
            if pending[r] == 0:
                return False


def can_move(occ: set[Coord], c: Coord, obstacles: set[Coord]) -> bool:
    """Whether the module at ``c`` has at least one legal rotation (ignoring connectivity)."""
    return next(lone_steps(occ, c, obstacles), None) is not None


def enterable(settled: set[Coord], void: Coord,
              obstacles: frozenset[Coord] | set[Coord] = frozenset()) -> bool:
    """Whether a void can still be entered once its neighbours stop moving.

    Table 4-3: some row must bring a walker from a free neighbour into ``void`` about
    an occupied substrate with the row's three swept cells free.
    """
    vx, vy = void
    for _, (sx, sy), empties, (gx, gy) in RULE_OFFSETS:
        mx, my = vx - gx, vy - gy
        if (mx, my) in settled or (mx, my) in obstacles or (mx + sx, my + sy) not in settled:
            continue
        if any((mx + ex, my + ey) in settled or (mx + ex, my + ey) in obstacles
               for ex, ey in empties):
            continue
        return True
    return False


# --- walks ---------------------------------------------------------------------------------
def walk(rest: set[Coord], start: Coord, targets: set[Coord], obstacles: set[Coord],
         limit: int | None = None, explored: set[Coord] | None = None) -> Path | None:
    """Shortest walk of a lone module from ``start`` to the nearest cell of ``targets``.

    ``rest`` is the structure without the walker; it must be connected and stays
    still. Returns the rotations as ``(cell before, rule)`` or None. ``limit`` caps the
    number of cells explored; ``explored``, if given, gets them.
    """
    came: dict[Coord, tuple[Coord, MoveRule] | None] = {start: None}
    todo = deque([start])
    end: Coord | None = None
    while todo:
        c = todo.popleft()
        if c in targets and c != start:
            end = c
            break
        for rule, g in lone_steps(rest, c, obstacles, came):
            came[g] = (c, rule)
            todo.append(g)
        if limit is not None and len(came) > limit:
            break
    if explored is not None:
        explored.update(came)
    if end is None:
        return None
    path: Path = []
    while (step := came[end]) is not None:
        path.append(step)
        end = step[0]
    return path[::-1]


def _ring_rules() -> tuple[tuple[tuple[MoveRule, Coord, tuple[Coord, ...]], ...], ...]:
    """For every pattern of the six neighbours (``occupied``, ``blocked`` bit masks in
    :data:`_DIRS` order, the occupied ones blocked too), the Table 4-3 rows whose
    substrate is there and whose goal and near sweep cells are free, in
    :data:`RULE_OFFSETS` order: ``(rule, goal offset, far sweep offsets)``. A walker
    then checks only the sweep cell two away (a module with four or more neighbours
    gets no row: a rotation needs three free cells around it)."""
    index = {d: i for i, d in enumerate(_DIRS)}
    table = []
    for key in range(64 * 64):
        occupied, blocked = key >> 6, key & 63
        rows = []
        if occupied & ~blocked == 0:
            for rule, s, empties, g in RULE_OFFSETS:
                near = [e for e in empties if e in index]
                if (occupied >> index[s] & 1 and not blocked >> index[g] & 1
                        and not any(blocked >> index[e] & 1 for e in near)):
                    rows.append((rule, g, tuple(e for e in empties if e not in index)))
        table.append(tuple(rows))
    return tuple(table)


_RING_RULES = _ring_rules()
#: Per neighbour pattern: the first direction (:data:`_DIRS` index) of each contiguous arc
#: of occupied neighbours.
_ARC_STARTS = tuple(tuple(i for i in range(6) if m >> i & 1 and not m >> (i - 1) % 6 & 1)
                    for m in range(64))
#: At most one arc: the neighbours stay connected around the cell, so it is no cut vertex.
ONE_ARC = tuple(len(starts) <= 1 for starts in _ARC_STARTS)


def ring_mask(cells: set[Coord] | frozenset[Coord], x: int, y: int) -> int:
    """Which of the six neighbours of ``(x, y)`` are in ``cells``, as :data:`_DIRS` bits."""
    return (((x - 1, y + 1) in cells) | ((x, y + 1) in cells) << 1
            | ((x + 1, y) in cells) << 2 | ((x + 1, y - 1) in cells) << 3
            | ((x, y - 1) in cells) << 4 | ((x - 1, y) in cells) << 5)


def lone_steps(rest: set[Coord], c: Coord, obstacles: set[Coord],
               skip: set[Coord] | dict[Coord, object] = frozenset()
               ) -> Iterator[tuple[MoveRule, Coord]]:
    """The legal rotations of a lone walker at ``c`` over the still structure ``rest``:
    ``(rule, goal cell)`` for each Table 4-3 row whose substrate is there and whose goal
    and sweep cells are free; goal cells in ``skip`` (already reached by a search) are
    left out before the sweep is checked."""
    cx, cy = c
    occupied = ring_mask(rest, cx, cy)
    blocked = occupied | ring_mask(obstacles, cx, cy) if obstacles else occupied
    for rule, (gx, gy), far in _RING_RULES[occupied << 6 | blocked]:
        g = (cx + gx, cy + gy)
        if g in skip:
            continue
        for ex, ey in far:
            e = (cx + ex, cy + ey)
            if e in rest or e in obstacles:
                break
        else:
            yield rule, g


def bfs(rest: set[Coord], start: Coord, obstacles: set[Coord]
        ) -> dict[Coord, tuple[int, Coord | None, MoveRule | None]]:
    """Walk lengths from ``start`` to every cell a lone walker reaches over ``rest``:
    ``cell -> (moves, previous cell, rule)``."""
    out: dict[Coord, tuple[int, Coord | None, MoveRule | None]] = {start: (0, None, None)}
    todo = deque([start])
    while todo:
        c = todo.popleft()
        d = out[c][0] + 1
        for rule, g in lone_steps(rest, c, obstacles, out):
            out[g] = (d, c, rule)
            todo.append(g)
    return out


_RING2 = tuple((dx, dy) for dx in range(-2, 3) for dy in range(-2, 3)
               if 0 < (abs(dx) + abs(dy) + abs(dx + dy)) // 2 <= 2)


def ring2(c: Coord) -> list[Coord]:
    """The cells at hex distance 1 or 2 from ``c``."""
    x, y = c
    return [(x + dx, y + dy) for dx, dy in _RING2]


def disk(c: Coord, r: int) -> list[Coord]:
    """The cells within hex distance ``r`` of ``c``."""
    x, y = c
    return [(x + dx, y + dy) for dx in range(-r, r + 1)
            for dy in range(max(-r, -dx - r), min(r, -dx + r) + 1)]
