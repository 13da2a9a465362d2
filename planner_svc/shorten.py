"""Plan shortening: drop the detours of a serial plan, keeping every move legal.

Planners that work locally (relay chains, window searches, digs) leave detours: a
module steps aside and later steps back, or the structure comes back to a configuration
it had. Modules are interchangeable, so a serial plan is a path through configurations
(sets of occupied cells), and two rewrites shorten it, repeated until neither applies:

* **loops**: when a configuration recurs, the moves between its two visits go;
* **returns**: a module moves ``a -> b`` and its next move is ``b -> a``; if every move
  in between is still legal with that module waiting at ``a`` (its Table 4-3 row and
  the connectivity of the rest), both go.

The result is rebuilt move by move on the configuration of its time (the joints a move
releases depend on who is next to it then) and checked as it is built; should any move
fail that check, the plan is returned unchanged.
"""

from __future__ import annotations

import random

from .complete import is_cut, lone_steps
from .plan import Plan
from .rules import Coord, Move, MoveRule, to_move, xy

#: Moves a return may span (the moves in between are rechecked).
RETURN_SPAN = 400
#: Rounds of both rewrites at most (each round that changes nothing ends it earlier).
ROUNDS = 6

Hop = tuple[Coord, Coord]


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


def drop_returns(initial: set[Coord], hops: list[Hop], fixed: Coord,
                 obstacles: set[Coord] | frozenset[Coord]) -> list[Hop]:
    """``hops`` without the step-aside-and-back pairs that nothing in between needs."""
    hops = list(hops)
    occ = set(initial)
    i = 0
    while i < len(hops):
        a, b = hops[i]
        j = next((j for j in range(i + 1, min(len(hops), i + RETURN_SPAN))
                  if hops[j][0] == b), None)
        if j is not None and hops[j][1] == a and _still_legal(occ, hops[i + 1:j], fixed,
                                                              obstacles):
            del hops[j]
            del hops[i]
            continue                # occ is still the configuration before hops[i]
        occ.discard(a)
        occ.add(b)
        i += 1
    return hops


def _still_legal(occ: set[Coord], hops: list[Hop], fixed: Coord,
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


def shorten(plan: Plan) -> int:
    """Shorten the serial ``plan`` in place; returns the moves it saved."""
    p = plan.problem
    if not plan.ok or any(len(step) != 1 for step in plan.steps):
        return 0
    initial = {xy(c) for c in p.initial}
    fixed = xy(p.fixed)
    obstacles = frozenset(xy(c) for c in p.obstacles)
    hops = [(xy(s[0].mobile), xy(s[0].goal)) for s in plan.steps]
    before = len(hops)
    for _ in range(ROUNDS):
        n = len(hops)
        hops = drop_returns(initial, drop_loops(initial, hops), fixed, obstacles)
        if len(hops) == n:
            break
    if len(hops) == before:
        return 0
    steps = rebuild(initial, hops, fixed, obstacles)
    if steps is None:
        return 0
    plan.steps = steps
    return before - len(hops)
