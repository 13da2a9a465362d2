"""``exact``: A* over whole configurations (small fleets).

Modules are interchangeable, so a configuration is the set of occupied cells. The
successors of a configuration are its :func:`planner_svc.planners.rules.legal_moves`; the
heuristic is the lower bound of :mod:`planner_svc.planners.bounds` taken from the configuration
(the minimum-cost assignment of its electrons to its voids by hex distance). A move
carries one module one cell and changes that cost by at most one, so it never
overestimates, and the first plan found has the fewest moves. (The hex distance of each
electron to its nearest goal cell, the heuristic before, is weaker: on the benchmark's
instances of 10 modules the search expanded 3-20 times as many configurations and gave
up on 4 of 20 within its limit; now it solves all 20, in 79 s instead of about 290 s,
and in 30 s since the estimate's small assignments run on lists,
:func:`planner_svc.planners.bounds.assignment_cost`.)

The lattice is unbounded, so the search is confined to a *region*: no module may
enter a cell farther than ``margin`` (default 3) from the initial or goal cells.
"Unreachable" therefore means "unreachable without leaving that region" and the reason
says so. The search also stops after ``max_configurations`` expansions and reports that
it gave up.
"""

from __future__ import annotations

import heapq
import itertools
from typing import Callable, Iterable

from bus.lattice import Cell

from .bounds import assignment_cost
from .plan import Plan
from .moves import GOAL_OFFSET
from .rules import Coord, legal_xy, to_move, xy

DEFAULT_MARGIN = 3
DEFAULT_MAX_CONFIGURATIONS = 200_000


def region_around(cells: set[Coord], margin: int) -> set[Coord]:
    """All cells within hex distance ``margin`` of ``cells``."""
    out = set(cells)
    rim = set(cells)
    for _ in range(margin):
        nxt = set()
        for c in rim:
            for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, -1), (-1, 1)):
                n = (c[0] + dx, c[1] + dy)
                if n not in out:
                    nxt.add(n)
        out |= nxt
        rim = nxt
    return out


def best_first(start: frozenset[Coord],
               successors: Callable[[frozenset[Coord]],
                                    Iterable[tuple[Coord, object, frozenset[Coord]]]],
               is_goal: Callable[[frozenset[Coord]], bool],
               priority: Callable[[int, frozenset[Coord]], float], budget: int,
               cap: float | None = None
               ) -> tuple[list[tuple[frozenset[Coord], Coord, object]] | None, int]:
    """Best-first search over configurations, one rotation per edge.

    ``successors(conf)`` yields ``(mobile, rule, next configuration)``; a configuration
    reached with ``g`` moves is queued by ``priority(g, conf)`` (A* when that is ``g`` plus
    an admissible estimate). Returns the path as ``(configuration before, mobile, rule)``
    from ``start`` to the first goal taken off the queue, or None (no goal reachable, more
    than ``budget`` expansions, or a priority above ``cap`` taken off the queue: with a
    consistent estimate, no plan of ``cap`` moves or fewer), and the number of expansions.
    """
    tie = itertools.count()
    parent: dict[frozenset[Coord], tuple[frozenset[Coord], Coord, object] | None] = {start: None}
    cost = {start: 0}
    heap = [(priority(0, start), next(tie), start)]
    expanded = 0
    while heap:
        f, _, conf = heapq.heappop(heap)
        if cap is not None and f > cap:
            return None, expanded
        if is_goal(conf):
            path = []
            while (link := parent[conf]) is not None:
                path.append(link)
                conf = link[0]
            return path[::-1], expanded
        expanded += 1
        if expanded > budget:
            return None, expanded
        g = cost[conf] + 1
        for m, rule, nxt in successors(conf):
            if g < cost.get(nxt, 1 << 30):
                cost[nxt] = g
                parent[nxt] = (conf, m, rule)
                heapq.heappush(heap, (priority(g, nxt), next(tie), nxt))
    return None, expanded


def search_moves(start: frozenset[Coord], goal: frozenset[Coord], fixed: Coord,
                 obstacles: set[Coord], region: set[Coord], max_configurations: int,
                 cap: int | None = None
                 ) -> tuple[list[tuple[frozenset[Coord], Coord, object]] | None, int]:
    """A* from ``start`` to ``goal``, never moving a module out of ``region``. Returns
    the path as a list of (configuration before, mobile, rule), or None if the goal is
    unreachable (or the limit hit, or it takes more than ``cap`` moves), and the number
    of expansions."""
    goal_list = sorted(goal)

    def h(conf: frozenset[Coord]) -> int:
        electrons = sorted(conf - goal)
        if not electrons:
            return 0
        return assignment_cost(electrons, [g for g in goal_list if g not in conf])

    def successors(conf: frozenset[Coord]):
        occ = set(conf)
        for _, m, rule in legal_xy(occ, fixed, obstacles):
            go = GOAL_OFFSET[rule]
            dest = (m[0] + go[0], m[1] + go[1])
            if dest in region:
                yield m, rule, frozenset(occ - {m} | {dest})

    return best_first(start, successors, lambda conf: conf == goal, lambda g, conf: g + h(conf),
                      max_configurations, cap)


def _search(occ: Iterable[Cell | Coord], goal: Iterable[Cell | Coord], fixed: Cell | Coord,
            obstacles: Iterable[Cell | Coord], margin: int, max_configurations: int,
            cap: int | None = None
            ) -> tuple[list[tuple[frozenset[Coord], Coord, object]] | None, int]:
    """:func:`search_moves` from ``occ`` to ``goal`` (cells or tuples), within ``margin`` of
    both."""
    start = frozenset(xy(c) for c in occ)
    end = frozenset(xy(c) for c in goal)
    region = region_around(set(start | end), margin)
    return search_moves(start, end, xy(fixed), {xy(c) for c in obstacles}, region,
                        max_configurations, cap)


def search_from(plan: Plan, occ: Iterable[Cell | Coord], margin: int = DEFAULT_MARGIN,
                max_configurations: int = DEFAULT_MAX_CONFIGURATIONS) -> int:
    """Append to ``plan`` the fewest moves from the configuration ``occ`` to its goal and
    set ``plan.ok``, or say in ``plan.reason`` why there are none. Returns the number of
    configurations expanded."""
    p = plan.problem
    path, expanded = _search(occ, p.goal, p.fixed, p.obstacles, margin, max_configurations)
    if path is None:
        if expanded > max_configurations:
            plan.reason = f"exact search gave up after {max_configurations} configurations"
        else:
            plan.reason = (f"unreachable: the exact search found no plan within {margin} cells "
                           f"of the configurations ({expanded} configurations explored)")
        return expanded
    plan.steps.extend([to_move(conf, m, rule)] for conf, m, rule in path)
    plan.ok = True
    return expanded


def fewer_moves(plan: Plan, margin: int = DEFAULT_MARGIN,
                max_configurations: int = DEFAULT_MAX_CONFIGURATIONS) -> bool | None:
    """Replace the steps of the finished serial ``plan`` by a plan with the fewest moves if
    that is fewer (True); False if none is fewer within ``margin``, None if the search
    gave up first. Only configurations that could lead to a shorter plan are expanded,
    so a plan close to the fewest costs little to confirm."""
    p = plan.problem
    path, expanded = _search(p.initial, p.goal, p.fixed, p.obstacles, margin,
                             max_configurations, cap=plan.moves - 1)
    if path is None:
        return None if expanded > max_configurations else False
    plan.steps = [[to_move(conf, m, rule)] for conf, m, rule in path]
    return True


def plan_exact(plan: Plan, margin: int = DEFAULT_MARGIN,
               max_configurations: int = DEFAULT_MAX_CONFIGURATIONS) -> None:
    """Fill ``plan`` with a fewest-moves serial plan, or say why there is none."""
    expanded = search_from(plan, plan.problem.initial, margin, max_configurations)
    if plan.ok:
        plan.notes.append(f"exact: {expanded} configurations expanded; plan has the fewest "
                          "moves within the search region")


def exact_reachable(initial, goal, fixed, obstacles=(), margin: int = DEFAULT_MARGIN,
                    max_configurations: int = DEFAULT_MAX_CONFIGURATIONS) -> bool | None:
    """True/False if the search decides reachability, None if it hit its limit."""
    path, expanded = _search(initial, goal, fixed, obstacles, margin, max_configurations)
    if path is None and expanded > max_configurations:
        return None
    return path is not None


__all__ = ["plan_exact", "exact_reachable", "fewer_moves", "region_around", "Cell"]
