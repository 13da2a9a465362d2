"""Admissible goals for Walter's algorithm, generated: n modules, a path cost class.

:func:`generate` lays a substrate path of the asked cost class west to east (cost 0: one
straight non-vertical run; cost 1: one NE/SE bend; cost > 1: two bends or a vertical step),
hangs contiguous columns north and south of it, turns the whole goal into a random
orientation and keeps it only if :func:`choose` finds it admissible with a path of that
class and (``world_safe``) the round model's moves are all legal in the HexBot world.
Deterministic for a seed.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

from bus.lattice import Cell

from .choose import Choice, Inadmissible, choose
from .frame import Heading, unturn
from .rounds import RoundModel, Schedule

COST_CLASSES = ("0", "1", ">1")


@dataclass
class Generated:
    goal: frozenset[Cell]
    choice: Choice
    seed: int
    tries: int


def _path(rng: random.Random, length: int, cost_class: str) -> list[Cell]:
    first = rng.choice((Heading.NE, Heading.SE))
    other = Heading.SE if first is Heading.NE else Heading.NE
    if cost_class == "0":
        steps = [first] * (length - 1)
    elif cost_class == "1":
        bend = rng.randint(1, max(1, length - 2))
        steps = [first] * bend + [other] * (length - 1 - bend)
    else:
        a = rng.randint(1, max(1, (length - 1) // 3))
        b = rng.randint(1, max(1, (length - 1) // 3))
        steps = [first] * a + [other] * b + [first] * max(1, length - 1 - a - b)
    cells = [Cell(0, 0)]
    for h in steps[:length - 1]:
        cells.append(h.of(cells[-1]))
    return cells


def _goal(rng: random.Random, n: int, cost_class: str) -> set[Cell]:
    min_len = {"0": 2, "1": 3, ">1": 4}[cost_class]
    length = rng.randint(min_len, max(min_len, min(n, n // 2 + 2)))
    path = _path(rng, length, cost_class)
    goal = set(path)
    xs = sorted({c.x for c in path})
    top = {x: max(c.y for c in path if c.x == x) for x in xs}
    bottom = {x: min(c.y for c in path if c.x == x) for x in xs}
    while len(goal) < n:
        x = rng.choice(xs)
        if rng.random() < 0.5:
            top[x] += 1
            goal.add(Cell(x, top[x]))
        else:
            bottom[x] -= 1
            goal.add(Cell(x, bottom[x]))
    return goal


def _fill_order_ok(goal: frozenset[Cell], choice: Choice) -> bool:
    """A quick look before the round model: in the schedule's fill order, each cell's
    already-filled neighbours form one run of at most three sides (a HexBot cannot turn
    into a cell that has more, Table 4-3)."""
    s = Schedule(goal, choice.path, choice.orientation)
    filled = set(choice.path)
    for cell in s.north + s.south:
        sides = [cell.neighbour(k) in filled for k in range(1, 7)]
        runs = sum(sides[i] and not sides[i - 1] for i in range(6))
        if sum(sides) > 3 or runs > 1:
            return False
        filled.add(cell)
    return True


def generate(n: int, cost_class: str, seed: int = 0, world_safe: bool = True,
             max_tries: int = 400) -> Generated:
    """An admissible goal of ``n`` cells whose chosen substrate path is of ``cost_class``."""
    if cost_class not in COST_CLASSES:
        raise ValueError(f"cost class {cost_class!r}: expected one of {', '.join(COST_CLASSES)}")
    if n < 3:
        raise ValueError("n must be at least 3")
    rng = random.Random(f"walter-{n}-{cost_class}-{seed}")
    for tries in range(1, max_tries + 1):
        k = rng.randrange(6)
        goal = frozenset(unturn(c, k) for c in _goal(rng, n, cost_class))
        try:
            choice = choose(goal, model=False)
        except Inadmissible:
            continue
        if choice.candidate.cost_class != cost_class:
            continue
        if world_safe and not _fill_order_ok(goal, choice):
            continue
        try:
            rep = RoundModel(goal, choice.chain, choice.path, choice.orientation,
                             stop_on_refusal=world_safe).report()
        except ValueError:
            continue
        if not rep.reached or rep.collisions or (world_safe and rep.world_refusals):
            continue
        choice.rounds, choice.moves, choice.reached = rep.rounds, rep.moves, rep.reached
        choice.world_refusals = rep.world_refusals
        return Generated(goal, choice, seed, tries)
    raise ValueError(f"no admissible goal of {n} cells with a cost {cost_class} path in "
                     f"{max_tries} tries (seed {seed})")
