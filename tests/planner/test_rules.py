"""The one legality rule and the plan validator."""

import random

import pytest

from bus.lattice import Cell, Direction, Joint

from planner_svc.planners.bounds import random_blob
from planner_svc.planners.plan import PlanError, Problem, validate
from planner_svc.planners.rules import (Move, apply_step, find_move, is_connected, legal_moves,
                               move_violation, xy)


def C(x, y):
    return Cell(x, y)


LINE = {C(0, 0), C(1, 0), C(2, 0)}


def test_two_modules_rotate_about_each_other():
    moves = legal_moves({C(0, 0), C(1, 0)}, fixed=C(0, 0))
    # The free module can roll either way round its substrate: two cells.
    assert sorted(str(m.goal) for m in moves) == ["(0,1)", "(1,-1)"]
    assert all(m.substrate == C(0, 0) and m.release == () for m in moves)


def test_fixed_and_articulation_modules_never_move():
    movers = {m.mobile for m in legal_moves(LINE, fixed=C(0, 0))}
    assert movers == {C(2, 0)}


def test_obstacles_block_goal_and_sweep():
    free = legal_moves({C(0, 0), C(1, 0)}, fixed=C(0, 0))
    blocked = legal_moves({C(0, 0), C(1, 0)}, fixed=C(0, 0), obstacles={C(0, 1)})
    assert len(blocked) < len(free)
    assert all(C(0, 1) not in (m.goal, *m.swept) for m in blocked)


def test_every_legal_move_passes_the_checker_and_is_reversible():
    rng = random.Random(3)
    for _ in range(40):
        occ = {C(*c) for c in random_blob(rng.randint(2, 12), rng)}
        fixed = C(0, 0)
        for mv in legal_moves(occ, fixed):
            assert move_violation(occ, mv, fixed) is None
            after = {C(*c) for c in apply_step({xy(c) for c in occ}, [mv])}
            assert is_connected({xy(c) for c in after})
            back = find_move(after, mv.goal, mv.mobile, fixed)
            assert back is not None and back.substrate == mv.substrate


def test_checker_agrees_with_enumeration():
    """No move outside legal_moves passes move_violation (same rule, two evaluations)."""
    from planner_svc.planners.rules import RULE_OFFSETS, to_move
    rng = random.Random(5)
    for _ in range(40):
        occ = {xy(c) for c in random_blob(rng.randint(2, 10), rng)}
        legal = {(m.mobile, m.joint, m.direction) for m in legal_moves(occ, (0, 0))}
        for cell in occ:
            for rule, (sx, sy), _, _ in RULE_OFFSETS:
                if (cell[0] + sx, cell[1] + sy) not in occ:
                    continue
                mv = to_move(occ, cell, rule)
                ok = move_violation(occ, mv, (0, 0)) is None
                assert ok == ((mv.mobile, mv.joint, mv.direction) in legal)


def test_validator_names_the_broken_condition():
    problem = Problem.of(LINE, {C(0, 0), C(1, 0), C(1, 1)}, C(0, 0))
    good = find_move(LINE, C(2, 0), C(1, 1), C(0, 0))
    assert good is not None
    validate([[good]], LINE, problem.goal, C(0, 0))
    # Pivot on an empty cell.
    bad = Move(C(2, 0), C(1, 1), Joint.J1, Direction.CW, C(3, 0))
    with pytest.raises(PlanError, match="pivots on|no substrate"):
        validate([[bad]], LINE, None, C(0, 0))
    # The articulation module (1,0) leaving disconnects (2,0).
    cut = Move(C(1, 0), C(1, 1), good.joint, good.direction, C(0, 1))
    assert "step 1" in _why(lambda: validate([[cut]], LINE, None, C(0, 0)))
    # Wrong released joints.
    wrong = Move(good.mobile, good.goal, good.joint, good.direction, good.substrate,
                 ((C(0, 0), Joint.J1),))
    with pytest.raises(PlanError, match="released"):
        validate([[wrong]], LINE, None, C(0, 0))
    # Claimed goal not reached.
    with pytest.raises(PlanError, match="off the goal"):
        validate([], LINE, problem.goal, C(0, 0))


def test_fixed_module_cannot_move():
    mv = find_move({C(0, 0), C(1, 0)}, C(1, 0), C(0, 1), C(1, 0))
    assert mv is None


def test_two_movers_leaving_a_module_alone_is_a_disconnection():
    # Thesis Fig. 5-10: two electrons, each mobile alone, together strand a third module.
    ring = {C(0, 0), C(1, 0), C(2, -1), C(2, -2), C(1, -2), C(0, -1)}
    fixed = C(0, 0)
    movers = [m for m in legal_moves(ring, fixed) if m.mobile in (C(2, -1), C(1, -2))]
    pairs = [(a, b) for a in movers for b in movers if a.mobile != b.mobile]
    assert pairs
    for a, b in pairs:
        # Removing (2,-1) and (1,-2) leaves (2,-2) alone.
        assert move_violation(ring, a, fixed, (), [b]) is not None


def _why(fn):
    with pytest.raises(PlanError) as exc:
        fn()
    return str(exc.value)
