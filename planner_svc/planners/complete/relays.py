"""The relay heuristic (:class:`Heuristic`): chains of walks from electrons to voids,
local exchanges, advances and repairs where no chain exists, and (mixed in from
:mod:`.digging`) hole digging as the last resort. See :mod:`planner_svc.planners.complete`."""

from __future__ import annotations

import heapq
from typing import Callable, Iterable

from ..moves import Path, bfs, can_move, disk, enterable, is_cut, ring2, walk
from ..plan import Plan
from ..rules import Coord, MoveRule, hex_distance, neighbours_xy, xy
from ..windows import (FAR, local_advance, local_exchange, local_repair, surface_distance,
                       surface_field)
from .digging import HOLE_CALLS, Digging
from .steps import play
from .walks import RELAY_LIMIT, Phase, goal_depth

#: Chain cost added per void that a fill would make unenterable.
UNSAFE_PENALTY = 1000
#: Chain cost taken off per unit of void depth (deep voids first, they seal soonest).
DEPTH_BONUS = 0.5
#: Chain cost added per relay (prefer direct walks on ties).
RELAY_PENALTY = 0.1
#: Chain cost taken off per settled neighbour of the void (enclosed voids first).
ENCLOSED_BONUS = 3.0
#: Chains tried per relay step when the cheapest cannot be walked.
RELAY_RETRIES = 8
#: Local repair windows (radius, expansions), tried in turn around a blocked void.
REPAIR_WINDOWS = ((3, 1000), (4, 2000))
#: Blocked cells tried per repair step, and repair searches allowed until the voids
#: left reach a new low (bounds the time; repairs that led to progress earn more).
REPAIR_TARGETS = 4
REPAIR_CALLS = 16
#: Local exchange (:func:`local_exchange`): window radius around a void, expansions.
EXCHANGE_WINDOW = (4, 1000)
#: Local advance (:func:`local_advance`): window radius around an electron, expansions.
ADVANCE_WINDOW = (4, 1500)
#: Local advance searches allowed until the voids left reach a new low.
ADVANCE_CALLS = 24
#: Move cap per module: relays that wander without filling voids must end.
MAX_MOVES_PER_MODULE = 60

class _Looks:
    """What lone walkers reach, kept while the cells it depends on stay as they were.

    A walk over the still structure reads the cells within two of each cell it explores
    (the Table 4-3 rows' substrate and sweep), nothing else: a result stays true until
    one of those cells changes. Between two relay steps a chain moves a few modules, so
    most of the reaches and walks a relay step needs are the last step's."""

    def __init__(self) -> None:
        self._got: dict[tuple, object] = {}
        self._by_cell: dict[Coord, list[tuple]] = {}
        self._occ: frozenset[Coord] = frozenset()

    def sync(self, occ: set[Coord]) -> None:
        """Forget what the cells changed since the last call may have changed."""
        now = frozenset(occ)
        for x in self._occ ^ now:
            for y in disk(x, 2):
                for key in self._by_cell.pop(y, ()):
                    self._got.pop(key, None)
        self._occ = now

    def reach(self, occ: set[Coord], k: Coord, obstacles: set[Coord]
              ) -> dict[Coord, tuple[int, Coord | None, MoveRule | None]]:
        """:func:`bfs` of the module at ``k`` over the rest of ``occ`` (do not modify)."""
        key = ("reach", k)
        got = self._got.get(key)
        if got is None:
            got = bfs(occ - {k}, k, obstacles)
            self._put(key, got, got)
        return got  # type: ignore[return-value]

    def walk_into(self, occ: set[Coord], a: Coord, b: Coord, obstacles: set[Coord]
                  ) -> int | None:
        """Moves of the shortest walk (within :data:`RELAY_LIMIT` cells) of the module at
        ``a`` into the cell of the module at ``b`` once that one has left, or None."""
        key = ("into", a, b)
        if key in self._got:
            return self._got[key]  # type: ignore[return-value]
        explored: set[Coord] = set()
        path = walk(occ - {a, b}, a, {b}, obstacles, limit=RELAY_LIMIT, explored=explored)
        moves = None if path is None else len(path)
        self._put(key, moves, explored)
        return moves

    def _put(self, key: tuple, value: object, cells: Iterable[Coord]) -> None:
        """Keep ``value`` until a cell within two of ``cells`` changes."""
        self._got[key] = value
        for c in cells:
            self._by_cell.setdefault(c, []).append(key)


class Heuristic(Digging, Phase):
    """One forward run of the relay heuristic on ``plan.problem``."""

    def __init__(self, plan: Plan, enclosed_bonus: float = ENCLOSED_BONUS,
                 start: set[Coord] | None = None, holes: bool = False,
                 advance: bool = False, hole_calls: int = HOLE_CALLS,
                 pins: bool = False) -> None:
        super().__init__(plan, {xy(c) for c in plan.problem.initial} if start is None
                         else set(start))
        self.depth = goal_depth(self.goal)
        self.enclosed_bonus = enclosed_bonus
        self.seen = {frozenset(self.occ)}
        self.looks = _Looks()
        self.stats: dict[str, int] = {}
        #: (target, radius) pairs whose local repair failed since the last repair.
        self.repair_failed: set[tuple[Coord, int]] = set()
        self.repair_budget = REPAIR_CALLS
        #: Voids whose local exchange failed since the last one that worked.
        self.exchange_failed: set[Coord] = set()
        #: (electron, configuration) pairs whose local advance failed.
        self.advance_failed: set[tuple[Coord, frozenset[Coord]]] = set()
        #: Window searches made, by what decides them (:func:`window_search`).
        self.window_memo: dict[tuple, Path | None] = {}
        self.advance = advance
        self.advance_budget = ADVANCE_CALLS
        self._init_digging(hole_calls if holes else 0)
        #: The fewest voids so far (fewer is progress: the budgets are renewed).
        self.fewest = len(self.goal - self.occ)
        #: Whether the voids next to a pinned electron wait (:meth:`_waiting`), and
        #: which cells off the goal pin (:meth:`_pinned`).
        self.pins = pins
        self.pinned_at: dict[Coord, bool] = {}

    def run(self, until: Callable[[], bool] | None = None) -> None:
        """Relay until the goal is reached (or ``until()`` holds) or neither a relay
        nor an opening move exists.

        A run that stopped may go on, in the same plan or a copy (:meth:`dig_on`)."""
        goal = self.goal
        max_moves = MAX_MOVES_PER_MODULE * len(goal) + 100
        while self.occ != goal:
            if until is not None and until():
                return
            left = len(goal - self.occ)
            if left < self.fewest:
                # Progress: the repairs that led here earn a fresh budget.
                self.fewest = left
                self.repair_budget = REPAIR_CALLS
                self.advance_budget = ADVANCE_CALLS
            if self.plan.moves > max_moves:
                self.plan.reason = (f"complete heuristic gave up after {self.plan.moves} moves "
                                    f"with {len(goal - self.occ)} voids left")
                return
            if self._relay_step():
                self.stats["relay"] = self.stats.get("relay", 0) + 1
            elif self._exchange_step():
                self.stats["exchange"] = self.stats.get("exchange", 0) + 1
            elif self._advance_step():
                self.stats["advance"] = self.stats.get("advance", 0) + 1
            elif self._repair_step():
                self.stats["repair"] = self.stats.get("repair", 0) + 1
            elif self._hole_step():
                self.stats["hole"] = self.stats.get("hole", 0) + 1
            else:
                self.plan.reason = (f"complete heuristic stuck after {self.plan.moves} moves "
                                    f"with {len(goal - self.occ)} voids left")
                return
        self.plan.ok = True

    def dig_on(self, plan: Plan, hole_calls: int = HOLE_CALLS) -> None:
        """Go on from where a run without digs stopped, now digging (at most
        ``hole_calls`` digs), into ``plan``, a copy of the moves so far: the same plan as
        a run with digs from the start, which only digs where this one stopped."""
        plan.steps = list(self.plan.steps)
        self.plan = plan
        self.hole_budget = hole_calls
        self.run()

    # -- helpers
    def _do_walk(self, path: Path) -> None:
        """Make the rotations of ``path`` (of one or several modules), one per step."""
        self.plan.steps += play(self.occ, path)
        self.seen.add(frozenset(self.occ))

    def _mobile(self, c: Coord, occ: set[Coord] | None = None) -> bool:
        occ = self.occ if occ is None else occ
        return (c != self.fixed and c in occ and can_move(occ, c, self.obstacles)
                and not is_cut(occ, c))

    def _targets(self) -> set[Coord]:
        """The voids (empty goal cells)."""
        return self.goal - self.occ

    def _sealed_by(self, v: Coord, settled: set[Coord]) -> int:
        """How many enterable voids near ``v`` filling it would make unenterable."""
        after = settled | {v}
        ob = self.obstacles
        return sum(1 for w in ring2(v) if w in self.goal and w not in self.occ
                   and not enterable(after, w, ob) and enterable(settled, w, ob))

    def _pinned(self, e: Coord) -> bool:
        """Whether an electron at ``e`` (a cell off the goal) could not rotate once the
        goal were complete around it: it sits in a crack of the goal shape, and each
        void around it filled before it leaves may wall it in."""
        pinned = self.pinned_at.get(e)
        if pinned is None:
            pinned = self.pinned_at[e] = not can_move(self.goal | {e}, e, self.obstacles)
        return pinned

    def _waiting(self) -> set[Coord]:
        """Voids the relays fill only when nothing else is left (they pay as much as
        sealing a void): an opened lake's crater while the lake has voids (filled first,
        it seals the lake again), the cells of an emptied wedge above its lowest void
        (refilled apex first, the peel backwards, else the apex is sealed) and, with
        ``pins``, the voids next to a pinned electron (:meth:`_pinned`) while it is
        there."""
        occ, fill, goal = self.occ, self.wedge_fill, self.goal
        wait = set(self.mouth) - occ if self.lake - occ else set()
        low = min((lv for c, lv in fill.items() if c not in occ), default=None)
        if low is not None:
            wait |= {c for c, lv in fill.items() if lv > low and c not in occ}
        if self.pins:
            for e in occ - goal:
                if self._pinned(e):
                    wait.update(n for n in neighbours_xy(e) if n in goal and n not in occ)
        return wait

    def _relay_step(self) -> bool:
        """Fill one void by the cheapest relay chain, and make its walks.

        A lone walker cannot cross a notch (a free cell with four occupied neighbours: no
        rotation pivots across its mouth), so on a rough surface each module reaches
        only a short stretch of it. Material still flows by relays: a settled module
        walks to a void and a module behind it takes its cell, and so on back to an
        electron. The chain is found by Dijkstra over modules: a module's cost is the
        length of its walk to a void, or of its walk into the cell of a settled module
        that has left (reach recomputed without that module) plus that module's cost.
        """
        occ, goal, obstacles = self.occ, self.goal, self.obstacles
        targets = self._targets()
        if not targets:
            return False
        settled = occ & goal
        wait = self._waiting()
        mobile = [k for k in sorted(occ) if self._mobile(k)]
        self.looks.sync(occ)
        regions = {k: self.looks.reach(occ, k, obstacles) for k in mobile}
        penalty: dict[Coord, float] = {}
        direct: dict[Coord, list[tuple[float, Coord]]] = {}     # module -> (cost, void)
        for k in mobile:
            opts = []
            for c, (d, _, _) in regions[k].items():
                if c in targets and c != k:
                    if c not in penalty:
                        # Voids whose filling seals others wait; enclosed ones go first.
                        penalty[c] = (UNSAFE_PENALTY * (self._sealed_by(c, settled)
                                                        + (c in wait))
                                      - DEPTH_BONUS * self.depth.get(c, 0)
                                      - self.enclosed_bonus * sum(n in settled
                                                             for n in neighbours_xy(c)))
                    opts.append((d + penalty[c], c))
            if opts:
                direct[k] = sorted(opts)
        # Who could take the cell of each settled mobile module once it has left.
        near: dict[Coord, set[Coord]] = {}
        for a, reg in regions.items():
            for c in reg:
                near.setdefault(c, set()).add(a)
        into: dict[Coord, list[tuple[Coord, int]]] = {}
        for b in mobile:
            if b not in goal:
                continue
            cands: set[Coord] = set()
            for c in ring2(b):
                cands |= near.get(c, set())
                if c in occ and hex_distance(b, c) == 1:
                    cands.add(c)
            cands.discard(b)
            cands.discard(self.fixed)
            if not cands:
                continue
            rest = occ - {b}
            for a in sorted(cands):
                if not can_move(rest, a, obstacles) or is_cut(rest, a):
                    continue
                moves = self.looks.walk_into(occ, a, b, obstacles)
                if moves:
                    into.setdefault(b, []).append((a, moves))
        # A chain whose hop cannot be made (e.g. it would repeat a configuration) is
        # banned and the next cheapest chain tried, a few times.
        banned: set[tuple[Coord, Coord]] = set()
        for _ in range(RELAY_RETRIES):
            hop = self._chain_walks(direct, into, banned)
            if hop is None:
                return True
            if hop is False:
                return False
            banned.add(hop)
        return False

    def _chain_walks(self, direct: dict[Coord, list[tuple[float, Coord]]],
                     into: dict[Coord, list[tuple[Coord, int]]],
                     banned: set[tuple[Coord, Coord]]) -> tuple[Coord, Coord] | bool | None:
        """Dijkstra for the cheapest chain avoiding ``banned`` hops, then its walks.
        Returns None when a walk was made, False when there is no chain, else the hop
        that could not be made (nothing moved)."""
        occ, goal, obstacles = self.occ, self.goal, self.obstacles
        inf = float("inf")
        dist: dict[Coord, float] = {}
        nxt: dict[Coord, Coord] = {}            # module -> cell it walks to
        for k, opts in direct.items():
            for cost, c in opts:
                if (k, c) not in banned:
                    dist[k], nxt[k] = cost, c
                    break
        # Dijkstra backwards from the voids.
        heap = [(d, k) for k, d in dist.items()]
        heapq.heapify(heap)
        done: set[Coord] = set()
        while heap:
            d, b = heapq.heappop(heap)
            if b in done or d > dist.get(b, inf):
                continue
            done.add(b)
            for a, w in into.get(b, ()):
                if (a, b) in banned:
                    continue
                if d + w + RELAY_PENALTY < dist.get(a, inf):
                    dist[a] = d + w + RELAY_PENALTY
                    nxt[a] = b
                    heapq.heappush(heap, (dist[a], a))
        electrons = [e for e in occ - goal if e in dist]
        if not electrons:
            return False
        e = min(electrons, key=lambda c: (dist[c], c))
        chain = [e]
        while nxt[chain[-1]] in occ and nxt[chain[-1]] != chain[-1]:
            if len(chain) > len(occ):
                return False
            chain.append(nxt[chain[-1]])
        hops = [(m, nxt[m]) for m in chain]
        moved = False
        for m, target in reversed(hops):
            if m == self.fixed or m not in self.occ or target in self.occ:
                break
            if is_cut(self.occ, m):
                break
            path = walk(self.occ - {m}, m, {target}, obstacles)
            if not path:
                break
            key = frozenset((self.occ - {m}) | {target})
            if key in self.seen and m in goal:
                break
            self._do_walk(path)
            self.seen.add(frozenset(self.occ))
            moved = True
        if moved:
            return None
        return hops[-1]

    def _exchange_step(self) -> bool:
        """Fill a void from an electron a few cells away by a local search
        (:func:`local_exchange`) in a window around the void, nearest pairs first. Voids
        with no electron that near are left to the repairs and digging; a void whose
        search failed waits until an exchange succeeds somewhere."""
        occ, goal = self.occ, self.goal
        electrons = sorted(occ - goal)
        radius, budget = EXCHANGE_WINDOW
        near = []
        for v in self._targets():
            if v not in self.exchange_failed:
                d = min((hex_distance(v, e) for e in electrons), default=radius + 1)
                if d <= radius:
                    near.append((d, v))
        for _, v in sorted(near):
            path = local_exchange(occ, goal, self.fixed, self.obstacles, v, radius, budget,
                                  self.window_memo)
            if path:
                self._do_walk(path)
                self.exchange_failed.clear()
                return True
            self.exchange_failed.add(v)
        return False

    def _advance_step(self) -> bool:
        """Bring an electron nearer the voids when no relay or exchange fills one.

        Distances are along the surface (:func:`surface_field`). An electron walks alone
        to the cell outside the goal it reaches nearest the voids, if that is nearer than
        where it is and seals no void; else a window search (:func:`local_advance`) lets
        settled modules step aside and back so electrons pass a notch. Parked electrons
        pave the rough surface, so the next ones roll further; once near a void, the
        relays and exchanges fill it. No advance repeats a configuration and the window
        searches are budgeted (:data:`ADVANCE_CALLS` per new low of voids left), so
        advancing ends.
        """
        occ, goal, ob = self.occ, self.goal, self.obstacles
        voids = goal - occ
        if not self.advance or not voids:
            return False
        dist = surface_distance(surface_field(occ, voids, ob))
        best: tuple[int, int, Coord, Coord] | None = None
        for e in sorted(occ - goal):
            if not self._mobile(e):
                continue
            here, rest = dist(e), occ - {e}
            for c, (d, _, _) in bfs(rest, e, ob).items():
                if c in goal or dist(c) >= here or (best and (dist(c), d) >= best[:2]):
                    continue
                if frozenset(rest | {c}) in self.seen or self._sealed_by(c, rest):
                    continue
                best = (dist(c), d, e, c)
        if best is not None:
            *_, e, c = best
            path = walk(occ - {e}, e, {c}, ob)
            if path:
                self._do_walk(path)
                return True
        radius, budget = ADVANCE_WINDOW
        here = frozenset(occ)
        for e in sorted(occ - goal, key=lambda c: (dist(c), c)):
            key = (e, here)
            if dist(e) >= FAR or key in self.advance_failed:
                continue
            if self.advance_budget <= 0:
                return False
            self.advance_budget -= 1
            path = local_advance(occ, goal, self.fixed, ob, e, radius, budget, dist, self.seen,
                                 self.window_memo)
            if path:
                self._do_walk(path)
                return True
            self.advance_failed.add(key)
        return False

    def _repair_step(self) -> bool:
        """Fill a blocked void (or free a trapped electron) by a local search that may
        move settled modules out and back (:func:`local_repair`)."""
        if self.repair_budget <= 0:
            return False
        occ, goal = self.occ, self.goal
        voids = sorted((v for v in self._targets() if not enterable(occ, v, self.obstacles)),
                       key=lambda v: (-self.depth.get(v, 0), v))
        trapped = [e for e in sorted(occ - goal) if not self._mobile(e)]
        for radius, budget in REPAIR_WINDOWS:
            for t in (voids + trapped)[:REPAIR_TARGETS]:
                self.repair_budget -= 1
                if (t, radius) in self.repair_failed:
                    continue
                path = local_repair(occ, goal, self.fixed, self.obstacles, t, radius, budget,
                                    self.window_memo)
                if path is None:
                    self.repair_failed.add((t, radius))
                    continue
                if not path:
                    continue
                self._do_walk(path)
                self.repair_failed = set()
                return True
        return False
