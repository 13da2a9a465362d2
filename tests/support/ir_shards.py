"""Two bytes that collide at the PC's receiver, sent from two shards (issue 50, item 10).

Byte X (0x0F) leaves m1's centre transceiver at 25 ms, byte Y (0xF0) m2's at 31 ms: they
overlap at the PC, so one process decodes X garbled, 0x01 (its bits 1-3 are sampled while
Y's carrier holds the line low). Over shards ``s0`` sends X,
``s1`` sends Y, and ``pc`` runs the PC's part of the world (the medium at its receiver) and
an :class:`bus.ir.IrReceiver`; each is a process (``python -m tests.support.ir_shards NAME``)
on a lockstep clock with the run's windows and lags (:mod:`module_sim.shards`), or the given
ones. ``pc`` writes what its receiver delivered and how many corrections came too late.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from bus import SessionOptions, VirtualClock
from bus.clock import Clock
from bus.ir import IrReceiver, IrTransmitter
from bus.scenario import load
from bus.timing import byte_time_ns
from bus.transport import Bus

#: who sends what when: (participant, source, byte, start)
SENT = [("s0", "m1.comm", 0x0F, 25_000_000), ("s1", "m2.comm", 0xF0, 31_000_000)]
UNTIL_NS = 200_000_000


def sender(bus: Bus, me: str) -> None:
    """The bursts of participant ``me``, each put when its byte starts (as a module's UART)."""
    sc = load("pair")
    for who, src, value, start in SENT:
        if who == me:
            tx = IrTransmitter(bus.put, bus.keys.ir_tx(src), src)
            bus.clock.call_at(start, tx.send, 0, bytes([value]), [start], byte_time_ns(sc.ir_baud))


def receiver(bus: Bus, slack_ns: int) -> tuple[list[list[Any]], IrReceiver]:
    """The PC's part of the world and a receiver: the bytes it delivers, as
    ``[stop bit, value, corrupt]``."""
    from module_sim.world import World

    World(bus, load("pair"), own=set(), pc=True, physics=False, slack_ns=slack_ns)
    got: list[list[Any]] = []
    clock: Clock = bus.clock
    rx = IrReceiver(clock, lambda k, value, start, bad: got.append([clock.now_ns(), value, bad]))
    bus.subscribe(bus.keys.ir_rx("pc"), rx.on_message)
    return got, rx


def one_process(fleet: str) -> list[list[Any]]:
    """All three on one virtual clock: the reference."""
    bus = Bus(VirtualClock(), fleet, options=SessionOptions(isolated=True))
    try:
        got, _ = receiver(bus, 0)
        for me in ("s0", "s1"):
            sender(bus, me)
        bus.clock.run(until_ns=UNTIL_NS)
    finally:
        bus.close()
    return got


def main(argv: list[str] | None = None) -> int:
    from bus.lockstep import Lockstep, LockstepClock
    from module_sim.shards import LAGS, PLANNER, participants, window_ns

    p = argparse.ArgumentParser()
    p.add_argument("name", choices=participants(2))
    p.add_argument("--fleet", required=True)
    p.add_argument("--out")
    p.add_argument("--window-ns", type=int, help="default: the run's (module_sim.shards.window_ns)")
    p.add_argument("--no-lags", action="store_true", help="every participant in the same window")
    args = p.parse_args(argv)
    w = args.window_ns or window_ns(load("pair").ir_baud)
    bus = Bus(LockstepClock(), args.fleet, options=SessionOptions())
    got, rx = receiver(bus, 2 * w) if args.name == PLANNER else ([], None)
    if args.name != PLANNER:
        bus.subscribe(f"{bus.keys.root}/nothing", lambda k, p: None)
        sender(bus, args.name)
    step = Lockstep(bus, args.name, participants(2), w, timeout_s=60, lags=None if args.no_lags else LAGS)
    try:
        # the planner's process ends the run, as in hexbench run --shards
        step.run(until_ns=(UNTIL_NS // w + 1) * w if args.name == PLANNER else None)
    finally:
        if args.out:
            with open(args.out, "w") as f:
                json.dump({"got": got, "conflicts": rx.conflicts if rx else 0, "windows": step.window}, f)
        step.close()
        bus.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
