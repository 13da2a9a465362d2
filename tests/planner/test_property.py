"""Property: on random small connected instances the complete planner's plans are legal
and reach the goal, or it reports unreachability, which the exact search confirms."""

import random

from hypothesis import HealthCheck, given, settings, strategies as st

from planner_svc import planners
from planner_svc.planners.bounds import assignment_lower_bound, random_blob
from planner_svc.planners.plan import Problem, validate
from planner_svc.planners.exact import exact_reachable


@st.composite
def instances(draw):
    n = draw(st.integers(2, 6))
    rng = random.Random(draw(st.integers(0, 10_000)))
    initial = random_blob(n, rng)
    goal = random_blob(n, rng)
    obstacles = set()
    if draw(st.booleans()):
        rim = sorted({(x + dx, y + dy) for x, y in initial | goal
                      for dx, dy in ((1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1))}
                     - initial - goal)
        obstacles = set(rng.sample(rim, k=min(len(rim), draw(st.integers(0, 3)))))
    return Problem.of(initial, goal, (0, 0), obstacles)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(instances())
def test_complete_is_legal_and_right_about_reachability(problem):
    plan = planners.get("complete").plan(problem)
    validate(plan)                       # raises on any illegal move or a false success
    truth = exact_reachable(problem.initial, problem.goal, problem.fixed, problem.obstacles)
    if plan.ok:
        assert truth is not False
        assert plan.moves >= assignment_lower_bound(problem.initial, problem.goal)
    else:
        assert plan.reason.startswith("unreachable"), plan.reason
        assert truth is False


@settings(max_examples=25, deadline=None)
@given(instances())
def test_exact_is_no_worse_than_complete(problem):
    exact = planners.get("exact").plan(problem)
    complete = planners.get("complete").plan(problem)
    validate(exact)
    assert exact.ok == complete.ok
    if exact.ok:
        assert assignment_lower_bound(problem.initial, problem.goal) <= exact.moves <= complete.moves
