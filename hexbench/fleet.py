"""``hexbench fleet <scenario>``: the world and its virtual modules on the bus, nothing else.

An external planner (``hexbench planner``), a serial bridge (``hexbench hil``) or a
recorder (``hexbench record``) joins the same fleet over zenoh.
"""

from __future__ import annotations

import argparse
import signal

from bus import UsageError, add_bus_arguments, open_bus


def register(sub: argparse._SubParsersAction) -> None:

    p = sub.add_parser("fleet", help="run the world and the virtual modules of a scenario",
                       description="Power up the world and every virtual module of a scenario on "
                                   "the bus and keep them running (Ctrl-C or --seconds to stop) "
                                   "for a planner, a serial bridge or a recorder in other processes.")
    p.add_argument("scenario", help="a built-in scenario name or a .toml file")
    p.add_argument("--clock", choices=["wall", "virtual"], default="wall",
                   help="wall (default): real time, for other processes; virtual: run --seconds "
                        "of sim time as fast as possible in this process")
    p.add_argument("--seconds", type=float, help="stop after this many seconds (sim seconds if virtual)")
    p.add_argument("--profile", choices=["v2", "thesis-2009"], help="override the scenario's profile")
    p.add_argument("--seed", type=int, help="override the scenario's seed")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                   help="inject an actuator fault, e.g. m3.S2-:off (repeatable)")
    p.add_argument("--real", action="append", default=[], metavar="ID=PORT[,DEBUG_PORT]",
                   help="module ID is a real board (bridged by 'hexbench hil'): the world runs "
                        "its twin; repeatable")
    add_bus_arguments(p)
    p.set_defaults(func=cmd_fleet)


def cmd_fleet(args: argparse.Namespace) -> int:
    from bus.scenario import ScenarioError, load, override
    from bus.timing import NS_PER_S
    from module_sim.fleet import Fleet

    try:
        sc = override(load(args.scenario), seed=args.seed, profile=args.profile, faults=args.fault,
                      real=args.real)
    except (ScenarioError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    if args.clock == "virtual" and args.seconds is None:
        raise UsageError("--clock virtual needs --seconds: nothing else can join a virtual run")
    bus = open_bus(args)
    clock = bus.clock
    try:
        fleet = Fleet(bus, sc)
        fleet.power_up()
        virtual = sum(1 for m in sc.modules if m.kind == "virtual")
        print(f"fleet {sc.name}: {virtual} virtual module(s), profile {sc.profile}, clock "
              f"{args.clock}, keys {bus.keys.all}", flush=True)
        signal.signal(signal.SIGTERM, lambda *_: clock.stop())
        try:
            if args.clock == "virtual":
                clock.run(until_ns=int(args.seconds * NS_PER_S))
            else:
                clock.run(timeout_s=args.seconds)
        except KeyboardInterrupt:
            pass
        run = fleet.world.mechanics.publish_run_energy()
        moves = sum(1 for o in fleet.world.mechanics.outcomes if type(o).__name__ == "MoveCompleted")
        print(f"fleet {sc.name}: stopped at {(clock.now_ns() - clock.started_ns) / NS_PER_S:.1f} s; "
              f"{moves} moves, {fleet.world.collisions} IR collisions, {run.total_j:.1f} J",
              flush=True)
    finally:
        bus.close()
    return 0
