"""Rotations into the plan's moves: a path of ``(cell, Table 4-3 row)`` played on a
structure, each move with the joints its neighbours release (Table 3-2), and a serial
plan played backwards (every rotation is undone about the same substrate)."""

from __future__ import annotations

import functools

from bus.lattice import NEIGHBOUR_OFFSET, Cell, Side

from ..moves import Path
from ..plan import Plan, Problem
from ..rules import RULE_OFFSETS, Coord, Move, MoveRule, find_move, to_move, xy

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
    """:func:`planner_svc.planners.rules.to_move` for a walker at ``mobile`` over ``rest`` (the
    structure without the walker), with the side tables precomputed: the same Move."""
    (sx, sy), (gx, gy), sides = _RULE_RELEASE[rule]
    x, y = mobile
    release = tuple((_cell(x + dx, y + dy), j) for (dx, dy), joints in sides
                    if (x + dx, y + dy) in rest for j in joints)
    return Move(_cell(x, y), _cell(x + gx, y + gy), rule.joint, rule.direction,
                _cell(x + sx, y + sy), release)

def reverse_steps(plan: Plan, problem: Problem) -> list[list[Move]]:
    """A serial plan played backwards: each rotation undone about the same substrate."""
    confs = plan.configurations()
    out: list[list[Move]] = []
    for conf, (mv,) in zip(reversed(confs[1:]), reversed(plan.steps)):
        back = find_move(conf, mv.goal, mv.mobile, problem.fixed, problem.obstacles)
        assert back is not None, "moves are reversible"
        out.append([back])
    return out
