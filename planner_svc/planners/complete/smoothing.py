"""Smoothed shapes: notches of the start and the goal filled first (:func:`smooth`), so
lone walkers get further, and a plan through them (:func:`smoothed_plan`). See
:mod:`planner_svc.planners.complete`."""

from __future__ import annotations

from ..moves import Path
from ..plan import Plan, Problem
from ..rules import Coord, Move, neighbours_xy, xy
from ..windows import local_repair
from .digging import HOLE_CALLS
from .relays import Heuristic
from .steps import play, reverse_steps

#: Smoothing (:func:`smooth`): local repair window radius and expansions per notch.
SMOOTH_WINDOW = (3, 1500)

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
    relays = Heuristic(mid, advance=advance)
    relays.run()
    if not mid.ok:
        Heuristic(mid, start=relays.occ, holes=True, advance=advance,
                   hole_calls=hole_calls).run()
    if not mid.ok:
        return False
    back = Plan(plan.planner, Problem.of(goal, out, fixed, ob, p.name))
    back.steps = tail
    plan.steps = head + mid.steps + reverse_steps(back, p)
    plan.ok = True
    return True
