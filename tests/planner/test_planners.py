"""Planners on the thesis scenarios, the registry, the CLI and the drawing."""

import pytest

from hexbench.cli import main
from bus.scenario import load

from planner_svc import planners
from planner_svc.planners import exact, shorten
from planner_svc.planners.complete import phases
from planner_svc.planners.bounds import random_problem, random_scrambled_problem
from planner_svc.planners.moves import GOAL_OFFSET
from planner_svc.planners.plan import JOULES_PER_MOVE, Plan, Problem, validate
from planner_svc.planners import as_problem
from planner_svc.planners.rules import legal_xy, xy


def run(planner, scenario):
    plan = planners.get(planner).plan(load(scenario))
    validate(plan)
    return plan


def test_thesis6_serial_reaches_the_goal():
    # Thesis §5.2.2 / Fig. 5-9 shows time steps 1..9, where "time step 1" is the initial
    # configuration (Test_All_S01 plots before each move): 8 moves.
    plan = run("thesis-serial", "thesis-6")
    assert plan.ok and len(plan.steps) == 8 and plan.moves == 8
    assert plan.energy_joules == pytest.approx(8 * JOULES_PER_MOVE)


def test_thesis6_parallel_fewer_steps_same_moves():
    # "six time steps" counted the same way: 5 parallel steps, the serial move count.
    plan = run("thesis-parallel", "thesis-6")
    assert plan.ok and len(plan.steps) == 5 and plan.moves == 8
    assert max(len(s) for s in plan.steps) == 2


def test_thesis12_serial():
    plan = run("thesis-serial", "thesis-12")
    assert plan.ok and plan.moves == 20


def test_thesis6_reverse_the_thesis_planner_stalls_and_says_so():
    for name in ("thesis-serial", "thesis-parallel"):
        plan = run(name, "thesis-6-reverse")
        assert not plan.ok
        assert plan.reason.startswith("no more possible motion at step 2")
    # Parallel mode refuses the pair that would strand a module (thesis Fig. 5-10).
    par = run("thesis-parallel", "thesis-6-reverse")
    assert any("disconnected" in n for n in par.notes)


@pytest.mark.parametrize("scenario", ["thesis-6", "thesis-6-reverse", "thesis-12"])
def test_complete_reaches_the_goal(scenario):
    plan = run("complete", scenario)
    assert plan.ok, plan.reason


def test_exact_is_optimal_on_thesis6():
    plan = run("exact", "thesis-6")
    assert plan.ok and plan.moves == 8
    rev = run("exact", "thesis-6-reverse")
    assert rev.ok and rev.moves <= run("complete", "thesis-6-reverse").moves


def test_exact_estimates_the_assignment_bound_and_stays_fewest_moves():
    # The estimate is the benchmark's lower bound taken from each configuration: thesis-12
    # (18 moves) within 5000 configurations (nearest goal cells needed 168 171), and on
    # small random blobs A* with it finds as few moves as a plain breadth-first search.
    plan = planners.get("exact").plan(load("thesis-12"))
    assert plan.ok and plan.moves == 18
    limited = Plan("exact", as_problem(load("thesis-12")))
    exact.plan_exact(limited, max_configurations=5000)
    assert limited.ok and limited.moves == 18
    for seed in range(6):
        p = random_problem(5, seed)
        start, goal = frozenset(xy(c) for c in p.initial), frozenset(xy(c) for c in p.goal)
        region = exact.region_around(set(start | goal), exact.DEFAULT_MARGIN)
        path, _ = exact.search_moves(start, goal, xy(p.fixed), set(), region, 10 ** 5)

        def successors(conf):
            for _, m, rule in legal_xy(set(conf), xy(p.fixed), set()):
                dest = (m[0] + GOAL_OFFSET[rule][0], m[1] + GOAL_OFFSET[rule][1])
                if dest in region:
                    yield m, rule, conf - {m} | {dest}
        plain, _ = exact.best_first(start, successors, lambda c: c == goal,
                                     lambda g, c: g, 10 ** 5)
        assert path is not None and plain is not None and len(path) == len(plain)


def test_complete_takes_the_fewest_moves_on_small_fleets_when_the_search_finds_them(
        monkeypatch):
    # thesis-12: the heuristics plan 19 moves; re-planned in windows, 18, and the exact
    # search proves that no plan is shorter. Without the windows, it finds those 18
    # within its budget. Scrambled 10 seed 2: no plan is shorter, and the search proves
    # it. With too small a budget the heuristics' plan stays, and nothing is claimed.
    plan = run("complete", "thesis-12")
    assert plan.moves == 18 and plan.notes[-2].startswith(shorten.WINDOWS_NOTE)
    assert plan.notes[-1] == ("exact search: no plan within 3 cells of start and goal has "
                              "fewer than these 18 moves")
    with monkeypatch.context() as m:
        m.setattr(shorten, "WINDOW_ROUNDS", 0)
        plan = run("complete", "thesis-12")
    assert plan.moves == 18 and plan.notes[-1] == (
        "exact search: 18 moves, the fewest within 3 cells of start and goal (the heuristics "
        "planned 19)")
    p = random_scrambled_problem(10, 2)
    proved = planners.get("complete").plan(p)
    assert proved.moves == 12 and proved.notes[-1] == (
        "exact search: no plan within 3 cells of start and goal has fewer than these 12 moves")
    heuristic = Plan("complete", as_problem(load("thesis-12")))
    phases._plan_phases(heuristic, phases.EXACT_LIMIT)
    shorten.shorten(heuristic)
    assert heuristic.moves == 19
    assert exact.fewer_moves(heuristic, max_configurations=100) is None and heuristic.moves == 19
    assert exact.fewer_moves(heuristic) is True and heuristic.moves == 18
    validate(heuristic)
    assert exact.fewer_moves(heuristic) is False and heuristic.moves == 18


def test_exact_proves_unreachable():
    # The free module's only two destinations are walled off by obstacles.
    blocked = Problem.of({(0, 0), (1, 0)}, {(0, 0), (-1, 0)}, (0, 0),
                         obstacles={(0, 1), (1, -1)})
    plan = planners.get("exact").plan(blocked)
    assert not plan.ok and plan.reason.startswith("unreachable")
    plan = planners.get("complete").plan(blocked)
    assert not plan.ok and plan.reason.startswith("unreachable")


def test_registry_and_unknown_names():
    assert planners.names()[:2] == ["thesis-serial", "thesis-parallel"]
    with pytest.raises(planners.UnknownPlanner, match="thesis-serial, thesis-parallel"):
        planners.get("nope")
    with pytest.raises(planners.UnknownPlanner, match="script:"):
        planners.get("script:moves.txt")


def test_cli_list_and_plan(capsys, tmp_path):
    assert main(["plan", "--list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in out] == planners.names() + ["script:<file>"]
    png = tmp_path / "plan.png"
    assert main(["plan", "thesis-6", "--planner", "thesis-parallel", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "steps 5, moves 8" in out and "joint" in out and "energy" in out
    assert png.stat().st_size > 1000 and png.read_bytes()[:4] == b"\x89PNG"


def test_cli_errors_exit_2(capsys):
    assert main(["plan", "thesis-6", "--planner", "nope"]) == 2
    assert "planners: thesis-serial" in capsys.readouterr().err
    assert main(["plan", "no-such-scenario"]) == 2
    assert main(["plan"]) == 2


def test_cli_reports_a_stall_with_exit_1(capsys):
    assert main(["plan", "thesis-6-reverse"]) == 1
    assert "no more possible motion at step 2" in capsys.readouterr().out
