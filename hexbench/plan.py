"""``hexbench plan`` (plan offline and print it), ``hexbench run`` (a whole run) and
``hexbench planner`` (the planner service alone, joining a fleet over zenoh)."""

from __future__ import annotations

import argparse
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="plan a reconfiguration offline and print the moves",
                       description="Plan a scenario offline: print steps, moves, planning time, "
                                   "estimated energy and every move (joint, direction, substrate, "
                                   "joints the neighbours release).")
    p.add_argument("scenario", nargs="?", help="a built-in scenario name or a .toml file")
    p.add_argument("--planner", default=None,
                   help="planner name (see --list); default the scenario's, else thesis-serial")
    p.add_argument("--png", help="also draw the plan, one panel per step, to this PNG file")
    p.add_argument("--list", action="store_true", help="list the planners and exit")
    p.set_defaults(func=cmd_plan)

    from .run import add_run_arguments, cmd_run
    p = sub.add_parser("run", help="run a scenario: world, virtual fleet, planner (and recorder)",
                       description="Boot the fleet, bring it up over the centre IR channel, plan, "
                                   "command every move and verify it against the world. Prints "
                                   "progress (step, moves, goal cells filled). Exit 0 when the "
                                   "goal is reached, 1 with the reason otherwise.")
    add_run_arguments(p, with_fleet=True)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("planner", help="the planner service alone, joining a fleet on the bus",
                       description="The PC on the bus: bring up, plan, actuate and verify a fleet "
                                   "that runs in another process ('hexbench fleet <scenario> "
                                   "--clock wall').")
    add_run_arguments(p, with_fleet=False)
    p.set_defaults(func=lambda args: cmd_run(args, with_fleet=False))


def cmd_plan(args: argparse.Namespace) -> int:
    from bus.errors import UsageError
    from bus.scenario import ScenarioError, load

    from planner_svc import planners
    from planner_svc.planners.plan import PlanError, check_reach, validate

    if args.list:
        for name in planners.names():
            print(f"{name:16} {planners.PLANNERS[name].description}")
        print(f"{'script:<file>':16} {planners.SCRIPT_DESCRIPTION}")
        return 0
    if not args.scenario:
        raise UsageError("give a scenario (see 'hexbench scenarios') or --list")
    try:
        scenario = load(args.scenario)
    except ScenarioError as exc:
        raise UsageError(str(exc)) from None
    name = args.planner or scenario.planner or planners.DEFAULT
    try:
        planner = planners.get(name)
    except planners.UnknownPlanner as exc:
        raise UsageError(str(exc)) from None
    try:
        plan = planner.plan(scenario)
    except PlanError as exc:
        raise UsageError(str(exc)) from None
    validate(plan)  # every planner's output goes through the one rule; a failure is a bug
    print(plan.summary())
    early = plan.notes if name == "walter" else []  # its substrate path and rounds come first
    for note in early:
        print(f"note: {note}")
    for n, step in enumerate(plan.steps, 1):
        for mv in step:
            print(f"step {n:3}: {mv.describe()}")
    for note in plan.notes[len(early):]:
        print(f"note: {note}")
    if args.png and name == "walter":
        from planner_svc.planners.walter import choose
        from planner_svc.planners.walter.draw import draw_walter
        if plan.ok or plan.steps:
            print(f"drawing: {draw_walter(choose(plan.problem.goal, sorted(plan.problem.initial)), args.png)}")
    elif args.png:
        from planner_svc.planners.draw import draw_plan
        print(f"drawing: {draw_plan(plan, args.png)}")
    try:
        check_reach(plan, scenario.reach)
    except PlanError as exc:
        print(f"hexbench plan: {exc} ('hexbench run' refuses it)", file=sys.stderr)
        return 1
    return 0 if plan.ok else 1
