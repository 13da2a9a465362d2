"""Planner benchmark: planning time and moves against the assignment lower bound.

Run alone: ``pytest -s tests/benchmarks/test_planner_bench.py``. Two families of random
connected instances of 10, 100 and 1000 modules, start and goal independent and sharing
the fixed cell (0,0) (see :mod:`planner_svc.bounds`):

* **eden**: compact Eden blobs (:func:`random_problem`). Hard under Table 4-3: a
  cell with four or more occupied neighbours can be neither entered nor left, so a
  blob's interior is frozen, a lone walker cannot cross a notch (an empty cell with
  four occupied neighbours) and holes inside thick regions must be dug open.
* **sparse**: random trees (:func:`random_sparse_problem`) in which no module has
  more than three occupied neighbours and no empty cell more than two, so walkers fit
  between branches. Note: these trees spread out (radius ~ n/4), so the bound and the
  plans grow fast (about 2.5e5 moves for 1000 modules).

The lower bound is the minimum-cost assignment of electrons to voids by hex distance
(Hungarian method in numpy). Target: 1000 modules in < 10 s with at most 1.5x the bound.
Figures are printed, not asserted (timing depends on the machine); the test asserts
that every plan is legal. Plans longer than :data:`FULL_VALIDATE` moves are checked
move by move for their first :data:`FULL_VALIDATE` moves only (the validator checks
connectivity of the whole structure per move: minutes for 5e5 moves) and replayed to
the end to check that they end in the goal.
"""

import time

import pytest

from planner_svc import planners
from planner_svc.bounds import assignment_lower_bound, random_problem, random_sparse_problem
from planner_svc.plan import validate
from planner_svc.rules import xy

FAMILIES = {"eden": random_problem, "sparse": random_sparse_problem}
CASES = [(10, range(5)), (100, range(3)), (1000, range(1))]
PLANNERS = ["complete", "thesis-serial"]
FULL_VALIDATE = 20_000


def _check(plan) -> str:
    """Validate ``plan`` (in part when long); returns how much was checked."""
    if plan.moves <= FULL_VALIDATE:
        validate(plan)
        return "full"
    p = plan.problem
    validate(plan.steps[:FULL_VALIDATE], p.initial, None, p.fixed, p.obstacles)
    occ = {xy(c) for c in p.initial}
    for step in plan.steps:
        for mv in step:
            occ.discard(xy(mv.mobile))
            occ.add(xy(mv.goal))
    if plan.ok:
        assert occ == {xy(c) for c in p.goal}, "plan claims success but misses the goal"
    return f"first {FULL_VALIDATE}"


@pytest.mark.slow
def test_planner_benchmark():
    rows = []
    for family, make in FAMILIES.items():
        for n, seeds in CASES:
            for seed in seeds:
                problem = make(n, seed)
                t0 = time.perf_counter()
                lb = assignment_lower_bound(problem.initial, problem.goal)
                lb_s = time.perf_counter() - t0
                for name in PLANNERS:
                    if name == "thesis-serial" and (n > 100 or family == "sparse"):
                        continue  # value iteration per move: minutes at this size
                    plan = planners.get(name).plan(problem)
                    checked = _check(plan)
                    rows.append((family, n, seed, name, plan.ok, plan.moves, lb, lb_s,
                                 plan.seconds, checked, plan.reason))
    print()
    print(f"{'family':7} {'n':>5} {'seed':>4} {'planner':14} {'ok':3} {'moves':>7} {'bound':>7} "
          f"{'ratio':>6} {'bound s':>8} {'plan s':>8} {'validated':>11}  reason")
    for family, n, seed, name, ok, moves, lb, lb_s, secs, checked, reason in rows:
        ratio = moves / lb if lb else float("nan")
        print(f"{family:7} {n:5} {seed:4} {name:14} {'yes' if ok else 'no':3} {moves:7} {lb:7} "
              f"{ratio:6.2f} {lb_s:8.3f} {secs:8.3f} {checked:>11}  {reason[:60]}")
    for family in FAMILIES:
        done = [r for r in rows if r[0] == family and r[3] == "complete"]
        print(f"complete on {family}: {sum(r[4] for r in done)}/{len(done)} instances reached "
              "the goal (target: all; 1000 modules in < 10 s at <= 1.5x the bound)")
