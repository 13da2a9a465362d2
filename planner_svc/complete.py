"""``complete``: a heuristic planner for large fleets that always finishes.

Idea: modules are interchangeable, so only electrons (modules off the goal) need to
move, each to some void (empty goal cell). One electron at a time walks over the
surface of the otherwise still structure to a void:

1. pick the movable electrons (not the fixed module, not an articulation point:
   with it lifted out the rest stays connected, so each step of its walk keeps
   the structure connected as it stays latched to a substrate);
2. for each, closest to a void first, search its walk: a breadth-first search over
   the cells it can reach by legal rotations (:mod:`planner_svc.rules`) with the rest
   of the structure fixed, stopping at the first void;
3. make the whole walk (one move per time step), repeat.

When no electron can reach a void, modules already on goal cells may walk to a void
instead (this can open a blocked pocket). If that does not help either, small fleets
(``exact_limit`` modules or fewer) fall back to :mod:`planner_svc.search` from the
current configuration; since every move is reversible (a rotation back about the same
vertex sweeps the same cells), "unreachable from here" is then also "unreachable from
the start". Larger fleets report that the heuristic is stuck, without claiming
unreachability.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from .plan import Plan, Problem
from .rules import (RULE_OFFSETS, Coord, Move, MoveRule, articulation_cells, find_move,
                    neighbours_xy, to_move, xy)
from .search import DEFAULT_MARGIN, search_moves, region_around

EXACT_LIMIT = 9
#: How many detours of goal-cell modules the heuristic may make before giving up.
UNBLOCK_BUDGET_PER_MODULE = 2


def walk(rest: set[Coord], start: Coord, targets: set[Coord], obstacles: set[Coord],
         limit: int | None = None, choose=None) -> list[tuple[Coord, MoveRule]] | None:
    """Shortest walk of a lone module from ``start`` to any cell of ``targets``.

    ``rest`` is the structure without the walker; it must be connected and stays
    still. Returns the rotations as ``(cell before, rule)`` or None. ``limit`` caps the
    number of cells explored. ``choose(found, depth)`` picks among all reachable
    targets (default: the nearest).
    """
    came: dict[Coord, tuple[Coord, MoveRule] | None] = {start: None}
    todo = deque([start])
    found: list[Coord] = []
    depth = {start: 0}
    while todo:
        c = todo.popleft()
        if c in targets and c != start:
            found.append(c)
            if choose is None:
                break
            # A walker may pass over a void on its way to a better one.
        cx, cy = c
        for rule, (sx, sy), empties, (gx, gy) in RULE_OFFSETS:
            g = (cx + gx, cy + gy)
            if g in came or g in rest or g in obstacles or (cx + sx, cy + sy) not in rest:
                continue
            if any((cx + ex, cy + ey) in rest or (cx + ex, cy + ey) in obstacles
                   for ex, ey in empties):
                continue
            came[g] = (c, rule)
            depth[g] = depth[c] + 1
            todo.append(g)
        if limit is not None and len(came) > limit:
            break
    if not found:
        return None
    c = found[0] if choose is None else choose(found, depth)
    path = []
    while came[c] is not None:
        prev, rule = came[c]
        path.append((prev, rule))
        c = prev
    return path[::-1]


def _by_distance_to(cells: list[Coord], targets: list[Coord]) -> list[Coord]:
    """``cells`` ordered by hex distance to their nearest target."""
    if not cells or not targets:
        return cells
    a = np.array(cells)
    b = np.array(targets)
    dx = b[None, :, 0] - a[:, None, 0]
    dy = b[None, :, 1] - a[:, None, 1]
    d = ((np.abs(dx) + np.abs(dy) + np.abs(dx + dy)) // 2).min(axis=1)
    return [cells[i] for i in np.lexsort((np.arange(len(cells)), d))]


def plan_complete(plan: Plan, exact_limit: int = EXACT_LIMIT) -> None:
    """Fill ``plan`` (serial, one move per step); see the module docstring.

    If the heuristic gets stuck going forwards, it also tries the reverse problem
    (goal to initial) and plays that plan backwards, since every move is reversible.
    """
    p: Problem = plan.problem
    forward = Plan(plan.planner, p)
    _heuristic(forward, exact_limit=0)
    if not forward.ok:
        backward = Plan(plan.planner, Problem(p.goal, p.initial, p.fixed, p.obstacles, p.name))
        _heuristic(backward, exact_limit=0)
        if backward.ok:
            plan.steps = reverse_steps(backward, p)
            plan.ok = True
            plan.notes.append("forward heuristic stuck; the reverse problem's plan played backwards")
            return
    plan.steps, plan.ok, plan.reason = forward.steps, forward.ok, forward.reason
    if not forward.ok:
        occ = {xy(c) for c in forward.configurations()[-1]}
        _finish_small(plan, occ, {xy(c) for c in p.goal}, xy(p.fixed),
                      {xy(c) for c in p.obstacles}, exact_limit)


def reverse_steps(plan: Plan, problem: Problem) -> list[list[Move]]:
    """A serial plan played backwards: each rotation undone about the same substrate."""
    confs = plan.configurations()
    out: list[list[Move]] = []
    for conf, (mv,) in zip(reversed(confs[1:]), reversed(plan.steps)):
        back = find_move(conf, mv.goal, mv.mobile, problem.fixed, problem.obstacles)
        assert back is not None, "moves are reversible"
        out.append([back])
    return out


def _heuristic(plan: Plan, exact_limit: int) -> None:
    p: Problem = plan.problem
    occ = {xy(c) for c in p.initial}
    goal = {xy(c) for c in p.goal}
    fixed = xy(p.fixed)
    obstacles = {xy(c) for c in p.obstacles}
    unblock_budget = UNBLOCK_BUDGET_PER_MODULE * len(occ)
    seen = {frozenset(occ)}
    layer = goal_layers(goal, fixed)

    def do_walk(path: list[tuple[Coord, MoveRule]]) -> None:
        for cell, rule in path:
            # Releases depend on who is next to the walker now, so build each move here.
            mv: Move = to_move(occ, cell, rule)
            plan.steps.append([mv])
            occ.discard(cell)
            occ.add(xy(mv.goal))

    while occ != goal:
        voids = goal - occ
        cut = articulation_cells(occ)
        electrons = [e for e in occ - goal if e != fixed and e not in cut]
        moved = False
        choose = _void_chooser(occ, goal, layer)
        for e in _by_distance_to(sorted(electrons), sorted(voids)):
            path = walk(occ - {e}, e, voids, obstacles, choose=choose)
            if path:
                do_walk(path)
                moved = True
                break
        if not moved and unblock_budget > 0:
            # Detour: a module already on a goal cell walks to a void; its own cell
            # becomes the void, possibly one an electron can reach.
            # Keepers next to sealed voids first: moving them may reopen the pocket.
            settled = occ & goal
            sealed = [v for v in voids if not enterable(settled, v)]
            keepers = [c for c in settled if c != fixed and c not in cut]
            for k in _by_distance_to(sorted(keepers), sorted(sealed or voids)):
                path = walk(occ - {k}, k, voids, obstacles)
                if path:
                    if frozenset((occ - {k}) | {_end(path)}) in seen:
                        continue
                    do_walk(path)
                    unblock_budget -= 1
                    moved = True
                    break
        if not moved:
            _finish_small(plan, occ, goal, fixed, obstacles, exact_limit)
            return
        seen.add(frozenset(occ))
    plan.ok = True


def enterable(settled: set[Coord], void: Coord) -> bool:
    """Whether a void can still be entered once its neighbours stop moving.

    Table 4-3: a module rolling into a cell about its substrate arrives from one side
    and needs the two sides after that empty, so the cell's other occupied neighbours
    must all lie within three consecutive sides (the substrate's and the two beyond).
    """
    ring = [n in settled for n in neighbours_xy(void)]
    occupied = {i for i in range(6) if ring[i]}
    return any(occupied <= {i, (i + 1) % 6, (i + 2) % 6} for i in range(6))


def goal_layers(goal: set[Coord], fixed: Coord) -> dict[Coord, int]:
    """Distance of each goal cell from the fixed module, inside the goal shape."""
    layer = {fixed: 0}
    todo = deque([fixed])
    while todo:
        c = todo.popleft()
        for n in neighbours_xy(c):
            if n in goal and n not in layer:
                layer[n] = layer[c] + 1
                todo.append(n)
    return layer


def _void_chooser(occ: set[Coord], goal: set[Coord], layer: dict[Coord, int]):
    """Pick the void to fill among those a walker reaches.

    Prefer voids whose filling keeps every neighbouring void enterable (so the goal is
    assembled without sealing pockets), then the most enclosed (it only gets harder to
    enter), then the nearest.
    """
    settled = occ & goal

    def safe(v: Coord) -> bool:
        after = settled | {v}
        return all(enterable(after, w) or not enterable(settled, w)
                   for w in neighbours_xy(v) if w in goal and w not in occ)

    def choose(found: list[Coord], depth: dict[Coord, int]) -> Coord:
        return max(found, key=lambda v: (safe(v), -layer.get(v, 0),
                                         sum(n in settled for n in neighbours_xy(v)), -depth[v]))
    return choose


_GOAL_OFFSET = {r: go for r, _, _, go in RULE_OFFSETS}


def _end(path: list[tuple[Coord, MoveRule]]) -> Coord:
    """Where a walk ends."""
    (x, y), rule = path[-1]
    gx, gy = _GOAL_OFFSET[rule]
    return (x + gx, y + gy)


def _finish_small(plan: Plan, occ: set[Coord], goal: set[Coord], fixed: Coord,
                  obstacles: set[Coord], exact_limit: int) -> None:
    """The heuristic is stuck: finish with the exact search if the fleet is small."""
    n = len(occ)
    if n > exact_limit:
        plan.reason = (f"complete heuristic stuck after {plan.moves} moves with "
                       f"{len(goal - occ)} voids left (not proven unreachable; "
                       f"{n} modules is too many for the exact search)")
        return
    region = region_around(occ | goal, DEFAULT_MARGIN)
    path, expanded = search_moves(frozenset(occ), frozenset(goal), fixed, obstacles, region,
                                  200_000)
    if path is None:
        if expanded > 200_000:
            plan.reason = "exact search gave up after 200000 configurations"
        else:
            plan.reason = (f"unreachable: the exact search found no plan within {DEFAULT_MARGIN} "
                           f"cells of the configurations ({expanded} configurations explored)")
        return
    plan.notes.append(f"heuristic stuck after {plan.moves} moves; exact search finished "
                      f"with {len(path)} more")
    plan.steps.extend([to_move(conf, m, rule)] for conf, m, rule in path)
    plan.ok = True
