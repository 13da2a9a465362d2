"""Lone walks: phase 0 (:class:`FrontWalk`, the goal filled row by row on compact
goals) and phase 1 (:class:`AssignWalk`, electrons walk to the voids the bound's
assignment gives them), the walk searches they use, and the fill order (goal depth)
the relays share. See :mod:`planner_svc.planners.complete` for where they fit."""

from __future__ import annotations

import bisect
import heapq
import itertools
from collections import deque

from ..bounds import distance_matrix, electron_void_assignment, min_cost_assignment
from ..moves import (GOAL_OFFSET, Path, bfs, can_move, disk, enterable, is_cut, lone_steps,
                     ring2, walk)
from ..plan import Plan
from ..rules import Coord, MoveRule, hex_distance, neighbours_xy, xy
from .steps import fast_move

#: Cells a relay walk may explore.
RELAY_LIMIT = 400


# --- fill order ------------------------------------------------------------------------------
def goal_depth(goal: set[Coord]) -> dict[Coord, int]:
    """Distance of each goal cell from the nearest cell outside the goal.

    Deep voids are filled first: they only get harder to enter as the goal fills up.
    """
    return layers(goal, {c for c in goal if any(n not in goal for n in neighbours_xy(c))})


def layers(cells: set[Coord], first: set[Coord]) -> dict[Coord, int]:
    """Breadth-first depth inside ``cells`` of each cell reached from ``first`` (depth 1)."""
    depth = dict.fromkeys(first, 1)
    todo: deque[Coord] = deque(first)
    while todo:
        c = todo.popleft()
        for n in neighbours_xy(c):
            if n in cells and n not in depth:
                depth[n] = depth[c] + 1
                todo.append(n)
    return depth

# --- phase 1: assigned walks ------------------------------------------------------------------
#: Cells the bounded cut test may explore before it calls a module a cut vertex (safe:
#: a module wrongly called a cut vertex only waits).
CUT_LIMIT = 40
#: A* expansions allowed per unit of hex distance (plus :data:`WALK_SLACK`) for one walk.
WALK_FACTOR = 6
WALK_SLACK = 60
#: Walks after which an electron that could not go is tried again.
RETRY_WALKS = 8
#: Electrons that may look for their nearest void when no assigned walk is possible.
NEAREST_TRIES = 20


def is_cut_bounded(occ: set[Coord], c: Coord, limit: int = CUT_LIMIT) -> bool:
    """:func:`is_cut` with a search limit (conservative: see there)."""
    return is_cut(occ, c, limit)


def astar_walk(rest: set[Coord], start: Coord, target: Coord, obstacles: set[Coord],
               limit: int) -> Path | None:
    """Shortest walk of a lone module from ``start`` to ``target`` over the still
    structure ``rest`` (A* by hex distance; None after ``limit`` expansions)."""
    tie = itertools.count()
    came: dict[Coord, tuple[Coord, MoveRule] | None] = {start: None}
    cost = {start: 0}
    heap = [(hex_distance(start, target), next(tie), start)]
    expanded = 0
    while heap:
        _, _, c = heapq.heappop(heap)
        if c == target:
            path: Path = []
            while (step := came[c]) is not None:
                path.append(step)
                c = step[0]
            return path[::-1]
        expanded += 1
        if expanded > limit:
            return None
        d = cost[c] + 1
        for rule, g in lone_steps(rest, c, obstacles):
            if d >= cost.get(g, 1 << 30):
                continue
            cost[g] = d
            came[g] = (c, rule)
            heapq.heappush(heap, (d + hex_distance(g, target), next(tie), g))
    return None

class Phase:
    """What every phase works on: the plan it extends, the live occupancy (shared, moved
    in place) and the problem's goal, fixed cell and obstacles as tuples."""

    def __init__(self, plan: Plan, occ: set[Coord]) -> None:
        p = plan.problem
        self.plan = plan
        self.occ = occ
        self.goal = {xy(c) for c in p.goal}
        self.fixed = xy(p.fixed)
        self.obstacles = {xy(c) for c in p.obstacles}


class AssignWalk(Phase):
    """Phase 1: electrons walk alone to the voids the assignment bound gives them.

    The minimum-cost assignment of electrons to voids by hex distance
    (:func:`planner_svc.planners.bounds.min_cost_assignment`, the lower bound's own) pairs them.
    Each step takes the pairs by increasing distance and makes the first walk that is
    possible now: the electron can leave (not the fixed module, has a rotation, not a
    cut vertex by :func:`is_cut_bounded`), its void touches the rest and is
    :func:`enterable`, and A* finds the walk within a budget proportional to the
    distance. Any prefix of walks keeps the remaining pairs an optimal assignment of
    what remains, so when the walks are about as long as the distances the plan is
    near the bound. When no assigned walk is possible an electron walks to the nearest
    void it reaches instead and the two pairs swap voids. The phase stops when neither
    works; the relay heuristic carries on from there.
    """

    def __init__(self, plan: Plan, occ: set[Coord]) -> None:
        super().__init__(plan, occ)
        self.retry: dict[Coord, int] = {}
        self.walks = 0
        electrons = sorted(self.occ - self.goal)
        voids = sorted(self.goal - self.occ)
        self.pair: dict[Coord, Coord] = {}
        if electrons:
            col, _ = electron_void_assignment(electrons, voids)
            self.pair = {e: voids[j] for e, j in zip(electrons, col)}
        # The pairs by increasing distance, kept sorted as pairs go and swap (sorting
        # them for every walk took a tenth of the time on trees of 1000 modules).
        self.order: list[tuple[int, Coord]] = sorted(
            (hex_distance(e, v), e) for e, v in self.pair.items())
        # can_move per electron: it depends on the cells within two of it only, and a
        # walk changes two cells (most electrons of a tree cannot move, and were asked
        # again before every walk: a quarter of the time at 1000 modules).
        self.can: dict[Coord, bool] = {}

    def run(self) -> None:
        while self.pair:
            if not (self._assigned_step(True) or self._nearest_step()
                    or self._assigned_step(False)):
                return

    def _leaves(self, e: Coord) -> bool:
        if e == self.fixed:
            return False
        can = self.can.get(e)
        if can is None:
            can = self.can[e] = can_move(self.occ, e, self.obstacles)
        return can and not is_cut_bounded(self.occ, e)

    def _open(self, rest: set[Coord], v: Coord) -> bool:
        return (any(n in rest for n in neighbours_xy(v)) and v not in rest
                and enterable(rest, v, self.obstacles))

    def _walk(self, e: Coord, path: Path, v: Coord) -> None:
        occ, steps = self.occ, self.plan.steps
        occ.discard(e)
        for cell, rule in path:
            steps.append([fast_move(occ, cell, rule)])
        occ.add(v)
        self.walks += 1
        for c in (e, v):
            for d in disk(c, 2):
                self.can.pop(d, None)
        self._unlist(e)
        del self.pair[e]

    def _unlist(self, e: Coord) -> None:
        order = self.order
        del order[bisect.bisect_left(order, (hex_distance(e, self.pair[e]), e))]

    def _pair(self, e: Coord, v: Coord) -> None:
        """Give ``e`` the void ``v`` (``e`` already unlisted)."""
        self.pair[e] = v
        bisect.insort(self.order, (hex_distance(e, v), e))

    def _assigned_step(self, use_memo: bool) -> bool:
        moves = self.walks
        pair = self.pair
        for _, e in self.order:
            if use_memo and self.retry.get(e, -1) > moves:
                continue
            v = pair[e]
            if not self._leaves(e):
                self.retry[e] = moves + RETRY_WALKS
                continue
            rest = self.occ - {e}
            if self._open(rest, v):
                path = astar_walk(rest, e, v, self.obstacles,
                                  WALK_FACTOR * hex_distance(e, v) + WALK_SLACK)
                if path:
                    self._walk(e, path, v)
                    return True
            self.retry[e] = moves + RETRY_WALKS
        return False

    def _nearest_step(self) -> bool:
        """Some electron walks to the nearest void it reaches; the pairs swap voids."""
        pair = self.pair
        owner = {v: e for e, v in pair.items()}
        tried = 0
        for _, e in self.order:
            if tried >= NEAREST_TRIES:
                break
            if not self._leaves(e):
                continue
            tried += 1
            rest = self.occ - {e}
            path = walk(rest, e, set(owner), self.obstacles, limit=RELAY_LIMIT * 4)
            if not path:
                continue
            cell, rule = path[-1]
            gx, gy = GOAL_OFFSET[rule]
            v = (cell[0] + gx, cell[1] + gy)
            other = owner[v]
            mine = pair[e]
            if other != e:
                self._unlist(other)
                self._unlist(e)
                self._pair(other, mine)
                self._pair(e, v)
            self._walk(e, path, v)
            return True
        return False


# --- phase 0: front walks (smooth shapes) -------------------------------------------------------
#: Hex radius around a filled void or emptied cell within which cached void checks are redone.
FRONT_RADIUS = 5
#: Layers ahead of the lowest unfilled one a void may be filled in.
FRONT_SLACK = 1000
#: Walks after which a (electron, void) walk that failed may be tried again.
FRONT_RETRY = 4
#: A* expansions per walk: :data:`WALK_FACTOR` per unit of hex distance plus this.
FRONT_WALK_SLACK = 600
#: Choose the electron for a void by walk length over the surface (else by hex distance).
FRONT_SURFACE = True



class FrontWalk(Phase):
    """Phase 0: fill the goal row by row, each void by a lone walk of a peelable
    electron.

    Voids are layered by breadth-first distance inside the goal from the cells that
    stay (those in both configurations, connected to the fixed module; layer 0; other
    pieces of the overlap, possible when a partial row breaks convexity, would wall in
    slots two cells wide that no lone walker can fill, so their modules count as
    electrons and their cells as voids). A *row* is a connected piece of one layer. A
    void may be filled when:

    * every neighbour of a lower layer is filled (rows grow outward, no pocket forms);
    * it touches a filled cell of its own row, or its row is still empty and it has the
      most lower neighbours of the row (a concave corner: filled after a neighbour it
      would have four occupied neighbours and could not be entered). One front per
      row, so no two fronts meet in a notch;
    * it is :func:`enterable` now, filling it leaves every nearby void that the settled
      cells let be entered enterable, and no free cell outside the goal next to it
      becomes a notch (a walker could not pass it: this happens where a growing row
      meets electrons at a concave angle; it clears when they leave).

    When no void qualifies the last rule, then the one-front rule, is dropped until a
    walk is made. For the first void that qualifies (by layer, then hex distance to its
    assigned electron), a breadth-first search from the void gives walk lengths to all
    movable electrons (moves are reversible); the electron taken is the one whose walk
    plus the change of the assignment's cost when it swaps partners with the void's
    electron is least (the assignment, the lower bound's own, stays near optimal and
    walks near their hex distance). The walk itself is A* by hex distance over the
    surface. Movable electrons (not fixed, with a rotation) are tracked incrementally:
    a rotation depends only on cells within distance two of the mobile, so only those
    around the two changed cells are rechecked; the (bounded) cut test runs only for
    the candidates about to walk.
    """

    def __init__(self, plan: Plan, occ: set[Coord]) -> None:
        super().__init__(plan, occ)
        self.walks = 0
        # The cells in both configurations that are connected (through such cells) to
        # the fixed module stay; other pieces of the overlap (they exist when a partial
        # row breaks convexity) would wall in narrow slots between them, which no lone
        # walker can fill, so their modules move out and back like electrons.
        both = self.goal & occ
        base = {self.fixed} if self.fixed in both else set()
        todo: deque[Coord] = deque(base)
        while todo:
            c = todo.popleft()
            for n in neighbours_xy(c):
                if n in both and n not in base:
                    base.add(n)
                    todo.append(n)
        stray = both - base if base else set()
        electrons = sorted((occ - self.goal) | stray)
        voids = sorted((self.goal - occ) | stray)
        self.pair: dict[Coord, Coord] = {}
        if electrons:
            if stray:                                   # nobody is paired with itself
                cost = distance_matrix(electrons, voids)
                vi = {v: j for j, v in enumerate(voids)}
                for i, e in enumerate(electrons):
                    if e in vi:
                        cost[i, vi[e]] = 1 << 20
                col, _ = min_cost_assignment(cost)
            else:                                       # the lower bound's own
                col, _ = electron_void_assignment(electrons, voids)
            self.pair = {e: voids[j] for e, j in zip(electrons, col)}
        self.owner = {v: e for e, v in self.pair.items()}
        # Layers: breadth-first distance inside the goal from the cells that stay.
        self.layer: dict[Coord, int] = {}
        for c in base:
            self.layer[c] = 0
            todo.append(c)
        while todo:
            c = todo.popleft()
            for n in neighbours_xy(c):
                if n in self.goal and n not in self.layer:
                    self.layer[n] = self.layer[c] + 1
                    todo.append(n)
        # Rows: connected pieces of one layer; each is filled from one seed outward.
        self.comp: dict[Coord, int] = {}
        self.comp_filled: list[int] = []       # cells filled per row
        for v in voids:
            if v in self.comp:
                continue
            k = len(self.comp_filled)
            self.comp_filled.append(0)
            self.comp[v] = k
            todo = deque([v])
            while todo:
                c = todo.popleft()
                for n in neighbours_xy(c):
                    if (n not in self.comp and n in self.owner
                            and self.layer[n] == self.layer[v]):
                        self.comp[n] = k
                        todo.append(n)
        # Lower-layer neighbours of each void: a row's seed is one with the most (a
        # concave corner of the row below: filled after its neighbours it would seal).
        self.lower = {v: sum(self.layer.get(n, 1 << 30) < self.layer[v] for n in neighbours_xy(v))
                      for v in voids}
        self.comp_lower = [0] * len(self.comp_filled)
        for v in voids:
            k = self.comp[v]
            self.comp_lower[k] = max(self.comp_lower[k], self.lower[v])
        self.movable = {e for e in electrons if e != self.fixed
                        and can_move(occ, e, self.obstacles)}
        self.not_ready: set[Coord] = set()          # voids failing the local checks
        self.failed: dict[tuple[Coord, Coord], int] = {}
        self.relax = 0          # 0: all rules, 1: notches allowed, 2: also second fronts
        self.slack = FRONT_SLACK
        self.surface = FRONT_SURFACE

    def run(self) -> bool:
        while self.pair:
            if not self._step():
                if self.relax >= 2:
                    return False
                # Stuck: let notches form outside the goal, then let a row have a
                # second front, rather than stop; back to the strict rules after a walk.
                self.relax += 1
                self.not_ready.clear()
            elif self.relax:
                self.relax = 0
                self.not_ready.clear()
        return True

    def _ready(self, v: Coord) -> bool:
        """Whether ``v`` may be filled now (see the class docstring)."""
        occ, layer = self.occ, self.layer
        if v in occ:
            return False                    # a stray module has not left yet
        lv = layer[v]
        same = False
        for n in neighbours_xy(v):
            ln = layer.get(n)
            if ln is None:
                continue
            if ln < lv and n not in occ:
                return False                # a lower neighbour is still a void
            if ln == lv and n in occ:
                same = True
        if not same:
            k = self.comp[v]
            if self.relax < 2 and (self.comp_filled[k] or self.lower[v] < self.comp_lower[k]):
                return False                # one front per row, from its innermost corner
        ob = self.obstacles
        if not enterable(occ, v, ob):
            return False
        # No nearby void may become unenterable (judged on the settled cells: the
        # electrons nearby will leave).
        settled = {c for w in ring2(v) for c in disk(w, 3) if c in occ and c in self.goal}
        after = settled | {v}
        if any(w in self.owner and not enterable(after, w, ob)
               and enterable(settled, w, ob) for w in ring2(v)):
            return False
        if self.relax == 0:
            # Nor may a free cell outside the goal become a notch (four or more occupied
            # neighbours): walkers could not pass it, e.g. where a growing goal region
            # meets electrons at a concave angle. It clears when the electrons leave.
            for w in neighbours_xy(v):
                if w not in occ and w not in self.goal:
                    k = sum(n in occ for n in neighbours_xy(w))
                    if k >= 3:
                        return False
        return True

    def _electron_for(self, v: Coord) -> Coord | None:
        """The partner of ``v`` if it can leave, else the cheapest swap."""
        e0 = self.owner[v]
        occ = self.occ
        if e0 in self.movable and not is_cut_bounded(occ, e0):
            return e0
        base = hex_distance(e0, v)
        cands = sorted(((hex_distance(e, v) + hex_distance(e0, self.pair[e])
                         - base - hex_distance(e, self.pair[e]), e) for e in self.movable))
        for _, e in cands[:12]:
            if not is_cut_bounded(occ, e):
                return e
        return None

    def _electron_by_surface(self, v: Coord) -> Coord | None:
        """The movable electron that is cheapest for ``v`` counting its walk over the
        surface: walk lengths from a breadth-first search from ``v`` (moves are
        reversible), plus what swapping partners adds to the assignment."""
        occ, pair = self.occ, self.pair
        e0 = self.owner[v]
        reach = bfs(occ, v, self.obstacles)
        cands = []
        for e in self.movable:
            best = min((reach[f][0] for f in neighbours_xy(e) if f in reach), default=None)
            if best is None:
                continue
            swap = 0 if e == e0 else (hex_distance(e0, pair[e]) - hex_distance(e, pair[e]))
            cands.append((best + 1 + swap, e != e0, e))
        cands.sort()
        tried = 0
        for _, _, e in cands:
            if self.failed.get((e, v), -1) > self.walks:
                continue                    # its walk failed lately: the next one
            if not is_cut_bounded(occ, e):
                return e
            tried += 1
            if tried >= 12:
                break
        return None

    def _step(self) -> bool:
        owner, layer = self.owner, self.layer
        low = min(layer[v] for v in owner)
        front = [v for v in owner if layer[v] <= low + self.slack and v not in self.not_ready]
        front.sort(key=lambda v: (layer[v], hex_distance(v, owner[v]), v))
        for v in front:
            if not self._ready(v):
                self.not_ready.add(v)
                continue
            e = self._electron_by_surface(v) if self.surface else self._electron_for(v)
            if e is None:
                continue
            if self.failed.get((e, v), -1) > self.walks:
                continue
            occ = self.occ
            occ.discard(e)
            d = hex_distance(e, v)
            path = astar_walk(occ, e, v, self.obstacles, WALK_FACTOR * d + FRONT_WALK_SLACK)
            if not path:
                occ.add(e)
                self.failed[(e, v)] = self.walks + FRONT_RETRY
                continue
            self._walk(e, path, v)
            return True
        return False

    def _walk(self, e: Coord, path: Path, v: Coord) -> None:
        occ, steps = self.occ, self.plan.steps
        for cell, rule in path:                    # occ is the rest (walker lifted out)
            steps.append([fast_move(occ, cell, rule)])
        occ.add(v)
        self.walks += 1
        self.comp_filled[self.comp[v]] += 1
        # Swap partners so that e takes v (a no-op when v was e's own).
        v0, e0 = self.pair.pop(e), self.owner.pop(v)
        if e0 != e:
            self.pair[e0] = v0
            self.owner[v0] = e0
        # Local updates: rotations and void checks depend on nearby cells only.
        for c in disk(e, 2) + disk(v, 2):
            if c in self.pair and c != self.fixed:
                if can_move(occ, c, self.obstacles):
                    self.movable.add(c)
                else:
                    self.movable.discard(c)
        self.movable.discard(e)
        for c in disk(e, FRONT_RADIUS) + disk(v, FRONT_RADIUS):
            self.not_ready.discard(c)
