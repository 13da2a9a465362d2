"""Planners behind one interface, and their registry.

``get(name).plan(problem_or_scenario) -> Plan``. Names: ``thesis-serial``,
``thesis-parallel``, ``exact``, ``complete``, ``walter``. ``script:<file>`` planners are not
planners of this kind: they drive a fleet frame by frame (:mod:`planner_svc.script`,
run by ``hexbench run``), so :func:`get` refuses them with that explanation.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Protocol

from bus.errors import HexbenchError
from bus.lattice import Cell

from . import thesis
from .plan import Plan, Problem
from .rules import Move, apply_step, move_violation, xy


class Planner(Protocol):
    """Anything that turns a problem into a plan."""

    name: str
    description: str

    def plan(self, problem) -> Plan:  # Problem or bus.scenario.Scenario
        ...


class UnknownPlanner(HexbenchError, KeyError):
    """A planner name that is not registered; the message lists the names."""

    def __str__(self) -> str:
        return str(self.args[0])


def as_problem(problem) -> Problem:
    """Accept a :class:`Problem`, a :class:`bus.scenario.Scenario` or a
    ``(initial, goal, fixed[, obstacles])`` tuple."""
    if isinstance(problem, Problem):
        return problem
    if isinstance(problem, tuple):
        return Problem.of(*problem)
    return Problem.from_scenario(problem)


@dataclass
class FunctionPlanner:
    """A planner made of a name, a description and a function filling a :class:`Plan`."""

    name: str
    description: str
    run: Callable[[Plan], None]

    def plan(self, problem) -> Plan:
        p = as_problem(problem)
        plan = Plan(self.name, p)
        t0 = time.perf_counter()
        if p.initial == p.goal:
            plan.ok = True
        else:
            self.run(plan)
        plan.seconds = time.perf_counter() - t0
        return plan


# --- the thesis planner ---------------------------------------------------------------------
def _max_steps(p: Problem) -> int:
    return 20 * len(p.initial) + 50


def _thesis(plan: Plan, parallel: bool) -> None:
    """``HexAll_S`` / ``HexAll_P`` run until the goal or a stall."""
    p = plan.problem
    occ = set(p.initial)
    seen = {frozenset(occ)}
    for step in range(1, _max_steps(p) + 1):
        electrons, voids = thesis.electrons_and_voids(occ, p.goal)
        me = thesis.mobile_electrons(electrons, occ)
        pv = thesis.potential_voids(voids, occ, me)
        if not me or not pv:
            what = "no mobile electron" if not me else "no potential void"
            plan.reason = f"no more possible motion at step {step} ({what})"
            return
        pairs = thesis.void_propagation(occ, p.goal, p.obstacles)
        if not pairs:
            plan.reason = f"no more possible motion at step {step} (no void wave reaches a mobile electron)"
            return
        chosen: list[Move] = []
        problems: list[str] = []
        for pair in (pairs if parallel else pairs[:1]):
            nxt, _ = thesis.next_location(occ, p.goal, pair.electron, pair.void, p.obstacles)
            if nxt == pair.electron:
                problems.append(f"electron {pair.electron} is best off staying (void {pair.void})")
                continue
            mv = thesis.actuation(occ, pair.electron, nxt, p.fixed, p.obstacles)
            if mv is None:
                problems.append(f"no legal Table 4-3 rotation {pair.electron}->{nxt}")
                continue
            # Parallel mode: refuse a move that would collide with, or disconnect the
            # structure together with, the moves already accepted for this step.
            trial = chosen + [mv]
            clash = next((why for k, m in enumerate(trial)
                          if (why := move_violation(occ, m, p.fixed, p.obstacles,
                                                    trial[:k] + trial[k + 1:]))), None)
            if clash:
                problems.append(f"refused {mv} in parallel: {clash}")
                continue
            chosen.append(mv)
        for msg in problems:
            plan.notes.append(f"step {step}: {msg}")
        if not chosen:
            plan.reason = f"no more possible motion at step {step} ({problems[0]})"
            return
        plan.steps.append(chosen)
        occ = {Cell(*c) for c in apply_step({xy(c) for c in occ}, chosen)}
        if occ == set(p.goal):
            plan.ok = True
            return
        key = frozenset(occ)
        if key in seen:
            plan.reason = f"no progress: step {step} repeats an earlier configuration"
            return
        seen.add(key)
    plan.reason = f"gave up after {_max_steps(p)} steps"


def _thesis_serial(plan: Plan) -> None:
    _thesis(plan, parallel=False)


def _thesis_parallel(plan: Plan) -> None:
    _thesis(plan, parallel=True)


def _exact(plan: Plan) -> None:
    from .exact import plan_exact
    plan_exact(plan)


def _complete(plan: Plan) -> None:
    from .complete import plan_complete
    plan_complete(plan)


def _walter(plan: Plan) -> None:
    from .walter.plan import plan_walter
    plan_walter(plan)


PLANNERS: dict[str, FunctionPlanner] = {
    p.name: p for p in (
        FunctionPlanner("thesis-serial", "thesis five-layer planner, one move per time step "
                        "(HexAll_S); may stall", _thesis_serial),
        FunctionPlanner("thesis-parallel", "thesis planner, every matched pair per step "
                        "(HexAll_P), refusing moves that collide or disconnect; may stall",
                        _thesis_parallel),
        FunctionPlanner("exact", "A* over configurations, fewest moves; small fleets only; "
                        "proves unreachability within its search region", _exact),
        FunctionPlanner("complete", "electrons walk the surface to voids (pocket-safe fill "
                        "order, reverse-problem retry); exact search finishes small stuck "
                        "cases; large stuck cases are reported, not claimed unreachable; detours "
                        "dropped from the plan",
                        _complete),
        FunctionPlanner("walter", "Walter, Tsai & Amato: I a straight chain; the admissible "
                        "substrate path of lowest cost that bisects G, then lockstep rounds in "
                        "which every module moves itself (the round model's moves)", _walter),
    )
}

#: ``hexbench run --planner walter`` does not execute this planner's plan move by move: the PC
#: checks the goal and beats the rounds and the modules decide their moves
#: (``PlannerService._run_walter``, planner_svc.rounds); ``hexbench plan`` shows its plan.
WALTER = "walter"


def progress_unit(planner: str) -> str:
    """What a run's progress counts in (``PlannerProgress.step``): a Walter run's step is a
    beat, one lockstep round in which many modules move; a central plan's is a step."""
    return "round" if planner == WALTER else "step"


#: The planner of a run or a plan when neither the command nor the scenario names one.
DEFAULT = "thesis-serial"

#: Prefix of the script planners (:mod:`planner_svc.script`).
SCRIPT_PREFIX = "script:"
SCRIPT_DESCRIPTION = ("one PC action per line (send, select, wait, expect) against a fleet: "
                      "hexbench run <scenario> --planner script:<file>")


def names() -> list[str]:
    return list(PLANNERS)


def get(name: str) -> Planner:
    """The planner called ``name``; :class:`UnknownPlanner` lists the choices otherwise."""
    if name in PLANNERS:
        return PLANNERS[name]
    if name.startswith(SCRIPT_PREFIX):
        raise UnknownPlanner(f"planner {name!r}: a script drives a fleet frame by frame and "
                             "makes no offline plan; run it with 'hexbench run <scenario> "
                             f"--planner {name}'")
    raise UnknownPlanner(f"unknown planner {name!r}; planners: {', '.join(PLANNERS)}")
