"""Planner benchmark: planning time and moves against the assignment lower bound.

Run alone: ``pytest -s tests/benchmarks/test_planner_bench.py``. Four families of random
connected instances of 10, 100 and 1000 modules sharing the fixed cell (0,0) (see
:mod:`planner_svc.planners.bounds`); in the first three start and goal are independent, in the
last the goal is the start scrambled:

* **eden**: compact Eden blobs (:func:`random_problem`). Hard under Table 4-3: a
  cell with four or more occupied neighbours can be neither entered nor left, so a
  blob's interior is frozen, a lone walker cannot cross a notch (an empty cell with
  four occupied neighbours) and holes inside thick regions must be dug open. The
  relays and local exchanges of ``complete`` stall on the instances of 100 and 1000
  modules; its last resort, hole digging (planned peels played forward and back),
  also between smoothed shapes (notches of start and goal filled first), solves the
  three of 100 modules (2.1-3.6x the bound once shortened and re-planned in windows,
  mean 2.66x, 8-16 s) and, with advances and a nearest-first peel for craters that end
  in a flat face, the one of 1000 (7.0x the bound, about a minute; of seeds 0-4, 0, 2
  and 3 are solved).
* **sparse**: random trees (:func:`random_sparse_problem`) in which no module has
  more than three occupied neighbours and no empty cell more than two, so walkers fit
  between branches. Note: these trees spread out (radius ~ n/4), so the bound and the
  plans grow fast (about 2.5e5 moves for 1000 modules), and walks follow the branches,
  so plans are about 2-2.5x the bound.
* **convex**: hex-convex shapes (:func:`random_convex_problem`; hexagons with random
  side lengths, the last row partial) overlapping partly. Smooth surfaces: corner
  modules peel off and walkers roll along flat faces, so ``complete`` fills the goal
  row by row (its front walks) with walks about 1.2-1.5x the hex distances.
* **scrambled**: an Eden blob and, as the goal, the same blob after 2n random legal
  rotations (:func:`random_scrambled_problem`): reachable by construction, so this
  family measures completeness. The random walkers leave thin tendrils and sometimes
  seal a pocket (an electron walled in), which must be reopened. At 1000 modules
  ``complete`` first descends the bound (moves that each lower it by one, window
  escapes where none does, fills of the last voids in wider windows) and the relays
  finish from there: seeds 0, 2 and 3 at 1.57x, 1.53x and 1.49x the bound once
  shortened and re-planned in windows, in 5-7 s (seed 2's descent reaches the goal with
  three fills; without them it stopped short, and the relays from where phase 1 stopped
  took it to 1.73x in 12 s); on seed 1 the descent's relays stop, and two digs from
  there take it to 1.58x in 8 s (12 s when the relays from the start and from where
  phase 1 stopped, which stop too, ran first).

Each instance also gets a *walk reference*
(:func:`planner_svc.planners.bounds.walk_reference`): the same assignment with each module's cost
its shortest path through the cells of start and goal. It is not a bound (a plan may
bridge free space) but it separates what the shapes cost from what the planner loses:
on random trees it is about 2x the bound.

The lower bound is the minimum-cost assignment of electrons to voids by hex distance
(Hungarian method in numpy). It ignores that modules must walk around the structure,
so no plan may reach it when material has to go around a large overlap. Target: 1000
modules in < 10 s with at most 1.5x the bound. Figures are printed, not asserted (timing
depends on the machine); the test asserts that every plan is legal. Plans longer than
:data:`FULL_VALIDATE` moves are checked move by move for their first
:data:`FULL_VALIDATE` moves only (the validator checks connectivity of the whole
structure per move: minutes for 5e5 moves) and replayed to the end to check that they
end in the goal. ``complete`` reuses the bound's assignment
(:func:`planner_svc.planners.bounds.electron_void_assignment`, computed first here), so its time
from scratch is "bound s" plus "plan s"; the summary lines count both. A summary line
per family gives, for ``complete``: instances solved, and per size the worst time
(bound + plan) and the worst and mean ratio to the bound; for 1000 modules, whether the
target is met and if not, what misses it.

A second benchmark times the ``exact`` planner (A* estimating each configuration's
assignment bound) on the thesis's scenarios and on the Eden and scrambled instances of
10 modules, and prints ``complete``'s moves beside its fewest (thesis-12: 18 moves in 1720
configurations, 0.6 s; ``complete`` ends with that search on fleets of 12 or fewer, so it
has 18 too).
"""

import time

import pytest

from bus.scenario import load
from planner_svc import planners
from planner_svc.planners.bounds import (assignment_lower_bound, random_convex_problem, random_problem,
                                random_scrambled_problem, random_sparse_problem, walk_reference)
from planner_svc.planners.plan import validate
from planner_svc.planners.rules import xy

FAMILIES = {"eden": random_problem, "sparse": random_sparse_problem,
            "convex": random_convex_problem, "scrambled": random_scrambled_problem}
CASES = [(10, range(5)), (100, range(3)), (1000, range(1))]
#: Convex and scrambled instances are quick: more seeds per size (scrambled blobs of 1000
#: modules vary: seed 1 seals a cave that must be dug open).
FAMILY_CASES = {"convex": [(10, range(5)), (100, range(5)), (1000, range(4))],
                "scrambled": [(10, range(5)), (100, range(3)), (1000, range(4))]}
PLANNERS = ["complete", "thesis-serial"]
FULL_VALIDATE = 20_000
#: The issue's target: fleets of this size planned in under TARGET_SECONDS (bound + plan)
#: with at most TARGET_RATIO times the bound's moves, on every instance.
TARGET_MODULES = 1000
TARGET_SECONDS = 10.0
TARGET_RATIO = 1.5


def _target(all_solved: bool, worst_time: float, worst_ratio: float) -> str:
    """Whether a family's largest instances meet the target, and if not, what misses."""
    missed = ([] if all_solved else ["not all solved"]) + (
        [f"time {worst_time:.1f} s > {TARGET_SECONDS:.0f} s"]
        if worst_time >= TARGET_SECONDS else []) + (
        [f"ratio {worst_ratio:.2f} > {TARGET_RATIO}"] if worst_ratio > TARGET_RATIO else [])
    return "; target met" if not missed else f"; target missed: {', '.join(missed)}"


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
        for n, seeds in FAMILY_CASES.get(family, CASES):
            for seed in seeds:
                problem = make(n, seed)
                t0 = time.perf_counter()
                lb = assignment_lower_bound(problem.initial, problem.goal)
                lb_s = time.perf_counter() - t0
                ref = walk_reference(problem.initial, problem.goal)
                for name in PLANNERS:
                    if name == "thesis-serial" and (n > 100 or family != "eden"):
                        continue  # value iteration per move: minutes at this size
                    plan = planners.get(name).plan(problem)
                    checked = _check(plan)
                    rows.append((family, n, seed, name, plan.ok, plan.moves, lb, lb_s,
                                 plan.seconds, checked, plan.reason, ref))
    print()
    print(f"{'family':7} {'n':>5} {'seed':>4} {'planner':14} {'ok':3} {'moves':>7} {'bound':>7} "
          f"{'ratio':>6} {'walkref':>7} {'ratio':>6} {'bound s':>8} {'plan s':>8} "
          f"{'validated':>11}  reason")
    for family, n, seed, name, ok, moves, lb, lb_s, secs, checked, reason, ref in rows:
        ratio = moves / lb if lb else float("nan")
        to_ref = moves / ref if ref else float("nan")
        print(f"{family:7} {n:5} {seed:4} {name:14} {'yes' if ok else 'no':3} {moves:7} {lb:7} "
              f"{ratio:6.2f} {ref:7} {to_ref:6.2f} {lb_s:8.3f} {secs:8.3f} {checked:>11}  "
              f"{reason[:60]}")
    for family in FAMILIES:
        done = [r for r in rows if r[0] == family and r[3] == "complete"]
        print(f"complete on {family}: {sum(r[4] for r in done)}/{len(done)} instances reached "
              f"the goal (target: all; {TARGET_MODULES} modules in < {TARGET_SECONDS:.0f} s at "
              f"<= {TARGET_RATIO}x the bound)")
        for n, _ in FAMILY_CASES.get(family, CASES):
            ok = [r for r in done if r[1] == n and r[4] and r[6]]
            if not ok:
                print(f"    n={n:5}: none solved")
                continue
            ratios = [r[5] / r[6] for r in ok]
            refs = [r[5] / r[11] for r in ok if r[11]]
            worst_time = max(r[7] + r[8] for r in ok)
            cases = sum(r[1] == n for r in done)
            print(f"    n={n:5}: solved {len(ok)}/{cases}, "
                  f"worst time {worst_time:.2f} s (bound + plan), "
                  f"ratio to bound worst "
                  f"{max(ratios):.2f} mean {sum(ratios) / len(ratios):.2f}, "
                  f"to walk reference mean {sum(refs) / max(len(refs), 1):.2f}"
                  + (_target(len(ok) == cases, worst_time, max(ratios))
                     if n == TARGET_MODULES else ""))


#: The exact planner's instances: the thesis's scenarios, and the Eden and scrambled
#: instances of 10 modules (sparse trees and convex shapes of 10 take it 4-22 s).
EXACT_CASES = [("thesis", name) for name in ("thesis-6", "thesis-6-reverse", "thesis-12")] + [
    (family, seed) for family in ("eden", "scrambled") for seed in range(5)]


@pytest.mark.slow
def test_exact_benchmark():
    # A* whose estimate is the assignment bound of each configuration: how many
    # configurations it expands, how long it takes, and how far ``complete`` is from the
    # fewest moves. Asserted: legal plans, and never more moves than ``complete``.
    print()
    print(f"{'instance':20} {'bound':>5} {'exact':>5} {'complete':>8} {'configs':>8} "
          f"{'exact s':>8}")
    for family, which in EXACT_CASES:
        problem = (planners.as_problem(load(which)) if family == "thesis"
                   else FAMILIES[family](10, which))
        exact = planners.get("exact").plan(problem)
        best = planners.get("complete").plan(problem)
        validate(exact)
        assert exact.ok and best.ok and exact.moves <= best.moves
        configs = next(n.split()[1] for n in exact.notes if n.startswith("exact:"))
        name = which if family == "thesis" else f"{family} 10 seed {which}"
        lb = assignment_lower_bound(problem.initial, problem.goal)
        print(f"{name:20} {lb:5} {exact.moves:5} {best.moves:8} {configs:>8} "
              f"{exact.seconds:8.2f}")
