"""``complete``: a heuristic planner for fleets of any size that aims to always finish.

It finishes on every instance of the benchmark's four families (convex, sparse, Eden
and scrambled, up to 1000 modules) and on small fleets (the exact search takes over).
Large rough blobs (Eden, 1000 modules) take a minute or so and long plans, through the last
resort below, and not all finish (of seeds 0-4, 0, 2 and 3 do): on seeds 1 and 4 the
relays wall voids into lakes, and opening them leaves 15-41 voids. Where it does not
finish it says "stuck" and never claims unreachability.

Modules are interchangeable, so only electrons (modules off the goal) need to move,
each to some void (empty goal cell).

Phase 0 (:class:`_FrontWalk`), on compact goals (:func:`compact`), fills the goal row by
row outward from the cells already in place, each void by a lone walk (A* over the
surface) of a peelable electron, chosen by walk length and the lower bound's own
minimum-cost assignment; the row order keeps every void enterable and every free cell
passable. It solves hex-convex shapes (:func:`planner_svc.bounds.random_convex_problem`)
up to 1000 modules in a second or two, with plans about 1.1-1.5x the bound. When it
finishes on a large fleet its plan is kept; otherwise the phases below start over.

Phase 1 (:class:`_AssignWalk`) pairs electrons with voids by the lower bound's own
minimum-cost assignment and walks them alone (A* over the surface), shortest pairs
first, an electron going to the nearest void it reaches when its own is out of reach.
On sparse shapes (:func:`planner_svc.bounds.random_sparse_problem`) it finishes on its
own. When it does not, the relay heuristic below runs from the start (it does better
on compact shapes) and, on fleets of :data:`SMOOTH_LIMIT` modules or fewer or when that
is stuck, also from where phase 1 stopped. Fleets of :data:`COMPARE_LIMIT` modules or
fewer run every phase. Candidates are compared as they will be played: shortened by
:mod:`planner_svc.shorten` (detours dropped).

Before the relays, fleets of more than :data:`SMOOTH_LIMIT` modules whose assignment
bound is at most :data:`DESCENT_REACH` moves per electron (a local rearrangement, as the
scrambled blobs: 2-3) *descend the bound* (:mod:`planner_svc.descent`): moves that each
lower the assignment bound by one, none sealing a void or freezing an electron, short
window searches where no move does, and wider ones that fill the last few voids; the
relays go on from where it stops. When they reach the goal that plan is kept (scrambled
blobs of 1000 modules, seeds 0-19: on 15, e.g. seed 0 344 moves instead of 423 and seed
9 339 instead of 1384). If not, a few digs from where it stopped come next (holes dug
open and refilled), kept when the plan is at most :data:`DUG_EARLY` times the bound;
otherwise everything below runs from the start. Where the relays are stuck too, digging
on from where the descent stopped is kept when it is at most :data:`DUG_KEEP` times the
bound (seeds 0-39: 6 of the 10 that get there, e.g. seed 6 259 moves instead of 646, in
10 s instead of 27); otherwise it is one more try of the last resort.

Under Table 4-3 a lone walker cannot cross a
notch of the surface (a free cell with four occupied neighbours: no rotation pivots
across its mouth), so on a rough structure each module reaches only a short stretch
of the surface. Material still flows by *relays*:

1. every movable module (not the fixed one, not an articulation point -- a local test
   that its occupied neighbours form one arc decides most cases, a breadth-first
   search the rest -- and with a legal rotation) gets its reach: a breadth-first search
   over the cells it reaches by legal rotations (:mod:`planner_svc.rules`) with the
   rest still; with it lifted out the rest stays connected, so every step of its walk
   keeps the structure connected as it stays latched to a substrate;
2. Dijkstra over modules, backwards from the voids, finds the cheapest chain
   electron -> settled module -> ... -> void: a settled module walks to a void, the
   module behind it walks into the cell it left, and so on back to an electron. The
   cost is the walks' length, plus a large penalty for a fill that makes a nearby void
   unenterable (no pocket is sealed while another choice exists), minus a bonus for
   enclosed and deep voids (they only get harder to enter);
3. the chain's walks are made from the void end, each re-searched on the current
   structure;
4. when no chain exists, a void with an electron at most four cells away is filled by
   a best-first search in a window around it (:func:`local_exchange`): the electron is
   often walled in, or the void behind a notch, and settled modules stepping aside and
   back let the two trade places (Eden blobs of 10 modules: mean 1.41x the bound
   instead of 1.81x; scrambled blobs of 100: at most 2.1x instead of 17.8x);
5. on fleets of more than :data:`SMOOTH_LIMIT` modules, electrons far from every void
   *advance* (:meth:`_Heuristic._advance_step`): one walks alone to the cell outside
   the goal nearest the voids along the surface (:func:`surface_field`), or a window
   search (:func:`local_advance`) lets settled modules step aside so electrons pass a
   notch. Parked electrons pave the rough surface for the next ones, until relays and
   exchanges take over (a scrambled blob of 1000 modules: solved, 689 moves in about
   6 s, where the heuristic stopped 4 voids short; Eden blobs of 1000: 19 voids left
   instead of 48). On smaller fleets the smoothed shapes below do better;
6. failing that, a small best-first search in a window around a blocked void (or
   trapped electron) may move settled modules out and back (:func:`local_repair`),
   pushing the vacancy out to the surface.

When the cheapest chain cannot be walked (e.g. it would repeat a configuration) the
next cheapest is tried (:data:`RELAY_RETRIES`).

If the heuristic is stuck it retries on the reverse problem (goal to initial, played
backwards: every rotation is undone about the same vertex, sweeping the same cells).
If that is stuck too, the relay heuristic runs once more as a last resort with *hole
digging* (:meth:`_Heuristic._hole_step`): a hole (voids no movable electron reaches,
e.g. enclosed by a frozen interior) or a walled-in electron is dug out by a peel planned
on the structure with the hole filled -- movable modules (at most three neighbours, not
cut vertices, also in the real structure) inside a hexagonal ball that reaches from
beyond the nearest open surface to the hole walk one by one to parking cells outside
the goal, until every hole cell has been peeled; when the crater's walls end flat (a flat
face rotates only at its ends), the movable module nearest to the hole is peeled
instead, so a face is eaten from its end inwards -- then played for real: the crater's
peels forward, then the whole peel backwards (every move is reversible), with an
electron (or a waiting crater module, leaving a surface void) taking each hole cell.
Each walk is re-searched on the current structure; a fill that fails is rolled back.
A hole's first dig takes the first peel found; when the same cells are dug again, wider
and deeper craters and other parkings are tried in turn (:data:`HOLE_DIGS`): holes a
few cells deep in the bulk need them, and trying them first makes the plans longer. A
walled-in electron is dug out once per cell per set of voids (freed electrons that fill
nothing are walled in again elsewhere, and digs went round in circles). A hole of more
than :data:`HOLE_MAX` voids (a *lake*, walled in by the relays) is not refilled but
opened for good (:meth:`_Heuristic._open_lake`): a crater to the lake's shore module with
the thinnest wall, its modules parked outside the goal; the relays then fill the crater's
cells last while lake voids remain (filled first, they seal the lake again), and another
lake is opened only once fewer voids are left than when the last one was. When no dig
works, a walled-in electron is freed by a detour (:meth:`_Heuristic._clear_wedge`): the
relays play towards the goal with a 120-degree :func:`wedge` of the structure at the
electron traded for a coat of parking cells, until the electron has left its cell, and
then refill the wedge apex first. Under a flat face only a row's ends peel, so only a
corner reaches a module in the bulk; the relays carry the wedge's modules past the
notches of its rough far side, where lone walks to parking cells stop.
These plans are long (Eden blobs of 100 modules: up to 8x the bound, 4.7x once
:mod:`planner_svc.shorten` has dropped their detours) but reach the goal.
The same is also tried between *smoothed* shapes (:func:`smoothed_plan`): the notches
of the start and of the goal are filled first by local repairs (:func:`smooth`; the
goal's smoothing is played backwards at the end), so fewer notches stop the walkers, the
relays go further and less is dug; the shorter plan is kept (Eden blobs of 100 modules:
3.8x the bound on two of three seeds; on fleets over :data:`SMOOTH_LIMIT` modules, with
advances and up to :data:`HOLE_CALLS_LARGE` digs). On those fleets, unless voids are
walled in (below), the relays also run again, digging where they stop, with the voids
next to a *pinned* electron waiting while it is there (:meth:`_Heuristic._pinned`: with
the goal complete around it, it could not rotate; relays that stopped had often walled
such electrons into cracks of the goal: scrambled blobs of 1000 modules, seed 1: 680
moves instead of 1706), and the shortest of the three plans is kept. On those larger
fleets, relays that
stop with more than :data:`FEW_VOIDS` voids left have walled voids in: the relays from
where phase 1 stopped and on the reverse problem are skipped, the smoothed shapes go
first and plain digging runs only when they fail (Eden blobs of 1000 modules: seeds 0
and 2 solved that way, seed 3 by the plain digging after, 6.3-10.6x the bound once
shortened, 52-90 s). If that fails too, small fleets
(``exact_limit`` modules or fewer) fall back to
:mod:`planner_svc.search` from the current configuration, which also proves
unreachability (moves are reversible, so unreachable from there is unreachable from
the start); larger fleets report that the heuristic is stuck, without claiming
unreachability.

The plan kept is shortened once more and re-planned in small windows
(:func:`planner_svc.shorten.replan_windows`: stretches of moves inside a disk of radius
2-4 replaced by the fewest rotations there, every other round on the plan played
backwards; scrambled blobs of 1000 modules: 19-32% fewer moves, for up to 13 s). Last,
on fleets of :data:`FEWEST_LIMIT` modules or fewer, the exact search looks for a plan
with fewer moves than that
(:func:`planner_svc.search.fewer_moves`, at most :data:`FEWEST_BUDGET` configurations,
stopping as soon as none can be shorter): the benchmark's Eden and scrambled instances
of 10 modules get the fewest, and on thesis-12 it proves that the 18 moves the windows
leave (the heuristics plan 19) are the fewest.
"""

from __future__ import annotations

import bisect
import functools
import heapq
import itertools
from collections import deque
from typing import Callable, Iterable, Iterator

from bus.lattice import NEIGHBOUR_OFFSET, Cell, Side

from .bounds import (assignment_lower_bound, distance_matrix, electron_void_assignment,
                     min_cost_assignment)
from .descent import descend
from .plan import Plan, Problem
from .rules import (RULE_OFFSETS, SIDE_OFFSETS, Coord, Move, MoveRule, find_move,
                    hex_distance, is_connected, neighbours_xy, to_move, xy)
from .moves import (GOAL_OFFSET, Path, bfs, can_move, disk, enterable, is_cut, lone_steps,
                    ring2, walk)
from .search import DEFAULT_MARGIN, fewer_moves, search_from
from .shorten import shorten
from .windows import (FAR, local_advance, local_exchange, local_repair, surface_distance,
                      surface_field)

#: Fleets up to this size fall back to the exact search when the heuristic is stuck.
EXACT_LIMIT = 10
#: Configurations the exact fallback may expand.
EXACT_BUDGET = 200_000
#: Fleets up to this size also look for a plan with fewer moves by the exact search, of at
#: most FEWEST_BUDGET configurations (thesis-12: 19 moves become 18, in 1720).
FEWEST_LIMIT = 12
FEWEST_BUDGET = 2500
#: Large fleets descend the bound first (:mod:`planner_svc.descent`) when it is at most
#: this many moves per electron.
DESCENT_REACH = 4
#: Where the descent and the relays are both stuck, digging on from where the descent
#: stopped is kept at once if, shortened, it is at most this many times the bound
#: (scrambled blobs of 1000 modules, seeds 0-39: 6 of 10 such plans were 2.0-3.3x, and
#: the last resort's other tries beat none of them; the other 4 were 3.8-8.7x, and the
#: smoothed run beat three. Seeds 40-59: kept on five, one of them 344 moves where the
#: reverse problem's relays, which run after, would have made 306).
DUG_KEEP = 3.5
#: Where the descent's relays are stuck, digging on from where the descent stopped (at
#: most DUG_EARLY_CALLS digs) is kept before any other relays run if, shortened, it is
#: at most this many times the bound. Scrambled blobs of 1000 modules, seeds 0-59: kept
#: on seeds 1, 6, 21, 40 and 55 (1.8-2.3x, 1-5 digs, 0.04-0.5 s). Seed 21 takes 276 moves
#: instead of the 314 of the relays from the start; the others had been dug from there
#: anyway once those relays stopped (1.5-2 s each). Seeds 18, 29 and 31 (2.7-3.1x) and 30
#: (3.0x; the relays from the start make 285 moves, 1.7x) are left to them, as before.
#: On seed 23 the five digs fail (4-5 s lost).
DUG_EARLY = 2.5
DUG_EARLY_CALLS = 5
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
#: Cells a relay walk may explore.
RELAY_LIMIT = 400
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
#: Hole digging (last resort, :meth:`_Heuristic._hole_step`): planned fills per run,
#: most voids per hole (larger ones are lakes, opened instead), peels per hole beyond its
#: cells, least distance of a parking cell from the aimed hole cell, electrons tried per
#: hole cell (and shore modules per lake), modules tried per peel.
HOLE_CALLS = 24
#: Digs on the smoothed shapes of fleets over SMOOTH_LIMIT modules (the last resort there).
HOLE_CALLS_LARGE = 100
#: On those fleets, relays stopped with more than this many voids left have walled voids
#: in: only digging is tried, through smoothed shapes first. With this many or fewer the
#: other relay runs go first, then digging both ways (the shorter plan is kept).
FEW_VOIDS = 4
HOLE_MAX = 12
HOLE_PEELS = 80
HOLE_PARK = 3
HOLE_ELECTRONS = 8
HOLE_TRY = 30
#: The crater is a hexagonal ball centred ``width`` cells beyond the open cell nearest
#: to the aimed hole cell, reaching ``deep`` cells past it; modules within
#: HOLE_PARK_GAP of it may peel too (a flat row peels from its end), and parking cells
#: are preferably farther. The ``(width, deep)`` of HOLE_CRATERS are tried in turn: a
#: hole a few cells deep in the bulk needs the wider, deeper balls (one whose face lies
#: along a flat surface ends flat, and which one does depends on the surface).
HOLE_CRATERS = ((3, 2), (5, 4), (8, 4))
HOLE_PARK_GAP = 3
#: When the crater's walls end flat, the peel goes nearest first
#: (:meth:`_Heuristic._peel_nearest`): modules at most HOLE_REACH from a cell still to
#: peel, at most HOLE_NEAR_PEELS peels.
HOLE_REACH = 12
HOLE_NEAR_PEELS = 300
#: Parking cells the nearest-first peel prefers, tried in turn: any (0: the nearest), or
#: at least this far from the cells still to peel. Parked near, modules wall in the face
#: being eaten; parked far, they may block the way elsewhere, so a fill that fails with
#: one is tried with the next (Eden 1000, seed 3: holes 2-4 cells deep in the bulk).
HOLE_PARK_FAR = (0, 10, 14)
#: The order the dig tries them in: the smallest craters first (the plans stay short).
HOLE_DIGS = (("crater", HOLE_CRATERS[0]), ("nearest", HOLE_PARK_FAR[0]),
             *(("crater", c) for c in HOLE_CRATERS[1:]),
             *(("nearest", f) for f in HOLE_PARK_FAR[1:]))
#: The last resort for a walled-in electron (:meth:`_Heuristic._clear_wedge`): the relays
#: empty a 120-degree wedge of the structure at it, of at most WEDGE_MAX modules.
WEDGE_MAX = 200
#: Smoothing (:func:`smooth`, tried before digging on fleets up to SMOOTH_LIMIT modules):
#: local repair window radius and expansions per notch.
SMOOTH_LIMIT = 300
SMOOTH_WINDOW = (3, 1500)
#: Move cap per module: relays that wander without filling voids must end.
MAX_MOVES_PER_MODULE = 60

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
#: Fleets up to this size also try the relay heuristic when phase 1 succeeds, keeping
#: the shorter plan.
COMPARE_LIMIT = 30


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


_SIDE_RELEASE = tuple((off, side.facing.joints) for side, off in
                      ((s, NEIGHBOUR_OFFSET[s]) for s in Side))
_RULE_PARTS = {r: (so, go) for r, so, _, go in RULE_OFFSETS}


def play(occ: set[Coord], path: Path) -> list[list[Move]]:
    """Make the rotations of ``path`` (of one or several modules) on ``occ``, in place;
    returns them as serial steps. Releases depend on who is next to the mobile at that
    moment, so each move is built on the structure as it is then."""
    steps: list[list[Move]] = []
    for cell, rule in path:
        mv = to_move(occ, cell, rule)
        steps.append([mv])
        occ.discard(cell)
        occ.add(xy(mv.goal))
    return steps


#: Per Table 4-3 row: substrate and goal offsets, and the sides (offset, joints) whose
#: neighbours release (every side but the substrate's; the goal's is free anyway).
_RULE_RELEASE = {r: (so, go, tuple((off, joints) for off, joints in _SIDE_RELEASE if off != so))
                 for r, (so, go) in _RULE_PARTS.items()}


@functools.lru_cache(maxsize=1 << 16)
def _cell(x: int, y: int) -> Cell:
    return Cell(x, y)


def fast_move(rest: set[Coord], mobile: Coord, rule: MoveRule) -> Move:
    """:func:`planner_svc.rules.to_move` for a walker at ``mobile`` over ``rest`` (the
    structure without the walker), with the side tables precomputed: the same Move."""
    (sx, sy), (gx, gy), sides = _RULE_RELEASE[rule]
    x, y = mobile
    release = tuple((_cell(x + dx, y + dy), j) for (dx, dy), joints in sides
                    if (x + dx, y + dy) in rest for j in joints)
    return Move(_cell(x, y), _cell(x + gx, y + gy), rule.joint, rule.direction,
                _cell(x + sx, y + sy), release)


class _Phase:
    """What every phase works on: the plan it extends, the live occupancy (shared, moved
    in place) and the problem's goal, fixed cell and obstacles as tuples."""

    def __init__(self, plan: Plan, occ: set[Coord]) -> None:
        p = plan.problem
        self.plan = plan
        self.occ = occ
        self.goal = {xy(c) for c in p.goal}
        self.fixed = xy(p.fixed)
        self.obstacles = {xy(c) for c in p.obstacles}


class _AssignWalk(_Phase):
    """Phase 1: electrons walk alone to the voids the assignment bound gives them.

    The minimum-cost assignment of electrons to voids by hex distance
    (:func:`planner_svc.bounds.min_cost_assignment`, the lower bound's own) pairs them.
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



class _FrontWalk(_Phase):
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


#: Mean number of occupied neighbours per goal cell from which a goal counts as compact
#: (a tree has less than two; hex-convex shapes have five or more).
COMPACT_DEGREE = 3.0


def compact(goal: set[Coord]) -> bool:
    """Whether ``goal`` is compact enough for front walks (:class:`_FrontWalk`): rows to
    fill rather than branches to follow (on trees walks along the rows' order go far
    around the branches; the assigned walks do better there)."""
    links = sum(n in goal for c in goal for n in neighbours_xy(c))
    return bool(goal) and links >= COMPACT_DEGREE * len(goal)


def _local(p: Problem) -> bool:
    """Whether the assignment bound per electron is at most :data:`DESCENT_REACH`: each
    void is a few cells from its electron, as on scrambled blobs (2-3 cells; Eden blobs
    8-20, where bound descent spends its allowance and stops)."""
    electrons = len({xy(c) for c in p.initial} - {xy(c) for c in p.goal})
    return electrons > 0 and assignment_lower_bound(p.initial, p.goal) <= DESCENT_REACH * electrons


def _descended(planner: str, p: Problem, advance: bool) -> _Heuristic:
    """Bound descent (:func:`planner_svc.descent.descend`), then the relays from where it
    stopped (returned: their plan is ok if they reached the goal; if not, the last resort
    may dig on from there)."""
    initial = {xy(c) for c in p.initial}
    occ = set(initial)
    path, escapes, fills = descend(occ, {xy(c) for c in p.goal}, xy(p.fixed),
                                   {xy(c) for c in p.obstacles})
    plan = Plan(planner, p)
    plan.steps = play(initial, path)
    escaped, filled = sum(n for _, n in escapes), sum(n for _, n in fills)
    note = len(plan.notes)
    plan.notes.append(f"bound descent: {len(path)} moves, {len(path) - escaped - filled} of "
                      "them each lowering the assignment bound by one, "
                      f"{escaped} in {len(escapes)} window escapes"
                      + (f", {filled} in {len(fills)} fills" if fills else ""))
    relays = _Heuristic(plan, start=occ, advance=advance)
    relays.run()
    # Said once the relays have run: the descent may have reached the goal alone.
    added = plan.moves - len(path)
    plan.notes[note] += ("; it reached the goal" if not added and plan.ok else
                         f"; relays from there: {added} moves" + ("" if plan.ok else
                                                                    ", stopped short"))
    return relays


def _dug_descent(planner: str, p: Problem, descent: _Heuristic, calls: int) -> Plan:
    """Holes dug open and refilled (at most ``calls`` digs) from where the descent's
    relays stopped, or its last dig did; shortened (detours dropped) if that reached the
    goal."""
    dug = Plan(planner, p)
    dug.notes = list(descent.plan.notes)
    descent.dig_on(dug, calls)
    shorten(dug)
    return dug


def _dug_kept(plan: Plan, dug: Plan, factor: float) -> bool:
    """Take ``dug`` (:func:`_dug_descent`) as ``plan`` if it reached the goal in at most
    ``factor`` times the assignment bound."""
    p = plan.problem
    if not dug.ok or dug.moves > factor * assignment_lower_bound(p.initial, p.goal):
        return False
    plan.steps, plan.ok = dug.steps, True
    plan.notes += dug.notes
    plan.notes.append(DESCENT_DUG_NOTE)
    return True


def plan_complete(plan: Plan, exact_limit: int = EXACT_LIMIT) -> None:
    """Fill ``plan`` (serial, one move per step); see the module docstring.

    If the heuristic gets stuck going forwards, it also tries the reverse problem
    (goal to initial) and plays that plan backwards, since every move is reversible.
    The plan is then shortened (:mod:`planner_svc.shorten`, stretches re-planned in
    windows too), unless it is made of lone walks only (phases 0 and 1): each electron
    walks once, along a shortest path, to a void it keeps, so no module comes back to a
    cell and no configuration recurs (on the 5e5 moves of a tree of 1000 modules it
    would spend 1 s finding nothing).

    On fleets of :data:`FEWEST_LIMIT` modules or fewer, the exact search then looks for a
    plan with fewer moves (:func:`planner_svc.search.fewer_moves`, at most
    :data:`FEWEST_BUDGET` configurations) and takes it if there is one.
    """
    if not _plan_phases(plan, exact_limit):
        shorten(plan, windows=True)
    small = len(plan.problem.goal) <= FEWEST_LIMIT
    if plan.ok and small and all(len(step) == 1 for step in plan.steps):
        _fewest(plan)


def _fewest(plan: Plan) -> None:
    """Replace the plan of a small fleet by one with the fewest moves, if the exact search
    finds that it has more (and says so either way in the notes)."""
    p = plan.problem
    before = plan.moves
    if before <= assignment_lower_bound(p.initial, p.goal):
        return
    fewer = fewer_moves(plan, DEFAULT_MARGIN, FEWEST_BUDGET)
    within = f"within {DEFAULT_MARGIN} cells of start and goal"
    if fewer:
        plan.notes.append(f"exact search: {plan.moves} moves, the fewest {within} (the "
                          f"heuristics planned {before})")
    elif fewer is False:
        plan.notes.append(f"exact search: no plan {within} has fewer than these {before} "
                          "moves")


def _shortened_difference(a: Plan, b: Plan) -> int:
    """Moves of ``a`` minus those of ``b``, both shortened first: candidate plans are
    compared as they will be played."""
    shorten(a)
    shorten(b)
    return a.moves - b.moves


def _plan_phases(plan: Plan, exact_limit: int) -> bool:
    """The phases of :func:`plan_complete`; True if the plan is lone walks only."""
    p: Problem = plan.problem
    goal = {xy(c) for c in p.goal}
    small = len(goal) <= COMPARE_LIMIT
    # Advances pay where smoothing is too slow to run (on Eden blobs of 100 modules they
    # do not beat the smoothed shapes' digging).
    advance = len(goal) > SMOOTH_LIMIT
    # Phase 0, front walks, on compact goals (rows to fill); at scale it is kept when it
    # finishes, small fleets keep the shortest plan of all phases.
    front: Plan | None = None
    if small or compact(goal):
        front = Plan(plan.planner, p)
        front.ok = _FrontWalk(front, {xy(c) for c in p.initial}).run()
        if front.ok and not small:
            plan.steps, plan.ok = front.steps, True
            return True
    # Phase 1, assigned walks alone, solves sparse shapes quickly and near the bound. When
    # it cannot finish, the relay heuristic runs from the start (better on compact shapes)
    # and from where phase 1 stopped.
    first = Plan(plan.planner, p)
    occ = {xy(c) for c in p.initial}
    _AssignWalk(first, occ).run()
    walked = occ == goal
    relays: _Heuristic | None = None
    descent: _Heuristic | None = None
    dug_descent: Plan | None = None
    walled = False
    if walked:
        first.ok = True
        forward = first
        if len(p.goal) <= COMPARE_LIMIT:        # cheap at this size: keep the shorter
            relay = Plan(plan.planner, p)
            _Heuristic(relay).run()
            if relay.ok and _shortened_difference(relay, first) < 0:
                forward = relay
    else:
        # Large fleets whose voids are near their electrons (a local rearrangement)
        # descend the bound first; where that and relays from where it stopped reach
        # the goal, the plan is kept.
        if len(goal) > SMOOTH_LIMIT and _local(p):
            descent = _descended(plan.planner, p, advance)
            if descent.plan.ok:
                plan.steps, plan.ok = descent.plan.steps, True
                plan.notes += descent.plan.notes
                return False
            # Its relays are stuck: digging on from there is quick and, when short
            # enough, kept before the relays run from the start (see DUG_EARLY).
            dug_descent = _dug_descent(plan.planner, p, descent, DUG_EARLY_CALLS)
            if _dug_kept(plan, dug_descent, DUG_EARLY):
                return False
        forward = Plan(plan.planner, p)
        relays = _Heuristic(forward, advance=advance)
        relays.run()
        # On large fleets, relays stopped with more than a few voids left have walled
        # voids in (holes, lakes): the relays from where phase 1 stopped and on the
        # reverse problem stop too (Eden blobs of 1000 modules, seeds 0-4: 19-68 voids
        # left, 40 s spent), and only digging (the last resort) is tried. Scrambled blobs
        # stop with at most 3 (seeds 0-9), where those runs often finish.
        walled = len(goal) > SMOOTH_LIMIT and len(goal - relays.occ) > FEW_VOIDS
        # Carrying on from where phase 1 stopped is sometimes much shorter (scrambled
        # blobs of 100 modules: mean 1.52x the bound instead of 1.70x over seeds 0-9);
        # on large fleets it only runs when needed (the time target).
        if not walled and (not forward.ok or len(goal) <= SMOOTH_LIMIT):
            _Heuristic(first, start=occ, advance=advance).run()
            if first.ok and (not forward.ok or _shortened_difference(first, forward) < 0):
                forward = first
    if front is not None and front.ok and (
            not forward.ok or _shortened_difference(front, forward) <= 0):
        forward = front
    # Where the relays are stuck too, the descent's dig is kept if short enough: what
    # runs below takes 10-40 s more, and beat 1 of the 11 plans kept so on scrambled
    # seeds 0-59 (see DUG_KEEP).
    if not forward.ok and descent is not None:
        assert dug_descent is not None
        if not dug_descent.ok:          # it stopped early: dig on with the rest
            dug_descent = _dug_descent(plan.planner, p, descent,
                                       HOLE_CALLS_LARGE - DUG_EARLY_CALLS)
        if _dug_kept(plan, dug_descent, DUG_KEEP):
            return False
    if not forward.ok and not walled:
        backward = Plan(plan.planner, Problem(p.goal, p.initial, p.fixed, p.obstacles, p.name))
        _Heuristic(backward, advance=advance).run()
        if backward.ok:
            plan.steps = reverse_steps(backward, p)
            plan.ok = True
            plan.notes.append("forward heuristic stuck; the reverse problem's plan played backwards")
            return False
    if not forward.ok:
        # Last resort: digging holes open and filling them (:meth:`_Heuristic._hole_step`;
        # long plans, but they reach the goal), by the relays from where they stopped
        # (no other run failed here), and through smoothed shapes: fewer notches stop the
        # walkers, so relays go further and less is dug (Eden blobs of 100 modules: 3.8x
        # the bound instead of 9x on two of three seeds). Both are tried and the shortest
        # plan kept: neither is always shorter (scrambled blobs of 1000 modules, seeds 1,
        # 6 and 9: 1706, 2056 and 2968 moves digging from where the relays stopped,
        # 1954, 942 and 3461 through smoothed shapes). After a bound descent, digging on
        # from where it stopped is a try too. On large fleets without a descent the
        # relays also run again with pinned electrons first (:meth:`_Heuristic._pinned`),
        # digging where they stop: stuck relays have often walled electrons into cracks
        # of the goal (before the descent, seeds 1, 9 and 10: 680, 2211 and 496 moves
        # instead of 1706, 2960 and 562; seeds 6, 11, 13, 15 and 18 kept their plans, one
        # relay run later). Where voids are walled in (large fleets only), smoothed
        # shapes go first and plain digging runs only when that fails: on Eden blobs of
        # 1000 modules (seeds 0-4) it finished none, and took 45 s (pins changed nothing
        # there on seeds 0 and 3).
        assert relays is not None
        large = len(goal) > SMOOTH_LIMIT
        calls = HOLE_CALLS_LARGE if large else HOLE_CALLS
        tries: list[tuple[Plan, str]] = []
        if dug_descent is not None and dug_descent.ok:
            tries.append((dug_descent, DESCENT_DUG_NOTE))
        smoothed = Plan(plan.planner, p)
        if walled:
            if smoothed_plan(smoothed, advance=advance, hole_calls=calls):
                tries.append((smoothed, SMOOTHED_NOTE))
            else:
                dug = Plan(plan.planner, p)
                relays.dig_on(dug)
                tries.append((dug, DUG_NOTE))
        else:
            dug = Plan(plan.planner, p)
            relays.dig_on(dug, calls)
            tries.append((dug, DUG_NOTE))
            # Pinned relays won none of the last resorts after a descent (scrambled
            # 1000, seeds 0-59: the descent's digs or the others were shorter).
            if large and descent is None:
                pinned = _Heuristic(Plan(plan.planner, p), advance=advance, pins=True)
                pinned.run()
                if pinned.plan.ok:
                    tries.append((pinned.plan, PINNED_NOTE))
                else:
                    dug = Plan(plan.planner, p)
                    pinned.dig_on(dug, calls)
                    tries.append((dug, f"{PINNED_NOTE}, holes dug open and refilled"))
            smoothed_plan(smoothed, advance=advance, hole_calls=calls)
            tries.append((smoothed, SMOOTHED_NOTE))
        done = [(t, note) for t, note in tries if t.ok]
        for t, _ in done:       # compared as they will be played; shortened here, the
            shorten(t)          # plan's notes say so before saying where it comes from
        if done:
            best, note = min(done, key=lambda tn: tn[0].moves)     # ties: the first
            plan.steps, plan.ok = best.steps, True
            plan.notes += best.notes
            plan.notes.append(note)
            return False
    plan.steps, plan.ok, plan.reason = forward.steps, forward.ok, forward.reason
    plan.notes += forward.notes
    if not forward.ok:
        occ = {xy(c) for c in forward.configurations()[-1]}
        _finish_small(plan, occ, exact_limit)
        return False
    return forward is front or (forward is first and walked)


#: How the last resort's plans say where they come from.
DUG_NOTE = "relays stuck; holes dug open and refilled"
SMOOTHED_NOTE = ("relays stuck; start and goal smoothed (notches filled), holes dug open and "
                 "refilled")
PINNED_NOTE = "relays stuck; run again with pinned electrons first"
DESCENT_DUG_NOTE = "relays stuck; holes dug open and refilled from where bound descent stopped"


def reverse_steps(plan: Plan, problem: Problem) -> list[list[Move]]:
    """A serial plan played backwards: each rotation undone about the same substrate."""
    confs = plan.configurations()
    out: list[list[Move]] = []
    for conf, (mv,) in zip(reversed(confs[1:]), reversed(plan.steps)):
        back = find_move(conf, mv.goal, mv.mobile, problem.fixed, problem.obstacles)
        assert back is not None, "moves are reversible"
        out.append([back])
    return out


def wedge(apexes: set[Coord], occ: set[Coord], side: int
          ) -> tuple[Callable[[Coord], bool], Callable[[Coord], int], list[Coord]]:
    """The 120-degree wedges at ``apexes`` that open between the directions d, d' of
    sides ``side`` and ``side + 2``, the cells apex + a*d + b*d' (a, b >= 0): a
    membership test, the level a + b of a cell (apex + a*d + b*d' for any apex: only
    differences count), and the modules of ``occ`` in them, highest level (farthest out)
    first, the apexes last.

    Taken away in that order, each module leaves with its neighbours farther out gone:
    those left lie in one arc of at most three (nearer the apex, or outside the wedge on
    its near side), so it can rotate and cuts nothing. Under a flat face that is the only
    way in (see ``docs/planner.md``): the wedge makes the apex a corner."""
    (ux, uy), (vx, vy) = SIDE_OFFSETS[side % 6], SIDE_OFFSETS[(side + 2) % 6]
    det = ux * vy - uy * vx                     # +-1: the two directions span the lattice

    def ab(c: Coord) -> tuple[int, int]:
        return (c[0] * vy - c[1] * vx) // det, (ux * c[1] - uy * c[0]) // det

    tips = [ab(t) for t in apexes]

    def inside(c: Coord) -> bool:
        a, b = ab(c)
        return any(a >= ta and b >= tb for ta, tb in tips)

    def level(c: Coord) -> int:
        return sum(ab(c))

    return inside, level, sorted((c for c in occ if inside(c)), key=lambda c: (-level(c), c))


class _Peel:
    """A simulated peel (:meth:`_Heuristic._peel_plan`): the structure ``sim`` with the
    hole filled, the cells still to peel, and the walks so far."""

    def __init__(self, h: "_Heuristic", hole: set[Coord], sim: set[Coord],
                 must: set[Coord]) -> None:
        self.ob, self.fixed = h.obstacles, h.fixed
        self.hole, self.sim = hole, sim
        self.left = set(hole) | set(must)
        self.peels: list[tuple[Coord, Coord]] = []
        self.parked: set[Coord] = set()
        self.hole_parks: set[Coord] = set()     # where the hole's own modules went

    def real(self) -> set[Coord]:
        """The structure the peel is played on: without the hole and its modules."""
        return self.sim - self.hole - self.hole_parks

    def movable(self, k: Coord, real: set[Coord]) -> bool:
        """Whether ``k`` can rotate and is no cut vertex, in ``sim`` and (unless a hole
        cell) in the real structure too: the crater is dug for real with the hole empty."""
        if k == self.fixed or k in self.hole_parks:
            return False
        if not can_move(self.sim, k, self.ob) or is_cut(self.sim, k):
            return False
        return k in self.hole or (can_move(real, k, self.ob) and not is_cut(real, k))

    def region(self, k: Coord, real: set[Coord]
               ) -> dict[Coord, tuple[int, Coord | None, MoveRule | None]]:
        """Where ``k`` can walk alone, in ``sim`` and (unless a hole cell) for real."""
        reg = bfs(self.sim - {k}, k, self.ob)
        if k not in self.hole:
            also = bfs(real - {k}, k, self.ob)
            reg = {c: v for c, v in reg.items() if c in also}
        return reg

    def peel_first(self, cands: list[tuple], real: set[Coord],
                   parks: Callable[[Coord, dict], list[tuple]]) -> bool:
        """Peel the first module of ``cands`` (keyed tuples ending in the cell, best first
        once sorted; at most :data:`HOLE_TRY` tried) that has a parking cell:
        ``parks(k, region)`` lists them as keyed tuples ending in the cell, best the least."""
        for *_, k in sorted(cands)[:HOLE_TRY]:
            options = parks(k, self.region(k, real))
            if options:
                self.take(k, min(options)[-1])
                return True
        return False

    def take(self, k: Coord, park: Coord) -> None:
        """Peel ``k`` to ``park``."""
        self.sim.discard(k)
        self.sim.add(park)
        self.parked.discard(k)
        self.parked.add(park)
        if k in self.hole:
            self.hole_parks.add(park)
        self.left.discard(k)
        self.peels.append((k, park))


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


class _Heuristic(_Phase):
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
        #: Window searches made, by what decides them (:func:`_window_search`).
        self.window_memo: dict[tuple, Path | None] = {}
        self.advance = advance
        self.advance_budget = ADVANCE_CALLS
        #: Planned hole fills left (:meth:`_hole_step`; only when ``holes``).
        self.hole_budget = hole_calls if holes else 0
        self.hole_failed: set[tuple[frozenset[Coord], ...]] = set()
        #: Cells (a hole, an electron) dug for before, whatever the outcome.
        self.dug_before: set[frozenset[Coord]] = set()
        #: The last lake opened (:meth:`_open_lake`), its crater's goal cells, and the
        #: voids left when it was opened (another lake opens only after progress).
        self.lake: set[Coord] = set()
        self.mouth: set[Coord] = set()
        self.lake_voids = 1 << 30
        #: The goal cells of the last wedge emptied (:meth:`_clear_wedge`) and their
        #: levels: refilled apex first, the peel backwards (else the apex is sealed).
        self.wedge_fill: dict[Coord, int] = {}
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

    def _hole_step(self) -> bool:
        """Fill a hole (a cluster of voids no walker reaches) by a planned dig (see
        :meth:`_fill_hole`), or open it if it is a lake (:meth:`_open_lake`). A hole that
        failed is tried again once the voids or the electrons have changed."""
        if self.hole_budget <= 0:
            return False
        occ, goal = self.occ, self.goal
        voids = self.goal - occ
        reach: set[Coord] = set()
        for e in sorted(occ - goal):
            if self._mobile(e):
                reach |= bfs(occ - {e}, e, self.obstacles).keys()
        # A failed dig leaves the structure as it was, and one that works returns: the
        # voids and electrons stay the same through both loops.
        these_voids, electrons = frozenset(voids), frozenset(occ - goal)
        done: set[Coord] = set()
        for t in sorted(voids - reach, key=lambda v: (-self.depth.get(v, 0), v)):
            if t in done:
                continue
            hole, todo = {t}, [t]
            while todo:
                for n in neighbours_xy(todo.pop()):
                    if n in voids and n not in hole and n not in reach:
                        hole.add(n)
                        todo.append(n)
            done |= hole
            # Retried when the electrons have moved (a dig that failed may work then).
            key = (frozenset(hole), these_voids, electrons)
            if key in self.hole_failed:
                continue
            if len(hole) > HOLE_MAX:
                if len(voids) >= self.lake_voids:
                    continue
                done_now = self._try_dig(key, lambda: self._open_lake(hole))
            else:
                done_now = self._try_dig(key, lambda: self._fill_hole(hole))
            if done_now is not None:
                return done_now
        # Electrons walled in (or reaching no void): dig each out the same way.
        for e in sorted(occ - goal, key=lambda c: (-self.depth.get(c, 0), c)):
            if self._mobile(e) and not voids.isdisjoint(bfs(occ - {e}, e, self.obstacles)):
                continue
            key = (frozenset({e}), these_voids)
            if key in self.hole_failed:
                continue
            before = set(occ)
            done_now = self._try_dig(key, lambda: self._fill_hole(set(), must={e}) and occ != before)
            # Once per cell per set of voids, even when it worked: freed electrons that
            # fill nothing get walled in again elsewhere, and the digs went round in circles.
            self.hole_failed.add(key)
            if done_now is not None:
                return done_now
        # Nothing else worked: a walled-in electron is freed by emptying a wedge at it.
        for e in sorted(occ - goal, key=lambda c: (-self.depth.get(c, 0), c)):
            key = (frozenset({e}), these_voids, "wedge")
            if key in self.hole_failed or self._mobile(e):
                continue
            done_now = self._try_dig(key, lambda: self._clear_wedge(e))
            self.hole_failed.add(key)
            if done_now is not None:
                return done_now
        return False

    def _clear_wedge(self, e: Coord) -> bool:
        """Free the walled-in electron at ``e`` by a detour: the relays play towards the
        goal with the goal cells of a :func:`wedge` at ``e`` traded for parking cells
        (:meth:`_detour_goal`), until ``e`` has left its cell. The smallest wedge first
        (at most :data:`WEDGE_MAX` modules, not the fixed one). The wedge's modules are
        peelable in order whatever its surface looks like, and the relays carry them past
        the notches of that surface, where lone walks to parking cells stop; afterwards
        the relays refill the wedge. False if no detour frees ``e`` (nothing moved)."""
        occ, fixed, ob = self.occ, self.fixed, self.obstacles
        wedges = []
        for side in range(6):
            inside, level, cells = wedge({e}, occ, side)
            if len(cells) <= WEDGE_MAX and not inside(fixed):
                wedges.append((len(cells), side, inside, level, cells))
        for *_, inside, level, cells in sorted(wedges, key=lambda w: w[:2]):
            detour = self._detour_goal(inside, set(cells))
            if detour is None:
                continue
            sub = Plan(self.plan.planner, Problem.of(occ, detour, fixed, ob, "wedge"))
            relays = _Heuristic(sub, advance=self.advance)
            relays.run(until=lambda: e not in relays.occ)
            if e in relays.occ:
                continue
            self.plan.steps += sub.steps
            occ.clear()
            occ |= relays.occ
            self.seen.add(frozenset(occ))
            self.wedge_fill = {c: level(c) for c in self.goal if inside(c)}
            return True
        return False

    def _detour_goal(self, inside: Callable[[Coord], bool], cells: set[Coord]
                     ) -> set[Coord] | None:
        """The goal without the cells ``inside`` a wedge (whose modules are ``cells``)
        and with as many parking cells, outside the goal and the wedge and touching none
        of its modules: a coat on the structure, nearest the wedge first (a second coat on
        the first if need be). A parking cell off the surface is hard to fill: clumps of
        them wall each other in. None if there are not enough, or the detour goal is not
        connected."""
        occ, ob = self.occ, self.obstacles
        keep = {c for c in self.goal if not inside(c)}
        need = len(occ) - len(keep)

        def ok(c: Coord) -> bool:
            return (c not in occ and c not in self.goal and c not in ob and not inside(c)
                    and not any(n in cells for n in neighbours_xy(c)))

        parks: set[Coord] = set()
        under = occ - cells
        while len(parks) < need:
            coat = sorted({n for c in under for n in neighbours_xy(c) if ok(n)} - parks,
                          key=lambda c: (min(hex_distance(c, w) for w in cells), c))
            if not coat:
                return None
            parks.update(coat[:need - len(parks)])
            under = parks
        detour = keep | parks
        return detour if is_connected(detour) else None

    def _open_lake(self, lake: set[Coord]) -> bool:
        """Open a hole too big to dig and refill (a *lake*) to the outside, for good: a
        crater from the open surface to the lake's shore module with the thinnest wall,
        its modules parked outside the goal (they become electrons; the crater's goal
        cells, voids the relays fill). False when no peel reaches it."""
        occ, ob = self.occ, self.obstacles
        lo = (min(x for x, _ in occ) - 2, min(y for _, y in occ) - 2)
        hi = (max(x for x, _ in occ) + 2, max(y for _, y in occ) + 2)
        outside, todo = {lo}, deque([lo])
        while todo:
            c = todo.popleft()
            for n in neighbours_xy(c):
                if (lo[0] <= n[0] <= hi[0] and lo[1] <= n[1] <= hi[1] and n not in occ
                        and n not in ob and n not in outside):
                    outside.add(n)
                    todo.append(n)
        # Wall thickness: breadth-first steps through modules from the outside.
        depth = layers(occ, {n for c in outside for n in neighbours_xy(c) if n in occ})
        shore = sorted({n for v in lake for n in neighbours_xy(v) if n in depth},
                       key=lambda c: (depth[c], c))
        before = len(self.goal - occ)
        for target in shore[:HOLE_ELECTRONS]:
            if target == self.fixed:
                continue
            for peels in self._peel_plans(set(), must={target}):
                if self._or_undo(lambda: all(self._walk_to(k, park) for k, park in peels)):
                    self.lake, self.lake_voids = set(lake), before
                    self.mouth = {k for k, _ in peels} & self.goal
                    return True
        return False

    def _or_undo(self, attempt: Callable[[], bool]) -> bool:
        """Run ``attempt`` (which plays moves); if it returns False, undo its moves."""
        mark, saved, seen = len(self.plan.steps), set(self.occ), set(self.seen)
        if attempt():
            return True
        del self.plan.steps[mark:]
        self.occ.clear()
        self.occ |= saved
        self.seen = seen
        return False

    def _try_dig(self, key, attempt) -> bool | None:
        """Run one dig ``attempt``; roll the plan back if it fails. True: it worked;
        False: the dig budget is spent; None: try the next hole."""
        self.hole_budget -= 1
        if self._or_undo(attempt):
            return True
        self.hole_failed.add(key)
        return False if self.hole_budget <= 0 else None

    def _fill_hole(self, hole: set[Coord], must: set[Coord] = frozenset()) -> bool:
        """Dig ``hole`` open and fill it, as the reverse of a peel (also digs out the
        electrons of ``must``, whose cells stay empty).

        :meth:`_peel_plan` peels the structure with the hole filled. Then for real:
        the crater's modules walk to their parking cells in that order, and the peel is
        undone backwards: a crater module walks back from a parking cell into a goal
        cell, a hole cell takes an electron that reaches it or else a waiting crater
        module (the outermost crater cell then stays a void on the surface for the
        relays). Each walk is searched on the current structure; False (the caller rolls
        back) when one is impossible. Once the hole is filled a failed walk back ends the
        fill early, with success: the relays refill the rest of the crater.
        """
        # A hole's first dig takes the first peel it finds (short plans); once one has
        # failed, the next digs of the same cells try every peel in turn.
        cells = frozenset(hole | must)
        plans: Iterable[list[tuple[Coord, Coord]]]
        if cells not in self.dug_before:
            self.dug_before.add(cells)
            plans = itertools.islice(self._peel_plans(hole, must=must, digs=HOLE_DIGS[:2]), 1)
        else:
            plans = self._peel_plans(hole, must=must)
        return any(self._or_undo(lambda: self._dig_and_fill(hole, peels)) for peels in plans)

    def _dig_and_fill(self, hole: set[Coord], peels: list[tuple[Coord, Coord]]) -> bool:
        """Play one planned peel of :meth:`_fill_hole` for real; False when a walk is
        impossible (the caller rolls back)."""
        occ, goal, fixed = self.occ, self.goal, self.fixed
        for k, park in peels:                       # dig the crater
            if k in hole:
                continue
            if not self._walk_to(k, park):
                return False
        # Crater goal cells in the order they were emptied (the first is the outermost,
        # the last to be refilled); modules are interchangeable: any waiting one may
        # go back to a cell, its own first.
        back = [k for k, _ in peels if k not in hole and k in goal]
        waiting: list[Coord] = []       # where the crater's modules wait (a parked
        for k, park in peels:           # module may have been moved on, farther)
            if k in hole:
                continue
            if k in waiting:
                waiting.remove(k)
            waiting.append(park)
        lent: set[Coord] = set()        # crater cells left empty (their module filled
        for k, park in reversed(peels):     # the hole); fill deepest first
            if k not in hole:
                if k in goal and k not in lent:
                    order = ([park] if park in waiting else []) + waiting[::-1]
                    for p in order:
                        if self._walk_to(p, k):
                            waiting.remove(p)
                            break
                    else:
                        # The hole is filled: the relays refill the rest of the crater.
                        return not (hole - self.occ)
                continue
            es = sorted((hex_distance(e, k), e) for e in occ - goal
                        if e not in waiting and e != fixed)
            if any(self._walk_to(e, k) for _, e in es[:HOLE_ELECTRONS]):
                continue
            # No electron reaches it: a waiting crater module fills it instead, and
            # the outermost crater cell stays a void on the surface.
            for p in waiting[::-1]:
                if self._walk_to(p, k):
                    waiting.remove(p)
                    spare = [c for c in back if c not in lent]
                    if spare:       # else it was an electron of the crater anyway
                        lent.add(spare[0])
                    break
            else:
                return False
        return True

    def _peel_plan(self, hole: set[Coord], sim: set[Coord] | None = None,
                   must: set[Coord] = frozenset()) -> list[tuple[Coord, Coord]] | None:
        """The peel of :meth:`_fill_hole`, simulated: ``(cell, parking cell)`` per
        walk, or None; every cell of ``hole`` and ``must`` gets peeled. ``sim`` is the
        structure with the hole filled (the default).

        A crater first (:meth:`_peel_crater`); when its walls end flat, peeling nearest
        first (:meth:`_peel_nearest`). The first of :meth:`_peel_plans`."""
        return next(self._peel_plans(hole, sim, must), None)

    def _peel_plans(self, hole: set[Coord], sim: set[Coord] | None = None,
                    must: set[Coord] = frozenset(), digs: tuple = HOLE_DIGS
                    ) -> Iterator[list[tuple[Coord, Coord]]]:
        """The peels :meth:`_fill_hole` tries in turn (see :meth:`_peel_plan`), in the
        order of ``digs`` (:data:`HOLE_DIGS`: the craters of :data:`HOLE_CRATERS` and the
        nearest-first peels with the parking preferences of :data:`HOLE_PARK_FAR`), only
        those that peel every cell."""
        sim = self.occ | hole if sim is None else sim
        for how, arg in digs:
            pl = _Peel(self, hole, set(sim), must)
            peels = (self._peel_crater(pl, *arg) if how == "crater"
                     else self._peel_nearest(pl, arg))
            if peels is not None:
                yield peels

    def _peel_crater(self, pl: _Peel, width: int = HOLE_CRATERS[0][0],
                     deep: int = HOLE_CRATERS[0][1]) -> list[tuple[Coord, Coord]] | None:
        """Aim at the cell still to peel nearest to an open free cell (at most two occupied
        neighbours) and dig the crater (see :data:`HOLE_CRATERS`) outermost first: each
        peel is a movable module (:meth:`_Peel.movable`) walking to the nearest parking
        cell outside the goal and the crater, preferably not next to another parked
        module. Bounded by :data:`HOLE_PEELS`."""
        goal, ob = self.goal, self.obstacles
        sim, left, hole = pl.sim, pl.left, pl.hole
        aim: Coord = (1 << 30, 0)       # not a hole cell: chosen in the first round
        centre, span = aim, 0
        for _ in range(HOLE_PEELS + len(hole)):
            if not left:
                break
            if aim not in left:         # the next hole cell to dig to
                rim = {n for c in sim for n in neighbours_xy(c)
                       if n not in sim and n not in ob and n not in hole}
                opens = [c for c in rim if sum(n in sim for n in neighbours_xy(c)) <= 2]
                if not opens:
                    return None
                aim, mouth = min(((h, c) for h in (left & hole or left) for c in opens),
                                 key=lambda hc: (hex_distance(*hc), hc))
                # The crater: a hexagonal ball about a centre beyond the mouth, touching
                # the aim (its walls open at 120 degrees or more, so modules peel).
                ln = hex_distance(aim, mouth)
                f = (ln + width) / ln
                centre = (round(aim[0] + (mouth[0] - aim[0]) * f),
                          round(aim[1] + (mouth[1] - aim[1]) * f))
                span = hex_distance(aim, centre) + deep
            real = pl.real()
            cands = []
            for k in sim:
                dk = hex_distance(k, centre)
                # Outside the crater only near it: the end of a flat row peels first.
                if k not in left and dk > span + HOLE_PARK_GAP:
                    continue
                if pl.movable(k, real):
                    cands.append((k not in left, dk > span, dk, k))

            def parks(k: Coord, reg: dict) -> list[tuple]:
                # Parking cells outside the crater, preferably not on its rim, apart from
                # the other parked modules (each can leave again, in any order, and no
                # notch forms between them).
                dk = hex_distance(k, centre)
                return [(hex_distance(c, centre) <= span + HOLE_PARK_GAP,
                         any(hex_distance(c, q) <= 2 for q in pl.parked if q != k), reg[c][0], c)
                        for c in reg if c not in goal and c not in hole
                        and hex_distance(c, centre) > max(span, dk)
                        and hex_distance(c, aim) >= HOLE_PARK]
            if not pl.peel_first(cands, real, parks):
                return None
        return None if left else pl.peels

    def _peel_nearest(self, pl: _Peel, far: int = 0) -> list[tuple[Coord, Coord]] | None:
        """Peel the movable module nearest to a cell still to peel (within
        :data:`HOLE_REACH`), modules not yet moved first, to the nearest parking cell
        outside the goal that is farther from those cells, preferably not next to another
        parked module and, if ``far``, at least ``far`` from those cells. A flat face only
        rotates at its ends (its other modules have four neighbours), so a crater ending in
        one is stuck; this peels the face from its end inwards (Eden blobs of 1000 modules:
        walled-in electrons in a bay's flat ceiling). Bounded by :data:`HOLE_NEAR_PEELS`."""
        goal = self.goal
        sim, left, hole = pl.sim, pl.left, pl.hole
        # Distances to the cells still to peel, kept until one is peeled (``left`` only
        # shrinks): each round asks again for most of the structure and its regions.
        gaps_for, known = len(left), {}

        def gap(c: Coord) -> int:
            nonlocal gaps_for
            if gaps_for != len(left):
                gaps_for = len(left)
                known.clear()
            d = known.get(c)
            if d is None:
                d = known[c] = min(hex_distance(c, a) for a in left)
            return d

        for _ in range(HOLE_NEAR_PEELS):
            if not left:
                return pl.peels
            real = pl.real()
            cands = []
            for k in sim:
                dk = gap(k)
                if dk <= HOLE_REACH and pl.movable(k, real):
                    cands.append((k not in left, k in pl.parked, dk, k))

            def parks(k: Coord, reg: dict) -> list[tuple]:
                dk = gap(k)
                gaps = {c: gap(c) for c in reg if c not in goal and c not in hole}
                return [(any(hex_distance(c, q) <= 1 for q in pl.parked if q != k),
                         g < far, reg[c][0], c)
                        for c, g in gaps.items() if g >= HOLE_PARK and g > dk]
            if not pl.peel_first(cands, real, parks):
                return None
        return None if left else pl.peels

    def _walk_to(self, m: Coord, target: Coord) -> bool:
        """Walk the module at ``m`` alone to ``target`` if it can leave and reach it."""
        occ, ob = self.occ, self.obstacles
        if m not in occ or target in occ or m == self.fixed:
            return False
        if not can_move(occ, m, ob) or is_cut(occ, m):
            return False
        path = walk(occ - {m}, m, {target}, ob, limit=RELAY_LIMIT * 4)
        if not path:
            return False
        self._do_walk(path)
        return True

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


def notches(occ: set[Coord], obstacles: set[Coord] | frozenset[Coord] = frozenset()) -> list[Coord]:
    """Free cells with four or more occupied neighbours: under Table 4-3 they cannot be
    entered, and no lone walker crosses their mouth."""
    rim = {n for c in occ for n in neighbours_xy(c)} - occ - set(obstacles)
    return sorted(c for c in rim if sum(n in occ for n in neighbours_xy(c)) >= 4)


def smooth(occ: set[Coord], fixed: Coord, obstacles: set[Coord]) -> list[list[Move]]:
    """Fill notches of the structure ``occ`` (updated in place) while that lowers their
    number; returns the moves.

    Each notch is filled by :func:`local_repair` (the vacancy runs out to the surface
    through modules that rotate into it), kept only if the structure ends with fewer
    notches. A rough surface (Eden blobs) stops lone walkers at every notch; smoothed,
    relays get much further.
    """
    steps: list[list[Move]] = []
    radius, budget = SMOOTH_WINDOW
    failed: set[Coord] = set()
    # Each search's goal (the structure plus the notch) is decided by its window's key;
    # a notch's search is made again after every fill kept, mostly to the same end.
    searches: dict[tuple, Path | None] = {}
    count = len(notches(occ, obstacles))
    while True:
        for n in notches(occ, obstacles):
            if n in failed:
                continue
            path = local_repair(occ, occ | {n}, fixed, obstacles, n, radius, budget,
                                searches)
            trial = set(occ)
            moves = play(trial, path or [])
            after = len(notches(trial, obstacles)) if moves else count
            if after < count:
                occ.clear()
                occ |= trial
                steps += moves
                count = after
                failed.clear()
                break
            failed.add(n)
        else:
            return steps


def smoothed_plan(plan: Plan, *, advance: bool = False, hole_calls: int = HOLE_CALLS) -> bool:
    """Plan ``plan.problem`` through smoothed shapes: the start smoothed (:func:`smooth`),
    the relays (with advances if ``advance``), digging from there (at most ``hole_calls``
    digs) to the smoothed goal, then the goal's smoothing played backwards (every rotation
    is reversible). True when it reaches the goal."""
    p: Problem = plan.problem
    fixed, ob = xy(p.fixed), {xy(c) for c in p.obstacles}
    start, goal = {xy(c) for c in p.initial}, {xy(c) for c in p.goal}
    into, out = set(start), set(goal)
    head, tail = smooth(into, fixed, ob), smooth(out, fixed, ob)
    mid = Plan(plan.planner, Problem.of(into, out, fixed, ob, p.name))
    relays = _Heuristic(mid, advance=advance)
    relays.run()
    if not mid.ok:
        _Heuristic(mid, start=relays.occ, holes=True, advance=advance,
                   hole_calls=hole_calls).run()
    if not mid.ok:
        return False
    back = Plan(plan.planner, Problem.of(goal, out, fixed, ob, p.name))
    back.steps = tail
    plan.steps = head + mid.steps + reverse_steps(back, p)
    plan.ok = True
    return True


def _finish_small(plan: Plan, occ: set[Coord], exact_limit: int) -> None:
    """The heuristic is stuck at ``occ``: finish with the exact search if the fleet is small."""
    n = len(occ)
    if n > exact_limit:
        voids = {xy(c) for c in plan.problem.goal} - occ
        plan.reason = (f"complete heuristic stuck after {plan.moves} moves with "
                       f"{len(voids)} voids left (not proven unreachable; "
                       f"{n} modules is too many for the exact search)")
        return
    before = plan.moves
    search_from(plan, occ, DEFAULT_MARGIN, EXACT_BUDGET)
    if plan.ok:
        plan.notes.append(f"heuristic stuck after {before} moves; exact search finished "
                          f"with {plan.moves - before} more")
