"""``hexbench fleet <scenario>``: the world and its virtual modules on the bus, nothing else.

An external planner (``hexbench planner``), a serial bridge (``hexbench hil``) or a
recorder (``hexbench record``) joins the same fleet over zenoh.
"""

from __future__ import annotations

import argparse
import os
import signal
import time
from typing import Any, Callable

from bus import UsageError, add_bus_arguments, open_bus

#: The console says a fleet's lag at most this often (the first time at once).
LAG_SAY_EVERY_S = 30.0
#: Tests only: ``K=CODE`` makes shard K exit with CODE once its run is over, as a shard that
#: fails after the last window would (tests/world/test_sharded_run.py).
SHARD_EXIT_ENV = "HEXBENCH_TEST_SHARD_EXIT"


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
    p.add_argument("--program", choices=["model", "firmware", "simavr"], help="what virtual modules run")
    p.add_argument("--shard", metavar="K/N",
                   help="with --clock virtual: run part K of N of the fleet (its modules and its "
                        "part of the world) on a lockstep clock shared with the other parts and "
                        "the planner's process ('hexbench run --shards N' starts them; docs/bus.md)")
    add_bus_arguments(p)
    p.set_defaults(func=cmd_fleet)


def cmd_fleet(args: argparse.Namespace) -> int:
    from bus.scenario import ScenarioError, load, override
    from bus.timing import NS_PER_S
    from module_sim.fleet import Fleet

    try:
        sc = override(load(args.scenario), seed=args.seed, profile=args.profile, faults=args.fault,
                      real=args.real, program=args.program)
    except (ScenarioError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    if args.shard is not None:
        return _shard(args, sc)
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
        if fleet.program_note:
            print(fleet.program_note, flush=True)
        if args.clock == "wall":
            LagNotice(bus)
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


def _shard(args: argparse.Namespace, sc) -> int:
    """One part of a fleet on a lockstep clock, until the planner's process ends the run."""
    from bus.lockstep import Lockstep, LockstepClock
    from bus.timing import NS_PER_S
    from module_sim.fleet import Fleet
    from module_sim.shards import LAGS, parse_shard, participants, shard_name, window_ns

    try:
        k, n = parse_shard(args.shard)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    check_shardable(sc, n)
    if args.clock != "virtual":
        raise UsageError("--shard runs on the virtual clock (a lockstep clock shared by the shards): "
                         "give --clock virtual")
    w = window_ns(sc.ir_baud)
    bus = open_bus(args, LockstepClock())
    clock = bus.clock
    step = None
    try:
        fleet = Fleet(bus, sc, shard=(k, n), slack_ns=2 * w)
        step = Lockstep(bus, shard_name(k), participants(n), w, lags=LAGS)
        fleet.power_up(freeze_gc=len(fleet.modules) >= 200)
        print(f"shard {k}/{n} of {sc.name}: modules {', '.join(f'm{i}' for i in sorted(fleet.modules))}; "
              f"window {w / 1e6:g} ms", flush=True)
        clock.run()
        moves = sum(1 for o in fleet.world.mechanics.outcomes
                    if type(o).__name__ == "MoveCompleted" and o.module in fleet.world.own)
        print(f"shard {k}/{n}: ended at {clock.now_ns() / NS_PER_S:.3f} s sim after {step.window} windows; "
              f"{moves} moves of its modules, {fleet.world.collisions} IR collisions, "
              f"{sum(m.ir_conflicts for m in fleet.modules.values())} IR conflicts", flush=True)
    finally:
        if step is not None:
            step.close()
        bus.close()
    return _test_exit_code(k)


def _test_exit_code(k: int) -> int:
    """0, or what :data:`SHARD_EXIT_ENV` says shard ``k`` ends with."""
    shard, _, code = os.environ.get(SHARD_EXIT_ENV, "").partition("=")
    return int(code) if shard == str(k) and code else 0


def check_shardable(sc, n: int) -> None:
    """What a fleet spread over shards cannot have (``UsageError`` saying why)."""
    if n < 1 or n > len(sc.modules):
        raise UsageError(f"{n} shards for {len(sc.modules)} modules: give 1 to {len(sc.modules)}")
    real = [f"m{m.id}" for m in sc.modules if m.kind != "virtual"]
    if real:
        raise UsageError(f"scenario {sc.name!r} has real or firmware modules ({', '.join(real)}): "
                         "shards run virtual modules only")
    if sc.bit_error_rate:
        raise UsageError(f"scenario {sc.name!r} has a bit error rate: its seeded noise follows the order "
                         "light arrives in, which shards change; run it in one process")


class LagNotice:
    """A fleet's ``lag`` events (``event/fleet``, :class:`module_sim.fleet.LagWatch`) said on
    the console, at most once every :data:`LAG_SAY_EVERY_S`; the worst of them for a failure
    line (:meth:`cause`)."""

    def __init__(self, bus: Any, say: Callable[[str], None] | None = None) -> None:
        from module_sim.fleet import LAG_SRC

        self.say = say or (lambda line: print(line, flush=True))
        self.worst_ns = 0
        self._said_at: float | None = None
        bus.subscribe_json(bus.keys.event(LAG_SRC), self._on_event)

    def _on_event(self, key: str, d: dict) -> None:
        if d.get("kind") != "lag":
            return
        late, timers, deliveries = int(d["late_ns"]), int(d["timer_late_ns"]), int(d["delivery_late_ns"])
        self.worst_ns = max(self.worst_ns, late)
        now = time.monotonic()
        if self._said_at is not None and now - self._said_at < LAG_SAY_EVERY_S:
            return
        self._said_at = now
        self.say(f"lag: the fleet ran {late / 1e6:.0f} ms behind the wall clock (timers up to "
                 f"{timers / 1e6:.0f} ms late, deliveries {deliveries / 1e6:.0f} ms; more than "
                 f"{int(d['threshold_ns']) / 1e6:.0f} ms is lag): the machine is overloaded, and a "
                 "timeout from now on may be this rather than a protocol fault")

    def cause(self) -> str:
        """`` (the fleet ran up to 85 ms behind the wall clock: the machine was overloaded)``
        for a failure line, or "" if it never fell behind."""
        if not self.worst_ns:
            return ""
        return (f" (the fleet ran up to {self.worst_ns / 1e6:.0f} ms behind the wall clock: the "
                "machine was overloaded)")
