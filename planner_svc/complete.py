"""``complete``: a heuristic planner for large fleets that always finishes.

Idea: modules are interchangeable, so only electrons (modules off the goal) need to
move, each to some void (empty goal cell). One electron at a time walks over the
surface of the otherwise still structure to a void:

1. electrons are paired with voids by a minimum-cost assignment on hex distance
   (:func:`planner_svc.bounds.min_cost_assignment`), so the walks add up to little more
   than the lower bound the benchmark compares against; the pairing is repaired, not
   recomputed, when a walk ends on another void than planned;
2. voids are filled deepest first (farthest from the outside of the goal shape) and
   never so that a neighbouring void can no longer be entered (Table 4-3 needs three
   consecutive free sides to roll into a cell), so no pocket is sealed;
3. a walker must not be an articulation point (with it lifted out the rest stays
   connected, so every step of its walk keeps the structure connected as it stays
   latched to a substrate); a local test (its occupied neighbours form one arc)
   decides most cases, a breadth-first search the rest;
4. the walk is a breadth-first search over the cells the lone walker reaches by legal
   rotations (:mod:`planner_svc.rules`) with the rest of the structure still.

When no electron can reach a void, modules already on goal cells may walk to a void
instead (this can open a blocked pocket or free a trapped electron). If the heuristic
is still stuck it retries on the reverse problem (goal to initial, played backwards:
every rotation is undone about the same vertex, sweeping the same cells). If that
fails too, small fleets (``exact_limit`` modules or fewer) fall back to
:mod:`planner_svc.search` from the current configuration, which also proves
unreachability; larger fleets report that the heuristic is stuck, without claiming
unreachability.
"""

from __future__ import annotations

from collections import deque
from typing import Callable

import numpy as np

from .bounds import distance_matrix, min_cost_assignment
from .plan import Plan, Problem
from .rules import (RULE_OFFSETS, Coord, Move, MoveRule, find_move, hex_distance,
                    neighbours_xy, to_move, xy)
from .search import DEFAULT_MARGIN, region_around, search_moves

#: Fleets up to this size fall back to the exact search when the heuristic is stuck.
EXACT_LIMIT = 10
#: Configurations the exact fallback may expand.
EXACT_BUDGET = 200_000
#: How many detours of goal-cell modules the heuristic may make, per module.
UNBLOCK_BUDGET_PER_MODULE = 2

#: How many modules may be parked to dig out pockets, per module.
DIG_BUDGET_PER_MODULE = 4
#: Walk searches per step for assigned pairs and for digging, before the next strategy.
ASSIGNED_TRIES = 8
DIG_TRIES = 12

Path = list[tuple[Coord, MoveRule]]

_GOAL_OFFSET = {r: go for r, _, _, go in RULE_OFFSETS}
_DIRS: tuple[Coord, ...] = ((-1, 1), (0, 1), (1, 0), (1, -1), (0, -1), (-1, 0))


# --- connectivity ------------------------------------------------------------------------
def is_cut(occ: set[Coord], c: Coord) -> bool:
    """Whether removing the module at ``c`` disconnects ``occ``.

    Local test first: if the occupied neighbours of ``c`` form one contiguous arc they
    stay connected to each other around ``c``, so the rest stays connected. Otherwise
    a breadth-first search from one neighbour must reach the others without ``c``.
    """
    x, y = c
    ring = [(x + dx, y + dy) in occ for dx, dy in _DIRS]
    n_occ = sum(ring)
    if n_occ <= 1:
        return False
    # Count the starts of occupied runs around the ring.
    runs = sum(1 for i in range(6) if ring[i] and not ring[i - 1])
    if runs <= 1:
        return False
    nbrs = [(x + dx, y + dy) for (dx, dy), o in zip(_DIRS, ring) if o]
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
    return True


def can_move(occ: set[Coord], c: Coord, obstacles: set[Coord]) -> bool:
    """Whether the module at ``c`` has at least one legal rotation (ignoring connectivity)."""
    x, y = c
    for _, (sx, sy), empties, (gx, gy) in RULE_OFFSETS:
        g = (x + gx, y + gy)
        if g in occ or g in obstacles or (x + sx, y + sy) not in occ:
            continue
        if any((x + ex, y + ey) in occ or (x + ex, y + ey) in obstacles for ex, ey in empties):
            continue
        return True
    return False


# --- walks ---------------------------------------------------------------------------------
def walk(rest: set[Coord], start: Coord, targets: set[Coord], obstacles: set[Coord],
         limit: int | None = None,
         choose: Callable[[list[Coord], dict[Coord, int]], Coord] | None = None
         ) -> Path | None:
    """Shortest walk of a lone module from ``start`` to any cell of ``targets``.

    ``rest`` is the structure without the walker; it must be connected and stays
    still. Returns the rotations as ``(cell before, rule)`` or None. ``limit`` caps the
    number of cells explored. ``choose(found, depth)`` picks among all reachable
    targets (default: the nearest, and the search stops there).
    """
    came: dict[Coord, tuple[Coord, MoveRule] | None] = {start: None}
    depth = {start: 0}
    todo = deque([start])
    found: list[Coord] = []
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
    path: Path = []
    while (step := came[c]) is not None:
        path.append(step)
        c = step[0]
    return path[::-1]


def _end(path: Path) -> Coord:
    """Where a walk ends."""
    (x, y), rule = path[-1]
    gx, gy = _GOAL_OFFSET[rule]
    return (x + gx, y + gy)


# --- fill order ------------------------------------------------------------------------------
def enterable(settled: set[Coord], void: Coord) -> bool:
    """Whether a void can still be entered once its neighbours stop moving.

    Table 4-3: a module rolling into a cell about its substrate arrives from one side
    and needs the two sides after that empty, so the cell's other occupied neighbours
    must all lie within three consecutive sides (the substrate's and the two beyond).
    """
    x, y = void
    ring = [(x + dx, y + dy) in settled for dx, dy in _DIRS]
    return any(not ring[i] and not ring[(i + 1) % 6] and not ring[(i + 2) % 6]
               for i in range(6))


def goal_depth(goal: set[Coord]) -> dict[Coord, int]:
    """Distance of each goal cell from the nearest cell outside the goal.

    Deep voids are filled first: they only get harder to enter as the goal fills up.
    """
    depth: dict[Coord, int] = {}
    todo: deque[Coord] = deque()
    for c in goal:
        if any(n not in goal for n in neighbours_xy(c)):
            depth[c] = 1
            todo.append(c)
    while todo:
        c = todo.popleft()
        for n in neighbours_xy(c):
            if n in goal and n not in depth:
                depth[n] = depth[c] + 1
                todo.append(n)
    return depth


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


# --- the planner -------------------------------------------------------------------------------
def plan_complete(plan: Plan, exact_limit: int = EXACT_LIMIT) -> None:
    """Fill ``plan`` (serial, one move per step); see the module docstring.

    If the heuristic gets stuck going forwards, it also tries the reverse problem
    (goal to initial) and plays that plan backwards, since every move is reversible.
    """
    p: Problem = plan.problem
    forward = Plan(plan.planner, p)
    _Heuristic(forward).run()
    if not forward.ok:
        backward = Plan(plan.planner, Problem(p.goal, p.initial, p.fixed, p.obstacles, p.name))
        _Heuristic(backward).run()
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


class _Heuristic:
    """One forward run of the electron-to-void heuristic on ``plan.problem``."""

    def __init__(self, plan: Plan) -> None:
        p = plan.problem
        self.plan = plan
        self.occ = {xy(c) for c in p.initial}
        self.goal = {xy(c) for c in p.goal}
        self.fixed = xy(p.fixed)
        self.obstacles = {xy(c) for c in p.obstacles}
        self.depth = goal_depth(self.goal)
        self.unblock_budget = UNBLOCK_BUDGET_PER_MODULE * len(self.occ)
        self.seen = {frozenset(self.occ)}
        #: electron -> void it is meant to fill (repaired as walks end elsewhere).
        self.assigned: dict[Coord, Coord] = {}
        #: A sealed void or trapped electron being dug out, and the cells opened for it.
        self.dig_target: Coord | None = None
        self.reserved: set[Coord] = set()
        self.dig_budget = DIG_BUDGET_PER_MODULE * len(self.occ)
        self._assign()

    # -- pairing
    def _assign(self) -> None:
        """Minimum-cost pairing of the current electrons with the current voids."""
        electrons = sorted(self.occ - self.goal)
        voids = sorted(self.goal - self.occ)
        if not electrons:
            self.assigned = {}
            return
        col, _ = min_cost_assignment(distance_matrix(electrons, voids))
        self.assigned = {e: voids[j] for e, j in zip(electrons, col)}

    def _repair(self, start: Coord, end: Coord) -> None:
        """The module at ``start`` now sits on ``end``: keep the pairing consistent."""
        a = self.assigned
        if start in a:                       # an electron moved
            v = a.pop(start)
            if end in self.goal:
                if v != end:
                    # Whoever was to fill ``end`` takes over this electron's void.
                    other = next(e for e, w in a.items() if w == end)
                    a[other] = v
            else:
                a[end] = v                   # parked off the goal: still an electron
        elif end in self.goal:
            # A settled module moved to a void: its old cell is a void now, for the
            # electron that was to fill ``end``.
            other = next(e for e, w in a.items() if w == end)
            a[other] = start
        else:
            a[end] = start                   # a settled module left the goal

    # -- moves
    def _do_walk(self, path: Path) -> None:
        occ, steps = self.occ, self.plan.steps
        start = path[0][0]
        for cell, rule in path:
            # Releases depend on who is next to the walker now, so build each move here.
            mv = to_move(occ, cell, rule)
            steps.append([mv])
            occ.discard(cell)
            occ.add(xy(mv.goal))
        self._repair(start, _end(path))

    def _mobile(self, c: Coord) -> bool:
        return (c != self.fixed and can_move(self.occ, c, self.obstacles)
                and not is_cut(self.occ, c))

    def _safe(self, v: Coord, settled: set[Coord]) -> bool:
        """Filling ``v`` keeps every enterable neighbouring void enterable."""
        after = settled | {v}
        return all(enterable(after, w) or not enterable(settled, w)
                   for w in neighbours_xy(v) if w in self.goal and w not in self.occ)

    def run(self) -> None:
        goal = self.goal
        while self.occ != goal:
            if self.dig_target is not None and self._dig_done():
                self.dig_target, self.reserved = None, set()
            if not (self._assigned_step(unsafe=False) or self._any_step(unsafe=False)
                    or self._assigned_step(unsafe=True) or self._any_step(unsafe=True)
                    or self._unblock_step() or self._dig_step()):
                self.plan.reason = (f"complete heuristic stuck after {self.plan.moves} moves "
                                    f"with {len(goal - self.occ)} voids left")
                return
            self.seen.add(frozenset(self.occ))
        self.plan.ok = True

    def _targets(self) -> set[Coord]:
        """Voids that may be filled now (not the cells dug open around a pocket)."""
        return self.goal - self.occ - self.reserved

    def _assigned_step(self, unsafe: bool) -> bool:
        """Walk one electron to its assigned void, deepest safe void first."""
        settled = self.occ & self.goal
        targets = self._targets()
        dig = self.dig_target
        order = sorted(((e, v) for e, v in self.assigned.items() if v in targets),
                       key=lambda ev: (ev[1] != dig, -self.depth.get(ev[1], 0),
                                       hex_distance(*ev), ev))
        tried = 0
        for e, v in order:
            if not enterable(self.occ, v) or self._safe(v, settled) == unsafe:
                continue
            if not self._mobile(e):
                continue
            path = walk(self.occ - {e}, e, {v}, self.obstacles)
            tried += 1
            if path:
                self._do_walk(path)
                return True
            if tried >= ASSIGNED_TRIES:
                break
        return False

    def _any_step(self, unsafe: bool) -> bool:
        """Walk some electron to the best void it can reach (pairing then repaired)."""
        settled = self.occ & self.goal
        voids = {v for v in self._targets() if unsafe or self._safe(v, settled)}
        if not voids:
            return False
        electrons = [e for e in sorted(self.occ - self.goal) if self._mobile(e)]
        dig = self.dig_target

        def choose(found: list[Coord], depth: dict[Coord, int]) -> Coord:
            return max(found, key=lambda v: (v == dig, self.depth.get(v, 0), -depth[v], v))
        for e in _by_distance_to(electrons, sorted(voids)):
            path = walk(self.occ - {e}, e, voids, self.obstacles, choose=choose)
            if path:
                self._do_walk(path)
                return True
        return False

    def _dig_done(self) -> bool:
        t = self.dig_target
        if t in self.goal:
            return t in self.occ
        return t not in self.occ or self._mobile(t)

    def _dig_step(self) -> bool:
        """Open a sealed void (or free a trapped electron) by parking the nearest movable
        modules outside the goal; the dug cells stay empty until the pocket is filled."""
        if self.dig_budget <= 0:
            return False
        occ = self.occ
        if self.dig_target is None:
            sealed = sorted((v for v in self.goal - occ if not enterable(occ, v)),
                            key=lambda v: (-self.depth.get(v, 0), v))
            trapped = [e for e in sorted(occ - self.goal) if not self._mobile(e)]
            if not sealed and not trapped:
                return False
            self.dig_target = (sealed or trapped)[0]
        t = self.dig_target
        park = {c for c in self._free_shell() if c not in self.goal and hex_distance(c, t) >= 3}
        movers = [c for c in occ if c != t and self._mobile(c)]
        movers.sort(key=lambda c: (hex_distance(c, t), c))
        for k in movers[:DIG_TRIES]:
            path = walk(occ - {k}, k, park, self.obstacles)
            if path:
                if frozenset((occ - {k}) | {_end(path)}) in self.seen:
                    continue
                self._do_walk(path)
                self.dig_budget -= 1
                if k in self.goal:
                    self.reserved.add(k)
                return True
        return False

    def _free_shell(self) -> set[Coord]:
        """Free cells next to the structure (where a walker may stop)."""
        out = set()
        for x, y in self.occ:
            for dx, dy in _DIRS:
                c = (x + dx, y + dy)
                if c not in self.occ and c not in self.obstacles:
                    out.add(c)
        return out

    def _unblock_step(self) -> bool:
        """Detour: a module already on a goal cell walks to a void; its own cell becomes
        the void, possibly one an electron can reach."""
        if self.unblock_budget <= 0:
            return False
        occ = self.occ
        voids = self._targets()
        settled = occ & self.goal
        keepers = [c for c in sorted(settled) if self._mobile(c)]
        for k in _by_distance_to(keepers, sorted(voids)):
            path = walk(occ - {k}, k, voids, self.obstacles)
            if path:
                if frozenset((occ - {k}) | {_end(path)}) in self.seen:
                    continue
                self._do_walk(path)
                self.unblock_budget -= 1
                return True
        return False


def _by_distance_to(cells: list[Coord], targets: list[Coord]) -> list[Coord]:
    """``cells`` ordered by hex distance to their nearest target."""
    if not cells or not targets:
        return cells
    d = distance_matrix(cells, targets).min(axis=1)
    return [cells[i] for i in np.lexsort((np.arange(len(cells)), d))]


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
                                  EXACT_BUDGET)
    if path is None:
        if expanded > EXACT_BUDGET:
            plan.reason = f"exact search gave up after {EXACT_BUDGET} configurations"
        else:
            plan.reason = (f"unreachable: the exact search found no plan within {DEFAULT_MARGIN} "
                           f"cells of the configurations ({expanded} configurations explored)")
        return
    plan.notes.append(f"heuristic stuck after {plan.moves} moves; exact search finished "
                      f"with {len(path)} more")
    plan.steps.extend([to_move(conf, m, rule)] for conf, m, rule in path)
    plan.ok = True
