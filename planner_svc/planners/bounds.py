"""Lower bounds on the number of moves, and random problem instances for tests and benchmarks.

A move carries one module one cell, so any plan needs at least the cost of the best
assignment of modules to goal cells by hex distance. With a metric cost there is an
optimal assignment that leaves every module already on a goal cell where it is
(re-route through it by the triangle inequality), so only electrons (modules off the
goal) and voids (empty goal cells) need assigning.

The bound ignores that modules must walk over the surface of the structure: when
material must go around a large overlap of start and goal, no plan comes near it (even at
10 modules the fewest moves can be 1.8x the bound: docs/planner.md, *Benchmark*).

Four families of random connected instances (both configurations containing the fixed
cell (0,0)) serve the tests and the benchmark; in the first three start and goal are
independent, the fourth (**scrambled**, :func:`random_scrambled_problem`) takes the goal
from the start by random legal rotations, so it is reachable by construction:

* **Eden** (:func:`random_problem`, :func:`random_blob`): compact blobs grown by Eden
  growth. They are hard for Table 4-3 (:mod:`planner_svc.planners.rules`): a rotation needs the
  goal and three swept cells free, so a cell with four or more occupied neighbours can
  be neither entered nor left. A blob's interior is therefore frozen, a lone walker
  cannot cross a notch of the surface (an empty cell with four occupied neighbours),
  and a hole inside a thick region can only be filled by digging it open. The
  ``complete`` planner solves those of 10 and 100 modules (100: by digging, 3-8x the
  bound) but not yet those of 1000.
* **sparse** (:func:`random_sparse_problem`, :func:`random_sparse_tree`): random trees
  in which no module has more than three occupied neighbours and no empty cell more
  than two. Every leaf can rotate away and a walker fits between any two branches, so
  surface walking works. (With empty cells allowed three occupied neighbours,
  ``empty_max=3``, branches run one cell apart, the gap between them cannot be walked
  -- a walker there would sweep an occupied cell -- and walkers are confined to short
  stretches again: most 30-module instances stall.) The trees spread out (radius
  about n/4), so bounds are large: about 2.5e5 moves for 1000 modules. Walks follow the
  branches, so the plans of ``complete`` are about 2-2.5x the bound.
* **convex** (:func:`random_convex_problem`, :func:`random_hex_convex`): hex-convex
  shapes -- hexagons with random side lengths (half-planes along the three hex axes),
  the last row partial to hit n exactly -- placed so that a random cell of each is
  (0,0), so they overlap partly. Connected, no holes, and no free cell touches four
  modules: the surface is smooth, corner modules (three neighbours or fewer) can be
  peeled, and walkers roll along flat faces one cell per move, so walks along the
  surface are close to hex distances when voids are filled in an order that keeps them
  enterable (row by row from a corner outward: ``complete``'s front walks). Bounds are
  moderate (1e4 to 4e4 moves for 1000 modules).
"""

from __future__ import annotations

import random
from typing import Collection, Iterable

import networkx as nx
import numpy as np

from bus.lattice import Cell

from .moves import is_cut, lone_steps
from .plan import Problem
from .rules import Coord, neighbours_xy, occupancy_graph, xy


#: Below this many rows :func:`min_cost_assignment` runs its inner loop in plain Python:
#: numpy's per-call overhead dominates small matrices (5 rows: 19 us instead of 160 us;
#: 48 rows: 2.5 ms instead of 4.8 ms; even at 100). The A* searches solve one per
#: configuration.
PLAIN_ROWS = 64
#: From this many rows :func:`min_cost_assignment` starts as Jonker and Volgenant's
#: method does (:func:`_reduced_start`): most rows are matched before any augmenting path
#: is searched (random trees of 1000 modules, 999 rows: 5-13 rows left to augment); and an
#: augmenting path, among columns tied at its least reduced cost, goes to a free one if
#: there is one, where it ends (hex-convex shapes of 1000 modules, whose distances tie
#: everywhere: 3-9x fewer steps). Their bounds at 1000 modules take 0.04-0.7 s instead
#: of 1-10 s. Below it the method is as before, so the optimal assignment it picks among
#: ties, which ``complete``'s plans follow, stays the same (Eden blobs of 1000 modules:
#: at most 258 rows, 0.13 s).
LARGE_ROWS = 400
#: Row visits the augmenting row reduction may make, per row (it ends far sooner on the
#: instances seen; a cap keeps a price war short: the rows still free are augmented).
REDUCTION_VISITS = 20
#: The reductions are used only if they leave at most this share of the rows free. Where
#: distances tie everywhere (hex-convex shapes: most rows left free), augmenting from
#: their potentials was no quicker than from zero.
REDUCED_FREE = 0.5


def min_cost_assignment(cost: np.ndarray | list[list[int]]) -> tuple[np.ndarray, float]:
    """Minimum-cost perfect assignment of a square cost matrix (Hungarian method,
    shortest augmenting paths with potentials, O(n^3) with a numpy inner loop, or a
    plain one below :data:`PLAIN_ROWS` rows; from :data:`LARGE_ROWS` rows only the rows
    :func:`_reduced_start` leaves free are augmented, and paths end at free columns
    among ties).

    Returns ``col_of_row`` (the column given to each row) and the total cost.
    """
    n = len(cost)
    if n == 0:
        return np.zeros(0, dtype=np.intp), 0.0
    if n < PLAIN_ROWS:
        rows = cost.tolist() if isinstance(cost, np.ndarray) else cost
        col, total = _plain_assignment(rows)
        return np.array(col, dtype=np.intp), float(total)
    c = np.asarray(cost, dtype=float)
    large = n >= LARGE_ROWS
    start = _reduced_start(c) if large else None
    if start is not None:
        u, v, row_of_col, free_rows = start
    else:
        u = np.zeros(n + 1)
        v = np.zeros(n + 1)
        row_of_col = np.zeros(n + 1, dtype=np.intp)   # 1-based; 0 = unassigned
        free_rows = list(range(1, n + 1))
    way = np.zeros(n + 1, dtype=np.intp)
    for i in free_rows:
        row_of_col[0] = i
        j0 = 0
        minv = np.full(n + 1, np.inf)
        used = np.zeros(n + 1, dtype=bool)
        while True:
            used[j0] = True
            i0 = row_of_col[j0]
            # Reduced costs of row i0 against every unused column, in one numpy step.
            cur = c[i0 - 1] - u[i0] - v[1:]
            free = ~used[1:]
            better = free & (cur < minv[1:])
            minv[1:][better] = cur[better]
            way[1:][better] = j0
            cand = np.where(free, minv[1:], np.inf)
            j1 = _tie_to_free(cand, row_of_col) if large else int(np.argmin(cand)) + 1
            delta = cand[j1 - 1]
            u[row_of_col[used]] += delta
            v[used] -= delta
            minv[1:][free] -= delta
            j0 = j1
            if row_of_col[j0] == 0:
                break
        _augment(row_of_col, way, j0)
    col_of_row = np.array(_columns(row_of_col), dtype=np.intp)
    return col_of_row, float(c[np.arange(n), col_of_row].sum())


def _tie_to_free(cand: np.ndarray, row_of_col: np.ndarray) -> int:
    """The column (1-based) of least ``cand``: a free one if any is among the ties, since
    the augmenting path ends there."""
    ties = np.flatnonzero(cand == cand.min())
    free = ties[row_of_col[ties + 1] == 0]
    return int(free[0] if free.size else ties[0]) + 1


def _reduced_start(c: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]] | None:
    """Potentials and a partial matching to start the augmenting paths from (Jonker and
    Volgenant, 1987): column reduction (each column's cheapest row takes it if still
    free), then two passes of augmenting row reduction (a free row takes its cheapest
    column, lowering that column's potential to the row's second cheapest, and the row it
    displaces is free again). Every matched row keeps its cheapest reduced cost, so with
    ``u`` each row's least reduced cost the potentials are feasible and the matched
    edges tight, as the augmenting paths require.

    Returns ``u``, ``v`` and ``row_of_col`` 1-based as :func:`min_cost_assignment`'s,
    and the rows (1-based) still free; None if more than :data:`REDUCED_FREE` of them
    are."""
    n = len(c)
    v = c.min(axis=0)
    row_of = np.full(n, -1, dtype=np.intp)          # 0-based here; -1 = free
    col_of = np.full(n, -1, dtype=np.intp)
    cheapest = c.argmin(axis=0)
    for j in range(n - 1, -1, -1):
        i = int(cheapest[j])
        if col_of[i] < 0:
            col_of[i], row_of[j] = j, i
    free = [i for i in range(n) if col_of[i] < 0]
    visits = REDUCTION_VISITS * n
    for _ in range(2):
        later: list[int] = []
        while free and visits > 0:
            visits -= 1
            i = free.pop()
            reduced = c[i] - v
            j1 = int(np.argmin(reduced))
            u1 = reduced[j1]
            reduced[j1] = np.inf
            j2 = int(np.argmin(reduced))
            u2 = reduced[j2]
            i0 = int(row_of[j1])
            if u1 < u2:
                v[j1] -= u2 - u1
            elif i0 >= 0:               # a tie: take the second column instead
                j1 = j2
                i0 = int(row_of[j1])
            col_of[i], row_of[j1] = j1, i
            if i0 >= 0:
                col_of[i0] = -1
                # Displaced from a column now dearer: it goes again in this pass; on
                # a tie, in the next.
                (free if u1 < u2 else later).append(i0)
        free += later
    if len(free) > REDUCED_FREE * n:
        return None
    u = np.zeros(n + 1)
    u[1:] = (c - v).min(axis=1)
    potentials = np.zeros(n + 1)
    potentials[1:] = v
    row_of_col = np.zeros(n + 1, dtype=np.intp)
    row_of_col[1:] = row_of + 1                     # -1 (free) becomes 0
    return u, potentials, row_of_col, sorted(i + 1 for i in free)


def _augment(row_of_col: np.ndarray | list[int], way: np.ndarray | list[int], j0: int) -> None:
    """Flip the augmenting path that ends at column ``j0`` (1-based, as ``way``)."""
    while j0:
        j1 = way[j0]
        row_of_col[j0] = row_of_col[j1]
        j0 = j1


def _columns(row_of_col: np.ndarray | list[int]) -> list[int]:
    """The column of each row, from the 1-based row of each column."""
    col = [0] * (len(row_of_col) - 1)
    for j in range(1, len(row_of_col)):
        col[row_of_col[j] - 1] = j - 1
    return col


def _plain_assignment(c: list[list[int]]) -> tuple[list[int], float]:
    """:func:`min_cost_assignment`'s method, step for step, on lists."""
    n = len(c)
    inf = float("inf")
    u = [0.0] * (n + 1)
    v = [0.0] * (n + 1)
    row_of_col = [0] * (n + 1)                      # 1-based; 0 = unassigned
    way = [0] * (n + 1)
    for i in range(1, n + 1):
        row_of_col[0] = i
        j0 = 0
        minv = [inf] * (n + 1)
        used = [False] * (n + 1)
        while True:
            used[j0] = True
            i0 = row_of_col[j0]
            row, ui = c[i0 - 1], u[i0]
            delta, j1 = inf, 0
            for j in range(1, n + 1):
                if not used[j]:
                    cur = row[j - 1] - ui - v[j]
                    if cur < minv[j]:
                        minv[j] = cur
                        way[j] = j0
                    if minv[j] < delta:
                        delta, j1 = minv[j], j
            for j in range(n + 1):
                if used[j]:
                    u[row_of_col[j]] += delta
                    v[j] -= delta
                else:
                    minv[j] -= delta
            j0 = j1
            if row_of_col[j0] == 0:
                break
        _augment(row_of_col, way, j0)
    col = _columns(row_of_col)
    return col, sum(c[i][col[i]] for i in range(n))


#: Up to this many electrons :func:`assignment_cost` takes the cheapest assignment by
#: dynamic programming over the sets of voids taken (4 cells: 11 us instead of 17 us;
#: from 5 the Hungarian method is as quick). Window searches price a configuration each
#: with it, mostly with 3-5 electrons.
SUBSET_ROWS = 4


def assignment_cost(electrons: Collection[Coord], voids: Collection[Coord]) -> int:
    """The minimum total hex distance of an assignment of ``electrons`` to ``voids``
    (as many of each, in any order): the lower bound of one configuration, quick for a
    few cells."""
    n = len(electrons)
    if n >= PLAIN_ROWS:
        return int(round(min_cost_assignment(distance_matrix(list(electrons),
                                                             list(voids)))[1]))
    # hex_distance inlined: a search prices tens of thousands of configurations.
    rows = [[(abs(vx - ex) + abs(vy - ey) + abs(vx - ex + vy - ey)) // 2 for vx, vy in voids]
            for ex, ey in electrons]
    if n > SUBSET_ROWS:
        return int(_plain_assignment(rows)[1])
    if n <= 1:
        return rows[0][0] if n else 0
    # best[mask]: the cheapest way for the first popcount(mask) electrons to take the
    # voids of mask.
    best = {0: 0}
    for row in rows:
        nxt: dict[int, int] = {}
        for mask, cost in best.items():
            for j, d in enumerate(row):
                bit = 1 << j
                if not mask & bit:
                    got = nxt.get(mask | bit)
                    if got is None or cost + d < got:
                        nxt[mask | bit] = cost + d
        best = nxt
    return best[(1 << n) - 1]


def distance_matrix(a: Iterable[Cell | Coord], b: Iterable[Cell | Coord]) -> np.ndarray:
    """Hex distances between two lists of cells (rows: ``a``)."""
    pa = np.array([xy(c) for c in a], dtype=np.int64).reshape(-1, 2)
    pb = np.array([xy(c) for c in b], dtype=np.int64).reshape(-1, 2)
    dx = pb[None, :, 0] - pa[:, None, 0]
    dy = pb[None, :, 1] - pa[:, None, 1]
    return (np.abs(dx) + np.abs(dy) + np.abs(dx + dy)) // 2


#: Recent electron-void assignments (the bound's and the planner's are the same, and at
#: 1000 modules the Hungarian method takes up to 0.7 s: hex-convex shapes): key
#: (electrons, voids).
_ASSIGNMENTS: dict[tuple[tuple[Coord, ...], tuple[Coord, ...]], tuple[np.ndarray, float]] = {}
_ASSIGNMENTS_KEPT = 4


def electron_void_assignment(electrons: list[Coord], voids: list[Coord]
                             ) -> tuple[np.ndarray, float]:
    """:func:`min_cost_assignment` of ``electrons`` to ``voids`` by hex distance, computed
    once for the lower bound and the ``complete`` planner (the last few are kept)."""
    key = (tuple(electrons), tuple(voids))
    hit = _ASSIGNMENTS.get(key)
    if hit is None:
        hit = min_cost_assignment(distance_matrix(electrons, voids))
        if len(_ASSIGNMENTS) >= _ASSIGNMENTS_KEPT:
            del _ASSIGNMENTS[next(iter(_ASSIGNMENTS))]
        _ASSIGNMENTS[key] = hit
    return hit[0].copy(), hit[1]


def assignment_lower_bound(initial: Iterable[Cell | Coord], goal: Iterable[Cell | Coord]) -> int:
    """Minimum total hex distance over assignments of electrons to voids (a lower bound
    on the moves of any plan)."""
    i = {xy(c) for c in initial}
    g = {xy(c) for c in goal}
    electrons, voids = sorted(i - g), sorted(g - i)
    if not electrons:
        return 0
    _, total = electron_void_assignment(electrons, voids)
    return int(round(total))


def walk_reference(initial: Iterable[Cell | Coord], goal: Iterable[Cell | Coord]) -> int:
    """Minimum total cost over assignments of electrons to voids when each travels its
    shortest path through the cells of start and goal (adjacent cells, start | goal).

    Not a lower bound: a plan may build a bridge across free space. It is what a plan
    costs that walks its modules over the two structures, so the ratio of a plan to it
    says how much is lost to the planner, and its ratio to
    :func:`assignment_lower_bound` how much to the shapes (random trees: about 2x, as
    the paths run down one branch and up another). Start and goal must share a cell
    (a problem's both hold the fixed module), so every void is reachable.
    """
    i = {xy(c) for c in initial}
    g = {xy(c) for c in goal}
    electrons, voids = sorted(i - g), sorted(g - i)
    if not electrons:
        return 0
    graph = occupancy_graph(i | g)
    cost = np.array([[lengths[v] for v in voids]
                     for lengths in (nx.single_source_shortest_path_length(graph, e)
                                     for e in electrons)], dtype=float)
    _, total = min_cost_assignment(cost)
    return int(round(total))


def random_blob(n: int, rng: random.Random, start: Coord = (0, 0),
                forbidden: frozenset[Coord] = frozenset()) -> set[Coord]:
    """A random connected set of ``n`` cells grown from ``start`` (Eden growth)."""
    cells = {start}
    rim: list[Coord] = [c for c in neighbours_xy(start) if c not in forbidden]
    while len(cells) < n:
        k = rng.randrange(len(rim))
        rim[k], rim[-1] = rim[-1], rim[k]
        c = rim.pop()
        if c in cells:
            continue
        cells.add(c)
        rim.extend(m for m in neighbours_xy(c) if m not in cells and m not in forbidden)
    return cells


def random_problem(n: int, seed: int, name: str | None = None) -> Problem:
    """Eden family: two independent Eden blobs (:func:`random_blob`) of ``n`` modules
    sharing the fixed cell (0,0). Compact, so hard under Table 4-3 (module docstring)."""
    rng = random.Random(seed)
    initial = random_blob(n, rng)
    goal = random_blob(n, rng)
    return Problem.of(initial, goal, (0, 0), name=name or f"random-{n}-{seed}")


#: Most occupied neighbours a module of a sparse shape may have.
SPARSE_MAX_NEIGHBOURS = 3
#: Most occupied neighbours an empty cell next to a sparse shape may have (2: no two
#: branches run one cell apart, so a walker fits between them).
SPARSE_MAX_EMPTY_NEIGHBOURS = 2


def random_sparse_tree(n: int, rng: random.Random, start: Coord = (0, 0),
                       empty_max: int = SPARSE_MAX_EMPTY_NEIGHBOURS) -> set[Coord]:
    """A random tree of ``n`` cells grown from ``start`` ("sparse Eden" growth).

    Eden growth that accepts a rim cell only when it touches exactly one occupied cell
    (so the occupancy graph stays a tree) and when afterwards no module has more than
    :data:`SPARSE_MAX_NEIGHBOURS` occupied neighbours and no empty cell more than
    ``empty_max``. A rejected cell is never accepted later (counts only grow), so it is
    dropped. With ``empty_max=3`` branches may run one cell apart: the trees are denser
    but a walker cannot pass between such branches (see the module docstring).
    """
    cells: set[Coord] = set()
    count: dict[Coord, int] = {}

    def add(c: Coord) -> None:
        cells.add(c)
        for m in neighbours_xy(c):
            count[m] = count.get(m, 0) + 1

    add(start)
    rim = list(neighbours_xy(start))
    while len(cells) < n:
        k = rng.randrange(len(rim))
        rim[k], rim[-1] = rim[-1], rim[k]
        c = rim.pop()
        if c in cells or count.get(c, 0) != 1:
            continue
        if any(count.get(m, 0) >= (SPARSE_MAX_NEIGHBOURS if m in cells else empty_max)
               for m in neighbours_xy(c)):
            continue
        add(c)
        rim.extend(m for m in neighbours_xy(c) if m not in cells)
    return cells


def random_sparse_problem(n: int, seed: int, name: str | None = None,
                          empty_max: int = SPARSE_MAX_EMPTY_NEIGHBOURS) -> Problem:
    """Sparse family: two independent random trees (:func:`random_sparse_tree`) of ``n``
    modules sharing the fixed cell (0,0); in each, no module has more than three
    occupied neighbours and no empty cell more than ``empty_max`` (default two)."""
    rng = random.Random(seed)
    initial = random_sparse_tree(n, rng, empty_max=empty_max)
    goal = random_sparse_tree(n, rng, empty_max=empty_max)
    tag = "sparse" if empty_max == SPARSE_MAX_EMPTY_NEIGHBOURS else f"sparse{empty_max}"
    return Problem.of(initial, goal, (0, 0), name=name or f"{tag}-{n}-{seed}")


# --- the convex family ------------------------------------------------------------------
def random_hex_convex(n: int, rng: random.Random) -> set[Coord]:
    """A random hex-convex shape of exactly ``n`` cells (not yet placed; see
    :func:`random_convex_problem`).

    A hexagon with random side lengths -- the cells with ``0 <= x < w``, ``0 <= y < h``
    and ``lo <= x + y <= hi`` (half-planes along the three hex axes) -- with at least
    ``n`` cells, cut down to ``n`` by keeping its rows along a random axis direction
    in order, the last one partly (a contiguous run from one end of that row). The
    result is connected, has no holes, and only the partial row's end breaks convexity
    (the empty cell there touches three modules, so it can be entered).
    """
    if n <= 0:
        return set()
    s = max(1.0, n ** 0.5)
    while True:
        w = rng.randint(1, max(1, round(2.2 * s)))
        h = rng.randint(1, max(1, round(2.2 * s)))
        if w * h < n or w * h > 3 * n + 4 or max(w, h) > 4 * min(w, h) + 2:
            continue
        span = w + h - 2
        lo = rng.randint(0, min(w, h) - 1)
        hi = span - rng.randint(0, min(w, h) - 1)
        cells = [(x, y) for x in range(w) for y in range(h) if lo <= x + y <= hi]
        if n <= len(cells) <= 2 * n + 4:
            break
    # Rows: lines y = const, x = const or x + y = const; which end loses rows, and
    # which end of the last row is kept, are random.
    row, along = rng.choice(((1, 0), (0, 1), (2, 0)))
    def coord(c: Coord, k: int) -> int:
        return c[1] if k == 0 else c[0] if k == 1 else c[0] + c[1]
    s1, s2 = rng.choice((1, -1)), rng.choice((1, -1))
    cells.sort(key=lambda c: (s1 * coord(c, row), s2 * coord(c, along)))
    return set(cells[:n])


def random_convex_problem(n: int, seed: int, name: str | None = None) -> Problem:
    """Convex family: two independent random hex-convex shapes (:func:`random_hex_convex`)
    of ``n`` modules, each placed so that a random one of its cells is the fixed cell
    (0,0): they overlap partly, by a random amount. Smooth surfaces, so the shapes are
    easy under Table 4-3 (module docstring)."""
    rng = random.Random(seed)

    def placed() -> set[Coord]:
        cells = random_hex_convex(n, rng)
        ox, oy = rng.choice(sorted(cells))
        return {(x - ox, y - oy) for x, y in cells}

    initial = placed()
    goal = placed()
    return Problem.of(initial, goal, (0, 0), name=name or f"convex-{n}-{seed}")


# --- the scrambled family ---------------------------------------------------------------
def scramble(cells: set[Coord], moves: int, rng: random.Random, fixed: Coord = (0, 0)
             ) -> tuple[set[Coord], list[tuple[Coord, object]]]:
    """``cells`` after ``moves`` random legal rotations: each a random module with at
    most three occupied neighbours (others cannot move), not ``fixed``, not a cut
    vertex, by a random Table 4-3 row. Returns the final cells and the rotations
    ``(cell before, rule)`` in order."""
    occ = set(cells)
    order = sorted(occ)                 # random picks in O(1); a move replaces its entry
    path: list[tuple[Coord, object]] = []
    none: set[Coord] = set()
    while len(path) < moves:
        k = rng.randrange(len(order))
        c = order[k]
        if c == fixed or sum(n in occ for n in neighbours_xy(c)) > 3:
            continue
        occ.discard(c)
        steps = list(lone_steps(occ, c, none))
        occ.add(c)
        if not steps or is_cut(occ, c):
            continue
        rule, g = rng.choice(steps)
        occ.discard(c)
        occ.add(g)
        order[k] = g
        path.append((c, rule))
    return occ, path


def random_scrambled_problem(n: int, seed: int, name: str | None = None,
                             moves: int | None = None) -> Problem:
    """Scrambled family: an Eden blob (:func:`random_blob`) of ``n`` modules and, as the
    goal, the same blob after ``moves`` (default ``2 n``) random legal rotations
    (:func:`scramble`). Reachable by construction, so a planner that stops short of
    the goal of one is incomplete there. The random walkers leave thin tendrils and
    occasionally seal a pocket, which must be reopened."""
    rng = random.Random(seed)
    initial = random_blob(n, rng)
    goal, _ = scramble(initial, 2 * n if moves is None else moves, rng)
    return Problem.of(initial, goal, (0, 0), name=name or f"scrambled-{n}-{seed}")
