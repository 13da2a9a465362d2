"""Plan shortening: drop the detours of a serial plan, keeping every move legal.

Planners that work locally (relay chains, window searches, digs) leave detours: a
module steps aside and later steps back, or the structure comes back to a configuration
it had. Modules are interchangeable, so a serial plan is a path through configurations
(sets of occupied cells), and two rewrites shorten it, repeated until neither applies:

* **loops**: when a configuration recurs, the moves between its two visits go;
* **round trips**: a module leaves a cell and its later moves bring it back there (a
  step aside and back, or a longer detour); if every other move in between is still
  legal with that module waiting in its cell (its Table 4-3 row and the connectivity
  of the rest), the trip goes. Trips are tried latest start first, so the trips nested
  in one are decided before it: a step aside inside a detour goes first and frees the
  detour in the same pass (tried earliest first, each pass freed one level: 29 passes
  instead of 3 on an Eden blob of 1000 modules).

A third rewrite, asked for with ``windows=True`` (``complete`` uses it on its final
plan), re-plans the plan piece by piece:

* **windows**: from each move, the stretch of the moves that follow it inside a small
  disk around it (the *window*, radius 2, 3 then 4), while every other move in the
  stretch keeps away from the window (no cell of it within 2 of the window, so its
  Table 4-3 row cannot change), is replaced by the fewest rotations inside the window
  that give the window the same cells at the end, if those are fewer (A* with the
  window's own assignment bound as the estimate, :func:`planner_svc.planners.exact.best_first`,
  the rest of the structure still); the other moves follow, and must still be legal.
  Relays, digs and walks that each look right leave such knots: three modules shuffle
  where two moves would do. The second round re-plans the plan played backwards (every
  rotation is reversible): its windows are centred where stretches end rather than where
  they start, and meet knots a second forward round would not (scrambled blobs of 1000
  modules: 19-32% fewer moves in all, 1-4% more than two rounds forwards in the same
  time).

The result is rebuilt move by move on the configuration of its time (the joints a move
releases depend on who is next to it then) and checked as it is built; should any move
fail that check, the plan is returned unchanged.
"""

from __future__ import annotations

import random
from typing import Iterable

from .bounds import assignment_cost
from .moves import disk, is_cut, lone_steps
from .plan import Plan
from .rules import Coord, Move, MoveRule, to_move, xy
from .exact import best_first
from .windows import window_moves

#: Moves a round trip may span (the moves in between are rechecked).
RETURN_SPAN = 2000
#: Rounds of both rewrites at most: dropping a loop or a trip can free another, so
#: rounds repeat until one changes nothing (Eden blobs: 2-3 rounds).
ROUNDS = 100
#: Window re-planning (:func:`replan_windows`): the windows' radii, tried in turn; rounds
#: of all three at most (forwards, backwards, ...); the configurations the search of one
#: window may expand; and those all windows of one plan may expand together. Each buys
#: moves with time: on scrambled blobs of 1000 modules 3000 per window and rounds until
#: nothing changes save 5% more in two to three times the time (4-7 s more); on Eden 1000
#: an allowance of 150 000 saves 6% more in 30 s more.
WINDOW_RADII = (2, 3, 4)
WINDOW_ROUNDS = 2
WINDOW_BUDGET = 1000
WINDOWS_ALLOWANCE = 60_000
#: The start of the note :func:`shorten` leaves when windows re-planned the plan.
WINDOWS_NOTE = "re-planned in windows"

Hop = tuple[Coord, Coord]
#: Assignment bounds of window searches: (cells too many, cells too few) -> bound.
Estimates = dict[tuple[frozenset[Coord], frozenset[Coord]], int]


def legal(occ: set[Coord], m: Coord, g: Coord, fixed: Coord,
          obstacles: set[Coord] | frozenset[Coord]) -> MoveRule | None:
    """The Table 4-3 row that legally takes the module at ``m`` to ``g``, if any."""
    if m == fixed or m not in occ or g in occ:
        return None
    for rule, dest in lone_steps(occ, m, obstacles):
        if dest == g:
            return None if is_cut(occ, m) else rule
    return None


def drop_loops(initial: set[Coord], hops: list[Hop]) -> list[Hop]:
    """``hops`` without the stretches that bring the configuration back to one it had."""
    rng = random.Random(0)
    key: dict[Coord, int] = {}

    def k(c: Coord) -> int:
        if c not in key:
            key[c] = rng.getrandbits(64)
        return key[c]

    h = 0
    for c in initial:
        h ^= k(c)
    out: list[Hop] = []
    hashes = [h]                    # hashes[i]: configuration after out[:i]
    where = {h: 0}
    for a, b in hops:
        h ^= k(a) ^ k(b)
        if h in where:              # back where the plan was after out[:i]: cut the loop
            i = where[h]
            for old in hashes[i + 1:]:
                del where[old]
            del out[i:]
            del hashes[i + 1:]
            continue
        out.append((a, b))
        hashes.append(h)
        where[h] = len(out)
    return out


def drop_round_trips(initial: set[Coord], hops: list[Hop], fixed: Coord,
                     obstacles: set[Coord] | frozenset[Coord]) -> list[Hop]:
    """``hops`` without the round trips that nothing in between needs: a module leaves
    a cell and, within :data:`RETURN_SPAN` moves, comes back to it, and every other
    move in between is still legal with it waiting there.

    Trips are tried latest start first, each on the plan's own configuration before it
    (nothing before a trip is dropped yet) and with the trips already dropped left out.
    Dropping one changes the configurations inside its span only, so every move kept
    has been checked on its final configuration by the earliest dropped trip around
    it. A trip sharing a move with a dropped trip that ends after it is kept: dropping
    both would leave its module where its next move does not start."""
    n = len(hops)
    # The index of the next move of the module a move brings to its goal cell (it is
    # the next move out of that cell), and of the move that first brings that module
    # back to the cell it left (one backward pass per module).
    nxt: list[int | None] = [None] * n
    first_out: dict[Coord, int] = {}
    for i in range(n - 1, -1, -1):
        a, b = hops[i]
        nxt[i] = first_out.get(b)
        first_out[a] = i
    back: list[int | None] = [None] * n
    followed = set(k for k in nxt if k is not None)
    for first in range(n):
        if first in followed:       # not the first move of its module
            continue
        chain = []
        k: int | None = first
        while k is not None:
            chain.append(k)
            k = nxt[k]
        arrives: dict[Coord, int] = {}
        for k in reversed(chain):
            back[k] = arrives.get(hops[k][0])
            arrives[hops[k][1]] = k
    #: Whether a move is dropped, and the last move of the trip it was dropped with.
    gone = [False] * n
    gone_end = [0] * n
    occ = set(initial)
    for a, b in hops:
        occ.discard(a)
        occ.add(b)
    for i in range(n - 1, -1, -1):
        a, b = hops[i]
        occ.discard(b)              # now the configuration before hops[i]
        occ.add(a)
        end = back[i]
        if end is None or end - i > RETURN_SPAN:
            continue
        trip = [i]
        while trip[-1] != end:
            trip.append(nxt[trip[-1]])
        if any(gone[k] and gone_end[k] > end for k in trip):
            continue
        mine = set(trip)
        # Lazily: most checks fail within a few moves of spans of hundreds.
        between = (hops[k] for k in range(i + 1, end) if not gone[k] and k not in mine)
        if still_legal(occ, between, fixed, obstacles):
            for k in trip:
                if not gone[k]:
                    gone[k], gone_end[k] = True, end
    return [h for h, g in zip(hops, gone) if not g]


def still_legal(occ: set[Coord], hops: Iterable[Hop], fixed: Coord,
                obstacles: set[Coord] | frozenset[Coord]) -> bool:
    """Whether ``hops`` can all be made, in order, from ``occ`` (left unchanged)."""
    made: list[Hop] = []
    ok = True
    for m, g in hops:
        if legal(occ, m, g, fixed, obstacles) is None:
            ok = False
            break
        occ.discard(m)
        occ.add(g)
        made.append((m, g))
    for m, g in reversed(made):
        occ.discard(g)
        occ.add(m)
    return ok


def replan_windows(initial: set[Coord], hops: list[Hop], fixed: Coord,
                   obstacles: set[Coord] | frozenset[Coord], radius: int,
                   allowance: int, estimates: Estimates | None = None
                   ) -> tuple[list[Hop], int]:
    """``hops`` with stretches re-planned in windows of ``radius`` (see the module
    docstring), and what is left of ``allowance`` (configurations the searches may
    expand). ``estimates`` keeps the searches' assignment bounds between calls (the
    rounds and radii of one plan meet the same windows again: half their bounds)."""
    hops = list(hops)
    occ = set(initial)                  # the configuration before hops[i]
    if estimates is None:
        estimates = {}

    def estimate(conf: frozenset[Coord], target: frozenset[Coord]) -> int:
        key = (conf - target, target - conf)
        if key not in estimates:
            estimates[key] = assignment_cost(key[0], key[1])
        return estimates[key]

    # The moves of the last window whose search failed: the windows of the next few
    # moves hold the same moves, or fewer, and fail as well (half the searches).
    failed: set[int] = set()
    i = 0
    while i < len(hops) and allowance > 0:
        window = set(disk(hops[i][0], radius))
        near = set(disk(hops[i][0], radius + 2))
        inside: list[int] = []
        others: list[Hop] = []
        k = i
        while k < len(hops):
            a, b = hops[k]
            if a in window and b in window:
                inside.append(k)
            elif a in near or b in near:
                break
            else:
                others.append(hops[k])
            k += 1
        new = None
        if len(inside) >= 2 and not set(inside) <= failed:
            start = frozenset(occ & window)
            target = frozenset(moved(start, [hops[j] for j in inside]))
            if estimate(start, target) < len(inside):
                found, expanded = best_first(
                    start, window_moves(window, occ - window, fixed, obstacles),
                    lambda conf: conf == target,
                    lambda g, conf: g + estimate(conf, target),
                    min(WINDOW_BUDGET, allowance), cap=len(inside) - 1)
                allowance -= expanded
                if found is None:
                    failed = set(inside)
                else:
                    confs = [conf for conf, _, _ in found] + [target]
                    new = [(m, next(iter(after - before)))
                           for (before, m, _), after in zip(found, confs[1:])]
        # The window's moves were searched with the rest still; the others now come
        # after them, and each must still be legal.
        if new is not None and still_legal(moved(occ, new), others, fixed, obstacles):
            hops[i:k] = new + others
            failed = set()
            continue
        a, b = hops[i]
        occ.discard(a)
        occ.add(b)
        i += 1
    return hops, allowance


def moved(occ: set[Coord] | frozenset[Coord], hops: list[Hop]) -> set[Coord]:
    """``occ`` after ``hops`` (a copy)."""
    out = set(occ)
    for a, b in hops:
        out.discard(a)
        out.add(b)
    return out


def rebuild(initial: set[Coord], hops: list[Hop], fixed: Coord,
            obstacles: set[Coord] | frozenset[Coord]) -> list[list[Move]] | None:
    """Serial steps for ``hops``, each move built and checked on its configuration;
    None if one is illegal."""
    occ = set(initial)
    steps: list[list[Move]] = []
    for m, g in hops:
        rule = legal(occ, m, g, fixed, obstacles)
        if rule is None:
            return None
        steps.append([to_move(occ, m, rule)])
        occ.discard(m)
        occ.add(g)
    return steps


def shorten(plan: Plan, windows: bool = False) -> int:
    """Shorten the finished serial ``plan`` in place (and say so in its notes); returns
    the moves it saved. ``windows``: re-plan it in windows too (:func:`replan_windows`)."""
    p = plan.problem
    if not plan.ok or any(len(step) != 1 for step in plan.steps):
        return 0
    initial = {xy(c) for c in p.initial}
    fixed = xy(p.fixed)
    obstacles = frozenset(xy(c) for c in p.obstacles)
    hops = [(xy(s[0].mobile), xy(s[0].goal)) for s in plan.steps]
    before = len(hops)
    hops = _drop_detours(initial, hops, fixed, obstacles)
    dropped = len(hops)
    if windows:
        hops = _replan_rounds(initial, hops, fixed, obstacles)
    if len(hops) == before:
        return 0
    steps = rebuild(initial, hops, fixed, obstacles)
    if steps is None:
        return 0
    plan.steps = steps
    if dropped < before:
        plan.notes.append(f"shortened by {before - dropped} moves (configuration loops and "
                          "round trips dropped)")
    if len(hops) < dropped:
        radii = f"{WINDOW_RADII[0]}-{WINDOW_RADII[-1]}"
        fewer = dropped - len(hops)
        plan.notes.append(f"{WINDOWS_NOTE}: {fewer} move{'s' if fewer > 1 else ''} fewer "
                          f"(stretches of moves inside disks of radius {radii} replaced by "
                          "the fewest rotations inside, found by A* search)")
    return before - len(hops)


def _replan_rounds(initial: set[Coord], hops: list[Hop], fixed: Coord,
                   obstacles: set[Coord] | frozenset[Coord]) -> list[Hop]:
    """Rounds of window re-planning (every radius in turn, detours dropped after each
    that saved moves), every other round on the plan played backwards.

    Backwards, a window starts at the plan's later moves and collects the earlier ones,
    so it meets other stretches: a round backwards saves more than a second round
    forwards, in the same time."""
    allowance = WINDOWS_ALLOWANCE
    final = moved(initial, hops)
    for round_ in range(WINDOW_ROUNDS):
        n = len(hops)
        backwards = round_ % 2 == 1
        start, seq = (final, _reversed(hops)) if backwards else (initial, hops)
        estimates: Estimates = {}
        for radius in WINDOW_RADII:
            m = len(seq)
            seq, allowance = replan_windows(start, seq, fixed, obstacles, radius,
                                            allowance, estimates)
            if len(seq) < m:
                seq = _drop_detours(start, seq, fixed, obstacles)
        hops = _reversed(seq) if backwards else seq
        if (len(hops) == n and round_ > 0) or allowance <= 0:
            break
    return hops


def _reversed(hops: list[Hop]) -> list[Hop]:
    """The plan played backwards: every rotation undone, last first (a rotation's
    reverse pivots about the same neighbour and sweeps the same cells)."""
    return [(b, a) for a, b in reversed(hops)]


def _drop_detours(initial: set[Coord], hops: list[Hop], fixed: Coord,
                  obstacles: set[Coord] | frozenset[Coord]) -> list[Hop]:
    """Rounds of both rewrites, until one changes nothing."""
    for _ in range(ROUNDS):
        n = len(hops)
        hops = drop_round_trips(initial, drop_loops(initial, hops), fixed, obstacles)
        if len(hops) == n:
            break
    return hops
