"""Planner benchmark: planning time and moves against the assignment lower bound.

Run alone: ``pytest -s tests/benchmarks/test_planner_bench.py``. Instances are two
independent random connected shapes (Eden growth from the fixed cell (0,0)) of 10, 100
and 1000 modules. The lower bound is the minimum-cost assignment of electrons to voids
by hex distance (Hungarian method in numpy). Target: 1000 modules in < 10 s with at
most 1.5x the bound. Figures are printed, not asserted (timing depends on the machine);
the test only asserts that every plan is legal.
"""

import time

import pytest

from planner_svc import planners
from planner_svc.bounds import assignment_lower_bound, random_problem
from planner_svc.plan import validate

CASES = [(10, range(5)), (100, range(3)), (1000, range(1))]
PLANNERS = ["complete", "thesis-serial"]


@pytest.mark.slow
def test_planner_benchmark():
    rows = []
    for n, seeds in CASES:
        for seed in seeds:
            problem = random_problem(n, seed)
            t0 = time.perf_counter()
            lb = assignment_lower_bound(problem.initial, problem.goal)
            lb_s = time.perf_counter() - t0
            for name in PLANNERS:
                if name == "thesis-serial" and n > 100:
                    continue  # value iteration per move: minutes at this size
                plan = planners.get(name).plan(problem)
                validate(plan)
                rows.append((n, seed, name, plan.ok, plan.moves, lb, lb_s, plan.seconds,
                             plan.reason))
    print()
    print(f"{'n':>5} {'seed':>4} {'planner':14} {'ok':3} {'moves':>6} {'bound':>6} {'ratio':>6} "
          f"{'bound s':>8} {'plan s':>8}  reason")
    for n, seed, name, ok, moves, lb, lb_s, secs, reason in rows:
        ratio = moves / lb if lb else float("nan")
        print(f"{n:5} {seed:4} {name:14} {'yes' if ok else 'no':3} {moves:6} {lb:6} {ratio:6.2f} "
              f"{lb_s:8.3f} {secs:8.3f}  {reason[:70]}")
    done = [r for r in rows if r[2] == "complete"]
    print(f"complete: {sum(r[3] for r in done)}/{len(done)} instances reached the goal "
          "(target: all; 1000 modules in < 10 s at <= 1.5x the bound)")
