"""Bound descent: its assignment stays optimal, its moves lower the bound, it seals no
void, and ``complete`` uses it where voids are near their electrons."""

import random

import pytest

from planner_svc.planners import descent
from planner_svc.planners.complete import phases
from planner_svc.planners.complete.relays import Heuristic
from planner_svc.planners.complete.steps import play
from planner_svc.planners.bounds import (assignment_lower_bound, random_blob, random_problem,
                                random_scrambled_problem, scramble)
from planner_svc.planners.descent import Assignment, descend
from planner_svc.planners.moves import GOAL_OFFSET, enterable, is_cut, lone_steps
from planner_svc.planners.plan import Plan, Problem, validate
from planner_svc.planners.rules import hex_distance, neighbours_xy, xy


def _cells(problem):
    return {xy(c) for c in problem.initial}, {xy(c) for c in problem.goal}


def _relays_made(monkeypatch):
    """Record every relay run ``complete`` makes: (its plan, its keyword arguments)."""
    made = []
    init = Heuristic.__init__

    def recording(self, plan, *args, **kwargs):
        made.append((plan, kwargs))
        init(self, plan, *args, **kwargs)

    monkeypatch.setattr(Heuristic, "__init__", recording)
    return made


def test_a_change_of_minus_one_leaves_an_optimal_assignment():
    # Every legal move of a few scrambled blobs: where the cheapest exchange lowers the
    # assignment's cost by one, the updated assignment is a true minimum (the bound of
    # the new configuration) and pairs every electron with a distinct void.
    checked = 0
    for seed in range(6):
        rng = random.Random(seed)
        start = random_blob(40, rng)
        goal, _ = scramble(start, 60, rng)
        for m in sorted(start - {(0, 0)}):
            if is_cut(start, m):
                continue
            for _, b in lone_steps(start, m, set()):
                bound = Assignment(start, goal)
                change = bound.change(m, b)
                assert change[0] >= -1
                if change[0] != -1:
                    continue
                bound.apply(m, b, change)
                after = (start - {m}) | {b}
                assert bound.cost == assignment_lower_bound(after, goal)
                assert bound.cost == sum(hex_distance(e, v) for e, v in bound.void_of.items())
                assert set(bound.void_of) == after - goal
                assert set(bound.void_of.values()) == goal - after
                checked += 1
    assert checked > 20


def test_descending_moves_lower_the_bound_and_seal_nothing():
    # Scrambled blobs of 120 modules: the path is legal; outside the escapes every move
    # lowers the bound by exactly one and leaves every enterable void near it enterable.
    descending = 0
    for seed in range(3):
        problem = random_scrambled_problem(120, seed)
        start, goal = _cells(problem)
        occ = set(start)
        path, escapes, fills = descend(occ, goal, (0, 0))
        inside = {i for first, n in escapes + fills for i in range(first, first + n)}
        cur = set(start)
        bound = assignment_lower_bound(cur, goal)
        for i, (m, rule) in enumerate(path):
            ox, oy = GOAL_OFFSET[rule]
            b = (m[0] + ox, m[1] + oy)
            after = (cur - {m}) | {b}
            now = assignment_lower_bound(after, goal) if after != goal else 0
            if i not in inside:
                assert now == bound - 1, i
                assert not any(enterable(cur, w) and not enterable(after, w)
                               for w in goal - after if hex_distance(w, b) <= 2)
                descending += 1
            cur, bound = after, now
        assert cur == occ
        plan = Plan("descent", problem)
        plan.steps = play(set(start), path)
        assert not plan.ok and {xy(c) for c in validate(plan)} == occ    # every move legal
    assert descending > 60


def test_complete_descends_on_large_scrambled_blobs_only():
    # Above SMOOTH_LIMIT modules, voids 2-3 cells from their electrons: complete descends
    # first, and its plan is legal. An Eden blob's voids are far: no descent.
    problem = random_scrambled_problem(phases.SMOOTH_LIMIT + 10, 0)
    plan = Plan("complete", problem)
    phases.plan_complete(plan)
    validate(plan)
    assert any(n.startswith("bound descent:") for n in plan.notes)
    assert phases._local(problem)
    # The note counts the relays' moves after the descent's, once they have run.
    relays = phases._descended("complete", problem, True)
    note = next(n for n in relays.plan.notes if n.startswith("bound descent:"))
    added = relays.plan.moves - int(note.split()[2])
    assert note.endswith("; it reached the goal") if relays.plan.ok and not added else (
        f"; relays from there: {added} moves" in note)
    assert not phases._local(random_problem(phases.SMOOTH_LIMIT + 10, 0))


def test_descent_keeps_off_obstacles():
    # A third of the free cells next to start or goal are obstacles: every move of the
    # descent, descending or escaping, is legal among them.
    moved = 0
    for seed in range(3):
        problem = random_scrambled_problem(120, seed)
        start, goal = _cells(problem)
        rng = random.Random(seed)
        rim = sorted({n for c in start | goal for n in neighbours_xy(c)} - start - goal)
        obstacles = set(rng.sample(rim, len(rim) // 3))
        problem = Problem.of(start, goal, (0, 0), obstacles)
        occ = set(start)
        path, _, _ = descend(occ, goal, (0, 0), obstacles)
        plan = Plan("descent", problem)
        plan.steps = play(set(start), path)
        assert {xy(c) for c in validate(plan)} == occ and not occ & obstacles
        moved += len(path)
    assert moved > 30                                  # 41


def test_a_fill_finishes_where_no_escape_is_left(monkeypatch):
    # Scrambled 120 seed 30: the escapes run out with one void left, walled in a few cells
    # from its electron; a fill (a wider window) takes the last pair out, the bound lower,
    # and the descent reaches the goal. Every move is legal.
    problem = random_scrambled_problem(120, 30)
    start, goal = _cells(problem)
    occ = set(start)
    path, _, fills = descend(occ, goal, (0, 0))
    assert occ == goal and fills
    plan = Plan("descent", problem)
    plan.steps = play(set(start), path)
    assert {xy(c) for c in validate(plan)} == goal            # every move legal
    configurations = [{xy(c) for c in conf} for conf in plan.configurations()]
    for first, n in fills:
        before, after = configurations[first], configurations[first + n]
        assert len(goal - after) == len(goal - before) - 1
        assert assignment_lower_bound(after, goal) < assignment_lower_bound(before, goal)
    monkeypatch.setattr(descent, "FILL_VOIDS", 0)
    occ = set(start)
    descend(occ, goal, (0, 0))
    assert occ != goal


@pytest.mark.slow
def test_stuck_relays_keep_the_descents_digs(monkeypatch):
    # Scrambled 1000 seed 18: the descent and its relays stop, so do the relays from the
    # start and from where phase 1 stopped. Digging on from where the descent stopped
    # reaches the goal within DUG_KEEP times the bound, so that plan is kept at once:
    # neither the reverse problem nor the last resort's other tries run.
    problem = random_scrambled_problem(1000, 18)
    made = _relays_made(monkeypatch)
    smoothed = []
    monkeypatch.setattr(phases, "smoothed_plan", lambda *a, **k: smoothed.append(a))
    plan = Plan("complete", problem)
    phases.plan_complete(plan)
    validate(plan)
    assert plan.ok and phases.DESCENT_DUG_NOTE in plan.notes
    # Neither the reverse problem's relays, nor pinned relays, nor smoothed shapes.
    assert not [p for p, kw in made if p.problem.initial == problem.goal or kw.get("pins")]
    assert not smoothed
    assert plan.moves <= phases.DUG_KEEP * assignment_lower_bound(*_cells(problem))


@pytest.mark.slow
def test_a_short_dig_from_the_descent_is_kept_before_other_relays(monkeypatch):
    # Scrambled 400 seed 13: the descent's relays stop. A few digs from there reach the
    # goal within DUG_EARLY times the bound, so that plan is kept and no relays run from
    # the start (with DUG_EARLY = 0 they do, and the plan comes from them).
    problem = random_scrambled_problem(400, 13)
    made = _relays_made(monkeypatch)
    plan = Plan("complete", problem)
    phases.plan_complete(plan)
    validate(plan)
    assert plan.ok and phases.DESCENT_DUG_NOTE in plan.notes
    starts = [kw.get("start") for _, kw in made]
    assert len(starts) == 1 and starts[0] is not None     # the descent's relays only
    assert plan.moves <= phases.DUG_EARLY * assignment_lower_bound(*_cells(problem))
